"""The whole jobs: the lower layers' functions with every choice ineid has, composed above them.

``data`` imports a recording without fitting a model, and ``identify`` solves without trained
networks: what they need from the layers above is passed in, never registered by an import. The
wrench delay of a recording is estimated by fitting the model
(:func:`ineid.identify.delay.estimate_delay`), and ``method="network"`` solves with a trained run
(:func:`ineid.learn.amortized.solve_with_run`). :func:`import_recording` and :func:`solve_dataset`
pass them (:func:`import_experiment` too); the command line calls them. Each imports what it passes when called, so that
importing this module (``ineid --help``) loads neither JAX nor Flax.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path

from ineid.data.recordings.settings import ImportSettings
from ineid.identify.solve import SolveMethod, SolveResults, SolveSettings
from ineid.progress import Progress


def methods() -> dict[str, SolveMethod]:
    """The methods implemented above ``identify``, by name, for :func:`ineid.identify.solve.solve_dataset`."""
    from ineid.learn.amortized import solve_with_run

    return {"network": solve_with_run}


class _Methods(Mapping):
    """:func:`methods`, imported when a method is looked up: a solve by any other method loads no Flax."""

    def __getitem__(self, name: str) -> SolveMethod:
        return methods()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(("network",))

    def __len__(self) -> int:
        return 1


def import_recording(path: str | Path, model, settings: ImportSettings | None = None, **options):
    """:func:`ineid.data.recordings.pipeline.import_recording` with the model-fitted delay estimate
    (``settings.estimate_delay``, ``ineid data import --delay auto``).

    Args:
        path, model, settings: as :func:`ineid.data.recordings.pipeline.import_recording`.
        **options: its other options (``joint_topic``, ``wrench_topic``, ``progress``, ``imu_topics``).

    Returns:
        ``(dataset, summary)``.
    """
    from ineid.data.recordings.pipeline import import_recording as read_recording
    from ineid.identify.delay import estimate_delay

    return read_recording(path, model, settings or ImportSettings(), delay_estimator=estimate_delay, **options)


def import_experiment(paths, model, settings: ImportSettings | None = None, **options):
    """:func:`ineid.data.recordings.experiment.import_experiment` (the recordings of one experiment with one
    cut-off and one wrench delay) with the model-fitted delay estimate, as :func:`import_recording`.

    Returns:
        The :class:`ineid.data.recordings.experiment.ExperimentImport`.
    """
    from ineid.data.recordings.experiment import import_experiment as read_experiment
    from ineid.identify.delay import estimate_delay

    return read_experiment(paths, model, settings or ImportSettings(), delay_estimator=estimate_delay, **options)


def solve_dataset(
    ds, settings: SolveSettings | None = None, model=None, progress: Progress | None = None
) -> SolveResults:
    """:func:`ineid.identify.solve.solve_dataset` with every method, ``network`` included (:func:`methods`)."""
    from ineid.identify.solve import solve_dataset as solve

    return solve(ds, settings or SolveSettings(), model, progress, methods=_Methods())
