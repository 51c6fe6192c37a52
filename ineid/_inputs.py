"""What ineid reads: only regular files (and folders where a format is a folder), bounded in size.

Opening a FIFO blocks until something writes to it, a character device (``/dev/zero``, ``/dev/urandom``)
never ends, and a socket cannot be read at all: every input a user names is checked here before it is
opened, and a file larger than its format's limit is refused before it is parsed. Each refusal is one
:class:`ineid.errors.InputFileError` line naming the file, what it is, and the fix.

Imports only the standard library and :mod:`ineid.errors` (the foundation layer).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ineid.errors import InputFileError

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str:
    """``"a regular file"``, ``"a FIFO (named pipe)"``, ... for a ``st_mode``."""
    for test, name in _KINDS:
        if test(mode):
            return name
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def regular_file(path: str | os.PathLike, what: str = "the input", *, max_bytes: int | None = None,
                 limit_name: str = "") -> Path:
    """``path`` if it names an existing regular file (symbolic links followed) of at most ``max_bytes``.

    Nothing is opened: ``os.stat`` tells a FIFO or a device from a file without blocking.

    Args:
        path: the file a user named.
        what: what it is, for the message (``"the CSV recording"``).
        max_bytes: the largest size ineid reads for this format (None: no limit).
        limit_name: the limit's name, for the message (``"INPUT_LIMITS.urdf_bytes"``).

    Raises:
        InputFileError: it does not exist, is not a regular file, or is larger than ``max_bytes``.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(f"{what} {path} does not exist; check the path") from None
    except OSError as e:
        reason = e.strerror or e
        raise InputFileError(f"{what} {path} cannot be read ({reason}); check the path and its permissions") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{what} {path} is {file_kind(st.st_mode)}, not a regular file; give a file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputFileError(
            f"{what} {path} is {st.st_size:,} bytes, over the {max_bytes:,} bytes ineid reads for it"
            f"{f' ({limit_name})' if limit_name else ''}; give a smaller file"
        )
    return path
