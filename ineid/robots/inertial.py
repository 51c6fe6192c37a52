"""A URDF link's ``<inertial>``, read as CAD tools write it: frames, point masses, rigid bodies.

* **A frame**: no ``<inertial>``, or a mass of at most :data:`FRAME_MASS` kg with every inertia
  entry at most :data:`FRAME_INERTIA` kg*m^2 (SO-101's 1e-9 kg dummy link, UR's ``tool0``).
  It carries nothing: zero parameters (a dropped tiny mass is noted, for ``ineid robot show``).
* **A point mass or a rod**: a real mass with an inertia about the centre of mass that is
  positive *semi*-definite and obeys the triangle inequality (TALOS's 0.1 kg F/T links with
  zero inertia). Accepted: it is a limit of rigid bodies, and Pinocchio loads it the same way.
* **Not a body**: a negative mass, a negative principal moment, a triangle violation (beyond
  :data:`INERTIA_RTOL` of the largest moment, for values rounded in a file), or no mass to
  speak of with a real inertia: refused with one line naming the link and the fix.
"""

from __future__ import annotations

import math

import numpy as np

from ineid.errors import RobotModelError
from ineid.params import theta_from_inertial

FRAME_MASS = 1e-6
"""kg: an ``<inertial>`` mass at or below this (with no inertia to speak of) is a frame; it weighs
1e-5 N, below the resolution of any force/torque sensor, so dropping it changes no measurement."""
FRAME_INERTIA = 1e-6
"""kg*m^2: the largest inertia entry a frame may carry (a 1 mg dummy with a 1 m radius of gyration)."""
INERTIA_RTOL = 1e-9
"""Relative tolerance (of the largest principal moment) of the semi-definiteness and triangle checks."""


def link_inertial(link, source: str) -> tuple[np.ndarray, str | None]:
    """``(theta, note)``: the link's own parameters about its frame origin (zeros for a frame), and a
    note for people when a tiny mass was dropped (else None).

    Raises:
        RobotModelError: the ``<inertial>`` is not finite, or is not a rigid body, a point mass
            or a frame (see the module doc).
    """
    inertial = link.inertial
    if inertial is None:
        return np.zeros(10), None
    m = float(inertial.mass if inertial.mass is not None else 0.0)
    inertia = np.asarray(inertial.inertia if inertial.inertia is not None else np.zeros((3, 3)), dtype=np.float64)
    if not (math.isfinite(m) and np.all(np.isfinite(inertia))):
        entries = " ".join(f"{v:g}" for v in inertia[np.triu_indices(3)])
        raise RobotModelError(
            f"{source}: link {link.name!r}: <inertial> holds a non-finite value (mass {m:g}, "
            f"inertia {entries}); give finite numbers"
        )
    if m < 0:
        raise RobotModelError(f"{source}: link {link.name!r}: mass {m:g} kg is negative; give it a positive mass")
    if m <= FRAME_MASS:
        if np.any(np.abs(inertia) > FRAME_INERTIA):
            what = "zero mass" if m == 0 else f"a mass of {m:g} kg (none to speak of)"
            raise RobotModelError(
                f"{source}: link {link.name!r}: {what} with a non-zero inertia is not a rigid body; "
                "give it a positive mass or remove the <inertial>"
            )
        note = (
            None
            if m == 0 and not np.any(inertia)
            else (
                f"link {link.name!r}: mass {m:g} kg with inertia of at most {np.abs(inertia).max():g} kg*m^2 is a "
                "frame; "
                "dropped"
            )
        )
        return np.zeros(10), note
    r, p = _origin(inertial.origin)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(p))):
        raise RobotModelError(
            f"{source}: link {link.name!r}: <inertial><origin> holds a non-finite value (nan or inf); "
            "give finite numbers"
        )
    problems = inertia_problems(inertia)
    if problems:
        raise RobotModelError(
            f"{source}: link {link.name!r}: non-physical <inertial>: {problems}; fix the <inertia> values"
        )
    return theta_from_inertial(m, p, r @ inertia @ r.T), None


def inertia_problems(inertia: np.ndarray) -> str:
    """Why an inertia about the centre of mass (3, 3) belongs to no body, point or rod ("" when it does)."""
    moments = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    tol = INERTIA_RTOL * float(np.max(np.abs(moments)))
    shown = "[" + ", ".join(f"{v:.6g}" for v in moments) + "]"
    if moments[0] < -tol:
        return f"inertia about the centre of mass has a negative principal moment (principal moments {shown})"
    a, b, c = moments
    if a + b < c - tol:
        return f"principal moments {shown} violate the triangle inequality ({a:.6g} + {b:.6g} < {c:.6g})"
    return ""


def _origin(origin) -> tuple[np.ndarray, np.ndarray]:
    if origin is None:
        return np.eye(3), np.zeros(3)
    t = np.asarray(origin, dtype=np.float64)
    return t[:3, :3].copy(), t[:3, 3].copy()
