"""MJCF -> the URDF ineid reads: MuJoCo models (MuJoCo Menagerie) as ineid robots.

MuJoCo's own parser reads the file (``mujoco.MjModel.from_xml_path``: includes, default
classes, ``<compiler angle=... eulerseq=...>``, ``inertiafromgeom``, ``fullinertia`` or
``diaginertia`` with ``quat``); this module reads the *compiled* model (``body_pos``,
``body_quat``, ``jnt_axis``, ``jnt_pos``, ``jnt_range``, ``body_mass``, ``body_ipos``,
``body_iquat``, ``body_inertia``) and writes the URDF of the same robot, which
:func:`ineid.robots.urdf.parse_chain` turns into the :class:`~ineid.chain.Chain`. So an
MJCF robot is a URDF robot from there on: datasets carry that URDF text, and locking joints,
payloads, welded frames, sensor frames and generated-code caching (by the chain's kinematic
fingerprint) work unchanged.

Frames. Each MuJoCo body is a URDF link; a body with one hinge or slide joint is a moving
link, a body without joints is welded to its parent (a fixed joint). A hinge's axis passes
through ``jnt_pos`` (body frame); ineid's link frame is the body frame moved to that point
(same axes): ``body_p = link_p + jnt_pos``, so the joint turns the link about its own origin.
A link's parameters (and the regressor's columns) refer to that frame; they equal the body
frame's when ``pos`` is 0, as it is in most models. A slide keeps the body frame. MuJoCo's
``qpos`` is ineid's ``q``: the joint's ``ref`` (the value at which the body has its given
pose) is folded into the joint origin. Each inertial is written about its centre of mass,
``I_c = R(iquat) diag(body_inertia) R(iquat)^T`` in link axes: what ineid's ``theta`` stands for.

The robot is the subtree of ``<worldbody>`` holding the joints. Its top body is the root
link (the fixture, tared away) when it has no joint; otherwise the world is (link ``world``).
Other bodies welded to the world (floor, scenery) are not part of the robot. Unsupported:
free and ball joints, a body with several joints, tendons and equality constraints, joints
in more than one subtree; one line says which element and what to do. Actuators, sensors,
contacts and options are ignored (MuJoCo's gravity: see the note in ``robot show``).
Primitive collision geoms become ``<collision>`` (capsules as cylinders of the same segment,
meshes and ellipsoids as their bounding box): the excitation's collision model reads them.

Before MuJoCo reads a file, :func:`ineid.robots.robot_files.scan_mjcf` bounds it (regular files,
bytes, bodies, joints, elements, encoding); while MuJoCo runs, its warnings come to ineid
(:func:`mujoco_warnings`), never to ``MUJOCO_LOG.TXT`` in the working folder: a NaN is refused,
other warnings become notes.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ineid.chain import Chain
from ineid.errors import OptionalDependencyError, RobotModelError
from ineid.robots.cad_rounding import matrix_rpy
from ineid.robots.robot_files import scan_mjcf

INSTALL_HINT = "needs MuJoCo: pip install 'ineid[mujoco]'"
MJCF_SUFFIXES = (".xml", ".mjcf")
"""A robot file whose top element is ``<mujoco>`` is read as MJCF; one that is not XML, by these suffixes."""

_HINGE, _SLIDE = 3, 2  # mjtJoint: FREE 0, BALL 1, SLIDE 2, HINGE 3
_JOINT_KIND = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}
_INERTIA = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}


def import_mujoco(purpose: str = "the MuJoCo simulation"):
    """The ``mujoco`` module, or :class:`OptionalDependencyError` naming ``purpose`` and the install command."""
    try:
        import mujoco
    except ImportError:
        raise OptionalDependencyError(f"{purpose} {INSTALL_HINT}") from None
    return mujoco


@contextmanager
def mujoco_warnings(mujoco) -> Iterator[list[str]]:
    """Collect MuJoCo's warnings while the block runs (the list yielded), instead of its default handler's.

    MuJoCo's default handler appends each warning (``XML contains a 'NaN'``, for one) to
    ``MUJOCO_LOG.TXT`` in the current working folder and prints it on stderr; ineid installs its own
    handler (``mujoco.set_mju_user_warning``) around every MuJoCo call that can warn, and puts back the
    one before it afterwards, so nothing is written into the user's folder.
    """
    warnings: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warnings.append)
    try:
        yield warnings
    finally:
        mujoco.set_mju_user_warning(previous)


def compile_mjcf(mujoco, path: str | Path, source: str, what: str = "the model", fix: str = "fix the MJCF"):
    """``(MjModel, warnings)`` of the MJCF ``path``, compiled by MuJoCo, its warnings caught (:func:`mujoco_warnings`).

    ``source`` begins the messages (none when empty), ``what`` names the model in them and ``fix`` ends them.

    Raises:
        RobotModelError: MuJoCo cannot compile it, or warns of a NaN (one line with MuJoCo's words).
    """
    with mujoco_warnings(mujoco) as warnings:
        try:
            m = mujoco.MjModel.from_xml_path(str(path))
        except ValueError as e:
            m, error = None, " ".join(str(e).split())
    where = f"{source}: " if source else ""
    nan = [w for w in warnings if "NaN" in w]
    if nan:
        raise RobotModelError(f"{where}MuJoCo reads a NaN in {what} ({' '.join(nan[0].split())}); give finite numbers")
    if m is None:
        raise RobotModelError(f"{where}MuJoCo cannot compile {what} ({error}); {fix}")
    return m, [" ".join(w.split()) for w in warnings]


def is_mjcf(path: str | Path) -> bool:
    """Whether the robot file ``path`` is MJCF: its top element is ``<mujoco>`` (unreadable or not XML:
    its suffix is one of :data:`MJCF_SUFFIXES`, so MuJoCo's parser says what is wrong)."""
    try:
        for _, el in ET.iterparse(path, events=("start",)):
            return el.tag == "mujoco"
    except (OSError, ET.ParseError, LookupError):  # LookupError: an encoding Python does not know
        pass
    return Path(path).suffix.lower() in MJCF_SUFFIXES


@dataclass(frozen=True)
class MjcfBody:
    """One MuJoCo body of the robot as a URDF link.

    ``xml_name`` is its name in the MJCF (None for an unnamed body, which gets ``body<id>``);
    ``link_p_body`` the body frame's origin in the link frame (``-jnt_pos`` of a hinge, else 0);
    ``body_id`` its index in the compiled model.
    """

    name: str
    xml_name: str | None
    body_id: int
    moving: bool
    link_p_body: np.ndarray


@dataclass(frozen=True)
class MjcfRobot:
    """An MJCF read by MuJoCo, as the URDF ineid reads: ``urdf_text``, its bodies, the notes."""

    source: str
    urdf_text: str
    root: str
    bodies: dict[str, MjcfBody]
    notes: tuple[str, ...]


def read_mjcf(path: str | Path) -> MjcfRobot:
    """Compile an MJCF with MuJoCo and write the URDF of its robot (module docstring).

    Raises:
        OptionalDependencyError: MuJoCo is not installed.
        InputFileError: the file, or one it includes or names, is not a regular file, or the model is
            over the limits of :mod:`ineid.robots.robot_files` (refused before MuJoCo reads it).
        RobotModelError: the file is not valid in the encoding it declares, MuJoCo cannot compile it or
            reads a NaN in it, a number of the robot is not finite, or the model is not one serial arm
            of hinge and slide joints (free or ball joints, tendons, equality constraints,
            several joints in one body, joints in several subtrees of the world).
    """
    mujoco = import_mujoco("MJCF")
    source = str(path)
    scan_mjcf(path)
    m, warnings = compile_mjcf(mujoco, path, source)
    _check_supported(mujoco, m, source)
    names = _names(mujoco, m, source)
    parent = m.body_parentid
    moving = [b for b in range(1, m.nbody) if m.body_jntnum[b] > 0]
    if not moving:
        raise RobotModelError(f"{source}: the model has no hinge or slide joint; nothing would move the base wrench")
    tops = sorted({int(m.body_rootid[b]) for b in moving})
    if len(tops) > 1:
        raise RobotModelError(
            f"{source}: joints in {len(tops)} separate bodies under <worldbody> "
            f"({', '.join(names['body'][t] for t in tops)}); ineid identifies one arm: remove the others from the model"
        )
    top = tops[0]
    root = 0 if m.body_jntnum[top] > 0 else top
    members = [b for b in range(1, m.nbody) if int(m.body_rootid[b]) == top]
    _check_finite(m, members, names, source)
    notes = [f"MuJoCo warns: {w}" for w in warnings]
    scenery = [names["body"][b] for b in range(1, m.nbody) if int(m.body_rootid[b]) != top and parent[b] == 0]
    if scenery:
        notes.append(f"bodies welded to the world outside the robot are not part of it: {', '.join(scenery)}")
    unnamed = [names["body"][b] for b in members if names["xml_body"][b] is None]
    unnamed += [
        names["joint"][j]
        for b in members
        for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b])
        if not mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
    ]
    if unnamed:
        notes.append(f"unnamed bodies and joints are called {', '.join(unnamed)} (export-mjcf needs named bodies)")
    world_R_root = _quat_matrix(mujoco, m.body_quat[root]) if root else np.eye(3)
    g_base = world_R_root.T @ np.asarray(m.opt.gravity, dtype=np.float64)
    if not np.allclose(g_base, (0.0, 0.0, -9.81), rtol=0, atol=1e-12):
        notes.append(
            "the model's gravity in the base frame is "
            + " ".join(f"{v:.6g}" for v in g_base)
            + " m/s^2; ineid's default is 0 0 -9.81: pass --gravity to use the model's"
        )
    shift = {b: _shift(m, b) for b in range(m.nbody)}
    bodies = {}
    robot = ET.Element("robot", name=_model_name(path))
    for b in [root, *members] if root == 0 else members:
        name = names["body"][b]
        bodies[name] = MjcfBody(name, names["xml_body"][b], b, bool(m.body_jntnum[b]), -shift[b])
        link = ET.SubElement(robot, "link", name=name)
        _inertial(mujoco, m, b, shift[b], link)
        _collisions(mujoco, m, b, shift[b], link)
    for b in members:
        if b == root:
            continue
        _joint(mujoco, m, b, shift, names, robot, source)
    ET.indent(robot, space="  ")
    text = '<?xml version="1.0"?>\n<!-- written by ineid from an MJCF compiled by MuJoCo (ineid.robots.mjcf) -->\n'
    return MjcfRobot(
        source, text + ET.tostring(robot, encoding="unicode") + "\n", names["body"][root], bodies, tuple(notes)
    )


