"""The time stamps of a recording's streams audited at import: the nominal rate, jitter, gaps, held values.

A lab's log is rarely sampled like a simulation: a controller's loop jitters, misses cycles, and a logger
that runs beside it may write the last value it holds again under a new time stamp. Each stream of a
recording (the joints, the wrench, each link IMU) is audited here before it is filtered and resampled
(:func:`audit_stream`, called by :func:`ineid.data.recordings.frames.checked_arrays` and
:func:`ineid.data.recordings.imus.prepare_imus`):

* **the nominal rate** (:func:`nominal_interval`): the rate the log was taken at, not the mean of its
  jitter or of its missing samples. A stream whose steps all equal their median (within
  :data:`ineid.data.recordings.signals.JITTER_RTOL`) is uniform at its median step. Otherwise every step is
  counted as the whole number of nominal periods it spans, ``n_k = max(1, round(dt_k / h))``, and
  ``h = (t_last - t_first) / sum(n_k)`` (three passes, starting from the median step): the stamps' own
  span over the periods they cover, which jitter shifts by at most one step over the whole log and missing
  samples not at all. That estimate is snapped to the nearest clean value (:func:`clean_interval`: a rate
  of 1, 1.2, 1.25, 1.5, 2, 2.4, 2.5, 3, 4, 5, 6 or 8 times a power of ten Hz, a power of two Hz, or a step
  of 1, 1.5, 2, 2.5, 3, 4, 5, 6 or 8 times a power of ten s) within :data:`SNAP_TOLERANCE`, when there is
  one; else it is used as it is.
* **held values** (:func:`held_rows`): a row whose every value of the stream equals the previous row's is
  a held value when the stream leaves it by more than its resolution allows: on some column the step out of
  the run of equal rows exceeds both :data:`HELD_QUANTA` times the column's smallest nonzero step and
  :data:`HELD_TYPICAL` times its median nonzero step. A coarse encoder's plateau on slow motion (left by one
  count) and a resting arm (left smoothly) are data; a controller logging a held value while the arm moves
  is not. Held rows are dropped before the stream is filtered (treated as missing, not as data).
* **jitter and gaps**: the steps' extremes and 1st and 99th percentiles, the jitter (the 99th percentile of
  ``|dt - h| / h`` over the steps that are not gaps), and the gaps: steps between the rows kept longer than
  :data:`GAP_STEPS` nominal steps.

A warning (:attr:`TimingReport.warnings`, printed by ``ineid data import``) above :data:`JITTER_WARN`,
:data:`REPEAT_WARN`, or for a gap longer than one period of the cut-off; an error (:func:`check_gaps`) for a
gap longer than the filter's support (:func:`ineid.data.recordings.signals.edge_seconds` of the cut-off),
unless ``ImportSettings(allow_gaps=True)`` (``--allow-gaps``). Time that does not increase is an error
earlier (the CSV reader names the line; :func:`ineid.data.recordings.signals.median_interval` the sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ineid.data.recordings import signals
from ineid.errors import DatasetError

SNAP_TOLERANCE = 0.01
"""The estimated nominal step is replaced by a clean value (:func:`clean_interval`) within this share of it."""
JITTER_WARN = 0.25
"""A stream whose steps' 99th percentile of ``|dt - h| / h`` is above this warns."""
REPEAT_WARN = 0.01
"""A stream with more than this share of its rows held (repeating the previous sample) warns."""
HELD_QUANTA = 2.0
"""A run of equal rows is held when the step out of it exceeds this many of a column's smallest nonzero step..."""
HELD_TYPICAL = 0.5
"""... and this share of the column's median nonzero step (see the module docstring)."""
GAP_STEPS = 1.5
"""A step between kept rows longer than this many nominal steps is a gap (a sample or more missing)."""
_RATE_MANTISSAS = (1.0, 1.2, 1.25, 1.5, 2.0, 2.4, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)
_STEP_MANTISSAS = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)


def clean_interval(h: float, tolerance: float = SNAP_TOLERANCE) -> float | None:
    """The clean step (s) nearest ``h`` within ``tolerance`` (relative), or None (see the module docstring)."""
    if not (h > 0 and math.isfinite(h)):
        return None
    rate = 1.0 / h
    candidates = [
        1.0 / (m * 10.0**e)
        for e in range(int(math.floor(math.log10(rate))) - 1, int(math.log10(rate)) + 2)
        for m in _RATE_MANTISSAS
    ]
    candidates += [2.0 ** -round(math.log2(rate))]
    candidates += [
        m * 10.0**e for e in range(int(math.floor(math.log10(h))) - 1, int(math.log10(h)) + 2) for m in _STEP_MANTISSAS
    ]
    best = min(candidates, key=lambda c: abs(c - h))
    return best if abs(best - h) <= tolerance * h else None


