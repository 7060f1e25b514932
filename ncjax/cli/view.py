"""``ncjax view DIR``: a folder of results served on this machine, with an index page, in the browser."""

from __future__ import annotations

import argparse
import functools
import http.server
import os
import sys
import webbrowser

HOST = "127.0.0.1"


class ResultsHandler(http.server.SimpleHTTPRequestHandler):
    """The folder's files, and at ``/`` its index page (:func:`~ncjax.viz.gallery.index_html`), made afresh at
    each request so that results written meanwhile appear."""

    def do_GET(self) -> None:
        if self.path.split("?", 1)[0] not in ("/", "/index.html"):
            super().do_GET()
            return
        from ..viz.gallery import index_html

        page = index_html(self.directory).encode("utf-8")
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(page)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(page)

    def log_message(self, format: str, *args) -> None:
        """Quiet: the requests of one person's browser are not news."""


def results_server(folder: str, port: int = 0) -> http.server.ThreadingHTTPServer:
    """A server of ``folder`` on this machine only (127.0.0.1), at ``port`` (0: a free one); not yet serving.

    Raises:
        FileNotFoundError: ``folder`` is not a folder.
    """
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"no such folder: {folder}")
    handler = functools.partial(ResultsHandler, directory=os.path.abspath(folder))
    return http.server.ThreadingHTTPServer((HOST, port), handler)


def run_view(args: argparse.Namespace) -> int:
    """``ncjax view DIR``: serve the folder until Ctrl-C, after opening its index in the browser."""
    server = results_server(args.folder, args.port)
    url = f"http://{HOST}:{server.server_address[1]}/"
    print(f"serving {os.path.abspath(args.folder)} at {url} (Ctrl-C stops)", flush=True)
    if args.browser and not webbrowser.open(url):
        print(f"no browser could be opened: open {url}", file=sys.stderr)
    with server:
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            print("stopped")
    return 0


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", help="a folder of results (ncjax reconstruct's or ncjax demo's --out)")
    parser.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default: a free one)")
    parser.add_argument(
        "--no-browser", dest="browser", action="store_false", help="only serve; do not open the index in a browser"
    )
