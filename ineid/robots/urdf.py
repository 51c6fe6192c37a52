"""URDF -> :class:`Chain`: the numeric description of a robot that ineid works on.

Parsing is yourdfpy's (once per URDF text: the result is kept in the cache folder, see
:func:`parse_chain`); this module turns its tree into a chain of moving joints, a tree on the
fixed root body (a serial arm, a torso with two arms, a hand with fingers; a closed loop or a
second root is refused):

* moving joints are in chain order: depth first from the root, each body's moving child joints
  in URDF order, so every parent precedes its children (:attr:`Chain.parents`), each subtree is a
  run of consecutive joints, and a serial chain keeps its URDF order;

* fixed joints are merged into their parent body, their inertia folded in (as Pinocchio
  does); links welded to the root belong to the fixture and are tared away;
* ``locked_joints`` turns chosen moving joints into fixed ones at a given position (the
  way to drop a gripper's fingers, for example); a joint that ``<mimic>``s a locked joint is
  locked with it, at ``multiplier * position + offset``;
* joint ``rpy`` angles within :data:`~ineid.robots.cad_rounding.ANGLE_ATOL` of a multiple of
  pi/2 are CAD rounding (``3.14159265359``) and are snapped to it (:mod:`ineid.robots.cad_rounding`);
* continuous joints are revolute joints without position limits;
* each link's ``<inertial>`` is read by :func:`ineid.robots.inertial.link_inertial`: links
  without mass are frames, point masses are accepted, a non-physical body with real mass is
  refused; every link of a moving body keeps its own inertial and pose
  (:attr:`Chain.body_links`), so a welded payload can be identified on its own;
* a moving link without mass is kept (a known link contributing nothing), but a chain whose
  moving links carry no mass at all is refused.

Sampling bounds: ``<limit velocity=...>`` bounds ``|qd|`` (absent or ``0``, URDF writers' "not
given": :data:`DEFAULT_QD_MAX`); the acceleration bound, which URDF has no field for, comes from
an optional ``<ineid acceleration="..."/>`` element inside a ``<joint>`` (ignored by other URDF
readers), else :data:`DEFAULT_QDD_MAX`. Every number read is checked first
(:mod:`ineid.robots.urdf_checks`: finite, limits not negative), and the text is bounded
(:mod:`ineid.robots.robot_files`).

:class:`Chain` and :class:`JointSpec` are defined in :mod:`ineid.chain` (importable
from here too).
"""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ineid._inputs import regular_file
from ineid.chain import BodyLink, Chain, JointSpec
from ineid.errors import RobotModelError
from ineid.params import theta_from_inertial
from ineid.robots.cad_rounding import snap_joint_angles
from ineid.robots.inertial import link_inertial
from ineid.robots.robot_files import URDF_MAX_BYTES, check_urdf_size
from ineid.robots.urdf_cache import CHAIN_SUBDIR, cached_chain, chain_key, store_chain  # noqa: F401  (CHAIN_SUBDIR re-exported)
from ineid.robots.urdf_checks import check_lxml, check_urdf_tree

DEFAULT_QD_MAX = 3.0
"""rad/s (m/s for prismatic): velocity bound for sampling where the URDF gives none."""
DEFAULT_QDD_MAX = 10.0
"""rad/s^2 (m/s^2 for prismatic): acceleration bound for sampling where the URDF gives none."""

_MOVING = {"revolute", "continuous", "prismatic"}
_SUPPORTED = _MOVING | {"fixed"}


def load_chain(path: str | Path, locked_joints: Mapping[str, float] | None = None) -> Chain:
    """Read a URDF file into a :class:`Chain`.

    Raises:
        InputFileError: the file is not a regular file, or is over :data:`~ineid.robots.robot_files.URDF_MAX_BYTES`
            (or its links and joints over their limits).
        RobotModelError: the file is unreadable, malformed, not a tree (a loop, two roots), or has
            an unsupported joint, a number that is not finite or a negative limit, or a non-physical inertial.
    """
    path = regular_file(path, "the URDF", max_bytes=URDF_MAX_BYTES, limit_name="URDF_MAX_BYTES")
    try:
        text = path.read_bytes()
    except OSError as e:
        raise RobotModelError(f"cannot read URDF {str(path)!r}: {e.strerror or e}") from None
    return parse_chain(text, source=str(path), locked_joints=locked_joints)


