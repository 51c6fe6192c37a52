"""How the joint states are estimated from the encoders and the link IMUs: the IMUs' noise (:class:`ImuNoise`),
the fusion's settings (:class:`EstimationSettings`) and what it reports (:class:`EstimationSummary`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ineid.data.imu.readings import (
    UNITS,
    ImuMount,
)
from ineid.errors import DatasetError

WEAK = 1e-9
"""The first pass's prior weight, relative to the sensors' largest mean information per joint: the
sensors' own estimate, to 1e-9, where they determine the rates (the prior where they do not)."""


RESIDUAL_FLOOR = 0.01
"""A residual within this fraction of its readings' RMS (about their mean) is never a misfit, whatever the noise:
low-passed readings against the model at low-passed angles differ by about 1e-3 of it; an IMU turned by
0.1 rad among others on the chain leaves 2.7 %."""


BIAS_ROUNDS = 3
"""With gyro biases: rounds of (biases from the fusion at the current prior weights, then the weights with those
biases taken off). The sensors alone cannot place a bias their frames confound with the rates (an IMU whose gyro
sees three joints, say)."""


@dataclass(frozen=True)
class ImuNoise:
    """Per-kind white-noise std at the recording rate (after resampling).

    Attributes:
        gyro: rad/s. accel: m/s^2. alpha: rad/s^2 (the paper's group's sensor, 0.17).
    """

    gyro: float = 0.005
    accel: float = 0.05
    alpha: float = 0.17

    def __post_init__(self) -> None:
        for k in ("gyro", "accel", "alpha"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise DatasetError(f"IMU noise {k}: a positive number ({UNITS[k]}), got {v!r}")


@dataclass(frozen=True)
class EstimationSettings:
    """How :func:`estimate_joint_states` weighs the sensors.

    Attributes:
        noise: the IMUs' noise per kind.
        encoder_qd_std: std of the encoders' derivative as the prior on ``qd`` (rad/s; one number or one
            per joint); None: from the data (module docstring).
        encoder_qdd_std: the same for the prior on ``qdd`` (rad/s^2).
        encoder_q_std: std of the encoders' angle errors (rad; one number or one per joint; for raw
            quantization ``2 pi / 2^bits / sqrt(12)``), for the gyro biases' std only; None: from the gyro
            residuals' excess over the noise (:mod:`ineid.data.imu.gyro_bias`; it sees only errors that rise above
            the gyro noise).
        gyro_bias: estimate one constant bias per gyro axis over the recording.
        max_residual_ratio: residual RMS / noise above this: the mount does not fit (DatasetError).
        max_encoder_misfit: readings differing from the encoders' prediction by more than this fraction
            of the predicted RMS (and by more than ``max_residual_ratio`` times the noise): DatasetError.
        qdd_prior: ``"encoders"`` (``qdd_enc``) or ``"gyros"`` (the derivative of the fused ``qd``,
            central differences over ``time``: low-pass the gyros first).
        cutoff: Hz, the low-pass the readings and the angles went through (None: unknown). With
            ``qdd_prior="gyros"``, when the gyros leave a direction unseen in some frames
            (:func:`ineid.data.imu.prior_weights.coverage` below
            :data:`~ineid.data.imu.prior_weights.COVERAGE_MIN`: IMUs
            on some links only), the derivative of the fused ``qd`` is then weighed frame by frame against
            ``qdd_enc`` (:func:`ineid.data.imu.prior_weights.blend`; its variance ``(2 pi cutoff)^2 / 3`` times the
            fused ``qd``'s, that of white noise through the filter), so that ``qdd`` leans on the encoders where
            the gyros see a joint poorly; give ``qdd_enc`` at the angles' own cut-off.
    """

    noise: ImuNoise = field(default_factory=ImuNoise)
    encoder_qd_std: float | Sequence[float] | None = None
    encoder_qdd_std: float | Sequence[float] | None = None
    encoder_q_std: float | Sequence[float] | None = None
    gyro_bias: bool = True
    max_residual_ratio: float = 5.0
    max_encoder_misfit: float = 0.2
    qdd_prior: str = "encoders"
    cutoff: float | None = None

    def __post_init__(self) -> None:
        if self.qdd_prior not in ("encoders", "gyros"):
            raise DatasetError(f"qdd_prior must be 'encoders' or 'gyros', got {self.qdd_prior!r}")
        if self.cutoff is not None and not (np.isfinite(self.cutoff) and self.cutoff > 0):
            raise DatasetError(f"cutoff must be a positive number of Hz or None, got {self.cutoff!r}")
        for k in ("max_residual_ratio", "max_encoder_misfit"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise DatasetError(f"{k} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class EstimationSummary:
    """What the estimate used and found.

    Attributes:
        imus: the mounts, in order.
        gyro_bias, gyro_bias_std: per IMU with a gyro, (3,) rad/s, sensor frame (zeros without ``gyro_bias``);
            the std is NaN on an axis leaning on an unidentified direction (:mod:`ineid.data.imu.gyro_bias`).
        gyro_bias_cov: per IMU with a gyro, (3, 3) (rad/s)^2: the biases' covariance (a Newey-West sandwich plus
            the encoders' angle errors); meaningful for combinations orthogonal to the unidentified directions.
        gyro_bias_unidentified: per IMU whose bias the gyros cannot tell from a constant rate error, (k, 3)
            orthonormal directions in its sensor frame (the last joint's axis for an IMU on the last link): there
            the bias rests on the encoders' mean rate alone, with no std.
        residual_rms: per IMU, per kind: RMS of reading minus fitted value (its unit).
        noise: the noise used.
        qd_prior_std, qdd_prior_std: (n_dof,) the priors' std used (None: that prior alone gave the estimate;
            NaN for a joint no IMU sees).
        qdd_prior: which prior ``qdd`` had (``encoders`` or ``gyros``).
        n_frames: frames estimated.
        q_error_std: (n_dof,) the encoders' angle-error std the biases' std assumes (rad; None without biases).
    """

    imus: tuple[ImuMount, ...]
    gyro_bias: dict[str, np.ndarray]
    gyro_bias_std: dict[str, np.ndarray]
    residual_rms: dict[str, dict[str, float]]
    noise: ImuNoise
    qd_prior_std: np.ndarray | None
    qdd_prior_std: np.ndarray | None
    qdd_prior: str
    n_frames: int
    gyro_bias_cov: dict[str, np.ndarray] = field(default_factory=dict)
    gyro_bias_unidentified: dict[str, np.ndarray] = field(default_factory=dict)
    q_error_std: np.ndarray | None = None

    def to_dict(self) -> dict:
        """A JSON-able record (the dataset's origin)."""

        def arr(x):
            return None if x is None else [float(v) if np.isfinite(v) else None for v in np.ravel(x)]

        return {
            "imus": [m.to_dict() for m in self.imus],
            "gyro_bias": {k: arr(v) for k, v in self.gyro_bias.items()},
            "gyro_bias_std": {k: arr(v) for k, v in self.gyro_bias_std.items()},
            "residual_rms": {k: {kk: float(vv) for kk, vv in v.items()} for k, v in self.residual_rms.items()},
            "noise": {"gyro": self.noise.gyro, "accel": self.noise.accel, "alpha": self.noise.alpha},
            "qd_prior_std": arr(self.qd_prior_std),
            "qdd_prior_std": arr(self.qdd_prior_std),
            "qdd_prior": self.qdd_prior,
            "n_frames": self.n_frames,
            "q_error_std": arr(self.q_error_std),
            "gyro_bias_cov": {k: np.asarray(v).tolist() for k, v in self.gyro_bias_cov.items()},
            "gyro_bias_unidentified": {k: np.asarray(v).tolist() for k, v in self.gyro_bias_unidentified.items()},
        }

    def lines(self) -> list[str]:
        """Human-readable lines for the CLI."""
        out = [f"joint states from {len(self.imus)} IMU(s) and the encoders over {self.n_frames:,} frames"]
        for m in self.imus:
            res = ", ".join(
                f"{k} {v:.3g} {UNITS[k]} ({v / getattr(self.noise, k):.2g} x noise)"
                for k, v in self.residual_rms[m.name].items()
            )
            out.append(f"  {m.describe()}: residual RMS {res}")
            if m.name in self.gyro_bias:
                b, s = self.gyro_bias[m.name], self.gyro_bias_std[m.name]
                out.append(
                    "    gyro bias (rad/s) "
                    + ", ".join(
                        f"{a} {v:.3g} +- {e:.2g}" if np.isfinite(e) else f"{a} {v:.3g} (not identified)"
                        for a, v, e in zip("xyz", b, s, strict=True)
                    )
                )
                for d in self.gyro_bias_unidentified.get(m.name, ()):
                    out.append(
                        "    gyro bias along ({}) not identified: the gyros cannot tell it from a constant "
                        "error in a joint's rate; there it rests on the encoders alone, no std".format(
                            ", ".join(f"{v:.3f}" for v in d)
                        )
                    )
        if self.q_error_std is not None:
            out.append(
                "  encoders' angle error std (rad, in the biases' std): "
                + " ".join(f"{v:.2g}" for v in self.q_error_std)
            )
        for label, s in (("qd", self.qd_prior_std), ("qdd", self.qdd_prior_std)):
            if s is not None:
                out.append(
                    f"  prior on {label} ({'encoders' if label == 'qd' else self.qdd_prior}) std: "
                    + " ".join("unseen" if not np.isfinite(v) else f"{v:.3g}" for v in s)
                    + (" (unseen: no IMU sees that joint; the prior alone)" if not np.all(np.isfinite(s)) else "")
                )
        return out
