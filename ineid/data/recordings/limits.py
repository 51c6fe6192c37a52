"""What an import's settings and a recording's values may be, checked before the work they would spoil.

A rate that leaves a handful of frames, or a cut-off whose filter edges are longer than the recording,
makes the filter's start-up singular (a ``LinAlgError`` from SciPy at ``--cutoff 1e-9``); a value of
``1e308`` overflows the filter's and the solver's squares. Each is one :class:`ineid.errors.DatasetError`
line here, naming the allowed range.
"""

from __future__ import annotations

import math

import numpy as np

from ineid.data.recordings import signals
from ineid.data.recordings.streams import ANGLE_UNITS, TIME_LIMIT, VALUE_LIMIT, check_units, first_beyond
from ineid.errors import DatasetError

MIN_FRAMES = 10
"""``--rate`` gives at least this many frames over the time both streams cover."""
WRENCH_SCALE_RANGE = (1e-6, 1e6)
"""``wrench_scale`` (``--wrench-scale``) is within it: from a wrench in micronewtons to one in meganewtons."""


def check_import_settings(settings) -> None:
    """Refuse an :class:`ineid.data.recordings.pipeline.ImportSettings` whose units, factors, rate, cut-off or delay no
    recording allows (those the recording bounds are checked against it: :func:`check_min_rate`, ...)."""
    check_units(settings.time_unit, settings.force_unit, settings.moment_unit)
    if settings.angle_unit not in ANGLE_UNITS:
        raise DatasetError(f"angle_unit must be one of {', '.join(ANGLE_UNITS)}, got {settings.angle_unit!r}")
    lo, hi = WRENCH_SCALE_RANGE
    if not lo <= settings.wrench_scale <= hi:
        raise DatasetError(
            f"wrench_scale must be a factor from {lo:g} to {hi:g}, got {settings.wrench_scale}; "
            "to negate the wrench use flip_wrench (--flip-wrench)"
        )
    for name in ("cutoff", "rate"):
        v = getattr(settings, name)
        if v is not None and not (v > 0 and math.isfinite(v)):
            raise DatasetError(f"{name} must be a positive number of Hz, got {v}")
    if not math.isfinite(settings.delay):
        raise DatasetError(f"delay must be a finite number of seconds, got {settings.delay}")


def check_min_rate(rate: float, overlap: float, highest: float) -> None:
    """Refuse a ``rate`` (Hz) that gives fewer than :data:`MIN_FRAMES` frames over ``overlap`` (s).

    Args:
        rate: the ``--rate`` asked for.
        overlap: the time both streams cover (a non-positive one is left to the import's own message).
        highest: the highest rate allowed, for the message.
    """
    if overlap > 0 and rate * overlap < MIN_FRAMES:
        raise DatasetError(
            f"--rate {rate:g} Hz gives {rate * overlap:.3g} frames over the {overlap:.6g} s both streams cover; use "
            f"from {MIN_FRAMES / overlap:.3g} to {highest:g} Hz (default: the slower stream's rate)"
        )


def check_cutoff(cutoff: float, overlap: float, rate: float) -> None:
    """Refuse a cut-off (Hz) whose filter edges (:func:`ineid.data.recordings.signals.edge_seconds` at each end)
    leave no frames of the ``overlap`` (s) both streams cover; ``rate`` (Hz, the frames') bounds it from above."""
    lo = 2 * signals.edge_seconds(1.0) / overlap if overlap > 0 else float("inf")
    if not cutoff > lo:
        raise DatasetError(
            f"--cutoff {cutoff:g} Hz drops {signals.edge_seconds(cutoff):.3g} s at each end (the filter's edges, "
            f"{signals.EDGE_PERIODS:g} periods of the cut-off), and the streams cover {max(overlap, 0.0):.6g} s "
            f"in all; use --cutoff above {lo:.3g} Hz (and below {0.45 * rate:g} Hz), or record longer"
        )


