"""How a recording becomes frames: :class:`ImportSettings`, the options of ``ineid data import``, checked when
made; and the signature of the model-fitted delay estimate the import may be given (:data:`DelayEstimator`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ineid.data.recordings.channels import (  # noqa: F401  (resolve_sensor re-exported)
    RIDER_NAMES,
    joint_channels,
    resolve_sensor,
    resolve_wrench_channel,
    rider_channels,
)
from ineid.data.recordings.limits import check_import_settings
from ineid.data.recordings.streams import (
    Streams,
)
from ineid.data.recordings.summary import DelayEstimate


@dataclass(frozen=True)
class ImportSettings:
    """How to turn :class:`Streams` into frames (the options of ``ineid data import``).

    Attributes:
        sensor_pose: ``"x,y,z,roll,pitch,yaw"`` (m, rad, URDF rpy) or a URDF frame name, the
            sensor frame in the base frame; None: the frame named by the wrench messages'
            ``frame_id`` when the URDF has it, else the base frame.
        cutoff: Hz, the low-pass cut-off; None: chosen from the joint angles (when they
            are differentiated) or no filter (when ``qd``/``qdd`` are measured).
        rate: Hz, the rate of the frames; None: the slower stream's.
        delay: s, how late the wrench time stamps are against the joints'.
        flip_wrench: the sensor reports the wrench on the robot; negate it.
        angle_unit: ``"rad"`` or ``"deg"``: the unit of the revolute joints' ``q`` (and of
            ``qd``, ``qdd`` when given, per s and per s^2); degrees are converted to radians.
            Prismatic joints stay in m.
        wrench_scale: every force and moment is multiplied by it (0.001 for a wrench in mN
            and N*mm); finite and positive (``flip_wrench`` negates).
        time_unit, force_unit, moment_unit: the units of the time stamps, forces and moments
            (:data:`ineid.data.recordings.streams.TIME_UNITS`, ...), converted to s, N and N*m.
        estimate_delay: estimate ``delay`` from the model instead
            (:func:`ineid.identify.delay.estimate_delay`, within ``+-max_delay`` s).
        max_delay: s, the search range of ``estimate_delay``.
        torque_constant, gear_ratio: the drives of a recording with motor currents: ``k_j``
            (N*m/A at the motor) and ``G_j`` (motor turns per joint turn), one number for every
            joint or one per joint; the currents are stored as a ``motor_current`` channel
            (``i = tau / (k G)``).
        coupling: a coupling file (:func:`ineid.channels.transmission.read_coupling`): the torques or currents
            are per motor, in the coupling's order, and their channels carry it.
        imus: ``--imu`` texts, the mounts of the recording's link IMUs (:mod:`ineid.data.recordings.imus`);
            an IMU not given is placed by the link or URDF frame its name names.
        imu_delay: s, how late the IMU time stamps are against the joints'.
        imu_noise: ``{"gyro": rad/s, "accel": m/s^2, "alpha": rad/s^2}``, the IMUs' white-noise std at
            their own rates (missing: :class:`ineid.data.imu.estimation.ImuNoise`'s defaults).
        estimation: the :class:`ineid.data.imu.estimation.EstimationSettings` of the fusion, used as
            given except for its noise, scaled by the filter (None: ``imu_noise``, and ``qdd`` from the
            derivative of the fused ``qd`` when a gyro measures, :func:`ineid.data.recordings.imus.qdd_prior`).
        allow_gaps: import a stream whose gaps are longer than the filter's support (else an error;
            :mod:`ineid.data.recordings.timing`).
        keep_repeats: use the rows that repeat the previous sample under a new time stamp as data (else they
            are dropped as held values; :func:`ineid.data.recordings.timing.held_rows`).
    """

    sensor_pose: str | None = None
    cutoff: float | None = None
    rate: float | None = None
    delay: float = 0.0
    flip_wrench: bool = False
    estimate_delay: bool = False
    max_delay: float = 0.05
    angle_unit: str = "rad"
    wrench_scale: float = 1.0
    time_unit: str = "s"
    force_unit: str = "N"
    moment_unit: str = "Nm"
    torque_constant: tuple[float, ...] | None = None
    gear_ratio: tuple[float, ...] | None = None
    coupling: str | None = None
    imus: tuple[str, ...] = ()
    imu_delay: float = 0.0
    imu_noise: dict | None = None
    estimation: object | None = None
    allow_gaps: bool = False
    keep_repeats: bool = False

    def __post_init__(self) -> None:
        check_import_settings(self)


DelayEstimator = Callable[[Streams, object, ImportSettings, float], DelayEstimate]
"""``estimator(streams, model, settings, max_delay)``: the wrench delay that best fits the model."""
