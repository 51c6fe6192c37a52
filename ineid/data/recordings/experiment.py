"""The recordings of one experiment imported together: one filter and one wrench delay for all of them.

Runs of one experiment (one arm, its sensors and logger, several excitations) are fitted together
(``ineid solve a.h5 b.h5``) and validated on one another (``--validate c.h5``). Each run imported alone gets
the cut-off its own angles call for (three runs of one experiment: 8.89, 7.19 and 8.67 Hz), and the fit then
mixes rows whose regressor and wrench went through different filters.
:func:`import_experiment` (``ineid data import a.csv b.csv c.csv --out FOLDER``) imports them with

- **one cut-off**: ``settings.cutoff`` when given; else the cut-off rule
  (:func:`ineid.data.recordings.signals.choose_cutoff`) on the runs' pooled spectra
  (:func:`ineid.data.recordings.signals.pooled_cutoff`: their accelerations' noise and motion summed, each run
  weighted by its length, the rows the fit sees), at most 0.4 times the slowest run's frame rate; with link
  gyros (whose own rule moves each run's cut-off) the lowest of the runs' own choices; no filter when every
  run measures ``qd``, ``qdd``. A run with measured ``qd``, ``qdd`` among runs that differentiate their
  angles is filtered at the shared cut-off too;
- **one wrench delay**: ``settings.delay``, or with ``settings.estimate_delay`` the median of each run's
  estimate (each at the shared cut-off), applied to every run.

Each run's own cut-off (what importing it alone would choose) and delay estimate are in the summary.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ineid.data.dataset.schema import Dataset
from ineid.data.recordings import signals
from ineid.data.recordings.pipeline import hinted_recording_dataset, own_cutoff, read_streams
from ineid.data.recordings.settings import DelayEstimator, ImportSettings
from ineid.data.recordings.summary import DelayEstimate, ImportSummary
from ineid.errors import DatasetError
from ineid.progress import Progress

CUTOFF_RULES = {
    "given": "given",
    "pooled": "the cut-off rule on their pooled spectra",
    "lowest": "the lowest of their own choices (link gyros move each one's)",
    "none": "no filter: every recording measures qd, qdd",
}
"""How the shared cut-off was chosen (:attr:`ExperimentImport.cutoff_rule`), in words."""


@dataclass
class ExperimentImport:
    """The recordings of one experiment, imported together (:func:`import_experiment`).

    Attributes:
        names: each recording's file name.
        datasets, summaries: each recording's dataset and import summary, in the order given.
        cutoff: Hz, the shared cut-off (None: no filter).
        cutoff_rule: a key of :data:`CUTOFF_RULES`.
        own_cutoffs: Hz, what each recording imported alone would choose (None: no filter).
        delay: s, the shared wrench delay.
        delay_estimates: each recording's estimate, when the delay was estimated (None otherwise).
    """

    names: tuple[str, ...]
    datasets: list[Dataset]
    summaries: list[ImportSummary]
    cutoff: float | None
    cutoff_rule: str
    own_cutoffs: tuple[float | None, ...]
    delay: float
    delay_estimates: tuple[DelayEstimate, ...] | None = None

    def lines(self) -> list[str]:
        """The experiment's shared filter and delay, with each recording's own choice, in words."""
        n = len(self.names)
        own = ", ".join(
            f"{name} {'no filter' if c is None else f'{c:.3g} Hz'}"
            for name, c in zip(self.names, self.own_cutoffs, strict=True)
        )
        if self.cutoff is None:
            out = [f"one filter for the {n} recordings: {CUTOFF_RULES['none']}"]
        else:
            out = [
                f"one filter for the {n} recordings: zero-phase Butterworth (order {signals.FILTER_ORDER}) at "
                f"{self.cutoff:.3g} Hz, {CUTOFF_RULES[self.cutoff_rule]} (each one's own choice: {own})"
            ]
        if self.delay_estimates is not None:
            each = ", ".join(
                f"{name} {1e3 * e.delay:.4g}" for name, e in zip(self.names, self.delay_estimates, strict=True)
            )
            out.append(
                f"one wrench delay for the {n} recordings: {1e3 * self.delay:.4g} ms, the median of their "
                f"estimates ({each} ms)"
            )
        elif self.delay:
            out.append(f"one wrench delay for the {n} recordings: {1e3 * self.delay:.4g} ms (given)")
        return out


def import_experiment(
    paths: Sequence[str | Path],
    model,
    settings: ImportSettings = ImportSettings(),
    joint_topic: str = "/joint_states",
    wrench_topic: str | None = None,
    progress: Progress | None = None,
    imu_topics: tuple[str, ...] = (),
    delay_estimator: DelayEstimator | None = None,
) -> ExperimentImport:
    """Import the recordings of one experiment with one cut-off and one wrench delay (module docstring).

    Args:
        paths: the recording files (CSV, bags), two or more (one works too: its own choice).
        model, settings, joint_topic, wrench_topic, imu_topics, delay_estimator: as
            :func:`ineid.data.recordings.pipeline.import_recording`'s, the same for every recording.
        progress: ``progress(done, total)`` over each file's rows or messages read.

    Raises:
        DatasetError: no recording, and see :func:`ineid.data.recordings.pipeline.import_recording`.
    """
    if not paths:
        raise DatasetError("no recording to import")
    names = tuple(Path(p).name for p in paths)
    every = [
        read_streams(p, model, joint_topic, wrench_topic, progress, imu_topics, settings.imus, settings.coupling)
        for p in paths
    ]
    cuts = [own_cutoff(s, model, replace(settings, cutoff=None)) for s in every]
    cutoff, rule = _shared_cutoff(cuts, every, settings)
    at = replace(settings, cutoff=cutoff)
    estimates = None
    delay = settings.delay
    if settings.estimate_delay:
        alone = [hinted_recording_dataset(s, model, at, delay_estimator)[1] for s in every]
        estimates = tuple(a.delay_estimate for a in alone)
        delay = float(np.median([e.delay for e in estimates]))
    imported = [hinted_recording_dataset(s, model, replace(at, delay=delay, estimate_delay=False)) for s in every]
    own = tuple(c.hz for c, _ in cuts)
    for (ds, summary), c in zip(imported, own, strict=True):
        if rule != "given" and cutoff is not None:
            summary.cutoff_note = f"shared by the experiment's {len(every)} recordings: {CUTOFF_RULES[rule]}; " + (
                "this one alone: no filter" if c is None else f"this one alone: {c:.3g} Hz"
            )
            ds.meta.origin["import"]["cutoff_note"] = summary.cutoff_note  # the file says it too
    return ExperimentImport(
        names,
        [ds for ds, _ in imported],
        [summary for _, summary in imported],
        cutoff,
        rule,
        own,
        delay,
        estimates,
    )


def _shared_cutoff(cuts, every, settings: ImportSettings) -> tuple[float | None, str]:
    """``(cutoff, rule)``: the experiment's cut-off (Hz, None: no filter) and the key of :data:`CUTOFF_RULES` that
    chose it, from each recording's ``(Cutoff, RecordingArrays)`` ``cuts`` and streams ``every``."""
    if settings.cutoff is not None:
        return settings.cutoff, "given"
    chosen = [(c, a) for c, a in cuts if c.hz is not None]
    if not chosen:
        return None, "none"
    if any("gyro" in r.readings for s in every for r in s.imus):
        return min(c.hz for c, _ in chosen), "lowest"
    spectra = [signals.angle_spectrum(c.q_uniform, 1.0 / a.hq) for c, a in chosen if c.q_uniform is not None]
    pooled = signals.pooled_cutoff(spectra)
    return min(pooled.cutoff, 0.4 * min(a.rate for _, a in cuts)), "pooled"
