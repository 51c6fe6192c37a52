"""A recording's streams on one time base: the arrays checked, the cut-off chosen, the filter, the frames' times.

The steps of :func:`ineid.data.recordings.pipeline.recording_dataset` (its module docstring tells the whole
sequence) from streams in SI units to the frames' time stamps: :func:`checked_arrays` (shapes, samples, the
delay, the rate), :func:`choose_cutoff` (given, from the angles' spectrum, or raised for the IMUs' gyros),
:func:`smoothed` (one zero-phase low-pass on every stream, the angles differentiated) and :func:`time_base`
(the frames' time stamps over what every stream covers, the filter's edges dropped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.data.recordings import signals
from ineid.data.recordings.channels import joint_channels, resolve_wrench_channel
from ineid.data.recordings.limits import check_cutoff, check_delay, check_rate, check_stream
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.streams import Streams
from ineid.data.recordings.timing import TimingReport, audit_stream
from ineid.errors import DatasetError


@dataclass
class RecordingArrays:
    """A recording's streams as checked float arrays, the wrench's clock shifted by the delay.

    Attributes:
        source: the recording, for messages.
        n_dof: the arm's joints.
        tq: (Nq,) s, the joints' time stamps.
        joint_arrays: ``q``, and ``qd``, ``qdd`` when measured: each (Nq, n_dof).
        riders: the joints' other channels, measured on the joints' clock (joint torques): ``{key: (Nq, n_a)}``.
        tw: (Nw,) s, the wrench's time stamps minus the delay (the instants it was measured); ``tq`` without
            a wrench.
        wrench: (Nw, 6) N and Nm in the sensor frame, negated when flipped; None without a wrench.
        hq, hw: s, the joints' and the wrench's nominal sampling intervals (``hw`` is ``hq`` without a wrench;
            :func:`ineid.data.recordings.timing.nominal_interval`).
        wrench_channel: the wrench's channel (it holds the sensor pose); None without a wrench.
        where: where the sensor is, in words, for the summary.
        rate: Hz, the frames' rate: ``settings.rate``, else the slower stream's.
        same_clock: no wrench, or the wrench stamped at the joints' very time stamps.
        timing: the streams' time stamps as audited (:mod:`ineid.data.recordings.timing`); the rows they
            hold as the previous sample are dropped from the arrays above.
    """

    source: str
    n_dof: int
    tq: np.ndarray
    joint_arrays: dict[str, np.ndarray]
    riders: dict[str, np.ndarray]
    tw: np.ndarray
    wrench: np.ndarray | None
    hq: float
    hw: float
    wrench_channel: object
    where: str
    rate: float
    same_clock: bool
    timing: TimingReport | None = None

    @property
    def measured(self) -> bool:
        """Whether the recording measures ``qd`` and ``qdd`` (else the angles are differentiated)."""
        return "qd" in self.joint_arrays

    @property
    def has_wrench(self) -> bool:
        """Whether the recording has an F/T sensor's wrench."""
        return self.wrench is not None

    @property
    def overlap(self) -> float:
        """s, the time both streams cover (negative when they do not overlap)."""
        return min(self.tq[-1], self.tw[-1]) - max(self.tq[0], self.tw[0])


