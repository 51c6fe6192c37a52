"""``ineid cache clear``: remove, entry by entry, what ineid wrote in its marked cache folder.

A folder is ineid's cache only when it holds ineid's ``CACHEDIR.TAG`` (:mod:`ineid.cache`); any
other folder is never cleared. In a marked folder an entry is removed only when ineid can tell
that it wrote it:

* ``generated/<fingerprint>/`` and ``casadi-c/``: the manifests ineid writes beside its code
  (:mod:`ineid._trust`) and the files they list;
* ``chains/``: parsed URDFs, ``<32 hex digits>.json`` holding a chain record;
* ``xla/``: JAX's compiled kernels, under the names JAX gives them (``<name>-<64 hex digits>-cache``,
  ``...-atime``, and its ``.lockfile``): ineid points JAX at this folder and writes nothing there itself;
* the temporaries of ineid's atomic writes of such names (``.NAME.<pid>.tmp``) that a killed run left.

Everything else (a file someone put there, a symbolic link, a folder of another shape) stays and is
named in :attr:`Cleared.kept`. Folders left empty are removed; the marker and the cache folder
itself go only when nothing else is left.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ineid._inputs import read_json
from ineid._trust import MANIFEST, is_manifest_doc
from ineid.cache import MARKER, SUBDIRS, XLA_SUBDIR, cache_state
from ineid.errors import CacheError, InputFileError

MANIFEST_MAX_BYTES = 4 * 2**20
"""The largest manifest or parsed-URDF entry read to recognise it as ineid's (4 MiB; ineid's are a few kB)."""

_TEMPORARY = re.compile(r"\.(?P<name>.+)\.\d+\.tmp(?:\.[^.]*)?")
"""A temporary of :func:`ineid._atomic.atomic_write` for the file ``name``."""
_GENERATED = re.compile(rf"{re.escape(MANIFEST)}|.+_(?:jax|casadi)\.py")
_LIBRARY = re.compile(r".+_[0-9a-f]{16}\.(?:so|json)")
_CHAIN = re.compile(r"[0-9a-f]{32}\.json")
_CHAIN_KEYS = frozenset({"name", "root_link", "joints", "merged_links", "body_links", "notes"})
_XLA = re.compile(r".+-[0-9a-f]{64}(?:-cache|-atime)?|\.lockfile")


@dataclass(frozen=True)
class Cleared:
    """What :func:`clear_cache` removed, and what it left."""

    path: Path
    files: int
    bytes: int
    kept: tuple[str, ...]
    """Entries that are not ineid's, left in place (paths relative to the cache folder)."""


@dataclass
class _Tally:
    root: Path
    files: int = 0
    bytes: int = 0
    kept: list[str] = field(default_factory=list)

    def keep(self, path: Path) -> None:
        self.kept.append(path.relative_to(self.root).as_posix())

    def remove(self, path: Path, size: int) -> None:
        path.unlink()
        self.files, self.bytes = self.files + 1, self.bytes + size


def _doc(path: Path) -> object:
    """The JSON in ``path``, or None when it is not a small regular file of UTF-8 JSON."""
    try:
        return read_json(path, max_bytes=MANIFEST_MAX_BYTES)
    except (InputFileError, OSError, ValueError):
        return None


def _entries(folder: Path) -> list[os.DirEntry]:
    with os.scandir(folder) as it:
        return sorted(it, key=lambda e: e.name)


def _clear_files(folder: Path, ours: Callable[[str, Path], bool], temporary: re.Pattern, tally: _Tally) -> None:
    """Remove the regular files of ``folder`` that ``ours(name, path)`` accepts, and the temporaries
    of names ``temporary`` matches; every other entry is kept. ``folder`` goes when it is left empty."""
    for entry in _entries(folder):
        path = Path(entry.path)
        st = entry.stat(follow_symlinks=False)
        m = _TEMPORARY.fullmatch(entry.name)
        mine = ours(entry.name, path) if m is None else temporary.fullmatch(m["name"]) is not None
        if stat.S_ISREG(st.st_mode) and mine:
            tally.remove(path, st.st_size)
        else:
            tally.keep(path)
    _remove_if_empty(folder)