def nominal_interval(t: np.ndarray) -> tuple[float, str, float]:
    """The nominal step (s) of increasing time stamps ``t`` (N,), how it was found, and the estimate before
    snapping (the module docstring states the rule).

    Returns:
        ``(h, how, estimate)``: ``how`` is ``"uniform"`` (every step equals the median), ``"snapped"`` (the
        lattice estimate snapped to a clean value) or ``"estimated"`` (no clean value near it).
    """
    t = np.asarray(t, dtype=np.float64)
    dt = np.diff(t)
    m = float(np.median(dt))
    if np.all(np.abs(dt - m) <= signals.JITTER_RTOL * m):
        return m, "uniform", m
    h = m
    for _ in range(3):
        h = float((t[-1] - t[0]) / np.maximum(1.0, np.rint(dt / h)).sum())
    snapped = clean_interval(h)
    return (snapped, "snapped", h) if snapped is not None else (h, "estimated", h)


def held_rows(values: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows of ``values`` (N, m) that hold the previous row's sample (module docstring)."""
    v = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    n = len(v)
    held = np.zeros(n, dtype=bool)
    if n < 3:
        return held
    steps = np.abs(np.diff(v, axis=0))
    repeat = np.concatenate([[False], ~(steps > 0).any(axis=1)])  # row k equals row k - 1
    if not repeat.any():
        return held
    quantum = np.where(steps > 0, steps, np.inf).min(axis=0)  # a column that never moves: inf, never left
    typical = np.array([np.median(c[c > 0]) if (c > 0).any() else np.inf for c in steps.T])
    bound = np.maximum(HELD_QUANTA * quantum, HELD_TYPICAL * typical)
    rows = np.arange(n)
    exit_row = np.minimum.accumulate(np.where(repeat, n, rows)[::-1])[::-1]  # the first fresh row at or after k
    k = np.flatnonzero(repeat & (exit_row < n))
    held[k] = (np.abs(v[exit_row[k]] - v[k]) > bound).any(axis=1)
    return held


@dataclass(frozen=True)
class StreamTiming:
    """One stream's time stamps as audited (module docstring).

    Attributes:
        name: ``"joint"``, ``"wrench"`` or ``"IMU 'NAME'"``.
        samples: rows read.
        rate: Hz, the nominal rate (``1 / h``).
        how: ``"uniform"``, ``"snapped"`` or ``"estimated"`` (:func:`nominal_interval`).
        estimate: Hz, the lattice estimate before snapping (the median step's rate when uniform).
        median_rate: Hz, ``1 /`` the median step.
        steps: s, the smallest step, the 1st and 99th percentiles, the largest.
        jitter: the 99th percentile of ``|dt - h| / h`` over the steps that are not gaps.
        held: rows that hold the previous sample, dropped (0 with ``keep_repeats``).
        repeats: rows equal to the previous one in every value (held or not).
        gaps: steps between the kept rows longer than :data:`GAP_STEPS` nominal steps.
        largest_gap: s, the longest step between the kept rows.
        gap_at: s, the time stamp that ends it.
        step: s, the nominal step ``h`` (the median step itself when uniform).
    """

    name: str
    samples: int
    rate: float
    how: str
    estimate: float
    median_rate: float
    steps: tuple[float, float, float, float]
    jitter: float
    held: int
    repeats: int
    gaps: int
    largest_gap: float
    gap_at: float
    step: float

    def line(self) -> str:
        """The summary's line of this stream."""
        ms = [f"{1e3 * s:.3g}" for s in self.steps]
        if self.how == "uniform":
            rate = f"{self.rate:g} Hz, uniform"
        else:
            how = (
                f"{self.estimate:.6g} Hz from the stamps' span over the periods they cover, snapped"
                if self.how == "snapped"
                else "from the stamps' span over the periods they cover"
            )
            rate = (
                f"{self.rate:g} Hz nominal ({how}; median step {1e3 / self.median_rate:.4g} ms), steps {ms[0]}..{ms[3]}"
                f" ms (1st-99th percentile {ms[1]}..{ms[2]} ms, jitter {100 * self.jitter:.3g} %)"
            )
        gaps = (
            f"{self.gaps:,} gap{'s' if self.gaps != 1 else ''}, the largest {1e3 * self.largest_gap:.3g} ms at "
            f"{self.gap_at:.6g} s"
            if self.gaps
            else "no gaps"
        )
        repeats = (
            f"{self.held:,} rows ({100 * self.held / self.samples:.2g} %) held the previous sample: dropped as missing"
            if self.held
            else (
                f"{self.repeats:,} rows repeat the previous one (kept as data)" if self.repeats else "no repeated rows"
            )
        )
        return f"{self.name} time stamps: {rate}; {gaps}; {repeats}"

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "samples": self.samples,
            "rate": self.rate,
            "how": self.how,
            "estimate": self.estimate,
            "median_rate": self.median_rate,
            "steps": list(self.steps),
            "jitter": self.jitter,
            "held": self.held,
            "repeats": self.repeats,
            "gaps": self.gaps,
            "largest_gap": self.largest_gap,
            "gap_at": self.gap_at,
            "step": self.step,
        }

    @classmethod
    def from_dict(cls, d: dict) -> StreamTiming:
        return cls(**{**d, "steps": tuple(float(s) for s in d["steps"])})


