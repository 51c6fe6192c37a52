"""Robot files bounded before a parser sees them: kind of file, bytes, bodies, joints, elements, encoding.

A robot file is read only when it is a regular file (:func:`ineid._inputs.regular_file`: a FIFO
or a device is refused before it is opened) within its format's size, and an MJCF only when
its counts are within the limits below. The counts come from one streaming pass of expat over
the file and the files it includes, before MuJoCo compiles it: MuJoCo's XML parser takes time
that grows with the square of the number of bodies (measured on a 2-core machine: 1,000 flat
bodies 0.015 s, 10,000 1.3 to 2.8 s, 30,000 19 to 45 s, 100,000 over 300 s, all of it inside
MuJoCo's parser, none in ineid's code after it), and of geoms (30,000 in one body: 1.7 s).
A URDF's counts are read from the tree ElementTree builds (linear: 100,000 links parse in
9 s, :mod:`ineid.robots.urdf_checks`).

The limits hold the largest real models many times over: MuJoCo Menagerie's arms, hands and
humanoids have tens of bodies, example-robot-data's largest URDF (TIAGo dual) is 210 kB, and
CAD exports have hundreds of links.

MuJoCo reads a file's bytes as UTF-8 whatever its XML declaration says, so an MJCF (and each
file it includes) must be valid in the encoding it declares, and that encoding a superset of
ASCII (:func:`xml_encoding`): a Latin-1 file with accents in its comments is read, a UTF-16
file is refused in one line.
"""

from __future__ import annotations

import codecs
import math
import os
import re
import stat
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

from ineid._inputs import file_kind, regular_file
from ineid.errors import InputFileError, RobotModelError

URDF_MAX_BYTES = 8 * 2**20
"""Bytes: the largest URDF ineid reads (a file, or the URDF text a dataset carries). It keeps every text
node under the 10 MB that lxml (yourdfpy's parser) reads with its default limits, and is 40 times the
largest URDF of example-robot-data."""
MJCF_MAX_BYTES = 16 * 2**20
"""Bytes: the largest MJCF ineid reads, its included files and attached models together (each
inclusion counted); meshes, textures and height fields are MuJoCo's to read and not counted."""
MAX_BODIES = 10_000
"""Links of a URDF, bodies of an MJCF (``<replicate>`` copies and included files counted): MuJoCo
parses 10,000 flat bodies in about 2 s; the largest real robots have a few hundred."""
MAX_JOINTS = 10_000
"""Joints of a URDF or an MJCF (counted as bodies are)."""
MJCF_MAX_ELEMENTS = 50_000
"""Elements of an MJCF of every kind (geoms, sites, meshes, actuators...), counted as bodies are:
MuJoCo's parser slows with the square of these too; real models have a few thousand."""
MJCF_MAX_INCLUDE_DEPTH = 32
"""Files included within included files: a scene includes a robot that includes its parts (depth 2 or 3)."""

_FIX = "give the model of the robot alone (the arm ineid identifies, without scenery or copies)"


@dataclass
class _Counts:
    """What one MJCF and the files it pulls in hold, inclusions and copies multiplied out."""

    source: str
    main_dir: Path
    nbytes: int = 0
    bodies: int = 0
    joints: int = 0
    elements: int = 0
    dirs: set[str] = field(default_factory=lambda: {""})
    models: dict[str, tuple[int, int, int]] = field(default_factory=dict)


def check_urdf_size(nbytes: int, source: str) -> None:
    """Refuse URDF text larger than :data:`URDF_MAX_BYTES` (one line naming the size, the limit and the fix)."""
    if nbytes > URDF_MAX_BYTES:
        raise InputFileError(
            f"{source}: the URDF is {nbytes:,} bytes, over the {URDF_MAX_BYTES:,} bytes ineid reads "
            "(URDF_MAX_BYTES); remove what no URDF reader needs (long comments, embedded data)"
        )


def check_counts(
    source: str, what: str, bodies: int, joints: int, elements: int | None = None, *, exact: bool = True
) -> None:
    """Refuse a model over :data:`MAX_BODIES`, :data:`MAX_JOINTS` or :data:`MJCF_MAX_ELEMENTS`.

    Args:
        what: ``"links"`` (URDF) or ``"bodies"`` (MJCF), for the message.
        exact: the counts are the model's (else counting stops at the first count over its limit,
            and the message says "more than").
    """
    checks = (
        (bodies, MAX_BODIES, "MAX_BODIES", what),
        (joints, MAX_JOINTS, "MAX_JOINTS", "joints"),
        (elements or 0, MJCF_MAX_ELEMENTS, "MJCF_MAX_ELEMENTS", "elements"),
    )
    for count, limit, name, noun in checks:
        if count > limit:
            has = f"{count:,} {noun}, over" if exact else f"more {noun} than"
            raise InputFileError(f"{source}: the model has {has} the {limit:,} ineid reads ({name}); {_FIX}")


