"""The numeric description of a serial arm that ineid works on: :class:`Chain` of :class:`JointSpec`.

Made from a URDF by :mod:`ineid.robots.urdf`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
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


@dataclass(frozen=True, eq=False)
class Chain:
    """A serial chain of moving joints from the fixed root body, in URDF joint order.

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

    @property
    def n_dof(self) -> int:
        return len(self.joints)

    def kinematic_fingerprint(self) -> str:
        """Hash of everything the base-wrench regressor depends on (not the inertia).

        The regressor depends on joint types, axes and origins only; masses do not enter
        it. Two URDFs with the same fingerprint share generated code.
        """
        h = hashlib.sha256()
        for j in self.joints:
            h.update(j.type.encode())
            for v in (*j.parent_R_joint.ravel(), *j.parent_p_joint, *j.axis):
                h.update(float(v).hex().encode())
        return h.hexdigest()[:16]
