"""The output policy: refuse to replace without ``overwrite``, write atomically, clean up on signals.

Every file ineid writes goes through here: :func:`atomic_write` for data in memory,
:func:`atomic_output` for files written by a library (HDF5, matplotlib, CSV writers), and
:class:`ineid.data.dataset.write.DatasetWriter` (which uses :func:`create_temporary`) for streamed
datasets. A temporary file beside the target is renamed into place only when complete, so
an exception, Ctrl-C or (once :func:`terminate_on_sigterm` is installed) a scheduler's
SIGTERM leaves either the old file or nothing, never half a file. Temporaries have
unpredictable names and are created exclusively, never through a link
(:mod:`ineid._temporary`).

Folders (training runs) are built under a hidden name beside the target and swapped in when
complete (:func:`staging_folder`, :func:`replace_folder`). :func:`output_lock` makes a second
process writing the same output stop with one line instead of racing the first, and removes
the temporary files that a killed run (SIGKILL, power loss) left beside the output.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import signal
import stat
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from ineid._interrupts import (  # the signals' names, also importable from here
    Terminated as Terminated,
)
from ineid._interrupts import (
    redeliver_ignored_interrupt as redeliver_ignored_interrupt,
)
from ineid._interrupts import (
    terminate_on_sigterm as terminate_on_sigterm,
)
from ineid._temporary import (
    create_temporary,
    create_temporary_folder,
    is_temporary,
    remove_stale_temporaries,
    temporary_stem,
)
from ineid.errors import DatasetError, OutputBusyError, OutputExistsError, StorageError

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


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield the name of a new empty temporary file to write; on a normal exit it replaces ``path``,
    otherwise it is deleted.

    The file exists already (:func:`create_temporary`: a file of this process, not a link), so
    a writer that opens it by name writes into it. It keeps the suffix of ``path``
    (``.NAME.ineid-PID-RANDOM.tmp.png``) for writers that go by the suffix.
    """
    path = Path(path)
    tmp = create_temporary(path, path.suffix)
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
    import csv
    import io

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


LOCK_BYTES = 32
"""The most a lock file of ineid holds (its holder's pid and a newline); a bigger file at a lock's name is someone's."""


def lock_path(path: str | Path) -> Path:
    """The hidden lock file of an output: ``.NAME.lock`` beside it (a long name shortened as in its
    temporaries, :func:`ineid._temporary.temporary_stem`)."""
    path = Path(path)
    return path.with_name(f".{temporary_stem(path.name)}.lock")


def _lock_problem(st: os.stat_result, fd: int | None = None) -> str | None:
    """What makes ``st`` (and the open ``fd``) something other than a lock file ineid could have made
    (a regular file with one name, holding nothing or a pid), or None."""
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    if st.st_nlink > 1:
        return "has other names (hard links)"
    held = os.pread(fd, LOCK_BYTES + 1, 0).strip() if fd is not None else b""
    if st.st_size > LOCK_BYTES or (held and not held.isdigit()):
        return "holds other data"
    return None


def _foreign_lock(lock: Path, problem: str, option: str) -> StorageError:
    return StorageError(f"{lock} {problem}, not a lock file of ineid; remove it, or choose another {option}")