def audit_stream(
    name: str, t: np.ndarray, values: np.ndarray, keep_repeats: bool = False
) -> tuple[StreamTiming, np.ndarray]:
    """A stream's time stamps audited (module docstring); ``t`` (N,) s, increasing, ``values`` (N, m) every
    column of the stream.

    Returns:
        ``(timing, keep)``: ``keep`` (N,) bool, the rows used as data (all with ``keep_repeats``).
    """
    t = np.asarray(t, dtype=np.float64)
    h, how, estimate = nominal_interval(t)
    dt = np.diff(t)
    held = held_rows(values)
    repeats = int(np.sum(~(np.abs(np.diff(np.asarray(values).reshape(len(t), -1), axis=0)) > 0).any(axis=1)))
    keep = np.ones(len(t), dtype=bool) if keep_repeats else ~held
    steady = dt[dt <= GAP_STEPS * h] if np.any(dt <= GAP_STEPS * h) else dt  # the steps that are not gaps
    kept_dt = np.diff(t[keep])
    k = int(np.argmax(kept_dt))
    timing = StreamTiming(
        name=name,
        samples=len(t),
        rate=1.0 / h,
        how=how,
        estimate=1.0 / estimate,
        median_rate=1.0 / float(np.median(dt)),
        steps=(float(dt.min()), *(float(p) for p in np.percentile(dt, [1, 99])), float(dt.max())),
        jitter=float(np.percentile(np.abs(steady - h), 99) / h),
        held=int(np.sum(~keep)),
        repeats=repeats,
        gaps=int(np.sum(kept_dt > GAP_STEPS * h)),
        largest_gap=float(kept_dt[k]),
        gap_at=float(t[keep][k + 1]),
        step=h,
    )
    return timing, keep


@dataclass
class TimingReport:
    """The audit of every stream of an import, the limits it was held to, and its warnings.

    Attributes:
        streams: each stream's :class:`StreamTiming`.
        rate_given: Hz, ``--rate`` when given (the frames' rate then), else None.
        cutoff: Hz, the cut-off the gaps were held to: the filter's, else the cut-off rule's upper bound
            (0.1 x the frames' rate) when no filter runs.
        allow_gaps: gaps longer than the filter's support were allowed (``--allow-gaps``).
        keep_repeats: held rows were kept as data (``--keep-repeats``).
        warnings: ``(code, message)`` pairs: ``timing_jitter``, ``timing_repeats``, ``timing_gaps``.
    """

    streams: tuple[StreamTiming, ...]
    rate_given: float | None = None
    cutoff: float | None = None
    allow_gaps: bool = False
    keep_repeats: bool = False
    warnings: list[tuple[str, str]] = field(default_factory=list)

    def lines(self) -> list[str]:
        """The import summary's lines: one per stream, and ``--rate`` when it overrides the nominal rates."""
        out = [s.line() for s in self.merged()]
        if self.rate_given is not None:
            nominal = ", ".join(f"{s.name} {s.rate:g} Hz" for s in self.merged())
            out.append(f"frames at {self.rate_given:g} Hz given by --rate (nominal: {nominal})")
        return out

    def merged(self) -> list[StreamTiming]:
        """The streams, those on one clock with the same rows (a CSV's joints and wrench) as one, named
        ``"joint and wrench"``: what the summary and the warnings say once."""
        named: list[StreamTiming] = []
        for s in self.streams:
            twin = next((k for k, o in enumerate(named) if replace(o, name=s.name) == s), None)
            if twin is None:
                named.append(s)
            else:
                named[twin] = replace(named[twin], name=f"{named[twin].name} and {s.name}")
        return named

    def to_dict(self) -> dict:
        return {
            "streams": [s.to_dict() for s in self.streams],
            "rate_given": self.rate_given,
            "cutoff": self.cutoff,
            "allow_gaps": self.allow_gaps,
            "keep_repeats": self.keep_repeats,
            "warnings": [{"code": c, "message": m} for c, m in self.warnings],
        }

    @classmethod
    def from_dict(cls, d: dict) -> TimingReport:
        return cls(
            streams=tuple(StreamTiming.from_dict(s) for s in d["streams"]),
            rate_given=d.get("rate_given"),
            cutoff=d.get("cutoff"),
            allow_gaps=bool(d.get("allow_gaps", False)),
            keep_repeats=bool(d.get("keep_repeats", False)),
            warnings=[(w["code"], w["message"]) for w in d.get("warnings", ())],
        )


