"""What ineid trusts on disk before it runs it: private folders, owned files, recorded hashes.

ineid runs code it wrote earlier: generated Python modules and compiled C libraries in the
cache folder (:mod:`ineid.cache`), generated modules in a folder given to ``ineid
generate --out``. Anyone who can change those files can make ineid run their code, so
before loading them ineid checks:

* **ownership and permissions** (cache folders only): every folder from the cache root
  down to the file, and the file itself, belong to the current user and are not writable
  by group or others; no symbolic links below the root. Folders are created 0700.
* **content**: when ineid writes code it records the SHA-256 of every file in a manifest
  beside it (:data:`MANIFEST`, written after the files, atomically); before loading, the
  bytes are read once, hashed, compared, and those same bytes are what is run (a module is
  compiled from them; a library is loaded through the descriptor they were read from), so
  nothing can swap the file between the check and the use.

A failed check raises :class:`Untrusted` with a phrase that completes "the code in DIR
...", e.g. "has a file that is writable by group or others (arm_jax.py)": the caller
regenerates and says why in one line.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from ineid._atomic import atomic_write
from ineid._inputs import parse_json, read_json
from ineid.errors import InputFileError

MANIFEST = "MANIFEST.json"
"""The manifest of the generated modules in a folder: ``{"format": ..., "sha256": {file: hex}}``."""
_FORMAT = "ineid-manifest-1"
PRIVATE_MODE = 0o700


class Untrusted(Exception):  # a verdict, caught by every caller
    """A folder or file failed a check; ``reason`` completes "the code in DIR ..."."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def current_uid() -> int | None:
    """The effective user id, or None where the platform has none (ownership is then not checked)."""
    return os.geteuid() if hasattr(os, "geteuid") else None


def stat_problem(st: os.stat_result) -> str | None:
    """Why a folder or file with this status is not to be trusted, or None.

    Not trusted: a symbolic link (from ``lstat``), owned by another user, or writable by
    group or others.
    """
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    uid = current_uid()
    if uid is not None and st.st_uid != uid:
        return f"is owned by another user (uid {st.st_uid})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return "is writable by group or others"
    return None


def root_problem(root: Path) -> str | None:
    """Why the folder ``root`` is not to be trusted (symbolic links to it are followed), or None."""
    try:
        st = os.stat(root)
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    return stat_problem(st)