def load_mjcf_chain(path: str | Path, locked_joints: Mapping[str, float] | None = None) -> tuple[Chain, str]:
    """``(chain, urdf_text)`` of an MJCF robot (:func:`read_mjcf`, then :func:`ineid.robots.urdf.parse_chain`)."""
    from ineid.robots.urdf import parse_chain

    robot = read_mjcf(path)
    chain = parse_chain(robot.urdf_text, source=robot.source, locked_joints=locked_joints)
    return replace(chain, notes=(*robot.notes, *chain.notes)), robot.urdf_text


# -- the pieces ------------------------------------------------------------------------


def _check_supported(mujoco, m, source: str) -> None:
    def name(kind, i, fallback):
        return _name(mujoco, m, kind, i, source) or fallback

    if m.ntendon:
        tendons = ", ".join(name(mujoco.mjtObj.mjOBJ_TENDON, i, f"#{i}") for i in range(m.ntendon))
        raise RobotModelError(
            f"{source}: <tendon> {tendons}: ineid models rigid serial arms without tendons; remove "
            "the <tendon> section (and the actuators and sensors that use it)"
        )
    if m.neq:
        eqs = ", ".join(name(mujoco.mjtObj.mjOBJ_EQUALITY, i, f"#{i}") for i in range(m.neq))
        raise RobotModelError(
            f"{source}: <equality> constraint {eqs}: ineid models serial arms without closed loops "
            "or coupled joints; remove the <equality> section"
        )
    for j in range(m.njnt):
        kind = int(m.jnt_type[j])
        if kind not in (_HINGE, _SLIDE):
            body = name(mujoco.mjtObj.mjOBJ_BODY, int(m.jnt_bodyid[j]), f"#{m.jnt_bodyid[j]}")
            fix = (
                'weld the body to its parent (remove the <freejoint>/<joint type="free">; a floating object '
                "is no part of the arm: remove it)"
                if kind == 0
                else "replace it by hinge joints in nested bodies, or remove it"
            )
            raise RobotModelError(
                f"{source}: {_JOINT_KIND[kind]} joint "
                f"{name(mujoco.mjtObj.mjOBJ_JOINT, j, f'#{j}')!r} of body {body!r}: ineid supports "
                f"hinge and slide joints only; {fix}"
            )
    for b in range(1, m.nbody):
        if m.body_jntnum[b] > 1:
            adr = int(m.body_jntadr[b])
            joints = ", ".join(name(mujoco.mjtObj.mjOBJ_JOINT, j, f"#{j}") for j in range(adr, adr + m.body_jntnum[b]))
            raise RobotModelError(
                f"{source}: body {name(mujoco.mjtObj.mjOBJ_BODY, b, f'#{b}')!r} has "
                f"{m.body_jntnum[b]} joints ({joints}); ineid needs one joint per body: give each "
                "joint a body of its own (nested, with no pos or quat)"
            )


