"""What ineid reads: only regular files (and folders where a format is a folder), bounded in size.

Opening a FIFO blocks until something writes to it, a character device (``/dev/zero``, ``/dev/urandom``)
never ends, and a socket cannot be read at all: every input a user names is checked here before it is
opened, and a file larger than its format's limit is refused before it is parsed. Each refusal is one
:class:`ineid.errors.InputFileError` line naming the file, what it is, and the fix.

JSON, in files and in HDF5 attributes, is read by :func:`read_json` and :func:`parse_json`: bounded in
size (:data:`JSON_MAX_BYTES`) and in nesting (:data:`JSON_MAX_DEPTH`), so a file nested 100,000 levels
deep is one line, not Python's ``RecursionError``.

Imports only the standard library and :mod:`ineid.errors` (the foundation layer).
"""

from __future__ import annotations

import json
import os
import re
import stat
from pathlib import Path

from ineid.errors import InputFileError

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str:
    """``"a regular file"``, ``"a FIFO (named pipe)"``, ... for a ``st_mode``."""
    for test, name in _KINDS:
        if test(mode):
            return name
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def regular_file(
    path: str | os.PathLike, what: str = "the input", *, max_bytes: int | None = None, limit_name: str = ""
) -> Path:
    """``path`` if it names an existing regular file (symbolic links followed) of at most ``max_bytes``.

    Nothing is opened: ``os.stat`` tells a FIFO or a device from a file without blocking.

    Args:
        path: the file a user named.
        what: what it is, for the message (``"the CSV recording"``).
        max_bytes: the largest size ineid reads for this format (None: no limit).
        limit_name: the limit's name, for the message (``"INPUT_LIMITS.urdf_bytes"``).

    Raises:
        InputFileError: it does not exist, is not a regular file, or is larger than ``max_bytes``.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(f"{what} {path} does not exist; check the path") from None
    except OSError as e:
        reason = e.strerror or e
        raise InputFileError(f"{what} {path} cannot be read ({reason}); check the path and its permissions") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{what} {path} is {file_kind(st.st_mode)}, not a regular file; give a file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputFileError(
            f"{what} {path} is {st.st_size:,} bytes, over the {max_bytes:,} bytes ineid reads for it"
            f"{f' ({limit_name})' if limit_name else ''}; give a smaller file"
        )
    return path


# -- JSON ---------------------------------------------------------------------------------------------

JSON_MAX_BYTES = 64 * 2**20
"""The largest JSON file (or JSON attribute of an HDF5 file) ineid reads: 64 MiB. ineid's own are far
smaller: the largest, a run's ``config.json``, lists its split's configuration indices (about 8 MB for
a million configurations)."""

JSON_MAX_DEPTH = 64
"""The deepest nesting of arrays and objects ineid reads in JSON. ineid's own JSON nests at most six
levels; Python's parser gives up with a ``RecursionError`` near a thousand."""

_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_NOT_BRACKETS = bytes(sorted(set(range(256)) - set(b"[]{}")))
_OPENING = frozenset(b"[{")


class JsonDepthError(ValueError):
    """JSON nested deeper than :data:`JSON_MAX_DEPTH` (a ``ValueError``, as ``json.JSONDecodeError`` is)."""


def _check_depth(data: bytes, max_depth: int) -> None:
    """Raise :class:`JsonDepthError` when the brackets outside strings nest deeper than ``max_depth``.

    The strings are cut out and the other bytes deleted by ``re`` and ``bytes.translate`` (C loops),
    so the Python loop runs over the brackets alone and stops at the first one too deep.
    """
    depth = 0
    for b in _JSON_STRING.sub(b"", data).translate(None, _NOT_BRACKETS):
        depth = depth + 1 if b in _OPENING else depth - 1
        if depth > max_depth:
            raise JsonDepthError(f"nested deeper than the {max_depth} levels ineid reads (JSON_MAX_DEPTH)")


def parse_json(text: str | bytes, *, max_depth: int = JSON_MAX_DEPTH, max_bytes: int = JSON_MAX_BYTES) -> object:
    """``json.loads(text)``, refusing text longer than ``max_bytes`` or nested deeper than ``max_depth``.

    Raises:
        ValueError: ``json.JSONDecodeError`` (not JSON), ``UnicodeDecodeError`` (bytes that are not
            UTF-8), :class:`JsonDepthError` (nested too deep), or a plain ``ValueError`` (too long);
            the caller words it as a damaged file of its own kind.
        TypeError: ``text`` is neither text nor bytes.
    """
    if not isinstance(text, (str, bytes, bytearray)):
        raise TypeError(f"JSON must be text, not {type(text).__name__}")
    data = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else bytes(text)
    if len(data) > max_bytes:
        raise ValueError(f"{len(data):,} bytes, over the {max_bytes:,} bytes ineid reads as JSON (JSON_MAX_BYTES)")
    _check_depth(data, max_depth)
    try:
        return json.loads(text)
    except RecursionError:  # not reached after the depth check; a last guard for any parser change
        raise JsonDepthError(f"nested deeper than Python's parser goes ({max_depth} levels is ineid's limit)") from None


def read_json(
    path: str | os.PathLike,
    what: str = "the JSON file",
    *,
    max_bytes: int = JSON_MAX_BYTES,
    max_depth: int = JSON_MAX_DEPTH,
) -> object:
    """The JSON value in the regular file ``path`` (:func:`regular_file`), bounded as :func:`parse_json` bounds it.

    Raises:
        InputFileError: ``path`` does not exist, is not a regular file, or is larger than ``max_bytes``.
        OSError: the file cannot be read.
        ValueError: it is not UTF-8 JSON, or is nested too deep (see :func:`parse_json`).
    """
    path = regular_file(path, what, max_bytes=max_bytes, limit_name="JSON_MAX_BYTES")
    with open(path, "rb") as f:
        data = f.read(max_bytes + 1)  # the file may have grown since the check: parse_json refuses it then
    return parse_json(data.decode("utf-8"), max_depth=max_depth, max_bytes=max_bytes)
