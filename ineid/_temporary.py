"""The names ineid makes up beside an output: temporaries, the folder moved aside, and their cleanup.

A file is written under a temporary name beside its target and renamed into place when
complete; a folder is built the same way, and the folder it replaces is moved aside for
the moment of the swap. These names are ineid's own, and ineid never follows a link at
one of them:

- a temporary is ``.NAME.ineid-PID-RANDOM.tmp`` (``RANDOM``: 8 hexadecimal digits from
  :mod:`secrets`), a file keeping the target's suffix (``.tmp.h5``); the folder moved aside
  is ``.NAME.ineid-PID-RANDOM.old``. Nobody can plant a link at a name they cannot guess;
- each is created exclusively (``O_CREAT | O_EXCL | O_NOFOLLOW`` for a file, ``mkdir`` for
  a folder): a name that exists, whatever it is, is never opened, only skipped for another;
- a target name too long to fit in one (a file name of 220 bytes and more) is shortened in
  it to its start and a hash of the whole name (:func:`temporary_stem`), so any legal name
  can be written.

:func:`remove_stale_temporaries` removes what killed runs left: only names of exactly this
pattern, for this target, of processes no longer alive, that are plain files or folders
(never links) owned by the user running ineid.

Imports only the standard library.
"""

from __future__ import annotations

import errno
import hashlib
import logging
import os
import re
import secrets
import shutil
import stat
from pathlib import Path

_log = logging.getLogger("ineid.atomic")

NAME_MAX = 255
"""The longest file name, in bytes, of the common file systems (ext4, XFS, btrfs, tmpfs, APFS, NTFS)."""

MAX_SUFFIX = 16
"""The longest target suffix (bytes, with its dot) a temporary keeps (``.h5``, ``.html``); a longer one is left off."""

_RANDOM_HEX = 8
_HASH_HEX = 8
_TAG = "ineid"
_PID_DIGITS = 10  # room for any process id, so a target's stem is the same whoever writes it
_OVERHEAD = len(f"..{_TAG}--.tmp") + _PID_DIGITS + _RANDOM_HEX + MAX_SUFFIX
_TRIES = 100

TEMPORARY = re.compile(
    rf"\.(?P<stem>.+)\.{_TAG}-(?P<pid>\d+)-[0-9a-f]{{{_RANDOM_HEX}}}\.(?P<kind>tmp|old)(?P<suffix>\.[^.]*)?"
)
"""The full name of every temporary ineid makes (``re.fullmatch``)."""

_long_names: dict[str, str] = {}
"""Shortened stems this process made -> the full target name (to name the target in a fault)."""


def temporary_stem(name: str) -> str:
    """The part of a temporary's name that names its target ``name``: the name itself, or for a long
    one its start, ``~`` and the first hexadecimal digits of its SHA-256, together 208 bytes at most."""
    room = NAME_MAX - _OVERHEAD
    if len(os.fsencode(name)) <= room:
        return name
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:_HASH_HEX]
    head = name
    while len(os.fsencode(head)) > room - 1 - _HASH_HEX:
        head = head[:-1]
    stem = f"{head}~{digest}"
    _long_names[stem] = name
    return stem


def _kept(suffix: str) -> str:
    return suffix if len(os.fsencode(suffix)) <= MAX_SUFFIX else ""