def _name(mujoco, m, kind, i: int, source: str) -> str | None:
    """The name of object ``i``, or None; MuJoCo keeps a name's bytes as written, whatever the file's encoding."""
    try:
        return mujoco.mj_id2name(m, kind, i)
    except UnicodeDecodeError:
        raise RobotModelError(
            f"{source}: the name of {kind.name[6:].lower()} #{i} is not UTF-8 (MuJoCo reads a file's "
            "bytes as UTF-8, whatever its XML declaration says); save the MJCF as UTF-8"
        ) from None


def _names(mujoco, m, source: str) -> dict[str, list]:
    """Body and joint names; an unnamed one gets ``body<id>`` / ``joint<id>`` (``xml_body``: None then)."""
    xml_body = [_name(mujoco, m, mujoco.mjtObj.mjOBJ_BODY, b, source) or None for b in range(m.nbody)]
    body = [n or f"body{b}" for b, n in enumerate(xml_body)]
    joint = [_name(mujoco, m, mujoco.mjtObj.mjOBJ_JOINT, j, source) or f"joint{j}" for j in range(m.njnt)]
    return {"xml_body": xml_body, "body": body, "joint": joint}


_BODY_FIELDS = ("body_pos", "body_quat", "body_mass", "body_ipos", "body_iquat", "body_inertia")
_JOINT_FIELDS = ("jnt_pos", "jnt_axis", "jnt_range")


