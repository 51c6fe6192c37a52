"""Forward kinematics of a :class:`Chain`: link frames, the frames welded to them, point Jacobians.

Frames (all in the base frame, the root link's): link ``i``'s frame is the frame of moving
joint ``i`` moved by ``q_i`` (:class:`ineid.chain.JointSpec`), so its pose is the
product ``prod_j (parent_R_joint_j, parent_p_joint_j) (Rot(axis_j, q_j) | axis_j q_j)``
over the joints that move it, root first (its ancestors in the tree, :attr:`Chain.parents`; the
joints before it in a serial chain). :func:`link_poses` evaluates it with array operations of the module it is
given (NumPy by default, ``jax.numpy`` works the same: n small 3x3 products per sample,
vectorised over samples, cheap to compile). :func:`welded_frames` reads from the URDF the
frames welded by fixed (or locked) joints to each moving link (the tool flange, a hand,
``ee_link``) so that they can be bounded too; :func:`point_jacobians` gives the exact
derivative of any point fixed in a link with respect to ``q`` (geometric Jacobian), and
:func:`reach` an upper bound of the distance from each joint to each such point in every
configuration, which bounds how fast the points move (used by ``ineid excite --floor``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ineid.chain import Chain


def _cross_matrix(axis: np.ndarray) -> np.ndarray:
    """(3, 3) ``K`` with ``K v = axis x v``."""
    return np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) the rotation by ``angle`` rad about the unit ``axis`` (3,): ``I + sin(angle) K + (1 - cos(angle)) K^2``
    (Rodrigues)."""
    k = _cross_matrix(axis)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _joint_basis(joint) -> np.ndarray:
    """(3, 10) the constant columns of one joint's step, ``[P, P K, P K^2, p]`` (``P = parent_R_joint``, ``K`` the
    axis' cross matrix, ``p = parent_p_joint``), so that ``R_parent @ basis`` gives every product the step needs."""
    k = _cross_matrix(joint.axis)
    rot = joint.parent_R_joint
    return np.concatenate([rot, rot @ k, rot @ k @ k, joint.parent_p_joint[:, None]], axis=1)


def link_poses(chain: Chain, q, xp=np):
    """Every moving link's frame in the base frame.

    Link ``i``'s rotation is ``R_i = R_k P_i Rot(axis_i, q_i)`` (``k`` its parent joint, the base frame
    for -1) with Rodrigues' formula ``Rot = I + sin(q) K + (1 - cos(q)) K^2``, so ``R_i = (R_k P_i) +
    sin(q_i) (R_k P_i K) + (1 - cos(q_i)) (R_k P_i K^2)``: one matrix product of the parent's rotations
    with the joint's constant columns (:func:`_joint_basis`, which also carries the joint's offset
    ``p_i = p_k + R_k parent_p_joint``) per joint, for every sample at once. A prismatic joint:
    ``R_i = R_k P_i``, ``p_i`` moved by ``R_i axis_i q_i``.

    Args:
        chain: the arm.
        q: (..., n_dof) joint positions (rad, m for prismatic joints).
        xp: the array module (``numpy`` or ``jax.numpy``).

    Returns:
        ``(R, p)``: (..., n_dof, 3, 3) rotations base_R_link and (..., n_dof, 3) origins
        base_p_link, m, in chain order.
    """
    q = xp.asarray(q)
    lead = q.shape[:-1]
    rs, ps = [], []
    for i, j in enumerate(chain.joints):
        qi = q[..., i]
        basis = _joint_basis(j)
        parent = chain.parents[i]
        r_acc, p_acc = (None, None) if parent < 0 else (rs[parent], ps[parent])
        if r_acc is None:  # a joint on the root: the parent is the base frame itself
            b = xp.broadcast_to(basis, lead + (3, 10))
            p_joint = xp.broadcast_to(j.parent_p_joint, lead + (3,))
        else:  # rows of every parent rotation times the constant columns: one (3 T, 3) x (3, 10) product
            b = (r_acc.reshape(-1, 3) @ basis).reshape(lead + (3, 10))
            p_joint = p_acc + b[..., 9]
        if j.type == "revolute":
            s, c = xp.sin(qi)[..., None, None], xp.cos(qi)[..., None, None]
            r_acc = b[..., 0:3] + s * b[..., 3:6] + (1.0 - c) * b[..., 6:9]
            p_acc = p_joint
        else:
            r_acc = b[..., 0:3]
            p_acc = p_joint + (r_acc @ j.axis) * qi[..., None]
        rs.append(r_acc)
        ps.append(p_acc)
    return xp.stack(rs, axis=-3), xp.stack(ps, axis=-2)


