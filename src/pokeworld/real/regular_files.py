"""Open a file of an untrusted dataset only if it is a regular file, so that no read can hang or touch a device.

A FIFO where a data file is expected blocks ``open`` (or the first read) forever, and a device such as
``/dev/zero`` or ``/dev/urandom`` never ends. Checking the path first (``lstat``) is not enough on its own (the
path could be swapped between the check and the open), and opening with ``O_NONBLOCK`` alone is not enough either
(a FIFO then opens, and reads return nothing or fail, or a device streams forever). So :func:`open_regular` does
both: ``lstat`` refuses anything but a regular file before it is opened (opening some devices has side effects),
then the file is opened with ``O_NONBLOCK`` (a FIFO swapped in cannot block the open) and ``fstat`` of the open
descriptor must again say regular file, after which ``O_NONBLOCK`` is cleared.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO


class NotRegularFileError(OSError):
    """The path exists but is not a regular file (a FIFO, socket, device, directory or dangling entry)."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "FIFO"), (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISDIR, "directory"), (stat.S_ISLNK, "symlink")):
        if test(mode):
            return name
    return "special file"


def check_regular(path: str | os.PathLike) -> os.stat_result:
    """``lstat`` of ``path``; raises :class:`NotRegularFileError` unless it is a regular file (a symlink is refused:
    resolve it first), ``FileNotFoundError`` if it is absent."""
    st = os.lstat(path)
    if not stat.S_ISREG(st.st_mode):
        raise NotRegularFileError(f"{path} is a {_kind(st.st_mode)}, not a regular file")
    return st


def open_regular(path: str | os.PathLike) -> BinaryIO:
    """``open(path, "rb")`` for a regular file only (symlinks are followed; their target must be regular).

    Raises :class:`NotRegularFileError` for anything else, before reading a byte; ``FileNotFoundError`` if absent.
    """
    real = Path(path).resolve()
    check_regular(real)
    fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
                 | getattr(os, "O_BINARY", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotRegularFileError(f"{path} is a {_kind(st.st_mode)}, not a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path: str | os.PathLike, max_bytes: int | None = None) -> bytes:
    """The bytes of a regular file (:func:`open_regular`); ``ValueError`` if it holds more than ``max_bytes``."""
    with open_regular(path) as fh:
        data = fh.read() if max_bytes is None else fh.read(max_bytes + 1)
    if max_bytes is not None and len(data) > max_bytes:
        raise ValueError(f"{path} is larger than {max_bytes} bytes")
    return data


__all__ = ["NotRegularFileError", "check_regular", "open_regular", "read_regular"]