def parse_chain(text: bytes | str, source: str = "<urdf>", locked_joints: Mapping[str, float] | None = None) -> Chain:
    """Parse URDF text into a :class:`Chain`; see :func:`load_chain`.

    A URDF parsed once is remembered in the cache folder (:func:`cached_chain`), so later
    processes skip yourdfpy (and its trimesh import, about half a second).
    """
    data = text.encode() if isinstance(text, str) else text
    check_urdf_size(len(data), source)
    key = chain_key(data, source, locked_joints)
    chain = cached_chain(key)
    if chain is not None:
        return chain
    chain = _parse_chain(data, source, locked_joints)
    store_chain(key, chain)
    return chain


def _parse_chain(data: bytes, source: str, locked_joints: Mapping[str, float] | None) -> Chain:
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise RobotModelError(f"{source}: malformed XML ({e}); fix the file so that it is well-formed XML") from None
    except LookupError as e:  # the XML declaration names an encoding Python does not know
        raise RobotModelError(f"{source}: {e} in the XML declaration; save the URDF as UTF-8") from None
    if root.tag != "robot":
        raise RobotModelError(f"{source}: top-level element is <{root.tag}>, a URDF needs <robot>")
    check_urdf_tree(root, source)
    robot = _yourdfpy_robot(data, source)
    qdd_bounds = {
        j.get("name"): j.find("ineid").get("acceleration")
        for j in root.iter("joint")
        if j.find("ineid") is not None and j.find("ineid").get("acceleration") is not None
    }
    notes = snap_joint_angles(root, robot)
    return _build_chain(robot, source, dict(locked_joints or {}), qdd_bounds, notes)


def _yourdfpy_robot(data: bytes, source: str):
    """yourdfpy's ``Robot`` of URDF ``data`` (no meshes, no scene graph), once lxml has read it (:func:`check_lxml`)."""
    import yourdfpy  # heavy: trimesh

    check_lxml(data, source)
    try:
        return yourdfpy.URDF.load(
            io.BytesIO(data),
            build_scene_graph=False,
            load_meshes=False,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
        ).robot
    except Exception as e:  # yourdfpy raises assorted builtin errors for bad attribute values
        raise RobotModelError(f"{source}: invalid URDF ({type(e).__name__}: {e})") from None


def _check_finite_joint(j, source: str) -> None:
    """A joint's ``<origin>`` and ``<axis>`` hold finite numbers (yourdfpy accepts nan and inf)."""
    if j.origin is not None and not np.all(np.isfinite(np.asarray(j.origin, dtype=np.float64))):
        raise RobotModelError(
            f"{source}: joint {j.name!r}: <origin xyz=... rpy=...> holds a non-finite value "
            "(nan or inf); give finite numbers"
        )
    if j.axis is not None and not np.all(np.isfinite(np.asarray(j.axis, dtype=np.float64))):
        raise RobotModelError(
            f"{source}: joint {j.name!r}: <axis xyz=...> holds a non-finite value (nan or inf); give a finite direction"
        )


def _transform(origin) -> tuple[np.ndarray, np.ndarray]:
    if origin is None:
        return np.eye(3), np.zeros(3)
    t = np.asarray(origin, dtype=np.float64)
    return t[:3, :3].copy(), t[:3, 3].copy()


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    s = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * s + (1 - math.cos(angle)) * s @ s


def link_theta(link, source: str) -> np.ndarray:
    """(10,) a yourdfpy link's own parameters about its frame origin, zero for a frame without mass
    (:func:`ineid.robots.inertial.link_inertial`, its note dropped)."""
    return link_inertial(link, source)[0]


def _fold(theta: np.ndarray, parent_R: np.ndarray, parent_p: np.ndarray) -> np.ndarray:
    """Express a body's parameters in its parent frame: theta' = X(parent_T_body) theta."""
    if theta[0] == 0:
        return np.zeros(10)
    from ineid.params import inertial_from_theta

    m, c, ic = inertial_from_theta(theta)
    return theta_from_inertial(m, parent_R @ c + parent_p, parent_R @ ic @ parent_R.T)