@dataclass(frozen=True)
class WeldedFrames:
    """Frames welded to moving links (by fixed or locked joints): the tool and its kind.

    Attributes:
        names: (m,) the URDF link names.
        link: (m,) index of the moving link each is welded to (chain order).
        rotation: (m, 3, 3) link_R_frame.
        offset: (m, 3) link_p_frame, m.
    """

    names: tuple[str, ...]
    link: np.ndarray
    rotation: np.ndarray
    offset: np.ndarray

    @property
    def tool(self) -> tuple[str, ...]:
        """The frames welded to the last moving link in chain order (the tool frame and its parents; in a tree,
        the last branch's)."""
        last = int(self.link.max()) if len(self.link) else -1
        return tuple(n for n, k in zip(self.names, self.link, strict=True) if k == last)


def rpy_rotation(rpy) -> np.ndarray:
    """(3, 3) the rotation of URDF angles ``rpy = (roll, pitch, yaw)``, rad: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def parse_floats(text: str | None, default) -> np.ndarray:
    """The numbers of a URDF attribute such as ``xyz="0 0 0.1"`` (floats); ``default`` when it is absent or empty."""
    return np.array([float(v) for v in text.split()], dtype=np.float64) if text else np.asarray(default, float)


def welded_poses(urdf_text: str, chain: Chain, locked_joints: Mapping[str, float] | None = None) -> dict:
    """Every URDF link merged into a body of the chain: ``{name: (k, k_R_link, k_p_link)}``.

    ``k`` is the moving link (chain order) it is welded to, or -1 for the root body (the
    fixture: its pose is in the base frame); the moving links themselves map to
    ``(k, I, 0)``. A locked joint contributes its locked position, as in
    :func:`ineid.robots.urdf.load_chain`.
    """
    root = ET.fromstring(urdf_text)
    locked = dict(locked_joints or {})
    by_child = {}
    for j in root.findall("joint"):  # top level: not the <joint> of a <transmission>
        child, parent = j.find("child"), j.find("parent")
        if child is None or parent is None:
            continue
        origin = j.find("origin")
        r = rpy_rotation(parse_floats(origin.get("rpy") if origin is not None else None, (0, 0, 0)))
        p = parse_floats(origin.get("xyz") if origin is not None else None, (0, 0, 0))
        axis_el = j.find("axis")
        axis = parse_floats(axis_el.get("xyz") if axis_el is not None else None, (1, 0, 0))
        name = j.get("name")
        if name in locked:
            axis = axis / np.linalg.norm(axis)
            if j.get("type") in ("revolute", "continuous"):
                r = r @ axis_rotation(axis, float(locked[name]))
            elif j.get("type") == "prismatic":
                p = p + r @ axis * float(locked[name])
        by_child[child.get("link")] = (parent.get("link"), r, p)
    moving = {j.link: i for i, j in enumerate(chain.joints)}
    out = {}
    for link, merged in chain.merged_links.items():
        k = moving.get(link, -1)
        for name in merged:
            r_acc, p_acc, cur = np.eye(3), np.zeros(3), name
            while cur != link:
                parent, r, p = by_child[cur]
                r_acc, p_acc = r @ r_acc, r @ p_acc + p
                cur = parent
            out[name] = (k, r_acc, p_acc)
    return out


def welded_frames(urdf_text: str, chain: Chain, locked_joints: Mapping[str, float] | None = None) -> WeldedFrames:
    """The frames of the links merged into each moving link (``chain.merged_links``), in that link's frame.

    The moving link itself is not listed (its frame is the link frame), nor what is welded
    to the root (it never moves).
    """
    moving = {j.link for j in chain.joints}
    items = [
        (name, v)
        for name, v in welded_poses(urdf_text, chain, locked_joints).items()
        if v[0] >= 0 and name not in moving
    ]
    return WeldedFrames(
        tuple(n for n, _ in items),
        np.array([v[0] for _, v in items], dtype=int),
        np.array([v[1] for _, v in items]).reshape(-1, 3, 3),
        np.array([v[2] for _, v in items]).reshape(-1, 3),
    )


def frame_points(chain: Chain, q, welded: WeldedFrames | None = None, xp=np):
    """(..., n_dof + m, 3): the moving link origins, then the welded frames' origins, base frame, m."""
    r, p = link_poses(chain, q, xp)
    if welded is None or not len(welded.names):
        return p
    extra = p[..., welded.link, :] + (r[..., welded.link, :, :] @ welded.offset[:, :, None])[..., 0]
    return xp.concatenate([p, extra], axis=-2)


