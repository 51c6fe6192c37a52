"""Atomic file writes: a temporary file beside the target, renamed into place when complete.

Every file ineid writes goes through here, so a crash or Ctrl-C never leaves half a file.
"""

from __future__ import annotations

import os
from pathlib import Path


def temporary_path(path: str | Path) -> Path:
    """The hidden temporary name a file is written under before it replaces ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text or bytes) to ``path`` atomically; on failure ``path`` is untouched."""
    path = Path(path)
    tmp = temporary_path(path)
    try:
        if isinstance(data, str):
            tmp.write_text(data)
        else:
            tmp.write_bytes(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
