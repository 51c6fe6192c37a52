"""The output policy: refuse to replace without ``overwrite``, write atomically, clean up on signals.

Every file ineid writes goes through here: :func:`atomic_write` for data in memory,
:func:`atomic_output` for files written by a library (HDF5, matplotlib, CSV writers), and
:class:`ineid.data.write.DatasetWriter` (which uses :func:`temporary_path`) for streamed
datasets. A temporary file beside the target is renamed into place only when complete, so
an exception, Ctrl-C or (once :func:`terminate_on_sigterm` is installed) a scheduler's
SIGTERM leaves either the old file or nothing, never half a file.

Folders (training runs) are built under a hidden name beside the target and swapped in when
complete (:func:`staging_folder`, :func:`replace_folder`). :func:`output_lock` makes a second
process writing the same output stop with one line instead of racing the first, and removes
the temporary files that a killed run (SIGKILL, power loss) left beside the output.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import signal
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from ineid._interrupts import (  # the signals' names, also importable from here
    Terminated as Terminated,
    redeliver_ignored_interrupt as redeliver_ignored_interrupt,
    terminate_on_sigterm as terminate_on_sigterm,
)
from ineid.errors import DatasetError, OutputBusyError, OutputExistsError

_log = logging.getLogger("ineid.atomic")


def check_output(path: str | Path, overwrite: bool) -> Path:
    """Return ``path`` if ineid may write it; :class:`OutputExistsError` if it exists and ``overwrite`` is off.

    The one place that words the refusal, so every command says the same thing.
    """
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{path} exists; pass --overwrite to replace it")
    return path


def check_output_file(path: str | Path, overwrite: bool, example: str) -> Path:
    """:func:`check_output` for a file: also refused, one line each, when ``path`` is a folder (``example`` names a
    file to give instead, ``results.h5``) or its folder does not exist."""
    path = Path(path)
    if path.is_dir():
        raise DatasetError(f"{path} is a folder; give a file name such as {example}")
    check_output(path, overwrite)
    if not path.parent.is_dir():
        raise DatasetError(f"folder {path.parent} does not exist; create it first")
    return path


def temporary_path(path: str | Path) -> Path:
    """The hidden temporary name a file is written under before it replaces ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on a normal exit it replaces ``path``, otherwise it is deleted.

    Writers that append their own suffix (``savefig`` with a format) are given the suffix
    of ``path``, so the temporary file keeps it: ``.name.<pid>.tmp.png``.
    """
    path = Path(path)
    tmp = temporary_path(path)
    if path.suffix:
        tmp = tmp.with_name(tmp.name + path.suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as e:
        # never let the cleanup raise (a read-only folder refuses even the unlink): the
        # first error is the one the user needs to see, naming the file (a failed write()
        # on a full disk does not)
        with suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(e, OSError) and e.filename is None:
            e.filename = str(path)
        raise


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text or bytes) to ``path`` atomically; on failure ``path`` is untouched."""
    with atomic_output(path) as tmp:
        if isinstance(data, str):
            tmp.write_text(data)
        else:
            tmp.write_bytes(data)
    return Path(path)


def write_csv(path: str | Path, fieldnames: list[str], rows: list[dict] | list[list]) -> Path:
    """Write a CSV with a header atomically; ``rows`` are dicts (by field name) or sequences."""
    import csv  # noqa: PLC0415
    import io  # noqa: PLC0415

    buf = io.StringIO(newline="")
    if rows and isinstance(rows[0], dict):
        w = csv.DictWriter(buf, fieldnames=fieldnames)
        w.writeheader()
        w.writerows(rows)
    else:
        w = csv.writer(buf)
        w.writerow(fieldnames)
        w.writerows(rows)
    return atomic_write(path, buf.getvalue())


def save_figure(fig, path: str | Path, **savefig_kwargs) -> Path:
    """``fig.savefig(path)`` atomically, the format taken from the suffix (default PNG)."""
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **savefig_kwargs)
    return path


# -- one writer per output, and what killed writers left ------------------------------------------

_held: dict[str, int] = {}
"""Lock files this process holds (real path -> depth): a library call under the CLI's lock re-enters it."""