def _mimic_locks(robot, locked: dict[str, float]) -> tuple[dict[str, float], list[str]]:
    """``locked`` with every joint that mimics a locked joint locked too, at ``multiplier * q + offset``
    (followers of followers included); and one note per leader. An explicit position wins."""
    locked = dict(locked)
    followers: dict[str, list[str]] = {}
    changed = True
    while changed:
        changed = False
        for j in robot.joints:
            if j.mimic is None or j.name in locked or j.mimic.joint not in locked:
                continue
            mult = 1.0 if j.mimic.multiplier is None else float(j.mimic.multiplier)
            offset = 0.0 if j.mimic.offset is None else float(j.mimic.offset)
            locked[j.name] = mult * locked[j.mimic.joint] + offset
            followers.setdefault(j.mimic.joint, []).append(f"{j.name} at {locked[j.name]:g}")
            changed = True
    notes = [
        f"locked with joint {leader!r}, which they mimic: {', '.join(names)}" for leader, names in followers.items()
    ]
    return locked, notes


def _build_chain(robot, source: str, locked: dict[str, float], qdd_bounds: dict[str, str], notes: list[str]) -> Chain:
    """The chain of yourdfpy's ``robot``: the links welded by fixed or locked joints merged into bodies, the
    root's body tared, one :class:`JointSpec` per moving joint; ``notes`` come first in the chain's notes.

    Raises:
        RobotModelError: no links, a locked joint not in the URDF, a joint of an unsupported type, a link
            missing or the child of two joints (a loop), not one root, a mimic joint, an axis of zero
            length, no moving joint, no moving link with mass (and :func:`_joint_spec`'s errors).
    """
    links = {link.name: link for link in robot.links}
    if not links:
        raise RobotModelError(f"{source}: the URDF has no <link>")
    joints_by_name = {j.name: j for j in robot.joints}
    for name in locked:
        if name not in joints_by_name:
            raise RobotModelError(
                f"{source}: locked joint {name!r} is not in the URDF (joints: {', '.join(joints_by_name)})"
            )
    locked, mimic_notes = _mimic_locks(robot, locked)
    children, root = _tree(robot, source, links, locked)
    bodies = _Bodies(source, links, children, locked, [*notes, *mimic_notes])
    specs, merged, parents = _moving_joints(bodies, root, qdd_bounds, {j.name: k for k, j in enumerate(robot.joints)})
    if not specs:
        raise RobotModelError(
            f"{source}: the URDF has no moving joint (every joint is fixed or locked); nothing "
            "would move the base wrench: lock fewer joints, or give a URDF with a moving chain"
        )
    if all(s.theta[0] <= 0 for s in specs):
        raise RobotModelError(
            f"{source}: no moving link carries mass ({', '.join(s.link for s in specs)}); nothing "
            "would move the base wrench: give the moving links <inertial> elements"
        )
    return Chain(
        name=robot.name or Path(source).stem,
        root_link=root,
        joints=tuple(specs),
        merged_links=merged,
        body_links=bodies.body_links,
        notes=tuple(bodies.notes),
        parents=tuple(parents),
    )


def _tree(robot, source: str, links: dict, locked: dict[str, float]) -> tuple[dict[str, list], str]:
    """``(children, root)``: each link's child joints, and the one root link, every joint checked (finite,
    supported or locked, both ends defined, each link the child of one joint at most)."""
    children: dict[str, list] = {name: [] for name in links}
    child_seen: dict[str, str] = {}
    for j in robot.joints:
        _check_finite_joint(j, source)
        if j.type not in _SUPPORTED and j.name not in locked:
            raise RobotModelError(
                f"{source}: joint {j.name!r} has type {j.type!r}; ineid supports revolute, continuous, "
                f"prismatic and fixed joints: lock it with --lock {j.name}=POS to treat it as fixed "
                "(Python: locked_joints={name: position})"
            )
        for end in (j.parent, j.child):
            if end not in links:
                raise RobotModelError(f"{source}: joint {j.name!r} refers to link {end!r}, which is not defined")
        if j.child in child_seen:
            raise RobotModelError(
                f"{source}: link {j.child!r} is the child of two joints ({child_seen[j.child]!r}, {j.name!r}): "
                "a closed loop; ineid models kinematic trees: remove one of the two joints"
            )
        child_seen[j.child] = j.name
        children[j.parent].append(j)
    roots = [name for name in links if name not in child_seen]
    if len(roots) != 1:
        raise RobotModelError(
            f"{source}: the URDF must have exactly one root link, found {len(roots)}: {roots}; join them "
            "with fixed joints or remove the links that are not part of the robot"
        )
    return children, roots[0]