def checked_arrays(streams: Streams, model, settings: ImportSettings) -> RecordingArrays:
    """The streams (in SI units) as float arrays, each checked, the wrench delayed and signed, the rate checked.

    Raises:
        DatasetError: angles or a wrench of the wrong shape, neither a wrench nor joint torques, a delay
            without a wrench or beyond the streams, NaN or infinite samples, time that does not increase,
            too few samples, a rate that does not fit the sampling.
    """
    src, keep = streams.source, settings.keep_repeats
    n = model.n_dof
    tq = np.asarray(streams.joint_time, dtype=np.float64)
    q = np.asarray(streams.q, dtype=np.float64)
    if q.ndim != 2 or q.shape != (len(tq), n):
        raise DatasetError(f"{src}: joint angles of shape {q.shape} for {len(tq)} time stamps and {n} joints")
    joint_arrays = {"q": q}
    if streams.qd is not None and streams.qdd is not None:
        joint_arrays.update(qd=np.asarray(streams.qd, dtype=np.float64), qdd=np.asarray(streams.qdd, dtype=np.float64))
    riders = joint_channels(streams, model, len(tq), settings)  # {key: (Nq, n_a)}: measured on the joints' clock
    has_wrench = streams.wrench is not None
    if not has_wrench and not riders:
        raise DatasetError(
            f"{src}: the recording has neither a wrench nor joint torques; give the F/T sensor's "
            "columns fx..mz (or its WrenchStamped topic) or the joint torques tau1..tauN (or "
            "JointState.effort)"
        )
    if has_wrench:
        tw = np.asarray(streams.wrench_time, dtype=np.float64) - settings.delay
        w = np.asarray(streams.wrench, dtype=np.float64) * (-1.0 if settings.flip_wrench else 1.0)
        if w.ndim != 2 or w.shape != (len(tw), 6):
            raise DatasetError(f"{src}: wrench of shape {w.shape} for {len(tw)} time stamps; expected 6 columns")
        check_delay(settings.delay, tq, np.asarray(streams.wrench_time, dtype=np.float64), src)
    elif settings.delay:
        raise DatasetError(f"{src}: --delay is how late the wrench is, and the recording has no wrench; drop it")
    check_stream("joint", tq, {**joint_arrays, **riders}, src)
    audits = [_audited("joint", tq, {**joint_arrays, **riders}, keep)]
    tq, kept = audits[0][1:]
    joint_arrays, riders = {k: kept[k] for k in joint_arrays}, {k: kept[k] for k in riders}
    hq = audits[0][0].step
    if has_wrench:
        check_stream("wrench", tw, {"wrench": w}, src)
        audits.append(_audited("wrench", tw, {"wrench": w}, keep))
        tw, w, hw = audits[1][1], audits[1][2]["wrench"], audits[1][0].step
        wrench_channel, where = resolve_wrench_channel(settings.sensor_pose, streams.frame_id, model)
    else:
        tw, w, hw, wrench_channel, where = tq, None, hq, None, "the base frame"
    rate = settings.rate or min(1.0 / hq, 1.0 / hw)
    same_clock = not has_wrench or (len(tq) == len(tw) and np.array_equal(tq, tw))
    arrays = RecordingArrays(src, n, tq, joint_arrays, riders, tw, w, hq, hw, wrench_channel, where, rate, same_clock)
    arrays.timing = TimingReport(tuple(a[0] for a in audits), settings.rate, None, settings.allow_gaps, keep)
    check_rate(settings.rate, 1.0 / hq, 1.0 / hw, arrays.overlap, n + sum(a.shape[1] for a in riders.values()))
    return arrays


def _audited(name: str, t: np.ndarray, parts: dict[str, np.ndarray], keep_repeats: bool):
    """``(timing, t, parts)``: the stream's time stamps audited (:func:`ineid.data.recordings.timing.audit_stream`
    on all its columns) and its rows used as data (those holding the previous sample dropped)."""
    timing, keep = audit_stream(name, t, np.concatenate(list(parts.values()), axis=1), keep_repeats)
    return timing, t[keep], {k: a[keep] for k, a in parts.items()}


@dataclass
class Cutoff:
    """The low-pass cut-off of an import and how it was chosen.

    Attributes:
        hz: Hz, the cut-off of every stream's filter; None: no filter (measured ``qd``, ``qdd``, no cut-off given).
        choice: the angles' spectrum's choice, when the cut-off was chosen from the angles.
        note: why the cut-off is not the noise rule's (the motion's band raised it, or the IMUs' gyros moved it),
            None when it is.
        priors_hz: Hz, the angles' own cut-off for the encoders' ``qd``, ``qdd`` priors of the IMU fusion, when
            the gyros raised the filters' above it; None otherwise.
        q_uniform: (M, n_dof) the angles on a uniform grid at the joints' rate, when the cut-off was chosen
            from them; None otherwise.
    """

    hz: float | None = None
    choice: signals.CutoffChoice | None = None
    note: str | None = None
    priors_hz: float | None = None
    q_uniform: np.ndarray | None = None


