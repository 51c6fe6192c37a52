"""Rehearse a recording with link IMUs: what the import would estimate from a lab's sensors.

``ineid data generate --imu LINK[:pose] --encoder-bits N --gyro-bias STD --noise gyro=..,accel=..,alpha=..``
(:class:`ImuRehearsal` in :class:`ineid.data.DatasetSpec`): for each configuration's time series
(the Fourier or trajectory frame modes: one period of a periodic motion),

1. the encoders read ``q`` quantized to ``2 pi / 2^N`` (revolute joints; prismatic ones to
   ``1 / 2^N`` m), unless ``encoder_bits`` is None;
2. the IMUs read :func:`ineid.data.imu.readings.imu_readings` of the true states plus white noise of the
   given std at the frames' rate and, on each gyro axis, one constant bias drawn with std
   ``gyro_bias``;
3. the angles, the IMU readings and every channel's (noisy) values go through the import's
   zero-phase Butterworth (:class:`ineid.data.recordings.signals.LowPass`) at the cut-off it would choose
   from these angles (:func:`ineid.data.recordings.signals.choose_cutoff`; with gyros
   :func:`ineid.data.recordings.imus.imu_cutoff`) or the one given, and the angles
   are differentiated by central differences (the fusion's priors at the angles' own cut-off when
   gyros raised it); the motion being periodic, the signals are filtered as periodic (no edges to drop);
4. :func:`ineid.data.imu.estimation.estimate_joint_states` fuses them, with the IMUs' noise as
   the filter leaves it plus the filter's own model error
   (:func:`ineid.data.recordings.imus.filter_model_error`).

The dataset's ``q``, ``qd``, ``qdd`` and channel values are then what a lab's import gives;
the truth stays in the ``*_clean`` arrays. :func:`rehearse` does one configuration.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ineid.data.recordings import signals
from ineid.errors import DatasetError

STREAM_IMU = 5
"""The random stream of the IMUs' noise and biases (:func:`ineid.data.synthesis.sampling.block_rng`), one block per
configuration."""


@dataclass(frozen=True)
class ImuRehearsal:
    """The sensors of a rehearsal (see the module docstring).

    Attributes:
        mounts: the :class:`ineid.data.imu.readings.ImuMount` of each IMU (none: the encoders alone).
        noise: ``{"gyro": rad/s, "accel": m/s^2, "alpha": rad/s^2}`` white-noise std at the frames' rate
            (missing: 0).
        gyro_bias: rad/s, the std of each gyro axis's constant bias, drawn per configuration.
        encoder_bits: the encoders' resolution in bits (None: exact angles).
        cutoff: Hz, the low-pass; None: chosen from the encoders' angles as the import does.
    """

    mounts: tuple = ()
    noise: Mapping[str, float] = field(default_factory=dict)
    gyro_bias: float = 0.0
    encoder_bits: int | None = None
    cutoff: float | None = None

    def __post_init__(self) -> None:
        bad = [k for k in self.noise if k not in ("gyro", "accel", "alpha")]
        if bad or any(not (0 <= float(v) < math.inf) for v in self.noise.values()):
            raise ValueError(f"IMU noise is gyro=, accel=, alpha= std >= 0, got {dict(self.noise)}")
        if not 0 <= self.gyro_bias < math.inf:
            raise ValueError(f"gyro_bias must be a std >= 0 in rad/s, got {self.gyro_bias}")
        if self.encoder_bits is not None and not 1 <= int(self.encoder_bits) <= 64:
            raise ValueError(f"encoder_bits must be 1..64, got {self.encoder_bits}")
        if self.cutoff is not None and not self.cutoff > 0:
            raise ValueError(f"cutoff must be a positive number of Hz, got {self.cutoff}")
        object.__setattr__(self, "mounts", tuple(self.mounts))
        object.__setattr__(self, "noise", {k: float(v) for k, v in self.noise.items()})

    def to_dict(self) -> dict:
        return {
            "mounts": [m.to_dict() for m in self.mounts],
            "noise": dict(self.noise),
            "gyro_bias": self.gyro_bias,
            "encoder_bits": self.encoder_bits,
            "cutoff": self.cutoff,
        }


def quantize(q: np.ndarray, bits: int | None, joint_types) -> np.ndarray:
    """``q`` (..., n_dof) as encoders of ``bits`` bits read it: steps of ``2 pi / 2^bits`` rad (``1 / 2^bits`` m)."""
    if bits is None:
        return np.asarray(q, dtype=np.float64)
    step = np.array([2 * math.pi if t == "revolute" else 1.0 for t in joint_types]) / 2.0**bits
    return np.round(np.asarray(q, dtype=np.float64) / step) * step


def periodic_filter(x: np.ndarray, low: signals.LowPass) -> np.ndarray:
    """``low.apply`` to one period ``x`` (N, ...) of a periodic signal: on three periods, the middle kept."""
    n = len(x)
    return low.apply(np.concatenate([x, x, x]))[n : 2 * n]


def periodic_derivatives(q: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of one period of a periodic ``q`` (N, n)."""
    nxt, prv = np.roll(q, -1, axis=0), np.roll(q, 1, axis=0)
    return (nxt - prv) / (2 * h), (nxt - 2 * q + prv) / h**2