def temporary_path(path: str | Path, suffix: str = "", kind: str = "tmp") -> Path:
    """A new unpredictable temporary name beside ``path``: ``.NAME.ineid-PID-RANDOM.KIND[SUFFIX]``.

    Nothing is created: :func:`create_temporary` and :func:`create_temporary_folder` do, exclusively.
    """
    path = Path(path)
    token = secrets.token_hex(_RANDOM_HEX // 2)
    return path.with_name(f".{temporary_stem(path.name)}.{_TAG}-{os.getpid()}-{token}.{kind}{_kept(suffix)}")


def create_temporary(path: str | Path, suffix: str = "") -> Path:
    """Create a new empty file under a temporary name beside ``path`` and return its name.

    The file is created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (mode 0666 less the umask, as
    any file a writer creates), so it is a file of this process: a writer that opens it by
    name (h5py, matplotlib, ``Path.write_bytes``) writes into it, never through a link.

    Raises:
        OSError: the folder refuses the file (read-only, forbidden, full); ``filename`` is the temporary.
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(_TRIES):
        tmp = temporary_path(path, suffix)
        try:
            os.close(os.open(tmp, flags, 0o666))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(tmp))


def create_temporary_folder(path: str | Path, kind: str = "tmp") -> Path:
    """Create a new empty folder under a temporary name beside ``path`` (``mkdir``: never through a link)."""
    for _ in range(_TRIES):
        folder = temporary_path(path, kind=kind)
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(folder))


def target_name(name: str) -> str | None:
    """The name of the file a temporary named ``name`` is written for, or None if ``name`` is none of ineid's.

    A shortened stem (:func:`temporary_stem`) is mapped back to the full name when this process made it.
    """
    found = TEMPORARY.fullmatch(name)
    return None if found is None else _long_names.get(found["stem"], found["stem"])


def is_temporary(name: str) -> bool:
    """Whether ``name`` is a temporary's (:data:`TEMPORARY`) or a lock file's (``.NAME.lock``)."""
    return TEMPORARY.fullmatch(name) is not None or (name.startswith(".") and name.endswith(".lock"))


# -- what killed writers left --------------------------------------------------------------------


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return pid > 0
    return True


def _size(path: Path) -> int:
    if path.is_dir() and not path.is_symlink():
        return sum(p.lstat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())
    return path.lstat().st_size


def human_size(n: int) -> str:
    """``206 MB``, ``3.1 kB``, ``12 bytes`` (decimal units)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            v = n / scale
            return f"{v:.1f} {unit}" if v < 10 else f"{v:.0f} {unit}"
    return f"{n} bytes"


def _stale(path: Path, entry: Path) -> str | None:
    """``"file"``, ``"folder"`` or ``"old"`` if ``entry`` is a temporary of ``path`` that a dead
    process of this user left, else None (a link, anything else, a live writer's, another user's)."""
    found = TEMPORARY.fullmatch(entry.name)
    if found is None or found["stem"] != temporary_stem(path.name):
        return None
    suffixes = (None,) if found["kind"] == "old" else (None, _kept(path.suffix) or None)
    if found["suffix"] not in suffixes:
        return None
    pid = int(found["pid"])
    if pid == os.getpid() or _alive(pid):
        return None
    try:
        st = entry.lstat()
    except OSError:
        return None
    if hasattr(os, "geteuid") and st.st_uid != os.geteuid():
        return None
    if stat.S_ISDIR(st.st_mode):
        return "old" if found["kind"] == "old" else "folder"
    return "file" if stat.S_ISREG(st.st_mode) and found["kind"] == "tmp" else None


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove the temporaries of ``path`` that processes no longer alive left beside it; one warning each.

    Only names of :data:`TEMPORARY` for ``path`` (its stem, its suffix or none) are looked at,
    and of those only plain files and folders (``lstat``: a link is never followed nor
    removed) owned by the user running ineid, whose process is gone. A process killed in the
    middle of a folder swap (the old folder moved aside as ``.old``, the new one not yet in
    place) leaves no ``path``: its ``.old`` folder is moved back instead. Call it holding the
    output's lock (:func:`ineid._atomic.output_lock` does), so no ineid writer of ``path`` is running.

    Returns:
        The temporaries removed (or moved back).
    """
    path = Path(path)
    prefix = f".{temporary_stem(path.name)}.{_TAG}-"
    try:
        entries = sorted(p for p in path.parent.iterdir() if p.name.startswith(prefix))
    except OSError:
        return []
    done = []
    for entry in entries:
        kind = _stale(path, entry)
        if kind is None:
            continue
        try:
            if kind == "old" and not (path.exists() or path.is_symlink()):
                os.rename(entry, path)
                _log.warning("restored %s from %s, left by an interrupted ineid run", path, entry.name)
            else:
                what = "file" if kind == "file" else "folder"
                size = human_size(_size(entry))
                if what == "folder":
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
                _log.warning(
                    "removed a stale temporary %s %s (%s) left by an interrupted ineid run", what, entry.name, size
                )
        except OSError as e:
            _log.warning("could not remove the stale temporary %s: %s", entry, e.strerror or e)
            continue
        done.append(entry)
    return done