def same_path(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` name the same file: :func:`os.path.samefile` when both exist (hard
    links, symlinks, case-insensitive file systems), else the same resolved path."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def lock_path(path: str | Path) -> Path:
    """The hidden lock file of an output: ``.NAME.lock`` beside it."""
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


def _lock_key(lock: Path) -> str:
    return os.path.join(os.path.realpath(lock.parent), lock.name)


def _holder(fd: int) -> str:
    try:
        pid = os.pread(fd, 32, 0).decode().strip()
    except (OSError, UnicodeDecodeError):
        pid = ""
    return f" (pid {pid})" if pid.isdigit() else ""


@contextmanager
def output_lock(path: str | Path, option: str = "--out") -> Iterator[Path]:
    """Hold the exclusive lock of the output ``path`` (a file or a folder) while it is written.

    The lock is ``flock`` on ``.NAME.lock`` beside the output, taken without waiting: a
    second process that asks for it gets :class:`OutputBusyError` naming the holder's pid.
    The kernel drops the lock when its holder dies, however it dies, so a lock file left by
    a killed run blocks nobody. Inside the lock, temporaries of ``path`` left by dead
    processes are removed (:func:`remove_stale_temporaries`). The lock file is removed on
    exit. Re-entrant within a process (the CLI holds it, the library takes it again).

    Where the lock file cannot be created (a read-only or missing folder) nothing is locked:
    the write itself then fails with the reason.

    Raises:
        OutputBusyError: another process holds the lock.
    """
    path = Path(path)
    lock = lock_path(path)
    key = _lock_key(lock)
    if key in _held:
        _held[key] += 1
        try:
            yield path
        finally:
            _held[key] -= 1
        return
    try:
        import fcntl  # noqa: PLC0415  (POSIX; elsewhere outputs are not locked)
    except ImportError:
        yield path
        return
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as e:
            _log.debug("no lock for %s (%s)", path, e)
            yield path
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise OutputBusyError(
                f"another ineid process{holder} is writing {path}; wait for it or choose another {option}"
            ) from None
        except OSError as e:  # a file system without locks (ENOLCK): write unlocked, as where flock is missing
            os.close(fd)
            _log.debug("no lock for %s (%s)", path, e)
            yield path
            return
        try:  # the previous holder may have removed the file between our open and flock: lock the new one
            current = os.stat(lock)
            mine = os.fstat(fd)
            if (current.st_dev, current.st_ino) == (mine.st_dev, mine.st_ino):
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    _held[key] = 1
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        remove_stale_temporaries(path)
        yield path
    finally:
        del _held[key]
        # Unlinked before it is released: a process that opened the old file then sees it is gone and retries.
        # A lock file that cannot be removed (a folder turned read-only meanwhile) blocks nobody once
        # released, and must not hide the command's own error.
        try:
            os.unlink(lock)
        except FileNotFoundError:
            pass
        except OSError as e:
            _log.debug("lock file %s left behind (%s)", lock, e)
        os.close(fd)


_TEMPORARY = re.compile(r"(\d+)\.(tmp|old)(\..*)?")


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
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())
    return path.lstat().st_size


def human_size(n: int) -> str:
    """``206 MB``, ``3.1 kB``, ``12 bytes`` (decimal units)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            v = n / scale
            return f"{v:.1f} {unit}" if v < 10 else f"{v:.0f} {unit}"
    return f"{n} bytes"


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove the temporaries of ``path`` that processes no longer alive left beside it; one warning each.

    Temporaries are ``.NAME.<pid>.tmp*`` (files of :func:`atomic_output`, folders of
    :func:`staging_folder`) and ``.NAME.<pid>.old`` (a folder moved aside by
    :func:`replace_folder`). A process killed in the middle of :func:`replace_folder` (the
    old folder moved aside, the new one not yet in place) leaves no ``NAME``: then its
    ``.old`` folder is moved back instead. Temporaries of live processes are left alone.
    Call it holding the output's lock (:func:`output_lock` does), so no ineid writer of
    ``path`` is running.

    Returns:
        The temporaries removed (or moved back).
    """
    path = Path(path)
    prefix = f".{path.name}."
    try:
        entries = [p for p in path.parent.iterdir() if p.name.startswith(prefix)]
    except OSError:
        return []
    done = []
    for entry in sorted(entries):
        m = _TEMPORARY.fullmatch(entry.name[len(prefix) :])
        if m is None or int(m[1]) == os.getpid() or _alive(int(m[1])):
            continue
        try:
            if m[2] == "old" and not (path.exists() or path.is_symlink()):
                os.rename(entry, path)
                _log.warning("restored %s from %s, left by an interrupted ineid run", path, entry.name)
            else:
                kind = "folder" if entry.is_dir() and not entry.is_symlink() else "file"
                size = human_size(_size(entry))
                if kind == "folder":
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
                _log.warning("removed a stale temporary %s %s (%s) left by an interrupted ineid run", kind, entry.name,
                             size)  # fmt: skip
        except OSError as e:
            _log.warning("could not remove the stale temporary %s: %s", entry, e.strerror or e)
            continue
        done.append(entry)
    return done


# -- folders ------------------------------------------------------------------------------------------


def _real(path: str | Path) -> Path:
    """A symlinked folder is replaced where it points (the link stays)."""
    path = Path(path)
    return path.resolve() if path.is_symlink() else path


def staging_folder(path: str | Path) -> Path:
    """A new empty hidden folder ``.NAME.<pid>.tmp`` beside ``path`` (or beside the folder a
    symlink ``path`` points to) to build its replacement in."""
    path = _real(path)
    staging = temporary_path(path)
    if staging.exists():  # this process's own leftover
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    return staging


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM wait until the block is done (main thread; elsewhere no change)."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    except (AttributeError, ValueError, OSError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def replace_folder(new: str | Path, path: str | Path, keep: tuple[str, ...] | None = None) -> Path:
    """Put the complete folder ``new`` at ``path``, replacing the folder there; the old one is removed last.

    The old folder is renamed aside (``.NAME.<pid>.old``), ``new`` renamed into place, then
    the old one deleted, with Ctrl-C and SIGTERM held back until it is done; so ``path``
    holds the old folder or the new one, whole. (A kill between the renames is repaired by
    the next :func:`remove_stale_temporaries`.)

    Args:
        new: the finished folder (on the same file system, e.g. :func:`staging_folder`).
        path: where it goes.
        keep: when given, entries of the old folder whose names are not in ``keep`` and are
            not ineid temporaries (files the user put there) are carried into the new folder.
    """
    new, path = Path(new), _real(path)
    aside = path.with_name(f".{path.name}.{os.getpid()}.old")
    with _signals_deferred():
        if path.is_dir():
            if keep is not None:
                for entry in path.iterdir():
                    if entry.name not in keep and not _is_temporary(entry.name) and not (new / entry.name).exists():
                        os.rename(entry, new / entry.name)
            os.rename(path, aside)
        os.rename(new, path)
        shutil.rmtree(aside, ignore_errors=True)
    return path


def _is_temporary(name: str) -> bool:
    return name.startswith(".") and (re.search(r"\.\d+\.(tmp|old)(\..*)?$", name) is not None or name.endswith(".lock"))
