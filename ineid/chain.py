"""The numeric description of a robot that ineid works on: :class:`Chain` of :class:`JointSpec`.

A chain is a tree of moving joints on a fixed root body: each joint's parent is a moving joint
before it (or the root), so a serial arm, a torso with two arms and a hand with fingers are all
chains; :func:`serial_parents`, :func:`ancestors` and :func:`subtree` read the topology. Made
from a URDF by :mod:`ineid.robots.urdf`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class JointSpec:
    """One moving joint and the rigid body it carries.

    The joint frame is placed in the parent body frame by ``parent_R_joint`` and
    ``parent_p_joint``; the child body frame is the joint frame moved by ``q`` about
    (revolute) or along (prismatic) ``axis``, a unit vector in the joint frame.
    """

    name: str
    type: str  # "revolute" or "prismatic"
    continuous: bool
    parent_R_joint: np.ndarray
    parent_p_joint: np.ndarray
    axis: np.ndarray
    link: str
    theta: np.ndarray  # (10,) the body's parameters in its frame, about its origin
    q_lower: float
    q_upper: float
    qd_max: float
    qdd_max: float


@dataclass(frozen=True, eq=False)
class BodyLink:
    """A URDF link of a moving body: the moving link itself, or a link welded to it by fixed
    (or locked) joints, with its own inertial kept apart (the body's ``JointSpec.theta`` is the sum).

    ``body_R_link``, ``body_p_link`` place the link frame in the body frame (the moving link's);
    ``theta`` is the link's own ``<inertial>`` about its origin, in its axes (zeros for a frame:
    no ``<inertial>``, or a massless one). ``parent`` is its URDF parent link ("" for the moving
    link itself), so the links welded beyond it can be found.
    """

    name: str
    body: str
    parent: str
    body_R_link: np.ndarray
    body_p_link: np.ndarray
    theta: np.ndarray


def serial_parents(n: int) -> tuple[int, ...]:
    """``(-1, 0, 1, ..., n - 2)``: the parents of a serial chain of ``n`` moving joints."""
    return tuple(range(-1, n - 1))


def ancestors(parents: Sequence[int], i: int) -> tuple[int, ...]:
    """The joints that move link ``i``, root first: its ancestors and ``i`` itself (``-1``: none)."""
    out = []
    while i >= 0:
        out.append(i)
        i = parents[i]
    return tuple(reversed(out))


def subtree(parents: Sequence[int], j: int) -> tuple[int, ...]:
    """The links joint ``j`` moves, ascending: ``j`` and its descendants (every parent precedes its children,
    so one pass in order finds them)."""
    inside = {j}
    for i in range(j + 1, len(parents)):
        if parents[i] in inside:
            inside.add(i)
    return tuple(sorted(inside))


def moved_by(parents: Sequence[int]) -> np.ndarray:
    """(n, n) bool: ``[i, j]`` is whether joint ``j`` moves link ``i`` (``j`` is ``i`` or one of its ancestors).
    Lower triangular; all of it for a serial chain."""
    n = len(parents)
    out = np.zeros((n, n), dtype=bool)
    for i in range(n):
        out[i, list(ancestors(parents, i))] = True
    return out


def check_parents(parents: Sequence[int], n: int) -> str | None:
    """Why ``parents`` is not the topology of ``n`` moving joints in an order where every parent precedes its
    children (``-1 <= parents[i] < i``), or None."""
    if len(parents) != n:
        return f"{len(parents)} parents for {n} moving joints"
    for i, p in enumerate(parents):
        if not isinstance(p, (int, np.integer)) or isinstance(p, bool) or not -1 <= p < i:
            return f"joint {i}'s parent {p!r} is not a joint before it (or -1, the root)"
    return None


@dataclass(frozen=True, eq=False)
class Chain:
    """A tree of moving joints on the fixed root body, every parent before its children.

    ``parents``: per moving joint the index of its parent moving joint (``-1``: the root body);
    empty (the default) means a serial chain, ``(-1, 0, 1, ...)``, which is what it is set to.
    The order is the URDF walk's (:mod:`ineid.robots.urdf`): depth first from the root, each
    body's moving child joints in URDF order, so a serial chain keeps its URDF joint order.

    ``merged_links``: per body (the root link and each moving link) the URDF links merged into
    it, itself first. ``body_links``: every link of a moving body with its own inertial and pose
    (:class:`BodyLink`; what lets a welded payload be identified on its own). ``notes``: what the
    parse decided that a user should see (frames whose tiny mass was dropped, mimic joints locked
    with their leader), one line each; ``ineid robot show`` prints them.
    """

    name: str
    root_link: str
    joints: tuple[JointSpec, ...]
    merged_links: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    body_links: Mapping[str, BodyLink] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    parents: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        parents = tuple(int(p) for p in self.parents) if self.parents else serial_parents(len(self.joints))
        problem = check_parents(parents, len(self.joints))
        if problem is not None:
            raise ValueError(f"Chain {self.name!r}: {problem}")
        object.__setattr__(self, "parents", parents)

    @property
    def n_dof(self) -> int:
        return len(self.joints)

    @property
    def is_serial(self) -> bool:
        """Whether each moving joint's parent is the one before it (one branch)."""
        return self.parents == serial_parents(self.n_dof)

    def children(self, j: int) -> tuple[int, ...]:
        """The moving joints whose parent is joint ``j`` (``-1``: those on the root body)."""
        return tuple(i for i, p in enumerate(self.parents) if p == j)

    def ancestors(self, i: int) -> tuple[int, ...]:
        """The joints that move link ``i``, root first, ``i`` last (:func:`ancestors`)."""
        return ancestors(self.parents, i)

    def subtree(self, j: int) -> tuple[int, ...]:
        """The links joint ``j`` moves: ``j`` and its descendants, ascending (:func:`subtree`)."""
        return subtree(self.parents, j)

    def moved_by(self) -> np.ndarray:
        """(n_dof, n_dof) bool, ``[i, j]``: joint ``j`` moves link ``i`` (:func:`moved_by`)."""
        return moved_by(self.parents)

    def kinematic_fingerprint(self) -> str:
        """Hash of everything the base-wrench regressor depends on (not the inertia).

        The regressor depends on joint types, axes, origins and the tree's topology only; masses
        do not enter it. Two URDFs with the same fingerprint share generated code. The parents
        are hashed only when the chain is not serial, so a serial chain's fingerprint is that of
        its joints alone.
        """
        h = hashlib.sha256()
        for j in self.joints:
            h.update(j.type.encode())
            for v in (*j.parent_R_joint.ravel(), *j.parent_p_joint, *j.axis):
                h.update(float(v).hex().encode())
        if not self.is_serial:
            h.update(b"parents" + ",".join(str(p) for p in self.parents).encode())
        return h.hexdigest()[:16]
