"""ineid's cache folder: generated code of user URDFs, URDF text of datasets, compiled XLA code.

``$INEID_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/ineid`` or ``~/.cache/ineid``. Deleting
the folder is always safe: whatever is missing is derived or compiled again.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    """The cache folder (not created here)."""
    env = os.environ.get("INEID_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ineid"
