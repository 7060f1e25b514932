"""A headless Chromium driven through the Chrome DevTools Protocol over a pipe (no network, no extra package).

``Browser.find()`` names the browser found on this machine, or None. A :class:`Browser` opens pages, runs
JavaScript, clicks, takes screenshots and keeps every error the page reports (uncaught exceptions,
``console.error`` and the browser's own error log entries).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import tempfile
import time

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserError(RuntimeError):
    """The browser answered a command with an error, or did not answer in time."""


class Browser:
    """One headless browser with one page of ``width`` x ``height`` CSS pixels (WebGL in software).

    Use as a context manager: the browser ends with the ``with`` block.
    """

    def __init__(self, executable: str, width: int = 1280, height: int = 800, timeout: float = 60.0):
        self.timeout = timeout
        self.errors: list[str] = []
        self._profile = tempfile.mkdtemp(prefix="ncjax-browser-")
        self._next_id = 0
        self._events: list[dict] = []
        self._buffer = b""
        to_browser, self._commands = os.pipe()
        self._replies, from_browser = os.pipe()
        arguments = [
            executable,
            "--headless=new",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--remote-debugging-pipe",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            f"--user-data-dir={self._profile}",
            f"--window-size={width},{height}",
            "about:blank",
        ]
        # the protocol's pipe is the browser's file descriptors 3 (commands in) and 4 (replies out)
        actions = [
            (os.POSIX_SPAWN_DUP2, to_browser, 3),
            (os.POSIX_SPAWN_DUP2, from_browser, 4),
            (os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0),
            (os.POSIX_SPAWN_OPEN, 2, os.devnull, os.O_WRONLY, 0),
        ]
        self._pid = os.posix_spawn(executable, arguments, os.environ, file_actions=actions)
        os.close(to_browser)
        os.close(from_browser)
        try:
            page = next(target for target in self.send("Target.getTargets")["targetInfos"] if target["type"] == "page")
            self._session = self.send("Target.attachToTarget", targetId=page["targetId"], flatten=True)["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                self.send(f"{domain}.enable", session=True)
            self.send(
                "Emulation.setDeviceMetricsOverride",
                session=True,
                width=width,
                height=height,
                deviceScaleFactor=1,
                mobile=False,
            )
        except BaseException:
            self.close()
            raise

    @staticmethod
    def find() -> str | None:
        """The path of a Chromium-based browser on this machine, or None."""
        return next((path for path in map(shutil.which, BROWSERS) if path), None)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exception) -> None:
        self.close()

    def close(self) -> None:
        """End the browser (the process this object started) and remove its profile."""
        for descriptor in (self._commands, self._replies):
            try:
                os.close(descriptor)
            except OSError:
                pass
        try:
            os.kill(self._pid, signal.SIGTERM)
            os.waitpid(self._pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
        shutil.rmtree(self._profile, ignore_errors=True)

    # --- the protocol ------------------------------------------------------------------------------------

    def send(self, method: str, session: bool = False, **params) -> dict:
        """Send one command (to the page where ``session``) and return its result."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = self._session
        os.write(self._commands, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._receive(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self._note(reply)

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            if time.monotonic() > deadline:
                raise BrowserError("the browser did not answer in time")
            chunk = os.read(self._replies, 1 << 20)
            if not chunk:
                raise BrowserError("the browser closed its pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def _note(self, event: dict) -> None:
        """Keep the page's errors and its events."""
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            self.errors.append(details.get("exception", {}).get("description") or details.get("text", ""))
        elif method == "Runtime.consoleAPICalled" and params["type"] == "error":
            self.errors.append(" ".join(str(arg.get("value", arg.get("description"))) for arg in params["args"]))
        elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
            self.errors.append(params["entry"]["text"])
        self._events.append(event)

    # --- the page ----------------------------------------------------------------------------------------

    def open(self, url: str) -> None:
        """Load ``url`` and wait for its load event."""
        self._events.clear()
        self.send("Page.navigate", session=True, url=url)
        self.wait_for(lambda: any(event.get("method") == "Page.loadEventFired" for event in self._events))

    def wait_for(self, condition, timeout: float | None = None) -> None:
        """Wait, reading the browser's events, until ``condition()`` holds."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while not condition():
            if time.monotonic() > deadline:
                raise BrowserError("timed out waiting for the page")
            self.evaluate("0")  # a round trip that collects the events sent meanwhile
            time.sleep(0.05)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression on the page (promises awaited)."""
        result = self.send(
            "Runtime.evaluate", session=True, expression=expression, returnByValue=True, awaitPromise=True
        )
        if "exceptionDetails" in result:
            raise BrowserError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def click(self, x: float, y: float, modifiers: int = 0) -> None:
        """A left click at (x, y) CSS pixels (``modifiers``: 1 Alt, 2 Ctrl, 4 Meta, 8 Shift)."""
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.send(
                "Input.dispatchMouseEvent",
                session=True,
                type=kind,
                x=x,
                y=y,
                button="none" if kind == "mouseMoved" else "left",
                clickCount=0 if kind == "mouseMoved" else 1,
                modifiers=modifiers,
            )

    def screenshot(self) -> bytes:
        """The page as PNG bytes."""
        return base64.b64decode(self.send("Page.captureScreenshot", session=True, format="png")["data"])