def rehearse(
    model,
    rehearsal: ImuRehearsal,
    time: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    values: Mapping[str, np.ndarray],
    rng: np.random.Generator,
):
    """One configuration: ``(q, qd, qdd, values, summary)`` as the import would estimate them.

    Args:
        model: the :class:`ineid.RobotModel`.
        rehearsal: the sensors.
        time: (F,) s, one period, uniform.
        q, qd, qdd: (F, n_dof) the true states.
        values: ``{key: (F, n_axes)}`` each channel's values as measured (noise added), filtered here.
        rng: the configuration's random stream (IMU noise, gyro biases).

    Returns:
        The filtered encoder angles, the fused ``qd``, ``qdd`` (the encoders' derivatives without IMUs),
        the filtered values, and the :class:`ineid.data.imu.estimation.EstimationSummary` (None without IMUs).
    """
    from ineid.data.imu.estimation import estimate_joint_states
    from ineid.data.imu.settings import EstimationSettings
    from ineid.data.recordings.imus import filter_model_error, filtered_noise, qdd_prior, with_model_error

    time = np.asarray(time, dtype=np.float64)
    if len(time) < 8:
        raise DatasetError(f"IMU fusion needs a time series; {len(time)} frames are too few (give --n-frames)")
    h = float(time[1] - time[0])
    rate = 1.0 / h
    q_enc = quantize(q, rehearsal.encoder_bits, model.joint_types)
    cutoff, priors_cutoff = _cutoffs(rehearsal, q_enc, rate)
    low = signals.LowPass(cutoff, rate)
    q_f = periodic_filter(q_enc, low)
    qd_e, qdd_e = periodic_derivatives(q_f, h)
    readings = _noisy_readings(model, rehearsal, q, qd, qdd, rng, low)
    summary = None
    if rehearsal.mounts:  # as the import does: the default settings (biases estimated), the noise as filtered
        # the mounts are exact by construction: no residual check (that is for a lab's mistakes)
        noise = with_model_error(
            filtered_noise(rehearsal.noise, cutoff, rate),
            filter_model_error(model, rehearsal.mounts, q_f, h, lambda x: periodic_filter(x, low)),
        )
        raised = priors_cutoff < cutoff  # the priors: the encoders at their own cut-off (imus.encoder_priors)
        if raised:
            qd_e, qdd_e = periodic_derivatives(periodic_filter(q_enc, signals.LowPass(priors_cutoff, rate)), h)
        settings = EstimationSettings(
            noise=noise,
            cutoff=cutoff if raised else None,
            max_residual_ratio=1e12,
            max_encoder_misfit=1e12,
            qdd_prior=qdd_prior(rehearsal.mounts),
        )
        qd_e, qdd_e, summary = estimate_joint_states(
            model, q_f, qd_e, qdd_e, rehearsal.mounts, readings, settings, time=time
        )
    filtered = {k: periodic_filter(np.asarray(v, dtype=np.float64), low) for k, v in values.items()}
    return q_f, qd_e, qdd_e, filtered, summary


def _cutoffs(rehearsal: ImuRehearsal, q_enc: np.ndarray, rate: float) -> tuple[float, float]:
    """``(cutoff, priors_cutoff)``, Hz: the filters' cut-off (given, or by the import's rules: the angles', or with
    gyros the upper bound of :func:`ineid.data.recordings.imus.imu_cutoff`) and the encoders' priors' (the angles'
    own).

    Raises:
        DatasetError: a cut-off at or above 0.45 times the frames' ``rate``.
    """
    from ineid.data.imu.settings import ImuNoise
    from ineid.data.recordings.imus import imu_cutoff

    cutoff = priors_cutoff = rehearsal.cutoff
    if cutoff is None:
        cutoff = priors_cutoff = min(signals.choose_cutoff(q_enc, rate).cutoff, 0.4 * rate)
        if any("gyro" in m.kinds for m in rehearsal.mounts):
            cutoff = imu_cutoff(
                q_enc,
                rate,
                cutoff,
                [m.kinds for m in rehearsal.mounts],
                rehearsal.noise.get("gyro", 0.0) or 1e-2 * ImuNoise().gyro,
            )[0]
    if cutoff >= 0.45 * rate:
        raise DatasetError(
            f"cut-off {cutoff:g} Hz is above what frames at {rate:g} Hz can hold; lower it or give "
            "more frames per period"
        )
    return cutoff, priors_cutoff


def _noisy_readings(model, rehearsal: ImuRehearsal, q, qd, qdd, rng: np.random.Generator, low: signals.LowPass):
    """``{imu: {kind: (F, 3)}}`` the IMUs' readings of the true states (F, n_dof) with their noise and the gyros'
    biases drawn from ``rng``, filtered by ``low`` as periodic signals."""
    from ineid.data.imu.readings import imu_readings

    truth = imu_readings(model, rehearsal.mounts, q, qd, qdd)
    readings: dict[str, dict[str, np.ndarray]] = {}
    for mount in rehearsal.mounts:  # a fixed order of draws: noise per kind, then the gyro's bias
        readings[mount.name] = {}
        for kind in mount.kinds:
            x = truth[mount.name][kind] + rehearsal.noise.get(kind, 0.0) * rng.standard_normal((len(q), 3))
            if kind == "gyro":
                x = x + rehearsal.gyro_bias * rng.standard_normal(3)
            readings[mount.name][kind] = periodic_filter(x, low)
    return readings