def _remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass  # it holds what was kept (or something written meanwhile): it stays


def _plain(name: str) -> bool:
    """A file name in the folder itself (a manifest naming ``../x`` or ``/x`` points outside: ignored)."""
    return name not in ("", ".", "..") and os.path.basename(name) == name and "\0" not in name


def _manifested(folder: Path) -> Callable[[str, Path], bool]:
    """``ours`` of a folder whose files ineid lists in manifests: the manifests and the files they list."""
    listed: set[str] = set()
    for entry in _entries(folder):
        if entry.name.endswith(".json") and entry.is_file(follow_symlinks=False):
            doc = _doc(Path(entry.path))
            if is_manifest_doc(doc):
                listed |= {entry.name, *(n for n in doc["sha256"] if _plain(n))}
    return lambda name, _: name in listed


def _is_chain(name: str, path: Path) -> bool:
    if _CHAIN.fullmatch(name) is None:
        return False
    doc = _doc(path)
    return isinstance(doc, dict) and _CHAIN_KEYS <= doc.keys()


def _clear_part(root: Path, part: str, tally: _Tally) -> None:
    """Clear ineid's entries of the subfolder ``part`` (a symbolic link or a file there is kept)."""
    folder = root / part
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(st.st_mode):
        tally.keep(folder)
        return
    if part == "generated":
        for entry in _entries(folder):
            path = Path(entry.path)
            if entry.is_dir(follow_symlinks=False):
                _clear_files(path, _manifested(path), _GENERATED, tally)
            else:
                tally.keep(path)
        _remove_if_empty(folder)
    elif part == "casadi-c":
        _clear_files(folder, _manifested(folder), _LIBRARY, tally)
    elif part == "chains":
        _clear_files(folder, _is_chain, _CHAIN, tally)
    elif part == XLA_SUBDIR:
        _clear_files(folder, lambda name, _: _XLA.fullmatch(name) is not None, _XLA, tally)


def _shown(names: list[str] | tuple[str, ...]) -> str:
    return ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")


def clear_cache(xla_only: bool = False) -> Cleared:
    """Remove, entry by entry, what ineid wrote in :func:`ineid.cache.cache_dir` (with ``xla_only``,
    only JAX's kernels in its ``xla`` folder); see the module's docstring for what counts as ineid's.

    The marker and the folder itself are removed only when nothing else is left in it. A folder
    without ineid's ``CACHEDIR.TAG`` is never cleared: an empty one is left as it is, any other
    is refused.

    Raises:
        CacheError: the folder has no marker from ineid and holds something, or is not a folder.
        OSError: an entry of ineid's cannot be removed (permissions).
    """
    state = cache_state()
    root = state.path
    if not state.exists:
        return Cleared(root, 0, 0, ())
    if not root.is_dir():
        raise CacheError(f"the cache folder {root} is not a folder; set INEID_CACHE_DIR to a folder of ineid's own")
    if not state.marked:
        entries = sorted(os.listdir(root))
        if not entries:
            return Cleared(root, 0, 0, ())
        raise CacheError(
            f"{root} is not an ineid cache folder (no CACHEDIR.TAG from ineid, and it holds {_shown(entries)}); "
            "nothing removed; set INEID_CACHE_DIR to ineid's own cache folder (or unset it) and clear again"
        )
    tally = _Tally(root)
    for part in (XLA_SUBDIR,) if xla_only else SUBDIRS:
        _clear_part(root, part, tally)
    if not xla_only:
        for entry in _entries(root):
            m = _TEMPORARY.fullmatch(entry.name)
            if m is not None and m["name"] == MARKER and entry.is_file(follow_symlinks=False):
                tally.remove(Path(entry.path), entry.stat(follow_symlinks=False).st_size)
            elif entry.name != MARKER and entry.name not in SUBDIRS:
                tally.keep(Path(entry.path))
        if os.listdir(root) == [MARKER]:
            (root / MARKER).unlink()
            _remove_if_empty(root)
    return Cleared(root / XLA_SUBDIR if xla_only else root, tally.files, tally.bytes, tuple(sorted(tally.kept)))