def choose_cutoff(arrays: RecordingArrays, streams: Streams, settings: ImportSettings) -> Cutoff:
    """The cut-off: ``settings.cutoff``, else chosen from the angles when they are differentiated
    (:func:`ineid.data.recordings.signals.choose_cutoff`: their noise, or three times their motion's band; at most
    0.4 times the frames' rate; the IMUs' gyros, which measure ``qd``, move it by
    :func:`ineid.data.recordings.imus.imu_cutoff`), else no filter.

    Raises:
        DatasetError: a cut-off at or above 0.45 times the frames' rate, or a given one whose filter's edges
            do not fit the time both streams cover.
    """
    cut = Cutoff(settings.cutoff)
    rate, hq = arrays.rate, arrays.hq
    if not arrays.measured and cut.hz is None:
        cut.q_uniform = signals.to_uniform(arrays.tq, arrays.joint_arrays["q"], hq)[1]  # for the priors too
        cut.choice = signals.choose_cutoff(cut.q_uniform, 1.0 / hq)
        cut.hz = min(cut.choice.cutoff, 0.4 * rate)
        if cut.choice.limited == "motion":
            c = cut.choice
            cut.note = (
                f"chosen from the joint angles: {signals.MOTION_FACTOR:g} x their motion's band "
                f"({c.motion_hz:.3g} Hz), above the {c.noise_cutoff:.3g} Hz their noise "
                f"({c.noise_rms.max():.2g} rad RMS) alone allows; "
                f"{100 * c.acceleration_noise:.2g} % noise in the accelerations"
            )
        if any("gyro" in s.readings for s in streams.imus):  # the gyros measure qd: imu_cutoff's rule
            from ineid.data.recordings.imus import imu_cutoff

            gyro = (settings.imu_noise or {}).get("gyro", 0.005)
            angles_cutoff = cut.hz
            kinds = [tuple(s.readings) for s in streams.imus]
            cut.hz, cut.note = imu_cutoff(cut.q_uniform, 1.0 / hq, cut.hz, kinds, gyro)
            cut.hz = min(cut.hz, 0.4 * rate)
            cut.priors_hz = angles_cutoff if angles_cutoff < cut.hz else None
    if cut.hz is not None and cut.hz >= 0.45 * rate:
        raise DatasetError(
            f"cut-off {cut.hz:g} Hz is above what frames at {rate:g} Hz can hold (Nyquist {rate / 2:g} Hz); "
            f"use --cutoff below {0.45 * rate:g} Hz or a higher --rate"
        )
    if settings.cutoff is not None:
        check_cutoff(settings.cutoff, arrays.overlap, rate)
    return cut


@dataclass
class Smoothed:
    """Each stream filtered on a uniform grid at its own rate (the angles differentiated), or as recorded.

    Attributes:
        tq: (Mq,) s, the joints' times.
        q, qd, qdd: (Mq, n_dof) each.
        riders: the joints' other channels, ``{key: (Mq, n_a)}``.
        tw: (Mw,) s, the wrench's times (``tq`` without a wrench).
        wrench: (Mw, 6) or None.
        edge: s, the filter's start-up at each end, to be dropped (0 without a filter).
    """

    tq: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    riders: dict[str, np.ndarray]
    tw: np.ndarray
    wrench: np.ndarray | None
    edge: float


def smoothed(arrays: RecordingArrays, cut: Cutoff) -> Smoothed:
    """Joint angles, the joints' other channels and the wrench through the same zero-phase low-pass at
    ``cut.hz``, each on a uniform grid at its own rate, the angles differentiated unless ``qd``, ``qdd``
    are measured; the streams as they are without a cut-off."""
    if cut.hz is None:
        a = arrays.joint_arrays
        return Smoothed(arrays.tq, a["q"], a["qd"], a["qdd"], arrays.riders, arrays.tw, arrays.wrench, 0.0)
    hq, hw = arrays.hq, arrays.hw
    joint_parts = {**arrays.joint_arrays, **arrays.riders}
    tq_u, jq = signals.to_uniform(arrays.tq, np.concatenate(list(joint_parts.values()), axis=1), hq)
    jq = signals.LowPass(cut.hz, 1.0 / hq).apply(jq)
    parts = split_columns(jq, joint_parts)
    if arrays.measured:
        q_s, qd_s, qdd_s = parts["q"], parts["qd"], parts["qdd"]
    else:
        q_s = parts["q"]
        qd_s, qdd_s = signals.derivatives(q_s, hq)
    riders_s = {k: parts[k] for k in arrays.riders}
    if arrays.has_wrench:
        tw_u, w_s = signals.to_uniform(arrays.tw, arrays.wrench, hw)
        w_s = signals.LowPass(cut.hz, 1.0 / hw).apply(w_s)
    else:
        tw_u, w_s = tq_u, None
    edge = signals.edge_seconds(min(cut.hz, cut.priors_hz or cut.hz))
    return Smoothed(tq_u, q_s, qd_s, qdd_s, riders_s, tw_u, w_s, edge)


