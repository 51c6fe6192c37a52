"""Faults of the machine worded for the user: one line naming the file and the fix.

A full disk, a read-only or forbidden folder, a name too long for the file system, memory
that runs out: nothing in ineid is wrong, and a traceback would only hide the one fact the
user needs. :func:`describe_fault` recognises them, in Python's own ``OSError`` and in
h5py's wrapped forms (``OSError``/``RuntimeError`` whose message carries HDF5's
``errno = 28`` and ``name = '...'``); the CLI prints the line it returns (exit status 1).
Anything else keeps its traceback: it is a bug.

:func:`require_disk` and :func:`require_memory` refuse a big write or allocation before it
starts, with the sizes in the message.

Imports only the standard library and :mod:`ineid._temporary` (itself standard library only; ``ineid --help``
loads this module).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
from pathlib import Path

from ineid._temporary import target_name
from ineid.errors import ResourceError, StorageError

FAULT_ERRNOS = (
    errno.ENOSPC,
    errno.EDQUOT,
    errno.EFBIG,
    errno.EROFS,
    errno.EACCES,
    errno.EPERM,
    errno.ENAMETOOLONG,
    errno.EIO,
)
"""The ``errno`` values :func:`describe_fault` words for the user."""

_ERRNO = re.compile(r"\berrno\s*=\s*(\d+)")
_NAME = re.compile(r"\b(?:file)?name\s*=\s*'([^']*)'")
_SHOWN_CHARS = 120


def fault_errno(exc: BaseException) -> int | None:
    """The ``errno`` of a file-system fault in ``exc`` (one of :data:`FAULT_ERRNOS`), else None.

    HDF5's errors reach Python as h5py ``OSError``s (``errno`` set, usually) or
    ``RuntimeError``s (``errno = N`` only in the text); both are recognised.
    """
    if not isinstance(exc, (OSError, RuntimeError)):
        return None
    code = exc.errno if isinstance(exc, OSError) else None
    if code not in FAULT_ERRNOS:
        found = _ERRNO.search(str(exc))
        code = int(found.group(1)) if found else None
    return code if code in FAULT_ERRNOS else None


def fault_path(exc: BaseException) -> str | None:
    """The file a fault is about, temporary names mapped back to their target; None if unknown."""
    name = getattr(exc, "filename", None)
    if name is None:
        found = _NAME.search(str(exc))
        name = found.group(1) if found else None
    if name is None:
        return None
    path = Path(os.fsdecode(name))
    target = target_name(path.name)
    return str(path.with_name(target) if target else path)


def _in_cache(path: str | None) -> bool:
    if path is None:
        return False
    try:
        from ineid.cache import cache_dir  # standard library only

        return Path(path).resolve().is_relative_to(cache_dir().resolve())
    except (OSError, ValueError):
        return False


def _shown(path: str | None) -> str:
    if path is None:
        return ""
    return path if len(path) <= _SHOWN_CHARS else f"{path[: _SHOWN_CHARS // 2]}...{path[-_SHOWN_CHARS // 3 :]}"


def describe_fault(exc: BaseException) -> str | None:
    """One line naming a fault the user can fix and how, or None for anything else (a bug).

    Covers the file-system faults of :data:`FAULT_ERRNOS` and running out of memory (NumPy's
    ``MemoryError``, XLA's ``RESOURCE_EXHAUSTED``).
    """
    if isinstance(exc, MemoryError) or (type(exc).__name__ == "JaxRuntimeError" and "RESOURCE_EXHAUSTED" in str(exc)):
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        return f"out of memory ({first}); use fewer configurations (--select) or frames, or a machine with more memory"
    code = fault_errno(exc)
    if code is None:
        return None
    path = fault_path(exc)
    shown = _shown(path)
    where = "point INEID_CACHE_DIR at another folder" if _in_cache(path) else "choose another --out"
    if code in (errno.ENOSPC, errno.EDQUOT):
        what = "no space left on device" if code == errno.ENOSPC else "disk quota exceeded"
        return f"{what}{f' writing {shown}' if path else ''}; free some space or {where}"
    if code == errno.EFBIG:
        return (
            f"file too large for the file system (or the limit of `ulimit -f`){f' writing {shown}' if path else ''}"
            f"; make a smaller output or {where}"
        )
    if code == errno.EROFS:
        return f"{shown or 'the output'} is on a read-only file system; {where}"
    if code in (errno.EACCES, errno.EPERM):
        return (
            f"permission denied: {shown or 'a file or folder'}; check the permissions of the file and its "
            f"folder, or {where}"
        )
    if code == errno.ENAMETOOLONG:
        return f"file name too long for the file system: {shown}; choose a shorter name"
    return (
        f"input/output error{f' on {shown}' if path else ''}: the disk or network file system failed; check it and "
        "retry"
    )


def format_bytes(n: float) -> str:
    """``1536`` -> ``'1.5 KiB'``: binary units, three significant digits."""
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.3g} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def free_disk(path: str | Path) -> int | None:
    """Bytes free for this user in the folder of ``path`` (or the nearest existing parent); None if unknown."""
    folder = Path(path).absolute()
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def require_disk(path: str | Path, nbytes: float, what: str, fix: str) -> None:
    """Raise :class:`StorageError` if ``nbytes`` will not fit beside ``path``.

    Args:
        path: the file about to be written (its folder's file system is checked).
        nbytes: the size it will have (an estimate is fine: the message says "about").
        what: what is written, for the message (``"the results file"``).
        fix: how to make it fit, after "free some space, choose another --out or ...".
    """
    free = free_disk(path)
    if free is not None and nbytes > free:
        raise StorageError(
            f"{what} {path} needs about {format_bytes(nbytes)}, and its disk has {format_bytes(free)} free; "
            f"free some space, choose another --out or {fix}"
        )


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``; else the free pages); None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def require_memory(nbytes: float, what: str, fix: str) -> None:
    """Raise :class:`ResourceError` if ``nbytes`` exceed the memory available now.

    Args:
        nbytes: the size of the allocation (an estimate).
        what: what needs it, for the message (``"resampling to 1e+09 Hz"``).
        fix: how to need less.
    """
    free = available_memory()
    if free is not None and nbytes > free:
        raise ResourceError(
            f"{what} needs about {format_bytes(nbytes)} of memory, more than the {format_bytes(free)} available; {fix}"
        )
