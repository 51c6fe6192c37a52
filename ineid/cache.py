"""ineid's cache folder: generated code of user URDFs, parsed URDFs and compiled code.

``$INEID_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/ineid`` or ``~/.cache/ineid``. Deleting
the folder is always safe: whatever is missing is derived or compiled again.

The cache holds code that ineid runs (generated modules, compiled C libraries, JAX's
compiled XLA executables), so ineid trusts it only when it is private: the folder and
every folder ineid makes in it (created 0700) belong to the current user and are not
writable by group or others (:mod:`ineid._trust` has the checks, and the content hashes
checked before code is loaded). A cache folder that fails this is not used at all: one
warning line, and the process works in a private temporary folder instead.
ineid's cache is marked with a ``CACHEDIR.TAG`` (backup tools skip it), written when ineid
creates the folder or finds it empty. A folder that holds anything but has no marker (a project
folder named by mistake) is never adopted: ineid then works in a private temporary folder, after
one warning line. ``ineid cache clear`` (:mod:`ineid.cache_clear`) removes only ineid's own
entries of a marked folder.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import stat
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ineid._trust import PRIVATE_MODE, Untrusted, make_private_dirs, root_problem


def cache_dir() -> Path:
    """The cache folder (not created here)."""
    env = os.environ.get("INEID_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ineid"


XLA_SUBDIR = "xla"
"""JAX's persistent compilation cache lives in ``cache_dir() / XLA_SUBDIR``."""
SUBDIRS = ("generated", "chains", "casadi-c", XLA_SUBDIR)
"""Everything ineid puts in its cache folder, besides the :data:`MARKER`."""
MARKER = "CACHEDIR.TAG"
SIGNATURE = "Signature: 8a477f597d28d172789f06886806bc55"
_MARKER_TEXT = (
    f"{SIGNATURE}\n"
    "# This file is a cache directory tag created by ineid: this folder is ineid's cache.\n"
    "# `ineid cache clear` removes ineid's entries in it. See https://bford.info/cachedir/\n"
)
DISABLE_ENV = "INEID_XLA_CACHE"
"""Set to ``0`` to keep ineid from turning on JAX's persistent compilation cache."""

MIN_SAVED_S = 0.005
"""A cache hit's compile time saved is logged only above this (it prints as 0.00 s below)."""

_log = logging.getLogger("ineid.cache")
_listening = False


def xla_cache_dir() -> Path:
    """Where ineid keeps compiled XLA executables: ``cache_dir()/xla``."""
    return cache_dir() / XLA_SUBDIR


@dataclass(frozen=True)
class CacheState:
    """What ineid makes of its cache folder (nothing is created to find out)."""

    path: Path
    exists: bool
    marked: bool
    """It holds ineid's ``CACHEDIR.TAG``."""
    problem: str | None
    """Why ineid does not use it (owned by another user, writable by others, not empty and not
    marked), or None."""
    foreign: tuple[str, ...]
    """Entries that are not ineid's (anything but :data:`SUBDIRS` and the marker)."""

    @property
    def private(self) -> bool:
        """Owned by the current user and not writable by others: ineid loads code from it."""
        return self.exists and self.problem is None


def cache_state() -> CacheState:
    """The trust state of :func:`cache_dir`."""
    root = cache_dir()
    if not root.exists():
        return CacheState(root, False, False, None, ())
    try:
        entries = os.listdir(root)
    except OSError:
        entries = []
    marked = _is_marked(root)
    problem = root_problem(root) or (None if marked else _unmarked_problem(root))
    foreign = tuple(sorted(set(entries) - {*SUBDIRS, MARKER}))
    return CacheState(root, True, marked, problem, foreign)


def _is_marked(root: Path) -> bool:
    """``root`` holds ineid's ``CACHEDIR.TAG``: a regular file, not a link (opened without blocking,
    so a FIFO planted under the marker's name is not waited on)."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(root / MARKER, flags)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        head = os.read(fd, 512).decode("utf-8", "replace")
    except OSError:
        return False
    finally:
        os.close(fd)
    return head.startswith(SIGNATURE) and "created by ineid" in head


def _is_marker_temporary(name: str) -> bool:
    """The temporary file of another process writing the marker (``.CACHEDIR.TAG.<pid>.tmp.TAG``)."""
    return name.startswith(f".{MARKER}.") and ".tmp" in name


def _unmarked_problem(root: Path) -> str | None:
    """Why the unmarked folder ``root`` is not ineid's to use: it holds something; None when empty."""
    try:
        entries = sorted(e for e in os.listdir(root) if not _is_marker_temporary(e))
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    if not entries:
        return None
    shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
    return f"is not empty and has no CACHEDIR.TAG from ineid (it holds {shown})"


def _prepare_root(root: Path) -> str | None:
    """Create the cache folder (0700, marked) if missing; why it cannot be trusted, or None.

    An existing folder without the marker is marked only when it is empty; one that holds
    anything is not ineid's (the reason is returned, nothing is written in it). A marked
    folder readable by others is tightened to 0700.
    """
    if not root.exists():
        try:
            missing = [p for p in (root, *root.parents) if not p.exists()]
            for p in reversed(missing):
                try:
                    os.mkdir(p, PRIVATE_MODE)
                    os.chmod(p, PRIVATE_MODE)
                except FileExistsError:  # another process made it first
                    pass
        except OSError as e:
            return f"cannot be created ({e.strerror or e})"
    problem = root_problem(root)
    if problem:
        return problem
    marked = _is_marked(root)
    if not marked:
        problem = _unmarked_problem(root)
        if problem:
            return problem
    try:
        if not marked:
            from ineid._atomic import atomic_write

            atomic_write(root / MARKER, _MARKER_TEXT)
        if os.stat(root).st_mode & 0o077:
            os.chmod(root, PRIVATE_MODE)
    except OSError:
        pass  # a read-only cache can still be read
    return None