def time_base(
    arrays: RecordingArrays,
    smooth: Smoothed,
    imu_span: tuple[float, float] | None,
    settings: ImportSettings,
    cutoff: float | None,
) -> tuple[np.ndarray, float]:
    """The frames' time stamps over what every stream covers, the filter's edges dropped.

    One clock, measured derivatives and neither a rate nor a cut-off: the joints' own rows; else the slower
    stream's own (uniform) time base, or a uniform grid at ``arrays.rate``.

    Args:
        arrays: the checked streams.
        smooth: the filtered streams.
        imu_span: s, the time every IMU covers (None without IMUs).
        settings: the import's settings (``rate``, ``delay`` for the messages).
        cutoff: Hz, the filters' cut-off (None: no filter).

    Returns:
        ``(grid, rate)``: the frames' time stamps (N,) on the joints' clock, s, and their rate, Hz.

    Raises:
        DatasetError: the streams (and IMUs) cover no common time beyond the filter's edges, or fewer than
            two frames are left.
    """
    src, tq, tw, hq, hw, edge = arrays.source, arrays.tq, arrays.tw, arrays.hq, arrays.hw, smooth.edge
    tq_u, tw_u = smooth.tq, smooth.tw
    start = max(tq_u[0], tw_u[0]) + edge
    stop = min(tq_u[-1], tw_u[-1]) - edge
    if imu_span is not None and imu_span[1] - imu_span[0] < stop - start:  # every IMU covers the frames
        start, stop = max(start, imu_span[0]), min(stop, imu_span[1])
        if not stop > start:
            raise DatasetError(
                f"{src}: the IMUs, the joints and the wrench cover no common time beyond the filter's "
                "edges; record longer, or check the time stamps, --delay and --imu-delay"
            )
    if not stop > start:
        if not arrays.has_wrench:
            raise DatasetError(
                f"{src}: the joint stream ({tq[0]:.6g}..{tq[-1]:.6g} s) is shorter than the filter's "
                f"edges ({edge:.3g} s at each end); record longer"
            )
        raise DatasetError(
            f"{src}: the joint stream ({tq[0]:.6g}..{tq[-1]:.6g} s) and the wrench stream ({tw[0]:.6g}..{tw[-1]:.6g} s"
            + (f", delay {settings.delay:g} s applied" if settings.delay else "")
            + f") overlap in {max(0.0, min(tq_u[-1], tw_u[-1]) - max(tq_u[0], tw_u[0])):.3g} s"
            + (f", less than the filter's edges ({edge:.3g} s at each end)" if edge else "")
            + "; record longer, or check the time stamps and --delay"
        )
    rate = arrays.rate
    slower_t = tq_u if hq >= hw else tw_u
    if arrays.same_clock and settings.rate is None and cutoff is None:  # measured derivatives: rows are frames
        grid = tq[(tq >= start) & (tq <= stop)]
        rate = 1.0 / hq
    elif settings.rate is None and signals.is_uniform(slower_t):  # the slower stream's own time base
        grid = slower_t[(slower_t >= start - 1e-9 * max(hq, hw)) & (slower_t <= stop + 1e-9 * max(hq, hw))]
    else:
        h = 1.0 / rate
        grid = start + h * np.arange(int(math.floor((stop - start) / h * (1 + 1e-12))) + 1)
    if len(grid) < 2:
        raise DatasetError(
            f"{src}: {len(grid)} frame{'s' if len(grid) != 1 else ''} left on the common time base; "
            "record longer or raise --rate"
        )
    return grid, rate


def split_columns(x: np.ndarray, like: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``x`` (N, sum of widths) cut into ``{key: (N, width of like[key])}``, in ``like``'s order."""
    out, start = {}, 0
    for key, a in like.items():
        out[key] = x[:, start : start + a.shape[1]]
        start += a.shape[1]
    return out