def make_private_dirs(root: Path, *parts: str) -> Path:
    """``root / parts``, each missing folder below ``root`` created with mode 0700.

    ``root`` must exist and is not checked here (see :func:`root_problem`). Every folder
    below it must be a real folder (no symbolic link) owned by the current user and not
    writable by others; one that is merely readable by others is tightened to 0700.

    Raises:
        Untrusted: naming the first folder that fails, e.g. ``"/c/generated is writable by group or others"``.
    """
    path = Path(root)
    for part in parts:
        path = path / part
        try:
            os.mkdir(path, PRIVATE_MODE)
            os.chmod(path, PRIVATE_MODE)  # the umask may have removed bits we want; never adds others'
            continue
        except FileExistsError:
            pass
        except OSError as e:
            raise Untrusted(f"{path} cannot be created ({e.strerror or e})") from None
        st = os.lstat(path)
        problem = stat_problem(st) or (None if stat.S_ISDIR(st.st_mode) else "is not a folder")
        if problem:
            raise Untrusted(f"{path} {problem}")
        if st.st_mode & 0o077:
            os.chmod(path, PRIVATE_MODE)  # an older ineid made it 0755: ours, so make it private
    return path


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@contextmanager
def opened(path: Path, *, private: bool) -> Iterator[tuple[int, bytes]]:
    """``(descriptor, bytes)`` of a regular file, the descriptor open for the ``with`` block.

    With ``private``, a symbolic link is refused and the open file must be owned by the
    current user and not writable by others (checked on the descriptor, so the bytes are
    those of the file checked).

    Raises:
        FileNotFoundError: the file does not exist.
        Untrusted: it fails a check.
    """
    flags = os.O_RDONLY | (getattr(os, "O_NOFOLLOW", 0) if private else 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise
    except OSError as e:
        if private and os.path.islink(path):
            raise Untrusted(f"has a file that is a symbolic link ({path.name})") from None
        raise Untrusted(f"has a file that cannot be read ({path.name}: {e.strerror or e})") from None
    try:
        st = os.fstat(fd)
        problem = (stat_problem(st) if private else None) or (None if stat.S_ISREG(st.st_mode) else "is not a file")
        if problem:
            raise Untrusted(f"has a file that {problem} ({path.name})")
        chunks = []
        while chunk := os.read(fd, 1 << 20):
            chunks.append(chunk)
        yield fd, b"".join(chunks)
    finally:
        os.close(fd)


def read_checked(path: Path, *, private: bool) -> bytes:
    """The bytes of a file, checked as :func:`opened` checks it."""
    with opened(path, private=private) as (_, data):
        return data


def recorded_hashes(directory: Path, *, private: bool, manifest: str = MANIFEST) -> dict[str, str]:
    """``{file name: sha256 hex}`` from the manifest ``directory / manifest``.

    Raises:
        Untrusted: no manifest, an unreadable or damaged one, or (``private``) one that fails the ownership check.
    """
    try:
        doc = parse_json(read_checked(directory / manifest, private=private))
    except FileNotFoundError:
        raise Untrusted(f"has no {manifest} (written by an older ineid, or not by ineid)") from None
    except (ValueError, UnicodeDecodeError):
        raise Untrusted(f"has a damaged {manifest}") from None
    if not is_manifest_doc(doc):
        raise Untrusted(f"has a {manifest} that ineid did not write")
    return dict(doc["sha256"])


def is_manifest_doc(doc: object) -> bool:
    """True for a parsed manifest ineid wrote."""
    return (
        isinstance(doc, dict)
        and doc.get("format") == _FORMAT
        and isinstance(doc.get("sha256"), dict)
        and all(isinstance(k, str) and isinstance(v, str) for k, v in doc["sha256"].items())
    )


def is_manifest(path: Path) -> bool:
    """True when ``path`` is a manifest ineid wrote (so ineid may replace it)."""
    try:
        return is_manifest_doc(read_json(path, "the manifest"))
    except (InputFileError, OSError, ValueError):
        return False


def verified(directory: Path, names: Iterable[str], *, private: bool, manifest: str = MANIFEST) -> dict[str, bytes]:
    """``{name: bytes}`` of files in ``directory`` whose SHA-256 equals the one in the manifest.

    Raises:
        FileNotFoundError: one of the files is absent (nothing to check: write them).
        Untrusted: a file is not in the manifest, does not match it, or fails :func:`opened`'s checks.
    """
    directory = Path(directory)
    names = list(names)
    data = {name: read_checked(directory / name, private=private) for name in names}
    hashes = recorded_hashes(directory, private=private, manifest=manifest)
    for name in names:
        if name not in hashes:
            raise Untrusted(f"is not in its manifest ({name})")
        if sha256(data[name]) != hashes[name]:
            raise Untrusted(f"does not match its manifest ({name} was modified after ineid wrote it)")
    return data


def write_manifest(directory: Path, files: Mapping[str, bytes], *, private: bool, manifest: str = MANIFEST) -> Path:
    """Record the SHA-256 of ``files`` (just written by ineid into ``directory``) in its manifest.

    Entries of other files in an existing manifest are kept (several robots' modules may
    share a folder); the manifest is replaced atomically and is byte-identical for the
    same files. Write the files first, the manifest last: a crash in between leaves files
    that do not match, which are then written again.
    """
    directory = Path(directory)
    try:
        hashes = recorded_hashes(directory, private=private, manifest=manifest)
    except Untrusted:
        hashes = {}
    hashes.update({name: sha256(data) for name, data in files.items()})
    doc = {"format": _FORMAT, "sha256": dict(sorted(hashes.items()))}
    return atomic_write(directory / manifest, json.dumps(doc, indent=1) + "\n")