_warned: set[str] = set()
_temporary: list[Path] = []


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        _log.warning(message)


def _temporary_root() -> Path:
    """This process's private stand-in for an untrusted cache (0700, removed at exit)."""
    if not _temporary:
        path = Path(tempfile.mkdtemp(prefix="ineid-cache-"))
        _temporary.append(path)
        atexit.register(shutil.rmtree, path, ignore_errors=True)
    return _temporary[0]


def trusted_root() -> Path | None:
    """:func:`cache_dir`, created if missing, when ineid may load code from it; else None
    (after one warning line per process naming the folder, the reason and the fix)."""
    root = cache_dir()
    problem = _prepare_root(root)
    if problem is None:
        return root
    if MARKER in problem:
        fix = "set INEID_CACHE_DIR to a new or empty folder (ineid marks it as its cache), or unset it"
    else:
        fix = f"{f'chmod 700 {root}, or ' if 'writable' in problem else ''}set INEID_CACHE_DIR to a folder of your own"
    _warn_once(
        f"the cache folder {root} {problem}, so ineid loads no code from it and works without a cache "
        f"this time (in a private temporary folder); fix: {fix}"
    )
    return None


def private_folder(*parts: str) -> Path:
    """``cache_dir() / parts``, created 0700 and checked (see :mod:`ineid._trust`).

    When the cache folder or one of these folders cannot be trusted, the same parts under
    a private temporary folder of this process (removed at exit) instead, after one
    warning line: the work is done again rather than loaded.
    """
    root = trusted_root()
    if root is not None:
        try:
            return make_private_dirs(root, *parts)
        except Untrusted as e:
            _warn_once(
                f"the cache folder {e.reason}, so ineid loads no code from it and works in a private "
                f"temporary folder this time; fix: ineid cache clear"
            )
    return make_private_dirs(_temporary_root(), *parts)


def _private_xla_dir() -> Path | None:
    """:func:`xla_cache_dir` created 0700 when the cache is private; else None (one warning line)."""
    root = trusted_root()
    if root is None:
        return None
    try:
        return make_private_dirs(root, XLA_SUBDIR)
    except Untrusted as e:
        _warn_once(
            f"the cache folder {e.reason}, so JAX's compilation cache (compiled native code) stays off; "
            f"fix: ineid cache clear --xla-only"
        )
        return None


def enable_compilation_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in :func:`xla_cache_dir` (idempotent).

    A second run of the same computation (any ``ineid`` command, or a script calling the
    library) then loads the compiled executable from disk instead of compiling again:
    seconds saved per kernel. Every compilation is cached, however quick
    (``jax_persistent_cache_min_compile_time_secs = 0``). Cache hits are logged at INFO
    on the ``ineid.cache`` logger (``ineid -v`` shows them).

    The cache holds compiled native code, so it is turned on only when the folder is
    private: created 0700 (see :func:`private_folder`), owned by the current user and not
    writable by others; otherwise it stays off, with one warning line.

    Nothing changes when the cache is already configured (``JAX_COMPILATION_CACHE_DIR`` or
    ``jax.config``: yours wins, unchecked), or when ``INEID_XLA_CACHE=0``. Before JAX is
    imported this only sets the environment variables JAX reads at import (no JAX import,
    no start-up cost); after, it updates ``jax.config``. ``ineid cache clear --xla-only``
    (or deleting the folder) clears it; it is rebuilt on demand.

    Returns:
        The cache folder in use, or None when disabled.
    """
    if os.environ.get(DISABLE_ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    if "jax" not in sys.modules:
        if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
            path = _private_xla_dir()
            if path is None:
                return None
            os.environ["JAX_COMPILATION_CACHE_DIR"] = str(path)
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    import jax

    if jax.config.jax_compilation_cache_dir is None:
        path = _checked_xla.get(str(cache_dir()), ...)
        if path is ...:
            path = _checked_xla[str(cache_dir())] = _private_xla_dir()
        if path is None:
            return None
        jax.config.update("jax_compilation_cache_dir", str(path))
        if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _listen()
    return Path(jax.config.jax_compilation_cache_dir)


_checked_xla: dict[str, Path | None] = {}
"""Per cache folder, the verdict of :func:`_private_xla_dir` (this runs before every kernel call)."""


def _listen() -> None:
    """Log JAX's persistent-cache hits (and, at DEBUG, misses) on ``ineid.cache``."""
    global _listening  # one listener per process
    if _listening:
        return
    _listening = True
    from jax import monitoring

    def on_duration(event: str, duration: float, **_: object) -> None:
        if event == "/jax/compilation_cache/compile_time_saved_sec":
            # JAX reports the stored compile time less the load time: near zero or negative for a small
            # kernel ("-0.00 s saved" says nothing), so the saving is named only when there is one.
            saved = f" ({duration:.2f} s of compilation saved)" if duration > MIN_SAVED_S else ""
            _log.info("XLA compilation cache hit: loaded a compiled kernel%s", saved)

    def on_event(event: str, **_: object) -> None:
        if event == "/jax/compilation_cache/cache_misses":
            _log.debug("XLA compilation cache miss: compiled a kernel and stored it in %s", xla_cache_dir())

    monitoring.register_event_duration_secs_listener(on_duration)
    monitoring.register_event_listener(on_event)