def check_magnitudes(a: np.ndarray, what: str, limit: float) -> None:
    """Refuse a finite value of ``a`` (N, ...) beyond ``limit`` in magnitude, naming ``what`` and the sample."""
    k = first_beyond(a, limit)
    if k is not None:
        row = np.asarray(a, dtype=np.float64).reshape(len(a), -1)[k]
        v = row[np.isfinite(row) & (np.abs(row) > limit)][0]
        raise DatasetError(
            f"{what} holds {v:g} at sample {k}, beyond {limit:g} in magnitude, more than any sensor "
            "or clock gives (ineid.data.recordings.streams.VALUE_LIMIT, TIME_LIMIT): drop or repair that sample"
        )


def check_stream(name: str, t: np.ndarray, arrays: dict[str, np.ndarray], source: str) -> float:
    """Finite values and increasing time; the median interval (s)."""
    for label, a in {"time": t, **arrays}.items():
        bad = ~np.isfinite(a.reshape(len(a), -1))
        if bad.any():
            rows = np.flatnonzero(bad.any(axis=1))
            k = int(rows[0])
            what = "NaN" if np.isnan(a.reshape(len(a), -1)[k]).any() else "an infinite value"
            when = f", t = {float(t[k])!r} s" if label != "time" and np.isfinite(t[k]) else ""
            raise DatasetError(
                f"{source}: the {name} stream's {label} holds {what} at sample {k}{when} ({len(rows)} sample"
                f"{'s' if len(rows) != 1 else ''} in all); values must be finite: drop or repair those samples"
            )
        check_magnitudes(a, f"{source}: the {name} stream's {label}", TIME_LIMIT if label == "time" else VALUE_LIMIT)
    return signals.median_interval(t, f"{source}: the {name} stream")


MAX_UPSAMPLING = 100.0
"""``--rate`` may be at most this multiple of the faster stream's rate: resampling adds no information,
and beyond it only memory (a 10 s recording at 1e9 Hz wanted 74 GiB)."""


def check_delay(delay: float, tq: np.ndarray, tw: np.ndarray, src: str) -> None:
    """A delay longer than the whole recording leaves no overlap (and, huge, no time resolution)."""
    with np.errstate(invalid="ignore"):
        span = float(np.max([tq.max(), tw.max()]) - np.min([tq.min(), tw.min()])) if tq.size and tw.size else 0.0
    if math.isfinite(span) and abs(delay) > span:
        raise DatasetError(
            f"{src}: a delay of {delay:g} s is longer than the whole recording ({span:.6g} s), so the streams cannot "
            "overlap; --delay is how late the wrench time stamps are against the joints', in seconds"
        )


def check_rate(rate: float | None, joint_rate: float, wrench_rate: float, overlap: float, n_dof: int) -> None:
    """Refuse a ``rate`` above :data:`MAX_UPSAMPLING` x the faster stream's, or frames that do not fit in memory."""
    if rate is None:
        return
    fastest = max(joint_rate, wrench_rate)
    check_min_rate(rate, overlap, MAX_UPSAMPLING * fastest)
    if rate > MAX_UPSAMPLING * fastest * (1 + 1e-9):  # the median interval of printed time stamps is inexact
        raise DatasetError(
            f"--rate {rate:g} Hz is more than {MAX_UPSAMPLING:g} x the faster stream's rate ({fastest:g} Hz): "
            f"resampling adds no information; use at most {MAX_UPSAMPLING * fastest:g} Hz (default: the slower "
            "stream's rate)"
        )
    from ineid._faults import require_memory

    # frames x (q, qd, qdd, wrench, time) in float64, about four copies alive while resampling
    n_frames = max(overlap, 0.0) * rate
    require_memory(n_frames * (3 * n_dof + 7) * 8 * 4, f"{n_frames:,.0f} frames at --rate {rate:g} Hz", "lower --rate")
