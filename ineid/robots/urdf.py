"""URDF -> :class:`Chain`: the numeric description of a serial arm that ineid works on.

Parsing is yourdfpy's (once per URDF text: the result is kept in the cache folder, see
:func:`parse_chain`); this module turns its tree into a chain of moving joints:

* fixed joints are merged into their parent body, their inertia folded in (as Pinocchio
  does); links welded to the root belong to the fixture and are tared away;
* ``locked_joints`` turns chosen moving joints into fixed ones at a given position (the
  way to drop a gripper's fingers, for example);
* continuous joints are revolute joints without position limits;
* every moving body must carry a physical ``<inertial>`` (its own, or one folded in).

Sampling bounds: ``<limit velocity=...>`` bounds ``|qd|``; the acceleration bound, which
URDF has no field for, comes from an optional ``<ineid acceleration="..."/>`` element
inside a ``<joint>`` (ignored by other URDF readers), else :data:`DEFAULT_QDD_MAX`.

:class:`Chain` and :class:`JointSpec` are defined in :mod:`ineid.robots.chain` (importable
from here too).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path

import numpy as np

from ineid.errors import RobotModelError
from ineid.params import physical_violations, theta_from_inertial
from ineid.robots.chain import Chain, JointSpec

DEFAULT_QD_MAX = 3.0
"""rad/s (m/s for prismatic): velocity bound for sampling where the URDF gives none."""
DEFAULT_QDD_MAX = 10.0
"""rad/s^2 (m/s^2 for prismatic): acceleration bound for sampling where the URDF gives none."""

_MOVING = {"revolute", "continuous", "prismatic"}
_SUPPORTED = _MOVING | {"fixed"}


def load_chain(path: str | Path, locked_joints: Mapping[str, float] | None = None) -> Chain:
    """Read a URDF file into a :class:`Chain`.

    Raises:
        RobotModelError: the file is unreadable, malformed, not a serial chain, or has
            an unsupported joint or a non-physical inertial.
    """
    path = Path(path)
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
    key = _chain_key(data, source, locked_joints)
    chain = cached_chain(key)
    if chain is not None:
        return chain
    chain = _parse_chain(data, source, locked_joints)
    _store_chain(key, chain)
    return chain


CHAIN_SUBDIR = "chains"
"""Parsed URDFs live in ``cache_dir() / CHAIN_SUBDIR`` as JSON, one file per URDF text."""


def _chain_key(data: bytes, source: str, locked_joints: Mapping[str, float] | None) -> str:
    """Hash of what a parse depends on: this module's code, the URDF bytes, the source
    name (a nameless ``<robot>`` is named after it) and the locked joints."""
    h = hashlib.sha256(Path(__file__).read_bytes())
    h.update(json.dumps([source, sorted((str(k), float(v)) for k, v in (locked_joints or {}).items())]).encode())
    h.update(data)
    return h.hexdigest()[:32]


def _chain_file(key: str) -> Path:
    from ineid.cache import private_folder  # noqa: PLC0415

    return private_folder(CHAIN_SUBDIR) / f"{key}.json"


def cached_chain(key: str) -> Chain | None:
    """The chain parsed earlier under ``key``, or None (not parsed yet, or an unreadable file).

    Like code, it is read only from a private cache folder (:mod:`ineid._trust`), and only
    when the file is owned by you and not writable by others.
    """
    import logging  # noqa: PLC0415

    from ineid._trust import Untrusted, read_checked  # noqa: PLC0415

    path = _chain_file(key)
    try:
        doc = json.loads(read_checked(path, private=True))
        joints = tuple(
            JointSpec(**{**j, **{k: np.asarray(j[k], dtype=np.float64) for k in _ARRAY_FIELDS}}) for j in doc["joints"]
        )
        chain = Chain(doc["name"], doc["root_link"], joints, {k: tuple(v) for k, v in doc["merged_links"].items()})
    except Untrusted as e:  # e.reason: "has a file that is writable by group or others (<file>)"
        logging.getLogger(__name__).warning("the cache of parsed URDFs in %s %s; parsing the URDF again",
                                            path.parent, e.reason)
        return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not _sound(chain):  # a damaged entry (disk, hand edit): parse the URDF again, which rewrites it
        return None
    return chain


_ARRAY_FIELDS = ("parent_R_joint", "parent_p_joint", "axis", "theta")
_ARRAY_SHAPES = {"parent_R_joint": (3, 3), "parent_p_joint": (3,), "axis": (3,), "theta": (10,)}


def _sound(chain: Chain) -> bool:
    """Whether a chain read back from the cache has the types, shapes and finite values a parse gives."""
    if not chain.joints or not all(isinstance(v, str) for v in (chain.name, chain.root_link)):
        return False
    for j in chain.joints:
        if not all(isinstance(v, str) for v in (j.name, j.type, j.link)) or not isinstance(j.continuous, bool):
            return False
        if any(getattr(j, k).shape != shape or not np.all(np.isfinite(getattr(j, k))) for k, shape in _ARRAY_SHAPES.items()):
            return False
        bounds = (j.q_lower, j.q_upper, j.qd_max, j.qdd_max)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and not np.isnan(v) for v in bounds):
            return False
    return True


def _store_chain(key: str, chain: Chain) -> None:
    """Remember a parsed chain (JSON: floats round-trip exactly); a read-only cache is skipped."""
    from ineid._atomic import atomic_write  # noqa: PLC0415

    joints = [
        {f.name: (getattr(j, f.name).tolist() if f.name in _ARRAY_FIELDS else getattr(j, f.name))
         for f in fields(JointSpec)}
        for j in chain.joints
    ]
    doc = {"name": chain.name, "root_link": chain.root_link, "joints": joints,
           "merged_links": {k: list(v) for k, v in chain.merged_links.items()}}
    path = _chain_file(key)
    try:
        atomic_write(path, json.dumps(doc))
    except OSError:
        pass


def _parse_chain(data: bytes, source: str, locked_joints: Mapping[str, float] | None) -> Chain:
    import yourdfpy  # noqa: PLC0415  (heavy: trimesh)

    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise RobotModelError(f"{source}: malformed XML ({e}); fix the file so that it is well-formed XML") from None
    if root.tag != "robot":
        raise RobotModelError(f"{source}: top-level element is <{root.tag}>, a URDF needs <robot>")
    _check_elements(root, source)
    try:
        robot = yourdfpy.URDF.load(
            io.BytesIO(data),
            build_scene_graph=False,
            load_meshes=False,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
        ).robot
    except Exception as e:  # yourdfpy raises assorted builtin errors for bad attribute values
        raise RobotModelError(f"{source}: invalid URDF ({type(e).__name__}: {e})") from None
    qdd_bounds = {
        j.get("name"): j.find("ineid").get("acceleration")
        for j in root.iter("joint")
        if j.find("ineid") is not None and j.find("ineid").get("acceleration") is not None
    }
    return _build_chain(robot, source, dict(locked_joints or {}), qdd_bounds)


def _check_elements(root: ET.Element, source: str) -> None:
    # yourdfpy reports missing names with a bare KeyError, and keeps the last of two
    # elements with one name; say which element instead.
    for tag in ("link", "joint"):
        seen: set[str] = set()
        for el in root.findall(tag):
            name = el.get("name")
            if name is None:
                raise RobotModelError(f"{source}: a <{tag}> element has no name attribute")
            if name in seen:
                raise RobotModelError(
                    f"{source}: two <{tag}> elements are named {name!r}; give every {tag} its own name"
                )
            seen.add(name)
    for j in root.findall("joint"):
        for sub, attrs in (("origin", ("xyz", "rpy")), ("axis", ("xyz",))):
            el = j.find(sub)
            for attr in attrs:
                if el is not None and _non_finite(el.get(attr)):
                    raise RobotModelError(f"{source}: joint {j.get('name')!r}: <{sub} {attr}={el.get(attr)!r}> holds a "
                                          "non-finite value (nan or inf); give finite numbers")
        for sub in ("parent", "child"):
            s = j.find(sub)
            if s is None or s.get("link") is None:
                raise RobotModelError(f"{source}: joint {j.get('name')!r} has no <{sub} link=...>")


def _non_finite(text: str | None) -> bool:
    """The attribute holds numbers and one of them is nan or inf (unparsable text is yourdfpy's to report)."""
    try:
        return text is not None and not all(math.isfinite(float(v)) for v in text.split())
    except ValueError:
        return False


def _check_finite_joint(j, source: str) -> None:
    """A joint's ``<origin>`` and ``<axis>`` hold finite numbers (yourdfpy accepts nan and inf)."""
    if j.origin is not None and not np.all(np.isfinite(np.asarray(j.origin, dtype=np.float64))):
        raise RobotModelError(f"{source}: joint {j.name!r}: <origin xyz=... rpy=...> holds a non-finite value "
                              "(nan or inf); give finite numbers")
    if j.axis is not None and not np.all(np.isfinite(np.asarray(j.axis, dtype=np.float64))):
        raise RobotModelError(f"{source}: joint {j.name!r}: <axis xyz=...> holds a non-finite value (nan or inf); "
                              "give a finite direction")


def _transform(origin) -> tuple[np.ndarray, np.ndarray]:
    if origin is None:
        return np.eye(3), np.zeros(3)
    t = np.asarray(origin, dtype=np.float64)
    return t[:3, :3].copy(), t[:3, 3].copy()


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    s = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * s + (1 - math.cos(angle)) * s @ s


def _link_theta(link, source: str) -> np.ndarray:
    """The link's own parameters about its frame origin, zero if it has no mass."""
    inertial = link.inertial
    if inertial is None:
        return np.zeros(10)
    m = float(inertial.mass if inertial.mass is not None else 0.0)
    inertia = np.asarray(inertial.inertia if inertial.inertia is not None else np.zeros((3, 3)), dtype=np.float64)
    if not (math.isfinite(m) and np.all(np.isfinite(inertia))):
        raise RobotModelError(f"{source}: link {link.name!r}: <inertial> holds a non-finite value")
    if m < 0:
        raise RobotModelError(f"{source}: link {link.name!r}: mass {m:g} kg is negative; give it a positive mass")
    if m == 0:
        if np.any(inertia != 0):
            raise RobotModelError(
                f"{source}: link {link.name!r}: zero mass with a non-zero inertia is not a rigid body; "
                "give it a positive mass or remove the <inertial>"
            )
        return np.zeros(10)
    r, p = _transform(inertial.origin)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(p))):
        raise RobotModelError(
            f"{source}: link {link.name!r}: <inertial><origin> holds a non-finite value (nan or inf); "
            "give finite numbers"
        )
    theta = theta_from_inertial(m, p, r @ inertia @ r.T)
    problems = physical_violations(theta_from_inertial(m, np.zeros(3), inertia), rtol=1e-9)
    if problems:
        raise RobotModelError(
            f"{source}: link {link.name!r}: non-physical <inertial>: {'; '.join(problems)}; "
            "fix the <inertia> values"
        )
    return theta


