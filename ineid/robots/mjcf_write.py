"""Write an MJCF with identified ``<inertial>`` elements: the model's file, edited in place.

The twin of :mod:`ineid.robots.urdf_write` for MuJoCo models (:mod:`ineid.robots.mjcf`). The
original file's text is kept byte for byte except the ``<inertial>`` elements of the bodies
written: each identified body gets ``<inertial pos=... mass=... fullinertia=...>``, the centre
of mass in the *body* frame (the link frame moved back by the hinge's ``pos``) and the inertia
about it in body axes (``ixx iyy izz ixy ixz iyz``, no ``quat``); floats are written with
``repr``. An identified moving body's parameters describe everything welded to it, so each body
welded to it that carries mass gets ``<inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>``
(nothing counted twice; an identified payload keeps its own). The file written is compiled by
MuJoCo before it replaces the output, and every body written must read back to what was meant
(a ``<compiler inertiafromgeom="true">``, ``boundmass`` or ``boundinertia`` that overrides it is
refused). Bodies must be named and in the main file (not in an ``<include>``d one).

The file is edited as bytes in the encoding its XML declaration names (UTF-8 without one): every
byte outside the replaced elements is written back as it was, and what ineid writes is ASCII,
the same bytes in any encoding MuJoCo reads. MuJoCo reads a file's bytes as UTF-8 whatever it
declares, so an encoding that is not a superset of ASCII (UTF-16, UTF-32) cannot be a MuJoCo
model and is refused, as is a file that is not valid in the encoding it declares.
"""

from __future__ import annotations

import xml.parsers.expat
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_output, check_output
from ineid.errors import IdentificationError, RobotModelError
from ineid.params import inertial_from_theta, physical_violations
from ineid.robots.mjcf import compile_mjcf, import_mujoco, read_mjcf
from ineid.robots.robot_files import xml_encoding
from ineid.robots.urdf_write import estimate_of

ZERO_INERTIAL = '<inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>'
"""What a body welded to an identified body gets: its mass is in the identified body's estimate."""
FRAME_ATOL = 1e-9
"""m and (unit-vector) rad: joint origins and axes of the results' robot and the MJCF agree to this."""


def mjcf_with_inertials(
    mjcf_path: str | Path, theta_by_link: dict[str, np.ndarray], results_urdf: str | None = None, locked_joints=None
) -> tuple[bytes, dict[str, tuple[float, np.ndarray, np.ndarray]]]:
    """The MJCF's bytes with the given bodies' inertials replaced, and what each body written must read back as.

    Args:
        mjcf_path: the MuJoCo model (the robot the results were identified on, or the same robot).
        theta_by_link: ``{body: (10,) parameters}`` about the link origin, link frame (a moving
            body with what is welded to it, or a payload body alone).
        results_urdf: the URDF the results were identified with (``results.meta["urdf"]``): its
            joints must be the MJCF's (names, origins, axes), so the link frames are the same.
        locked_joints: as when the model was loaded.

    Returns:
        ``(data, expected)``: the file's bytes, edited (in the encoding it declares); ``expected[body] = (mass,
        com, inertia about com)`` in the body frame,
        for each body written (by its MJCF name).

    Raises:
        IdentificationError: an estimate is not a rigid body (identify with ``--method consistent``).
        RobotModelError: a link is not a body of the MJCF, the MJCF is not the results' robot, a
            body is unnamed or defined in an included file, or the file's encoding is not one MuJoCo
            reads or its bytes are not valid in it.
    """
    from ineid.robots.urdf import parse_chain

    robot = read_mjcf(mjcf_path)
    chain = parse_chain(robot.urdf_text, source=robot.source, locked_joints=locked_joints or None)
    if results_urdf is not None:
        _check_same_robot(
            parse_chain(results_urdf, source="the results' URDF", locked_joints=locked_joints or None),
            chain,
            robot.source,
        )
    expected = _expected_inertials(robot, chain, theta_by_link)
    data = Path(mjcf_path).read_bytes()
    encoding = xml_encoding(data, robot.source)
    edits, by_xml = _inertial_edits(data, encoding, robot, expected)
    for start, stop, new_bytes in sorted(edits, reverse=True):
        data = data[:start] + new_bytes + data[stop:]
    return data, by_xml