def scan_mjcf(path: str | Path) -> Path:
    """``path`` when it is an MJCF ineid may hand to MuJoCo: a regular file, within the limits, whose included
    files and referenced assets are regular files too.

    Included files (``<include file>``) and attached models (``<model file>`` with ``<attach>``) are read
    as MuJoCo finds them (beside the main file, then beside the including file) and counted once per
    inclusion; ``<replicate count>`` multiplies what it holds, and ``<composite>``/``<flexcomp>`` count
    as ``count`` bodies. Other files (meshes, textures, height fields, skins) are only checked to be
    regular files where they exist: MuJoCo reads them, and blocks forever on a FIFO.

    Raises:
        InputFileError: a file is not a regular file, the bytes or the counts are over their limits, or
            a file is not well-formed XML (its bodies cannot be counted).
    """
    path = regular_file(path, "the MJCF", max_bytes=MJCF_MAX_BYTES, limit_name="MJCF_MAX_BYTES")
    counts = _Counts(str(path), path.resolve().parent)
    _scan(counts, path, 1, None, ())
    return path


def _scan(counts: _Counts, path: Path, mult: int, parent: str | None, stack: tuple[Path, ...]) -> None:
    """Count ``path``'s elements into ``counts``, ``mult`` times each; ``parent``: the tag it is spliced under."""
    if len(stack) > MJCF_MAX_INCLUDE_DEPTH:
        raise InputFileError(
            f"{counts.source}: files included {len(stack)} deep, over the {MJCF_MAX_INCLUDE_DEPTH} "
            "ineid follows (MJCF_MAX_INCLUDE_DEPTH); include the parts from fewer levels"
        )
    try:
        counts.nbytes += os.stat(path).st_size
        if counts.nbytes > MJCF_MAX_BYTES:
            raise InputFileError(
                f"{counts.source}: the MJCF and the files it includes hold over {MJCF_MAX_BYTES:,} "
                f"bytes (MJCF_MAX_BYTES, each inclusion counted); {_FIX}"
            )
        with open(path, "rb") as f:
            data = f.read(MJCF_MAX_BYTES)  # a file that grew since its size was read: no more than the limit
    except OSError as e:
        raise InputFileError(
            f"{counts.source}: cannot read {path} ({e.strerror or e}); check the path and its permissions"
        ) from None
    main = path == Path(counts.source)
    xml_encoding(data, counts.source, "the MJCF" if main else f"the file it pulls in, {path},")
    here = path.resolve().parent
    tags: list[tuple[str, int]] = []  # (tag, multiplier of what it holds)
    parser = xml.parsers.expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        outer = tags[-1][1] if tags else mult
        if not tags and parent is not None:  # an included file's <mujoco>: its children join the includer's
            tags.append((parent, outer))
            return
        up = tags[-1][0] if tags else None
        tags.append((tag, outer * _copies(attrs.get("count")) if tag == "replicate" else outer))
        _count(counts, tag, up, attrs, outer)
        if tag == "include" and attrs.get("file"):
            _include(counts, attrs["file"], here, outer, up, (*stack, path))
        elif tag == "model" and up == "asset" and attrs.get("file"):
            _model(counts, attrs.get("name", ""), attrs["file"], here, (*stack, path))
        else:
            for name, value in attrs.items():
                if name.startswith("file") and value:
                    _check_asset(counts, value, here)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: tags.pop()
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        where = "" if main else f" (in {path})"
        raise InputFileError(
            f"{counts.source}: not well-formed XML{where}: {e}; ineid counts an MJCF's bodies before "
            "MuJoCo reads it: fix the XML"
        ) from None


def _count(counts: _Counts, tag: str, up: str | None, attrs: dict[str, str], mult: int) -> None:
    """Add one element (``mult`` copies) to ``counts`` and refuse at once when a count passes its limit."""
    counts.elements += mult
    if tag == "body":
        counts.bodies += mult
    elif tag == "freejoint" or (tag == "joint" and up == "body"):
        counts.joints += mult
    elif tag in ("composite", "flexcomp"):
        counts.bodies += mult * _copies(attrs.get("count"), product=True)
    elif tag == "compiler":
        counts.dirs.update(attrs.get(k, "") for k in ("meshdir", "texturedir", "assetdir"))
    elif tag == "attach" and attrs.get("model") in counts.models:
        bodies, joints, elements = counts.models[attrs["model"]]
        counts.bodies += mult * bodies
        counts.joints += mult * joints
        counts.elements += mult * elements
    check_counts(counts.source, "bodies", counts.bodies, counts.joints, counts.elements, exact=False)


