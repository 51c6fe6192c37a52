"""CAD rounding in joint origins: ``rpy="0 3.14159265359 0"`` is a half turn, not 2e-13 rad off one.

Exporters print angles with 12 significant digits, so a quarter or half turn arrives a few
1e-13 rad off. Taken literally it tilts a joint frame by that much, and a regressor column
that is exactly zero for the true half turn (Kinova Jaco2: a link's ``mz``) comes out at
1e-12 of the others: rank decisions then see a direction that is round-off. An angle within
:data:`ANGLE_ATOL` of a multiple of pi/2 is therefore taken as that multiple, with its exact
cosine and sine (0, +-1). The change to the kinematics is below 1e-9 rad, far below any
real mounting tolerance; each joint changed is noted for ``ineid robot show``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

ANGLE_ATOL = 1e-9
"""rad: a joint ``<origin rpy>`` angle this close to a multiple of pi/2 is snapped to it."""


def _quarter_turns(angle: float) -> int | None:
    """``k`` when ``angle`` is within :data:`ANGLE_ATOL` of ``k pi/2``, else None."""
    k = round(angle / (math.pi / 2))
    return k if abs(angle - k * math.pi / 2) <= ANGLE_ATOL else None


def _cos_sin(angle: float) -> tuple[float, float]:
    k = _quarter_turns(angle)
    if k is None:
        return math.cos(angle), math.sin(angle)
    return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[k % 4]


def rpy_rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (3, 3), with exact 0 and +-1 for multiples of pi/2."""
    cr, sr = _cos_sin(roll)
    cp, sp = _cos_sin(pitch)
    cy, sy = _cos_sin(yaw)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def matrix_rpy(r: np.ndarray) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` with ``rpy_rotation(roll, pitch, yaw) == r`` (pitch in [-pi/2, pi/2])."""
    r = np.asarray(r, dtype=np.float64)
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if math.hypot(r[0, 0], r[1, 0]) < 1e-12:  # gimbal lock: put the whole turn into roll
        return math.atan2(-r[1, 2], r[1, 1]), pitch, 0.0
    return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])


def snap_joint_angles(root: ET.Element, robot) -> list[str]:
    """Snap CAD-rounded joint ``<origin rpy>`` angles in ``robot`` (yourdfpy's, changed in place).

    For each joint of the XML ``root`` with an angle within :data:`ANGLE_ATOL` of a multiple
    of pi/2 but not equal to it in floating point, the rotation of the joint's origin in
    ``robot`` is rebuilt from the angles (:func:`rpy_rotation`); its translation is kept.

    Returns:
        A note for people naming the joints changed (none when no angle was changed).
    """
    joints = {j.name: j for j in robot.joints}
    changed = []
    for el in root.findall("joint"):
        origin, joint = el.find("origin"), joints.get(el.get("name"))
        if origin is None or origin.get("rpy") is None or joint is None or joint.origin is None:
            continue
        try:
            rpy = [float(v) for v in origin.get("rpy").split()]
        except ValueError:
            continue  # yourdfpy has reported it
        if len(rpy) != 3 or not all(math.isfinite(a) for a in rpy):
            continue
        rounded = [a for a in rpy if _quarter_turns(a) is not None and a != _quarter_turns(a) * math.pi / 2]
        if not rounded:
            continue
        t = np.array(joint.origin, dtype=np.float64)
        t[:3, :3] = rpy_rotation(*rpy)
        joint.origin = t
        changed.append(joint.name)
    if not changed:
        return []
    return [
        f"origin rpy angles within {ANGLE_ATOL:g} rad of a multiple of pi/2 taken as exact (CAD rounding) at "
        f"{len(changed)} joint{'s' if len(changed) > 1 else ''}: {', '.join(changed)}"
    ]