def _fold(theta: np.ndarray, parent_R: np.ndarray, parent_p: np.ndarray) -> np.ndarray:
    """Express a body's parameters in its parent frame: theta' = X(parent_T_body) theta."""
    if theta[0] == 0:
        return np.zeros(10)
    from ineid.params import inertial_from_theta  # noqa: PLC0415

    m, c, ic = inertial_from_theta(theta)
    return theta_from_inertial(m, parent_R @ c + parent_p, parent_R @ ic @ parent_R.T)


def _build_chain(robot, source: str, locked: dict[str, float], qdd_bounds: dict[str, str]) -> Chain:
    links = {link.name: link for link in robot.links}
    if not links:
        raise RobotModelError(f"{source}: the URDF has no <link>")
    joints_by_name = {j.name: j for j in robot.joints}
    for name in locked:
        if name not in joints_by_name:
            raise RobotModelError(f"{source}: locked joint {name!r} is not in the URDF (joints: {', '.join(joints_by_name)})")
    children: dict[str, list] = {name: [] for name in links}
    child_seen: dict[str, str] = {}
    for j in robot.joints:
        _check_finite_joint(j, source)
        if j.type not in _SUPPORTED and j.name not in locked:
            raise RobotModelError(
                f"{source}: joint {j.name!r} has type {j.type!r}; ineid supports revolute, continuous, "
                "prismatic and fixed joints (lock it with locked_joints to treat it as fixed)"
            )
        for end in (j.parent, j.child):
            if end not in links:
                raise RobotModelError(f"{source}: joint {j.name!r} refers to link {end!r}, which is not defined")
        if j.child in child_seen:
            raise RobotModelError(f"{source}: link {j.child!r} is the child of two joints ({child_seen[j.child]!r}, {j.name!r})")
        child_seen[j.child] = j.name
        children[j.parent].append(j)
    roots = [name for name in links if name not in child_seen]
    if len(roots) != 1:
        raise RobotModelError(f"{source}: the URDF must have exactly one root link, found {len(roots)}: {roots}")

    def is_moving(j) -> bool:
        return j.type in _MOVING and j.name not in locked

    def collect_body(link_name: str) -> tuple[np.ndarray, list, list[str]]:
        """Merge link_name and everything welded to it: (theta, moving joints out, link names)."""
        theta = _link_theta(links[link_name], source)
        moving_out: list = []
        names = [link_name]
        stack = [(link_name, np.eye(3), np.zeros(3))]
        while stack:
            name, body_R, body_p = stack.pop()
            for j in children[name]:
                r, p = _transform(j.origin)
                if j.name in locked:
                    axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
                    value = float(locked[j.name])
                    if j.type in ("revolute", "continuous"):
                        r = r @ _axis_rotation(axis, value)
                    elif j.type == "prismatic":
                        p = p + r @ (axis / np.linalg.norm(axis)) * value
                if is_moving(j):
                    moving_out.append((j, body_R, body_p))
                    continue
                child_R, child_p = body_R @ r, body_R @ p + body_p
                theta = theta + _fold(_link_theta(links[j.child], source), child_R, child_p)
                names.append(j.child)
                stack.append((j.child, child_R, child_p))
        return theta, moving_out, names

    merged: dict[str, tuple[str, ...]] = {}
    _, moving_out, names = collect_body(roots[0])
    merged[roots[0]] = tuple(names)
    specs: list[JointSpec] = []
    while moving_out:
        if len(moving_out) > 1:
            where = specs[-1].link if specs else roots[0]
            raise RobotModelError(
                f"{source}: branching tree: body {where!r} has {len(moving_out)} moving child joints "
                f"({', '.join(j.name for j, _, _ in moving_out)}); ineid needs a serial chain, "
                "lock the extra joints with locked_joints={name: position}"
            )
        j, body_R, body_p = moving_out[0]
        if j.mimic is not None:
            raise RobotModelError(
                f"{source}: joint {j.name!r} mimics {j.mimic.joint!r}; coupled joints are not supported, "
                "lock it with locked_joints"
            )
        axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        norm = float(np.linalg.norm(axis))
        if not math.isfinite(norm) or norm < 1e-12:
            raise RobotModelError(f"{source}: joint {j.name!r} has an axis of zero length; give <axis xyz=...> a direction")
        r, p = _transform(j.origin)
        theta, moving_out, names = collect_body(j.child)
        merged[j.child] = tuple(names)
        if theta[0] <= 0:
            raise RobotModelError(
                f"{source}: moving link {j.child!r} has no mass (no <inertial>, and nothing with mass is "
                "fixed to it); add an <inertial> element with a positive mass"
            )
        specs.append(_joint_spec(j, source, body_R @ r, body_R @ p + body_p, axis / norm, theta, qdd_bounds))
    if not specs:
        raise RobotModelError(f"{source}: the URDF has no moving joint; nothing would move the base wrench")
    return Chain(name=robot.name or Path(source).stem, root_link=roots[0], joints=tuple(specs), merged_links=merged)


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
    import yourdfpy  # noqa: PLC0415

    data = text.encode() if isinstance(text, str) else text
    try:
        robot = yourdfpy.URDF.load(io.BytesIO(data), build_scene_graph=False, load_meshes=False,
                                   build_collision_scene_graph=False, load_collision_meshes=False).robot
    except Exception as e:  # yourdfpy raises assorted builtin errors for bad attribute values
        raise RobotModelError(f"{source}: invalid URDF ({type(e).__name__}: {e})") from None
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
        r, p = _transform(j.origin)
        if j.name in locked:
            axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
            if j.type in ("revolute", "continuous"):
                r = r @ _axis_rotation(axis, float(locked[j.name]))
            elif j.type == "prismatic":
                p = p + r @ (axis / np.linalg.norm(axis)) * float(locked[j.name])
        elif j.type != "fixed":
            raise RobotModelError(
                f"{source}: frame {frame!r} moves with {j.type} joint {j.name!r}; the sensor frame must be welded "
                "to the root link (a link reached from it by fixed joints only)"
            )
        # parent_T_name = (r, p); accumulate root_T_frame = parent_T_name @ name_T_frame
        r_acc, p_acc = r @ r_acc, r @ p_acc + p
        name = j.parent
    return r_acc, p_acc
