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
class Chain:
    """A serial chain of moving joints from the fixed root body, in URDF joint order."""

    name: str
    root_link: str
    joints: tuple[JointSpec, ...]
    merged_links: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

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
