"""Atomic file writes shared by the dataset writer and the reconstruction outputs."""

from __future__ import annotations

import contextlib
import os
import pathlib
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator


def write_atomic(path: str | os.PathLike, payload: bytes) -> None:
    """Write ``payload`` to a temporary file beside ``path``, then rename it over ``path``.

    The rename is atomic on one file system, so readers see the old file or
    the complete new one; on any error the temporary file is removed and the
    old file is left as it was.
    """
    path = pathlib.Path(path)
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    # os.open with mode 0o666 honours the umask, unlike tempfile's private 0o600 files.
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(descriptor, "wb") as file:
            file.write(payload)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def replace_together(
    folder: str | os.PathLike, owned: Iterable[str] = (), last: str | None = None
) -> Iterator[pathlib.Path]:
    """Write a group of files in a hidden staging folder inside ``folder``, then rename them into ``folder``.

    The body writes the files into the staging folder it is given, under their final names.
    When it returns, each staged file is renamed over ``folder``'s file of that name
    (``os.replace``, atomic per file: the staging folder is on the same file system),
    ``last`` at the end, so that its presence says the others are in place; before ``last``
    is renamed, every name of ``owned`` that was not staged is removed from ``folder`` (the
    group's files of an earlier run that this group no longer has). When the body raises
    (KeyboardInterrupt included), the staging folder is removed and ``folder`` is unchanged.

    Args:
        folder: the existing folder the files end in.
        owned: the names of every file the group can have in ``folder``.
        last: the name renamed last (e.g. the record that lists the others).

    Yields:
        The staging folder.
    """
    staging = pathlib.Path(tempfile.mkdtemp(prefix=".ncjax-", suffix=".partial", dir=folder))
    try:
        yield staging
        staged = sorted(path.name for path in staging.iterdir() if path.is_file())
        first = [name for name in staged if name != last]
        for name in first:
            os.replace(staging / name, pathlib.Path(folder, name))
        for name in sorted(set(owned) - set(staged)):
            pathlib.Path(folder, name).unlink(missing_ok=True)
        if last in staged:
            os.replace(staging / last, pathlib.Path(folder, last))
    finally:
        shutil.rmtree(staging, ignore_errors=True)
