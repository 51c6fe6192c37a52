"""ineid's cache folder: generated code of user URDFs, parsed URDFs and compiled XLA code.

``$INEID_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/ineid`` or ``~/.cache/ineid``. Deleting
the folder is always safe: whatever is missing is derived or compiled again.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path


def cache_dir() -> Path:
    """The cache folder (not created here)."""
    env = os.environ.get("INEID_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ineid"


XLA_SUBDIR = "xla"
"""JAX's persistent compilation cache lives in ``cache_dir() / XLA_SUBDIR``."""
DISABLE_ENV = "INEID_XLA_CACHE"
"""Set to ``0`` to keep ineid from turning on JAX's persistent compilation cache."""

_log = logging.getLogger("ineid.cache")
_listening = False


def xla_cache_dir() -> Path:
    """Where ineid keeps compiled XLA executables: ``cache_dir()/xla``."""
    return cache_dir() / XLA_SUBDIR


def enable_compilation_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in :func:`xla_cache_dir` (idempotent).

    A second run of the same computation (any ``ineid`` command, or a script calling the
    library) then loads the compiled executable from disk instead of compiling again:
    seconds saved per kernel. Every compilation is cached, however quick
    (``jax_persistent_cache_min_compile_time_secs = 0``). Cache hits are logged at INFO
    on the ``ineid.cache`` logger (``ineid -v`` shows them).

    Nothing changes when the cache is already configured (``JAX_COMPILATION_CACHE_DIR`` or
    ``jax.config``: yours wins), or when ``INEID_XLA_CACHE=0``. Before JAX is imported
    this only sets the environment variables JAX reads at import (no JAX import, no
    start-up cost); after, it updates ``jax.config``. ``ineid cache clear --xla-only`` (or
    deleting the folder) clears it; it is rebuilt on demand.

    Returns:
        The cache folder in use, or None when disabled.
    """
    if os.environ.get(DISABLE_ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    path = xla_cache_dir()
    if "jax" not in sys.modules:
        os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(path))
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    import jax  # noqa: PLC0415

    if jax.config.jax_compilation_cache_dir is None:
        jax.config.update("jax_compilation_cache_dir", str(path))
        if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _listen()
    return Path(jax.config.jax_compilation_cache_dir)


def _listen() -> None:
    """Log JAX's persistent-cache hits (and, at DEBUG, misses) on ``ineid.cache``."""
    global _listening  # noqa: PLW0603 - one listener per process
    if _listening:
        return
    _listening = True
    from jax import monitoring  # noqa: PLC0415

    def on_duration(event: str, duration: float, **_: object) -> None:
        if event == "/jax/compilation_cache/compile_time_saved_sec":
            _log.info("XLA compilation cache hit: loaded a compiled kernel (%.2f s of compilation saved)", duration)

    def on_event(event: str, **_: object) -> None:
        if event == "/jax/compilation_cache/cache_misses":
            _log.debug("XLA compilation cache miss: compiled a kernel and stored it in %s", xla_cache_dir())

    monitoring.register_event_duration_secs_listener(on_duration)
    monitoring.register_event_listener(on_event)
