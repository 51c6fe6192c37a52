"""The installed package's version, from its metadata (imports nothing else of ineid)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ineid")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
