"""What ``ineid data import`` did, for the user and the file: :class:`ImportSummary` (and the delay estimate)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.channels.pose import SensorPose
from ineid.data.recordings import signals
from ineid.data.recordings.timing import TimingReport


@dataclass(frozen=True)
class DelayEstimate:
    """The estimated delay (s) and the linear fit's relative residual ``sqrt(r / ||D y_c||^2)`` at it and at 0."""

    delay: float
    residual: float
    residual_at_zero: float


@dataclass
class ImportSummary:
    """What the import did, for the user (printed by ``ineid data import``) and the file."""

    n_frames: int
    rate: float
    span: float
    joint_rate: float
    wrench_rate: float | None
    derived: bool
    cutoff: float | None
    cutoff_choice: signals.CutoffChoice | None
    dropped_start: float
    dropped_end: float
    dropped_joint_samples: int
    dropped_wrench_samples: int
    resampled: tuple[str, ...]
    sensor: SensorPose | None
    delay: float
    delay_estimate: DelayEstimate | None = None
    units: str | None = None
    joint_channels: tuple[str, ...] = ()
    """What rides on the joints' clock besides the angles (``"joint torques"``), filtered like the wrench."""
    sensor_where: str = "the base frame"
    """Where :attr:`sensor` is given: the base frame, or a link's frame for an F/T sensor on a link."""
    imu: tuple[str, ...] = ()
    """The link IMUs' lines: mounts, rates, the fused estimate's gyro biases and residuals."""
    cutoff_note: str | None = None
    """Why the cut-off is what it is when a rule other than the angles' chose it (the IMUs')."""
    timing: TimingReport | None = None
    """The streams' time stamps as audited: nominal rates, jitter, gaps, held rows (:mod:`.timing`)."""

    def lines(self) -> list[str]:
        wrench = self.wrench_rate is not None
        out = [
            f"{self.n_frames:,} frames at {self.rate:g} Hz over {self.span:.3f} s "
            f"(joints at {self.joint_rate:g} Hz"
            + (f", wrench at {self.wrench_rate:g} Hz" if wrench else "")
            + (f"; {' and '.join(self.resampled)} resampled" if self.resampled else "")
            + ")"
        ]
        if self.timing is not None:
            out += self.timing.lines()
        if self.joint_channels:
            out.append(
                f"{' and '.join(self.joint_channels)} on the joints' clock"
                + ("" if wrench else "; no wrench (the recording measures no F/T sensor)")
            )
        filtered = " and ".join([*self.joint_channels, *(["the wrench"] if wrench else [])])
        if self.derived:
            c = self.cutoff_choice
            how = (
                self.cutoff_note or "given"
                if c is None or self.cutoff_note
                else {
                    "noise": f"chosen from the joint angles: noise {_fmt_list(c.noise_rms)} rad RMS keeps "
                    f"{100 * c.acceleration_noise:.2g} % of the accelerations' RMS",
                    "rate": f"the upper bound, 0.1 x the rate: the joint angles' noise ({_fmt_list(c.noise_rms)} rad "
                    "RMS) allows more",
                    "floor": "the lower bound: the joint angles are noisy for their motion "
                    f"({100 * c.acceleration_noise:.2g} % noise in the accelerations even so)",
                }[c.limited]
            )
            out.append(
                f"qd, qdd from the joint angles: zero-phase Butterworth low-pass at {self.cutoff:.3g} Hz "
                f"({how}), central differences" + (f"; {filtered} filtered the same" if filtered else "")
            )
        elif self.cutoff is not None:
            out.append(f"measured qd, qdd; every channel low-passed at {self.cutoff:.3g} Hz (given)")
        else:
            out.append("measured qd, qdd used as they are (no filter)")
        if self.units:
            out.append(self.units)
        if wrench:
            out.append(
                f"dropped {self.dropped_start:.3f} s at the start and {self.dropped_end:.3f} s at the end "
                f"({self.dropped_joint_samples:,} joint and {self.dropped_wrench_samples:,} wrench samples: "
                "filter edges and time covered by one stream only)"
            )
        else:
            out.append(
                f"dropped {self.dropped_start:.3f} s at the start and {self.dropped_end:.3f} s at the end "
                f"({self.dropped_joint_samples:,} joint samples: filter edges)"
            )
        if self.sensor is not None:
            out.append(
                f"sensor frame in {self.sensor_where}: {self.sensor.describe()}"
                + (f"; messages name frame {self.sensor.frame_id!r}" if self.sensor.frame_id else "")
                + (f"; wrench delayed by {self.delay:g} s" if self.delay and self.delay_estimate is None else "")
            )
        if self.delay_estimate is not None:
            e = self.delay_estimate
            out.append(
                f"wrench delay estimated: {1e3 * e.delay:.4g} ms (relative residual of the linear fit with "
                f"offsets {e.residual:.3g}, against {e.residual_at_zero:.3g} without a delay)"
            )
        return out + list(self.imu)

    def to_dict(self) -> dict:
        return {
            "frames": self.n_frames,
            "rate": self.rate,
            "joint_rate": self.joint_rate,
            "wrench_rate": self.wrench_rate,
            "derived": self.derived,
            "cutoff": self.cutoff,
            "cutoff_rule": None if self.cutoff_choice is None else self.cutoff_choice.limited,
            **({} if self.cutoff_note is None else {"cutoff_note": self.cutoff_note}),  # shared, or the IMUs' rule
            "filter": None if self.cutoff is None else f"zero-phase Butterworth, order {signals.FILTER_ORDER}",
            "dropped_start": self.dropped_start,
            "dropped_end": self.dropped_end,
            "delay": self.delay,
            "delay_estimated": self.delay_estimate is not None,
            **({} if self.timing is None else {"timing": self.timing.to_dict()}),
        }


def _fmt_list(values) -> str:
    v = np.asarray(values)
    return f"{v.min():.2g}" if np.allclose(v, v.min(), rtol=0.5) else f"{v.min():.2g}..{v.max():.2g}"