def _expected_inertials(robot, chain, theta_by_link: dict[str, np.ndarray]) -> dict[str, tuple]:
    """``{body: (mass, com, inertia about com)}`` each body is to read back as, in the body frame: the estimates,
    and a zero inertial for each body with mass welded to an identified moving body (and not identified itself).

    Raises:
        RobotModelError: a link that is neither a moving body of the MJCF nor a body welded to one.
        IdentificationError: an estimate that is not a rigid body.
    """
    moving = {j.link for j in chain.joints}
    payloads = {b.name for b in chain.body_links.values() if b.parent}
    bad = []
    for link, theta in theta_by_link.items():
        if link not in moving | payloads:
            raise RobotModelError(
                f"{robot.source}: {link!r} is not a moving body of the MJCF "
                f"({', '.join(sorted(moving))}) nor a body welded to one"
            )
        problems = physical_violations(np.asarray(theta, dtype=np.float64), rtol=0.0)
        if problems:
            bad.append(f"link {link!r} ({'; '.join(problems)})")
    if bad:
        raise IdentificationError(
            f"the estimate is not a rigid body for {len(bad)} of {len(theta_by_link)} links, {', '.join(bad)}; "
            "an MJCF cannot hold it: identify with --method consistent (physically consistent by construction)",
            status="non_physical",
        )
    expected: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
    for link, theta in theta_by_link.items():
        m, c, ic = inertial_from_theta(np.asarray(theta, dtype=np.float64))
        expected[link] = (float(m), c - robot.bodies[link].link_p_body, ic)
        if link in moving:
            for welded in chain.merged_links.get(link, (link,))[1:]:
                if welded not in theta_by_link and chain.body_links[welded].theta[0] > 0:
                    expected[welded] = (0.0, np.zeros(3), np.zeros((3, 3)))
    return expected


def _inertial_edits(data: bytes, encoding: str, robot, expected: dict[str, tuple]) -> tuple[list, dict[str, tuple]]:
    """``(edits, by_xml)``: the byte edits ``(start, stop, new bytes)`` that write each body's ``<inertial>`` (in
    place of its own, or as its first child), and ``expected`` keyed by the bodies' MJCF names.

    Raises:
        RobotModelError: a body is unnamed or not in this file (an ``<include>``d one).
    """
    spans = _body_spans(data)
    edits = []
    by_xml: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
    for name, (m, c, ic) in expected.items():
        xml_name = robot.bodies[name].xml_name
        if xml_name is None or xml_name not in spans:
            where = "is unnamed" if xml_name is None else "is not in this file (an <include>d file?)"
            raise RobotModelError(
                f"{robot.source}: body {name!r} {where}; ineid edits named bodies of the main file: "
                "name it, or move it into the main file"
            )
        start_end, inertial = spans[xml_name]
        by_xml[xml_name] = (m, c, ic)
        if m == 0.0:
            new = ZERO_INERTIAL
        else:
            full = (ic[0, 0], ic[1, 1], ic[2, 2], ic[0, 1], ic[0, 2], ic[1, 2])
            new = f'<inertial pos="{_fmt(c)}" mass="{m!r}" fullinertia="{_fmt(full)}"/>'
        new_bytes = new.encode(encoding)
        if inertial is not None:
            edits.append((inertial[0], inertial[1], new_bytes))
        elif data[start_end - 2 : start_end] == b"/>":  # <body name=.../>: open it
            edits.append((start_end - 2, start_end, b">" + _indent(data, start_end) + new_bytes + b"</body>"))
        else:
            edits.append((start_end, start_end, _indent(data, start_end) + new_bytes))
    return edits, by_xml


def _check_same_robot(results_chain, chain, source: str) -> None:
    """The results' joints are the MJCF's: same names and child links, origins and axes within :data:`FRAME_ATOL`."""
    by_name = {j.name: j for j in chain.joints}
    for a in results_chain.joints:
        b = by_name.get(a.name)
        if b is None or b.link != a.link:
            raise RobotModelError(
                f"{source}: the results' joint {a.name!r} (link {a.link!r}) is not in the MJCF "
                f"(joints: {', '.join(by_name)}); give --robot the MJCF of the robot the results "
                "were identified on (names must match)"
            )
        if not all(
            np.allclose(getattr(a, k), getattr(b, k), rtol=0, atol=FRAME_ATOL)
            for k in ("parent_R_joint", "parent_p_joint", "axis")
        ):
            raise RobotModelError(
                f"{source}: joint {a.name!r} has another origin or axis in the MJCF than in the "
                "results' robot, so the link frames differ; identify with the MJCF as ROBOT"
            )