def _check_finite(m, members: list[int], names: dict[str, list], source: str) -> None:
    """Every number ineid reads of the robot's bodies and joints is finite (MuJoCo compiles ``inf``), and each
    joint's range is in order."""
    for b in members:
        for f in _BODY_FIELDS:
            value = np.asarray(getattr(m, f)[b], dtype=np.float64)
            if not np.all(np.isfinite(value)):
                raise RobotModelError(
                    f"{source}: body {names['body'][b]!r}: {f[5:]} {_fmt(value)} is not finite; give finite numbers"
                )
        for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b] + m.body_jntnum[b])):
            for f in _JOINT_FIELDS:
                value = np.asarray(getattr(m, f)[j], dtype=np.float64)
                if not np.all(np.isfinite(value)):
                    raise RobotModelError(
                        f"{source}: joint {names['joint'][j]!r}: {f[4:]} {_fmt(value)} is not "
                        "finite; give finite numbers"
                    )
            ref = float(m.qpos0[int(m.jnt_qposadr[j])])
            if not math.isfinite(ref):
                raise RobotModelError(
                    f"{source}: joint {names['joint'][j]!r}: ref {ref!r} is not finite; give a finite number"
                )
            lo, hi = (float(v) for v in m.jnt_range[j])
            if lo > hi:
                raise RobotModelError(
                    f"{source}: joint {names['joint'][j]!r}: range {lo!r} {hi!r} (compiled, rad or "
                    'm) has its lower end above the upper one; give range="LOWER UPPER"'
                )


def _model_name(path) -> str:
    try:
        for _, el in ET.iterparse(path, events=("start",)):
            return el.get("model") or Path(path).stem
    except (OSError, ET.ParseError, LookupError):  # LookupError: an encoding Python does not know
        pass
    return Path(path).stem


def _shift(m, b: int) -> np.ndarray:
    """The link frame's origin in the body frame: a hinge's ``jnt_pos``, else 0."""
    if b == 0 or m.body_jntnum[b] == 0:
        return np.zeros(3)
    j = int(m.body_jntadr[b])
    return np.array(m.jnt_pos[j], dtype=np.float64) if m.jnt_type[j] == _HINGE else np.zeros(3)


def _quat_matrix(mujoco, quat) -> np.ndarray:
    r = np.empty(9)
    mujoco.mju_quat2Mat(r, np.asarray(quat, dtype=np.float64))
    return r.reshape(3, 3)


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    s = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * s + (1 - math.cos(angle)) * s @ s


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _origin(el: ET.Element, r: np.ndarray, p: np.ndarray) -> None:
    ET.SubElement(el, "origin", xyz=_fmt(p), rpy=_fmt(matrix_rpy(r)))