def _moves(chain: Chain, link: np.ndarray) -> np.ndarray:
    """(P, n_dof) bool: whether joint ``j`` moves each point's link (``link`` (P,), -1: the root, moved by none)."""
    link = np.asarray(link, dtype=int)
    table = np.vstack([chain.moved_by(), np.zeros((1, chain.n_dof), dtype=bool)])  # row -1: the root
    return table[link]


def point_jacobians(chain: Chain, q: np.ndarray, link: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact ``d point / d q`` of points fixed in links (NumPy).

    Args:
        q: (T, n_dof) joint positions.
        link: (P,) the moving link each point is fixed in (chain order).
        points: (T, P, 3) the points at ``q``, base frame.

    Returns:
        (T, P, 3, n_dof): column ``j`` is ``s_j x (point - o_j)`` for a revolute joint ``j``
        that moves the point's link (the link's or an ancestor's), ``s_j`` for a prismatic one, zero
        for the others (``s_j``, ``o_j`` the joint's axis and origin in the base frame).
    """
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    r, p = link_poses(chain, q)
    t, n = q.shape
    jac = np.zeros((t, len(link), 3, n))
    moves = _moves(chain, link)
    for i, j in enumerate(chain.joints):
        # joint i's axis in the base frame: the link frame's rotation (the joint rotates about its own axis)
        s = r[:, i] @ j.axis  # (T, 3)
        o = p[:, i] if j.type == "revolute" else None
        moved = moves[:, i]
        if not np.any(moved):
            continue
        if j.type == "revolute":
            col = np.cross(s[:, None, :], points[:, moved] - o[:, None, :])
        else:
            col = np.broadcast_to(s[:, None, :], (t, int(moved.sum()), 3))
        jac[..., i][:, moved] = col  # basic index first: a view, so the assignment lands in jac
    return jac


def reach(chain: Chain, welded: WeldedFrames | None = None) -> np.ndarray:
    """(n_dof + m, n_dof) upper bounds of ``|point - o_j|`` in every configuration within the joint limits, m.

    Row ``k`` is a point of :func:`frame_points`, column ``j`` a joint; zero where the joint
    does not move the point. The bound adds the lengths of the joint offsets from joint
    ``j`` to the point (along the tree's path, the point's link's ancestors after ``j``), the
    largest travel ``max(|q_lower|, |q_upper|)`` of every prismatic joint on the way, and the
    welded frame's offset.
    """
    n = chain.n_dof
    offsets = np.array([np.linalg.norm(j.parent_p_joint) for j in chain.joints])
    travel = np.array([max(abs(j.q_lower), abs(j.q_upper)) if j.type == "prismatic" else 0.0 for j in chain.joints])
    links = list(range(n))
    extra = [0.0] * n
    if welded is not None:
        links += [int(k) for k in welded.link]
        extra += [float(np.linalg.norm(o)) for o in welded.offset]
    out = np.zeros((len(links), n))
    for k, (i, e) in enumerate(zip(links, extra, strict=True)):
        path = chain.ancestors(i)
        for at, j in enumerate(path):
            after = list(path[at + 1 :])
            out[k, j] = travel[j] + offsets[after].sum() + travel[after].sum() + e
    return out


def entry_jacobians(chain: Chain, q: np.ndarray, link: np.ndarray, points: np.ndarray, poses=None) -> np.ndarray:
    """:func:`point_jacobians` of one point per configuration: ``q`` (E, n_dof), ``link`` (E,) the moving link each
    point is fixed in (-1: the root, zero Jacobian), ``points`` (E, 3) base frame -> (E, 3, n_dof); ``poses``: the
    links' ``(R (E, n_dof, 3, 3), p (E, n_dof, 3))`` at ``q`` when already computed (:func:`link_poses`)."""
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    r, p = link_poses(chain, q) if poses is None else poses
    e, n = q.shape
    jac = np.zeros((e, 3, n))
    moves = _moves(chain, link)
    for i, j in enumerate(chain.joints):
        moved = moves[:, i]
        if not np.any(moved):
            continue
        s = r[moved, i] @ j.axis  # (E', 3): joint i's axis in the base frame
        jac[moved, :, i] = np.cross(s, points[moved] - p[moved, i]) if j.type == "revolute" else s
    return jac
