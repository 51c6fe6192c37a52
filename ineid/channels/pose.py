"""Where a sensor sits, and wrenches in its frame: the arithmetic of a wrench channel's ``T``.

ineid's model gives the wrench the moving links exert on the fixture in the *base frame*
(the root link's), moment about the *base origin*: ``w_b = [F; M] = Psi(q, qd, qdd) theta``.
A sensor mounted under the base at pose ``(base_R_sensor, base_p_sensor)`` reads the same
load in its own frame, moment about its own origin:

    F_s = R^T F
    M_s = R^T (M - p x F)          (moment about p: M_p = M_O - p x F)

that is ``w_s = X w_b`` with the 6x6 wrench transform

    X = [[R^T, 0], [-R^T S(p), R^T]]          (S(p) v = p x v)

(:func:`wrench_transform`). ``X`` is invertible (block triangular, ``det X = 1``), so the
base parameters, ranks and null spaces are those of the base frame; only the residual's
metric (per sensor axis) changes. ``X`` is the transform ``T`` of the base-wrench channel
(:class:`ineid.channels.wrench.BaseWrench`): every regressor and every prediction that
meets a measured sensor wrench goes through the channel (or :func:`wrench_in_sensor`,
:func:`regressor_in_sensor`): the dynamics have one implementation, in the base frame.
The same ``X`` maps a wrench in a link's frame to a sensor mounted on that link, so a
sensor on any link (a cut-wrench channel) reuses it unchanged.

(``ineid.sensor`` re-exports this module with a deprecation warning; that name is removed in
ineid 0.3.)

Poses follow URDF: ``x,y,z`` in metres and ``roll,pitch,yaw`` in radians with
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes X, then Y, then Z).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ineid.errors import DatasetError
from ineid.robots.cad_rounding import matrix_rpy  # public here: ineid.channels.matrix_rpy


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, (3, 3)."""
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def wrench_transform(base_R_sensor: np.ndarray, base_p_sensor: np.ndarray) -> np.ndarray:
    """``X`` (6, 6) with ``[F; M]_sensor = X @ [F; M]_base`` (see the module docstring).

    Args:
        base_R_sensor: (3, 3) the sensor axes in the base frame.
        base_p_sensor: (3,) m, the sensor origin in the base frame.
    """
    from ineid.params import skew

    rt = np.asarray(base_R_sensor, dtype=np.float64).T
    x = np.zeros((6, 6))
    x[:3, :3] = rt
    x[3:, 3:] = rt
    x[3:, :3] = -rt @ skew(np.asarray(base_p_sensor, dtype=np.float64))
    return x


def wrench_in_sensor(x_sensor: np.ndarray | None, wrench):
    """``w_s = X w_b`` for wrenches (..., 6); NumPy or JAX. ``x_sensor=None`` (the base frame) returns ``wrench``."""
    return wrench if x_sensor is None else wrench @ x_sensor.T


def regressor_in_sensor(x_sensor: np.ndarray | None, regressor):
    """``Psi_s = X Psi_b`` for regressors (..., 6, p): ``Psi_s theta = X (Psi_b theta)``; NumPy or JAX."""
    return regressor if x_sensor is None else x_sensor @ regressor


@dataclass(frozen=True)
class SensorPose:
    """Where the F/T sensor sits in the base (root link) frame, and what it calls itself.

    Attributes:
        xyz: (3,) m, the sensor origin in the base frame.
        rpy: (3,) rad, URDF roll, pitch, yaw of the sensor axes in the base frame.
        frame: the URDF frame the pose was read from, or None when given as numbers.
        frame_id: the ``frame_id`` of the recorded wrench messages (ROS bags), or None.
    """

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame: str | None = None
    frame_id: str | None = None

    @property
    def base_R_sensor(self) -> np.ndarray:
        return rpy_matrix(*self.rpy)

    @property
    def base_p_sensor(self) -> np.ndarray:
        return np.asarray(self.xyz, dtype=np.float64)

    @property
    def is_identity(self) -> bool:
        """The sensor frame is the base frame: its readings are ineid's base wrench."""
        return not any(self.xyz) and not any(self.rpy)

    def transform(self) -> np.ndarray:
        """The 6x6 :func:`wrench_transform` of this pose (base frame -> sensor frame)."""
        return wrench_transform(self.base_R_sensor, self.base_p_sensor)

    def describe(self) -> str:
        """``xyz=(..) m rpy=(..) rad`` (and the URDF frame it came from)."""
        text = f"xyz=({', '.join(f'{v:.6g}' for v in self.xyz)}) m, rpy=({', '.join(f'{v:.6g}' for v in self.rpy)}) rad"
        return text + (f" (URDF frame {self.frame!r})" if self.frame else "")

    def to_dict(self) -> dict:
        return {"xyz": list(self.xyz), "rpy": list(self.rpy), "frame": self.frame, "frame_id": self.frame_id}

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "sensor") -> SensorPose:
        try:
            xyz = tuple(float(v) for v in d["xyz"])
            rpy = tuple(float(v) for v in d["rpy"])
        except (KeyError, TypeError, ValueError):
            raise DatasetError(f"{where}: the sensor pose must hold xyz and rpy (3 numbers each), got {d!r}") from None
        if len(xyz) != 3 or len(rpy) != 3 or not all(math.isfinite(v) for v in xyz + rpy):
            raise DatasetError(f"{where}: the sensor pose must hold 3 finite numbers in xyz and in rpy, got {d!r}")
        return cls(xyz, rpy, d.get("frame"), d.get("frame_id"))  # type: ignore[arg-type]

    @classmethod
    def from_matrix(cls, base_R_sensor: np.ndarray, base_p_sensor: np.ndarray, frame: str | None = None) -> SensorPose:
        p = tuple(float(v) for v in np.asarray(base_p_sensor, dtype=np.float64))
        return cls(p, matrix_rpy(base_R_sensor), frame)  # type: ignore[arg-type]


def parse_sensor_pose(
    text: str | None,
    urdf: str | None = None,
    locked_joints: Mapping[str, float] | None = None,
    source: str = "the robot's URDF",
) -> SensorPose:
    """A pose from ``"x,y,z,roll,pitch,yaw"`` (m, rad) or from a URDF frame name.

    A name must be a link welded to the root link (by fixed joints, or joints in
    ``locked_joints``): a sensor under the base does not move with the arm.

    Raises:
        DatasetError: neither six numbers nor a frame of ``urdf`` (naming what was expected).
    """
    if text is None or not text.strip():
        return SensorPose()
    parts = [p.strip() for p in text.replace(" ", ",").split(",") if p.strip()]
    numbers = []
    for p in parts:
        try:
            numbers.append(float(p))
        except ValueError:
            break
    if len(numbers) == len(parts):
        if len(numbers) != 6 or not all(math.isfinite(v) for v in numbers):
            raise DatasetError(
                f"sensor pose {text!r}: expected six finite numbers x,y,z,roll,pitch,yaw (m, rad, URDF rpy) "
                "or the name of a URDF frame"
            )
        return SensorPose(tuple(numbers[:3]), tuple(numbers[3:]))  # type: ignore[arg-type]
    if len(parts) != 1 or urdf is None:
        raise DatasetError(
            f"sensor pose {text!r} does not parse: expected six numbers x,y,z,roll,pitch,yaw (m, rad, URDF rpy) "
            "or the name of one URDF frame"
        )
    from ineid.robots.urdf import fixed_frame_pose

    r, p = fixed_frame_pose(urdf, parts[0], source=source, locked_joints=locked_joints)
    return SensorPose.from_matrix(r, p, frame=parts[0])