def _inertial(mujoco, m, b: int, shift: np.ndarray, link: ET.Element) -> None:
    """``<inertial>`` of body ``b`` in its link frame: centre of mass ``body_ipos - shift``, inertia about it."""
    mass = float(m.body_mass[b])
    if mass <= 0:
        return
    r = _quat_matrix(mujoco, m.body_iquat[b])
    ic = r @ np.diag(np.asarray(m.body_inertia[b], dtype=np.float64)) @ r.T
    el = ET.SubElement(link, "inertial")
    ET.SubElement(el, "origin", xyz=_fmt(np.asarray(m.body_ipos[b]) - shift), rpy="0 0 0")
    ET.SubElement(el, "mass", value=repr(mass))
    ET.SubElement(el, "inertia", **{k: repr(float(ic[a, b])) for k, (a, b) in _INERTIA.items()})


def _collisions(mujoco, m, b: int, shift: np.ndarray, link: ET.Element) -> None:
    """The body's colliding primitive geoms (``contype`` or ``conaffinity`` set) as URDF ``<collision>``."""
    g = mujoco.mjtGeom
    for i in np.flatnonzero(np.asarray(m.geom_bodyid) == b):
        if not (m.geom_contype[i] or m.geom_conaffinity[i]):
            continue
        kind, size = int(m.geom_type[i]), np.asarray(m.geom_size[i], dtype=np.float64)
        r, c = _quat_matrix(mujoco, m.geom_quat[i]), np.asarray(m.geom_pos[i], dtype=np.float64) - shift
        if kind == g.mjGEOM_SPHERE:
            shape = ("sphere", {"radius": repr(float(size[0]))})
        elif kind in (g.mjGEOM_CAPSULE, g.mjGEOM_CYLINDER):
            shape = ("cylinder", {"radius": repr(float(size[0])), "length": repr(float(2 * size[1]))})
        elif kind in (g.mjGEOM_BOX, g.mjGEOM_ELLIPSOID):
            shape = ("box", {"size": _fmt(2 * size)})
        elif kind == g.mjGEOM_MESH:
            aabb = np.asarray(m.geom_aabb[i], dtype=np.float64)
            c = c + r @ aabb[:3]
            shape = ("box", {"size": _fmt(2 * aabb[3:])})
        else:
            continue
        el = ET.SubElement(link, "collision")
        _origin(el, r, c)
        ET.SubElement(ET.SubElement(el, "geometry"), shape[0], **shape[1])


def _joint(mujoco, m, b: int, shift: dict, names: dict, robot: ET.Element, source: str) -> None:
    """The URDF joint into body ``b``: ``parent_T_link = Trans(-shift_p) P_T_B Trans(shift_b) (ref undone)``."""
    p = int(m.body_parentid[b])
    r = _quat_matrix(mujoco, m.body_quat[b])
    pos = np.asarray(m.body_pos[b], dtype=np.float64) + r @ shift[b] - shift[p]
    if m.body_jntnum[b] == 0:
        el = ET.SubElement(robot, "joint", name=f"{names['body'][b]}_weld", type="fixed")
        _origin(el, r, pos)
    else:
        j = int(m.body_jntadr[b])
        axis = np.asarray(m.jnt_axis[j], dtype=np.float64)
        ref = float(m.qpos0[int(m.jnt_qposadr[j])])
        hinge = m.jnt_type[j] == _HINGE
        if ref and hinge:
            r = r @ _axis_rotation(axis, -ref)
        elif ref:
            pos = pos - r @ axis * ref
        limited = bool(m.jnt_limited[j])
        if not hinge and not limited:
            raise RobotModelError(
                f"{source}: slide joint {names['joint'][j]!r} has no range; give it "
                'range="LOWER UPPER" (and limited="true" where the compiler needs it)'
            )
        kind = ("revolute" if limited else "continuous") if hinge else "prismatic"
        el = ET.SubElement(robot, "joint", name=names["joint"][j], type=kind)
        _origin(el, r, pos)
        ET.SubElement(el, "axis", xyz=_fmt(axis))
        if limited:
            lo, hi = (float(v) for v in m.jnt_range[j])
            ET.SubElement(el, "limit", lower=repr(lo), upper=repr(hi), effort="0", velocity="0")
    ET.SubElement(el, "parent", link=names["body"][p])
    ET.SubElement(el, "child", link=names["body"][b])