def _body_spans(data: bytes) -> dict[str, tuple[int, tuple[int, int] | None]]:
    """Per named ``<body>``: the byte offset just past its start tag, and its own ``<inertial>``'s (start, stop)."""
    parser = xml.parsers.expat.ParserCreate()
    stack: list[tuple[str, dict, int]] = []
    out: dict[str, list] = {}

    def start(tag, attrs):
        stack.append((tag, attrs, parser.CurrentByteIndex))

    def end(tag):
        _, attrs, begin = stack.pop()
        tag_stop = _tag_end(data, begin)
        # an empty element ends with its start tag; else expat is at the end tag's "<"
        stop = tag_stop if data[tag_stop - 2 : tag_stop] == b"/>" else data.index(b">", parser.CurrentByteIndex) + 1
        if tag == "body" and attrs.get("name"):
            out.setdefault(attrs["name"], [None, None])[0] = tag_stop
        elif tag == "inertial" and stack and stack[-1][0] == "body" and stack[-1][1].get("name"):
            out.setdefault(stack[-1][1]["name"], [None, None])[1] = (begin, stop)

    parser.StartElementHandler, parser.EndElementHandler = start, end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise RobotModelError(f"the MJCF is not well-formed XML ({e})") from None
    return {k: (v[0], v[1]) for k, v in out.items()}


def _tag_end(data: bytes, begin: int) -> int:
    """The offset just past the ``>`` that closes the tag starting at ``begin`` (quotes skipped)."""
    quote = None
    for i in range(begin, len(data)):
        ch = data[i : i + 1]
        if quote:
            quote = None if ch == quote else quote
        elif ch in (b'"', b"'"):
            quote = ch
        elif ch == b">":
            return i + 1
    raise RobotModelError("the MJCF has an unterminated tag")


def _indent(data: bytes, at: int) -> bytes:
    """A newline and the indentation (spaces and tabs) of the line holding offset ``at``, two spaces deeper."""
    line = data[data.rfind(b"\n", 0, at) + 1 : at]
    return b"\n" + line[: len(line) - len(line.lstrip(b" \t"))] + b"  "


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def check_read_back(path: str | Path, expected: dict[str, tuple[float, np.ndarray, np.ndarray]]) -> None:
    """MuJoCo compiles ``path`` and each body of ``expected`` has that mass, centre of mass and inertia (body frame).

    Raises:
        RobotModelError: MuJoCo cannot compile it (an include or mesh not found from its folder), or a
            body reads back otherwise (the compiler overrides ``<inertial>``).
    """
    mujoco = import_mujoco("export-mjcf")
    m, _ = compile_mjcf(
        mujoco,
        path,
        "",
        "the exported model from its folder",
        "nothing was written: write it beside the original (includes and meshes are found relative to the model file)",
    )
    for name, (mass, c, ic) in expected.items():
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        r = np.empty(9)
        mujoco.mju_quat2Mat(r, np.asarray(m.body_iquat[b], dtype=np.float64))
        r = r.reshape(3, 3)
        got = r @ np.diag(m.body_inertia[b]) @ r.T
        scale = max(float(np.abs(ic).max()), 1e-300)
        ok = abs(m.body_mass[b] - mass) <= 1e-9 * max(mass, 1.0) and (
            mass == 0.0
            or (np.allclose(m.body_ipos[b], c, rtol=0, atol=1e-9) and np.allclose(got, ic, rtol=0, atol=1e-9 * scale))
        )
        if not ok:
            raise RobotModelError(
                f"MuJoCo reads body {name!r} of the exported model back as mass "
                f"{float(m.body_mass[b]):g} kg, not the identified {mass:g}: its <compiler> overrides "
                '<inertial> (inertiafromgeom="true", boundmass, boundinertia); set '
                'inertiafromgeom="auto" and drop the bounds; nothing was written'
            )


def export_mjcf(results, config: int, robot: str | Path, out: str | Path, overwrite: bool = False) -> Path:
    """Write the MJCF ``robot`` with ``results``' configuration ``config``'s estimates to ``out`` (atomically).

    Args:
        results: a :class:`ineid.identify.solve.SolveResults` (or its file's contents).
        config: the configuration's index in the dataset (``config_index``).
        robot: the MJCF of the results' robot (identified from it, or the MJCF twin of its URDF).
        out: the ``.xml`` file to write; MuJoCo compiles it before it replaces ``out``.
    """
    out = check_output(out, overwrite)
    by_link = estimate_of(results, config)
    data, expected = mjcf_with_inertials(robot, by_link, results.meta["urdf"], results.meta.get("locked_joints"))
    with atomic_output(out) as tmp:
        tmp.write_bytes(data)
        check_read_back(tmp, expected)
    return out
