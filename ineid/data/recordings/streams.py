"""What a lab records, as read from a file: joint angles (with joint torques, motor currents) and the
sensor wrench, each on its own clock.

The file readers (:mod:`ineid.data.recordings.csv_import`, :mod:`ineid.data.recordings.bags`) produce
:class:`Streams`, :func:`in_si_units` converts a lab's units, and
:func:`ineid.data.recordings.pipeline.recording_dataset` turns them into frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ineid.errors import DatasetError

VALUE_LIMIT = 1e9
"""The largest magnitude ineid reads for a recorded value (angles, velocities, torques, currents, forces,
moments, IMU readings) in the file's own units: beyond anything a sensor reports in any unit a lab logs
in (a 10 kN force in mN is 1e7; an hour of a joint turning at 10 rad/s, in degrees, is 2e6), so a larger
value is a corrupt cell or a wrong column, and it would overflow the filter's and the solver's squares."""
TIME_LIMIT = 1e19
"""The largest magnitude of a recorded time stamp: nanoseconds since 1970 fit (1.8e18 in 2027)."""


def first_beyond(a: np.ndarray, limit: float) -> int | None:
    """The first row of ``a`` (N, ...) holding a finite value of magnitude above ``limit``, or None.

    NaN and infinite values are left to the finiteness checks, which name them as such.
    """
    a = np.asarray(a, dtype=np.float64)
    if not a.size:
        return None
    a = a.reshape(len(a), -1)
    with np.errstate(invalid="ignore"):
        rows = np.flatnonzero(((np.abs(a) > limit) & np.isfinite(a)).any(axis=1))
    return int(rows[0]) if rows.size else None


@dataclass
class Streams:
    """A recording as read from a file: two streams, each on its own clock.

    Attributes:
        joint_time: (Nq,) s, increasing.
        q: (Nq, n_dof) joint angles (rad; m for prismatic joints), chain order.
        qd, qdd: (Nq, n_dof) measured velocities and accelerations, or None (derived).
        wrench_time: (Nw,) s, increasing, on the wrench's clock; None without an F/T sensor.
        wrench: (Nw, 6) what the sensor reads: the load of the robot on it, in its frame,
            moment about its origin (N, N*m); None without an F/T sensor (then ``tau`` is
            needed).
        source: the file, for messages.
        frame_id: the frame the wrench messages name (ROS bags), or None.
        origin: provenance recorded in the dataset (format, topics, message counts...).
        tau: (Nq, n_dof) joint torques (N*m; N for prismatic joints: what the actuators
            apply, Pinocchio's ``rnea`` convention), on the joints' clock, chain order; or None.
        current: (Nq, n_dof) motor currents (A), on the joints' clock, chain order; or None.
        imus: the link IMUs' streams (:class:`ImuStream`), each on its own clock; an IMU whose angular
            acceleration comes on a topic of its own has two streams of one name.
    """

    joint_time: np.ndarray
    q: np.ndarray
    qd: np.ndarray | None
    qdd: np.ndarray | None
    wrench_time: np.ndarray | None
    wrench: np.ndarray | None
    source: str
    frame_id: str | None = None
    origin: dict = field(default_factory=dict)
    tau: np.ndarray | None = None
    current: np.ndarray | None = None
    imus: tuple[ImuStream, ...] = ()


@dataclass
class ImuStream:
    """One link IMU's readings as read from a file, on its own clock (:mod:`ineid.data.recordings.imus`).

    Attributes:
        name: the IMU's name: the ``<NAME>`` of its CSV columns ``imu_<NAME>_wx``..., or the ``frame_id``
            of its bag messages; matched to an ``--imu`` mount of that name, else to a link or URDF frame.
        time: (N,) s, increasing, on the IMU's clock.
        readings: ``{kind: (N, 3)}`` in the sensor frame: ``"gyro"`` rad/s, ``"accel"`` m/s^2 (specific
            force), ``"alpha"`` rad/s^2 (angular acceleration).
        where: the columns or topic, for messages.
    """

    name: str
    time: np.ndarray
    readings: dict[str, np.ndarray]
    where: str = ""


ANGLE_UNITS = ("rad", "deg")
"""Units of a recording's revolute joint angles (``data import --angle-unit``)."""
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Units of a recording's time stamps (``data import --time-unit``), in seconds."""
FORCE_UNITS = {"N": 1.0, "mN": 1e-3, "kN": 1e3}
"""Units of a recording's forces (``data import --force-unit``), in N."""
MOMENT_UNITS = {"Nm": 1.0, "Nmm": 1e-3, "kNm": 1e3}
"""Units of a recording's moments (``data import --moment-unit``), in N*m (``Nmm`` is also mN*m)."""
SI_UNITS = {"angle_unit": "rad", "time_unit": "s", "force_unit": "N", "moment_unit": "Nm", "wrench_scale": 1.0}
"""The unit settings of an import (:class:`ineid.data.recordings.pipeline.ImportSettings`) that convert nothing."""


def check_units(time_unit: str, force_unit: str, moment_unit: str) -> None:
    """Refuse a time, force or moment unit not in :data:`TIME_UNITS`, :data:`FORCE_UNITS`, :data:`MOMENT_UNITS`.

    Raises:
        DatasetError: naming the setting and its choices.
    """
    for name, value, units in (
        ("time_unit", time_unit, TIME_UNITS),
        ("force_unit", force_unit, FORCE_UNITS),
        ("moment_unit", moment_unit, MOMENT_UNITS),
    ):
        if value not in units:
            raise DatasetError(f"{name} must be one of {', '.join(units)}, got {value!r}")


def in_si_units(
    streams: Streams,
    model,
    angle_unit: str = "rad",
    wrench_scale: float = 1.0,
    time_unit: str = "s",
    force_unit: str = "N",
    moment_unit: str = "Nm",
) -> Streams:
    """``streams`` in SI units: time stamps in s, revolute joints' ``q`` (``qd``, ``qdd``) in rad, forces in N and
    moments in N*m, then the wrench multiplied by ``wrench_scale``.

    Args:
        streams: as read from the file.
        model: the :class:`ineid.RobotModel` (which joints are revolute: prismatic ones stay in m).
        angle_unit: ``"rad"`` (nothing to convert) or ``"deg"``.
        wrench_scale: the factor on every force and moment.
        time_unit, force_unit, moment_unit: keys of :data:`TIME_UNITS`, :data:`FORCE_UNITS`,
            :data:`MOMENT_UNITS`: the unit of every stream's time stamps (joints, wrench, IMUs), of the
            wrench's forces and of its moments. Measured ``qd``, ``qdd`` and the IMUs' readings are per s
            whatever the time stamps' unit.

    Returns:
        A new :class:`Streams`; its ``origin`` records the five settings.
    """
    from dataclasses import replace

    check_units(time_unit, force_unit, moment_unit)
    factor = np.ones(model.n_dof)
    if angle_unit == "deg":
        factor[[k for k, kind in enumerate(model.joint_types) if kind == "revolute"]] = math.pi / 180
    joints = {}
    for k in ("q", "qd", "qdd"):
        a = getattr(streams, k)
        a = None if a is None else np.asarray(a, dtype=np.float64)
        # a wrongly shaped array is left as it is: recording_dataset names the problem
        joints[k] = a * factor if a is not None and a.ndim == 2 and a.shape[1] == model.n_dof else a
    origin = {
        **streams.origin,
        "angle_unit": angle_unit,
        "wrench_scale": float(wrench_scale),
        "time_unit": time_unit,
        "force_unit": force_unit,
        "moment_unit": moment_unit,
    }
    wrench = None if streams.wrench is None else np.asarray(streams.wrench, dtype=np.float64) * wrench_scale
    if wrench is not None and wrench.ndim == 2 and wrench.shape[1] == 6:
        wrench = wrench * np.repeat([FORCE_UNITS[force_unit], MOMENT_UNITS[moment_unit]], 3)
    seconds = TIME_UNITS[time_unit]

    def stamps(t):
        return None if t is None else np.asarray(t, dtype=np.float64) * seconds

    return replace(
        streams,
        **joints,
        wrench=wrench,
        origin=origin,
        joint_time=stamps(streams.joint_time),
        wrench_time=stamps(streams.wrench_time),
        imus=tuple(replace(s, time=stamps(s.time)) for s in streams.imus),
    )


def units_note(origin: dict) -> str | None:
    """The summary line of :func:`in_si_units`'s conversions, or None."""
    parts = []
    if origin.get("time_unit", "s") != "s":
        parts.append(f"time stamps converted from {origin['time_unit']}")
    if origin.get("angle_unit") == "deg":
        parts.append("revolute joint angles (and measured qd, qdd) converted from degrees")
    converted = [
        f"{what} from {origin[key]}"
        for what, key, si in (("forces", "force_unit", "N"), ("moments", "moment_unit", "Nm"))
        if origin.get(key, si) != si
    ]
    if converted:
        parts.append(" and ".join(converted) + " converted")
    if origin.get("wrench_scale", 1.0) != 1.0:
        parts.append(f"wrench multiplied by {origin['wrench_scale']:g}")
    return "; ".join(parts) or None