class _Bodies:
    """The URDF's links merged into rigid bodies across fixed and locked joints, read as the chain is walked.

    Attributes:
        body_links: every link of a moving body, with its pose in the body's frame and its own parameters
            (:attr:`Chain.body_links`), in the order they were read.
        notes: the chain's notes so far, the inertials' notes appended as they are read.
    """

    def __init__(self, source: str, links: dict, children: dict[str, list], locked: dict[str, float], notes: list):
        self.source, self.links, self.children, self.locked = source, links, children, locked
        self.notes = notes
        self.body_links: dict[str, BodyLink] = {}

    def is_moving(self, j) -> bool:
        """Whether joint ``j`` moves (a revolute, continuous or prismatic joint, not locked)."""
        return j.type in _MOVING and j.name not in self.locked

    def inertial(self, name: str) -> np.ndarray:
        """(10,) link ``name``'s own parameters about its frame (:func:`ineid.robots.inertial.link_inertial`)."""
        theta, note = link_inertial(self.links[name], self.source)
        if note:
            self.notes.append(note)
        return theta

    def collect(self, link_name: str, tared: bool = False) -> tuple[np.ndarray, list, list[str]]:
        """Merge link_name and everything welded to it: (theta, moving joints out, link names).

        ``theta`` (10,) is the body's parameters in ``link_name``'s frame; each moving joint out comes with
        the pose ``(body_R, body_p)`` of its parent link in that frame. The root body is tared away (the
        sensor is zeroed with it): its links' inertials are not read."""
        theta = np.zeros(10) if tared else self.inertial(link_name)
        if not tared:
            self.body_links[link_name] = BodyLink(link_name, link_name, "", np.eye(3), np.zeros(3), theta)
        moving_out: list = []
        names = [link_name]
        stack = [(link_name, np.eye(3), np.zeros(3))]
        while stack:
            name, body_R, body_p = stack.pop()
            for j in self.children[name]:
                if self.is_moving(j):
                    moving_out.append((j, body_R, body_p))
                    continue
                r, p = _joint_transform(j, self.locked)
                child_R, child_p = body_R @ r, body_R @ p + body_p
                if not tared:
                    own = self.inertial(j.child)
                    theta = theta + _fold(own, child_R, child_p)
                    self.body_links[j.child] = BodyLink(j.child, link_name, name, child_R, child_p, own)
                names.append(j.child)
                stack.append((j.child, child_R, child_p))
        return theta, moving_out, names


def _moving_joints(
    bodies: _Bodies, root: str, qdd_bounds: dict[str, str], order: dict[str, int]
) -> tuple[list[JointSpec], dict, list[int]]:
    """Walk the tree of bodies from the root's out along the moving joints: ``(specs, merged, parents)``, each
    moving joint's :class:`JointSpec` in chain order, each body's link names (the root's first) and each
    joint's parent joint (-1: the root).

    Chain order is depth first: a joint, then the whole subtree of its first moving child joint (URDF
    order, ``order``), then its next one's; every parent precedes its children, each subtree is a run of
    consecutive joints, and a serial chain is in its URDF order."""
    source = bodies.source
    merged: dict[str, tuple[str, ...]] = {}
    _, moving_out, names = bodies.collect(root, tared=True)
    merged[root] = tuple(names)
    specs: list[JointSpec] = []
    parents: list[int] = []
    stack = [(-1, out) for out in sorted(moving_out, key=lambda o: order[o[0].name], reverse=True)]
    while stack:
        parent, (j, body_R, body_p) = stack.pop()
        if j.mimic is not None:
            raise RobotModelError(
                f"{source}: joint {j.name!r} mimics {j.mimic.joint!r}; coupled joints are not supported: lock "
                f"{j.mimic.joint!r} with --lock {j.mimic.joint}=POS (its mimic joints are locked with it; "
                "Python: locked_joints={name: position})"
            )
        axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        norm = float(np.linalg.norm(axis))
        if not math.isfinite(norm) or norm < 1e-12:
            raise RobotModelError(
                f"{source}: joint {j.name!r} has an axis of zero length; give <axis xyz=...> a direction"
            )
        r, p = _transform(j.origin)
        theta, moving_out, names = bodies.collect(j.child)
        merged[j.child] = tuple(names)
        if theta[0] <= 0:  # a massless moving link: known, contributes nothing, not identified by default
            bodies.notes.append(
                f"moving link {j.child!r} has no mass (no <inertial>, and nothing with mass is welded "
                "to it): a known link contributing nothing"
            )
        index = len(specs)
        specs.append(_joint_spec(j, source, body_R @ r, body_R @ p + body_p, axis / norm, theta, qdd_bounds))
        parents.append(parent)
        stack += [(index, out) for out in sorted(moving_out, key=lambda o: order[o[0].name], reverse=True)]
    return specs, merged, parents