def _open_lock(lock: Path, option: str) -> tuple[int, bool] | None:
    """Open the lock file ``lock``, creating it, never through a link: ``(fd, owned)``, ``owned`` when it is
    this user's file (only then is the holder's pid written in it); None where it cannot be opened
    (a read-only or missing folder: the write itself then fails with the reason).

    A name already taken is checked (:func:`_lock_problem`) before it is opened, so a FIFO or a
    device is never opened, and again through the open file.

    Raises:
        StorageError: the name holds a link, something other than a regular file, a file with
            other names or other data.
    """
    flags = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        problem = _lock_problem(os.lstat(lock))
    except OSError:  # none yet (or the folder is unusable: the open below says so)
        problem = None
    if problem:
        raise _foreign_lock(lock, problem, option)
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | flags, 0o644)
    except OSError as e:
        if e.errno == errno.ELOOP:  # a link planted since the check above
            raise _foreign_lock(lock, "is a symbolic link", option) from None
        try:  # another user's lock file in a shared folder: lockable, not writable
            fd = os.open(lock, os.O_RDONLY | flags)
        except OSError:
            _log.debug("no lock for %s (%s)", lock, e)
            return None
    try:
        st = os.fstat(fd)
        problem = _lock_problem(st, fd)
        if problem:
            raise _foreign_lock(lock, problem, option)
    except BaseException:
        os.close(fd)
        raise
    return fd, not hasattr(os, "geteuid") or st.st_uid == os.geteuid()


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

    The lock file is opened without following a link (:func:`_open_lock`); the pid is
    written only into a lock file of this user. Where it cannot be created (a read-only or
    missing folder) nothing is locked: the write itself then fails with the reason.

    Raises:
        OutputBusyError: another process holds the lock.
        StorageError: the lock's name holds a link or anything but a lock file of ineid.
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
        import fcntl  # POSIX; elsewhere outputs are not locked
    except ImportError:
        yield path
        return
    while True:
        opened = _open_lock(lock, option)
        if opened is None:
            yield path
            return
        fd, owned = opened
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
            current, held = os.lstat(lock), os.fstat(fd)
            if (current.st_dev, current.st_ino) == (held.st_dev, held.st_ino):
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    _held[key] = 1
    try:
        if owned:
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


# -- folders ------------------------------------------------------------------------------------------


def _real(path: str | Path) -> Path:
    """A symlinked folder is replaced where it points (the link stays)."""
    path = Path(path)
    return path.resolve() if path.is_symlink() else path


def staging_folder(path: str | Path) -> Path:
    """A new empty hidden folder ``.NAME.ineid-PID-RANDOM.tmp`` beside ``path`` (or beside the folder a
    symlink ``path`` points to) to build its replacement in (:func:`ineid._temporary.create_temporary_folder`)."""
    path = _real(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return create_temporary_folder(path)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM that come during the block take effect once it is done (main thread; elsewhere no change).

    Python runs signal handlers in the main thread, whichever thread the signal reached (a
    process-directed signal goes to any thread that does not block it: JAX's, XLA's), so
    the handlers themselves are swapped for one that notes the signal; after the block the
    previous handlers are put back and each signal noted is raised again.
    """
    signums = (signal.SIGINT, signal.SIGTERM)
    came: list[int] = []
    previous = {s: signal.getsignal(s) for s in signums}
    if any(handler is None for handler in previous.values()):  # a handler set outside Python: cannot be put back
        yield
        return
    try:
        for s in signums:
            signal.signal(s, lambda signum, frame: came.append(signum))
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for s in dict.fromkeys(came):
            signal.raise_signal(s)


def replace_folder(new: str | Path, path: str | Path, keep: tuple[str, ...] | None = None) -> Path:
    """Put the complete folder ``new`` at ``path``, replacing the folder there; the old one is removed last.

    The old folder is renamed aside (onto ``.NAME.ineid-PID-RANDOM.old``, an empty folder made
    for it), ``new`` renamed into place, then the old one deleted, with Ctrl-C and SIGTERM
    held back until it is done; so ``path`` holds the old folder or the new one, whole, and a
    signal that came meanwhile is raised once the new one is in place. (A kill between the
    renames is repaired by the next :func:`remove_stale_temporaries`.)

    Args:
        new: the finished folder (on the same file system, e.g. :func:`staging_folder`).
        path: where it goes.
        keep: when given, entries of the old folder whose names are not in ``keep`` and are
            not ineid temporaries (files the user put there) are carried into the new folder.
    """
    new, path = Path(new), _real(path)
    with signals_deferred():
        aside = None
        if path.is_dir():
            if keep is not None:
                for entry in path.iterdir():
                    carried = entry.name not in keep and not is_temporary(entry.name)
                    if carried and not os.path.lexists(new / entry.name):
                        os.rename(entry, new / entry.name)
            aside = create_temporary_folder(path, "old")
            os.rename(path, aside)  # replaces the empty folder just made: the name is this process's
        os.rename(new, path)
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
    return path