def check_gaps(report: TimingReport, cutoff: float, source: str) -> None:
    """Hold every stream's gaps to the filter at ``cutoff`` Hz and fill ``report.warnings``.

    A gap longer than the filter's support (:func:`ineid.data.recordings.signals.edge_seconds`) is an error
    unless ``report.allow_gaps``; one longer than a period of the cut-off warns, as do jitter above
    :data:`JITTER_WARN` and held rows above :data:`REPEAT_WARN` of a stream's.

    Raises:
        DatasetError: a gap longer than the filter's support, naming the stream, the gap, when it ends, the
            support and the options that import it.
    """
    report.cutoff = float(cutoff)
    support = signals.edge_seconds(cutoff)
    for s in report.streams:
        if s.largest_gap > support and not report.allow_gaps:
            raise DatasetError(
                f"{source}: the {s.name} stream has a gap of {1e3 * s.largest_gap:.4g} ms ending at t = "
                f"{s.gap_at:.6g} s, longer than the filter's support ({1e3 * support:.3g} ms: "
                f"{signals.EDGE_PERIODS:g} periods of the {cutoff:.3g} Hz cut-off), so the frames across it would "
                f"be interpolated, not measured; split the recording at the gap, give --cutoff at most "
                f"{signals.EDGE_PERIODS / s.largest_gap:.3g} Hz, or pass --allow-gaps to import it as it is"
            )
    report.warnings = [w for s in report.merged() for w in _stream_warnings(s, cutoff, report.keep_repeats)]


def _stream_warnings(s: StreamTiming, cutoff: float, keep_repeats: bool) -> list[tuple[str, str]]:
    """The warnings of one stream (or of streams on one clock, ``s.name`` naming them all)."""
    out = []
    several = " and " in s.name
    stream = f"{s.name} stream{'s' if several else ''}"
    owner = f"{stream}'" if several else f"{stream}'s"
    if s.jitter > JITTER_WARN:
        out.append(
            (
                "timing_jitter",
                f"the {owner} time steps jitter: 1 % of them are more than {100 * s.jitter:.3g} % off the nominal "
                f"{1e3 / s.rate:.4g} ms (steps {1e3 * s.steps[0]:.3g}..{1e3 * s.steps[3]:.3g} ms); the samples are "
                "resampled at their time stamps, which must be when the values were measured, not when the rows "
                "were logged",
            )
        )
    if s.held > REPEAT_WARN * s.samples and not keep_repeats:
        out.append(
            (
                "timing_repeats",
                f"{s.held:,} {s.name} rows ({100 * s.held / s.samples:.2g} %) repeat the previous sample under a new "
                "time stamp (a logger writing a held value) and were dropped as missing; pass --keep-repeats if "
                "they are measurements",
            )
        )
    if s.largest_gap > 1.0 / cutoff:
        out.append(
            (
                "timing_gaps",
                f"the {stream} {'have' if several else 'has'} {s.gaps:,} gap{'s' if s.gaps != 1 else ''} "
                f"in {'their' if several else 'its'} samples, the largest {1e3 * s.largest_gap:.4g} ms "
                f"ending at t = {s.gap_at:.6g} s, longer than a period of the {cutoff:.3g} Hz cut-off: the frames "
                "across it are interpolated, not measured",
            )
        )
    return out


def timing_warnings(origin: dict | None) -> list[tuple[str, str]]:
    """The ``(code, message)`` warnings an import's timing audit stored in a dataset's ``origin``."""
    record = ((origin or {}).get("import") or {}).get("timing")
    return [(w["code"], w["message"]) for w in record.get("warnings", ())] if record else []


def timing_lines(origin: dict | None) -> list[str]:
    """The lines of the timing audit stored in a dataset's ``origin`` (``ineid data info``), its warnings
    last; [] for a dataset not imported from a recording."""
    record = ((origin or {}).get("import") or {}).get("timing")
    if not record:
        return []
    return TimingReport.from_dict(record).lines() + [f"timing warning: {m}" for _, m in timing_warnings(origin)]