def _joint_transform(j, locked: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """``(parent_R_child, parent_p_child)`` of joint ``j`` from its ``<origin>``, turned or slid to its position
    when ``j`` is in ``locked`` (the axis defaults to x)."""
    r, p = _transform(j.origin)
    if j.name in locked:
        axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        value = float(locked[j.name])
        if j.type in ("revolute", "continuous"):
            r = r @ _axis_rotation(axis, value)
        elif j.type == "prismatic":
            p = p + r @ (axis / np.linalg.norm(axis)) * value
    return r, p


def _joint_spec(j, source, parent_R, parent_p, axis, theta, qdd_bounds) -> JointSpec:
    continuous = j.type == "continuous"
    limit = j.limit
    lower = getattr(limit, "lower", None)
    upper = getattr(limit, "upper", None)
    if continuous or lower is None or upper is None or (lower == 0 and upper == 0 and j.type != "prismatic"):
        if j.type == "prismatic":
            raise RobotModelError(f"{source}: prismatic joint {j.name!r} needs <limit lower=... upper=...>")
        lower, upper = -math.pi, math.pi
    if not lower < upper:
        raise RobotModelError(f"{source}: joint {j.name!r}: lower limit {lower} is not below upper limit {upper}")
    velocity = getattr(limit, "velocity", None)
    qd_max = float(velocity) if velocity is not None and velocity > 0 else DEFAULT_QD_MAX
    raw = qdd_bounds.get(j.name)
    try:
        qdd_max = float(raw) if raw is not None else DEFAULT_QDD_MAX
    except ValueError:
        raise RobotModelError(f"{source}: joint {j.name!r}: <ineid acceleration={raw!r}> is not a number") from None
    if not (math.isfinite(qdd_max) and qdd_max > 0):
        raise RobotModelError(f"{source}: joint {j.name!r}: acceleration bound {qdd_max} must be positive")
    return JointSpec(
        name=j.name,
        type="prismatic" if j.type == "prismatic" else "revolute",
        continuous=continuous,
        parent_R_joint=parent_R,
        parent_p_joint=parent_p,
        axis=axis,
        link=j.child,
        theta=theta,
        q_lower=float(lower),
        q_upper=float(upper),
        qd_max=qd_max,
        qdd_max=qdd_max,
    )


def fixed_frame_pose(
    text: bytes | str, frame: str, source: str = "<urdf>", locked_joints: Mapping[str, float] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(root_R_frame, root_p_frame)``: the pose of link ``frame`` in the root link's frame.

    The frame must be welded to the root (fixed joints, or joints in ``locked_joints``
    at their locked positions): it is where a sensor under the base can sit.

    Raises:
        RobotModelError: the URDF does not parse, has no such link, or a moving joint
            lies between the frame and the root.
    """
    data = text.encode() if isinstance(text, str) else text
    check_urdf_size(len(data), source)
    robot = _yourdfpy_robot(data, source)
    links = [link.name for link in robot.links]
    if frame not in links:
        joint = next((j for j in robot.joints if j.name == frame), None)
        hint = f" ({frame!r} is a joint; give its child link {joint.child!r})" if joint is not None else ""
        raise RobotModelError(f"{source}: no link named {frame!r}{hint}; links: {', '.join(links)}")
    locked = dict(locked_joints or {})
    for j in robot.joints:
        _check_finite_joint(j, source)
    parent_joint = {j.child: j for j in robot.joints}
    r_acc, p_acc = np.eye(3), np.zeros(3)
    name = frame
    while name in parent_joint:
        j = parent_joint[name]
        r, p = _joint_transform(j, locked)
        if j.name not in locked and j.type != "fixed":
            raise RobotModelError(
                f"{source}: frame {frame!r} moves with {j.type} joint {j.name!r}; the sensor frame must be welded "
                "to the root link (a link reached from it by fixed joints only)"
            )
        # parent_T_name = (r, p); accumulate root_T_frame = parent_T_name @ name_T_frame
        r_acc, p_acc = r @ r_acc, r @ p_acc + p
        name = j.parent
    return r_acc, p_acc