def _copies(text: str | None, product: bool = False) -> int:
    """``<replicate count>`` (or the product of a ``<composite count>``); 1 where MuJoCo will report it."""
    try:
        values = [int(v) for v in (text or "").split()]
    except ValueError:
        return 1
    if not values:
        return 1
    return max(math.prod(values) if product else values[0], 1)


def _candidates(counts: _Counts, name: str, here: Path, dirs: set[str]) -> list[Path]:
    if Path(name).is_absolute():
        return [Path(name)]
    return [base / d / name for base in dict.fromkeys((counts.main_dir, here)) for d in sorted(dirs)]


def _found(paths: list[Path]) -> tuple[Path | None, os.stat_result | None]:
    for p in paths:
        try:
            return p, os.stat(p)
        except OSError:
            continue
    return None, None


def _include(counts: _Counts, name: str, here: Path, mult: int, parent: str | None, stack: tuple[Path, ...]) -> None:
    path, st = _found(_candidates(counts, name, here, {""}))
    if path is None:
        return  # MuJoCo says which file it cannot open
    _check_kind(counts, "includes", path, st)
    if any(path.resolve() == p.resolve() for p in stack):
        return  # MuJoCo refuses an inclusion cycle
    _scan(counts, path, mult, parent, stack)


def _model(counts: _Counts, model: str, name: str, here: Path, stack: tuple[Path, ...]) -> None:
    path, st = _found(_candidates(counts, name, here, counts.dirs))
    if path is None:
        return
    _check_kind(counts, "attaches", path, st)
    if any(path.resolve() == p.resolve() for p in stack):
        return
    sub = _Counts(counts.source, counts.main_dir, counts.nbytes, dirs=set(counts.dirs), models=counts.models)
    _scan(sub, path, 1, None, stack)
    counts.nbytes = sub.nbytes
    counts.models[model] = (sub.bodies, sub.joints, sub.elements)


def _check_asset(counts: _Counts, name: str, here: Path) -> None:
    for path in _candidates(counts, name, here, counts.dirs):
        try:
            st = os.stat(path)
        except OSError:
            continue
        _check_kind(counts, "names", path, st)


def _check_kind(counts: _Counts, verb: str, path: Path, st: os.stat_result) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(
            f"{counts.source}: the MJCF {verb} {path}, which is {file_kind(st.st_mode)}, not a "
            "regular file; give a file"
        )


_DECLARATION = re.compile(rb"""<\?xml[^>]*?\sencoding\s*=\s*["']([^"']*)["']""")
_PROBE = '<inertial pos="-0.5 1e-3" mass="2.0"/>\n\t '
"""The characters of markup and of what ``export-mjcf`` writes: an encoding MuJoCo reads writes them as ASCII."""


def xml_encoding(data: bytes, source: str, what: str = "the MJCF") -> str:
    """The encoding the XML declaration of ``data`` names (UTF-8 without one), checked to be one MuJoCo reads
    (a superset of ASCII: MuJoCo reads a file's bytes as UTF-8, whatever it declares) and to decode ``data``.

    Args:
        what: the file, for the messages (``"the MJCF"``, ``"the file it includes, parts.xml,"``).

    Raises:
        RobotModelError: a byte-order mark of UTF-16 or UTF-32, an encoding Python does not know or that
            is not a superset of ASCII, or bytes that are not valid in the declared encoding.
    """
    fix = "save the file as UTF-8 (MuJoCo reads a file's bytes as UTF-8)"
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):  # UTF-32's marks begin with these too
        raise RobotModelError(
            f"{source}: {what} is UTF-16 or UTF-32 (a byte-order mark), which MuJoCo does not read; {fix}"
        )
    found = _DECLARATION.match(data.removeprefix(codecs.BOM_UTF8))
    name = found.group(1).decode("ascii", "replace") if found else "UTF-8"
    try:
        codec = codecs.lookup(name)
    except LookupError:
        raise RobotModelError(
            f"{source}: {what} declares encoding {name!r}, which ineid does not know; {fix}"
        ) from None
    if _PROBE.encode(codec.name, "replace") != _PROBE.encode("ascii"):
        raise RobotModelError(
            f"{source}: {what} declares encoding {name!r}, which is not a superset of ASCII and "
            f"which MuJoCo does not read; {fix}"
        )
    try:
        data.decode(codec.name)
    except UnicodeDecodeError as e:
        declared = "the encoding its XML declaration names" if found else "the encoding of XML without a declaration"
        raise RobotModelError(
            f"{source}: byte {e.start:,} (0x{data[e.start]:02x}) of {what} is not valid {name}, "
            f"{declared}; save the file in that encoding, or declare the one it is in"
        ) from None
    return codec.name
