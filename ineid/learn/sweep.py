"""Train a grid of networks and rank them by test error (``ineid sweep``).

Trials that can share a compiled program train together, one population at a time, in this
process (``engine="sequential"``, the default) or as Ray tasks on a cluster, one a population
(``engine="ray"``, :mod:`ineid.learn.ray_engine`); either way each trial has its own run folder
``OUT/<name>`` and the ranked table goes to ``OUT/sweep.csv`` and ``OUT/sweep.png``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid._atomic import atomic_write, save_figure, write_csv
from ineid._inputs import read_json
from ineid.errors import IneidError, TrainingError
from ineid.learn.models import SIZED
from ineid.learn.train import TrainConfig
from ineid.learn.trials import (  # noqa: F401  (re-exported)
    TRIAL_STATES,
    SweepRow,
    populations,
    run_name,
    run_population,
    run_trial,
    trial_state,
)

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.robots import RobotModel


@dataclass(frozen=True)
class Grid:
    """The settings to combine (every combination is one run)."""

    archs: tuple[str, ...] = ("simple", "net1", "net2", "net3", "net4", "net5", "net6", "net7", "funnel")
    activations: tuple[str, ...] = ("tanh",)
    scalers: tuple[str, ...] = ("robust",)
    optimizers: tuple[str, ...] = ("adam",)
    losses: tuple[str, ...] = ("mse",)
    frames: tuple[int, ...] = (1,)
    siamese: tuple[bool, ...] = (False,)

    def configs(self, base: TrainConfig) -> list[TrainConfig]:
        out = []
        for arch, act, scaler, opt, loss, k, siam in itertools.product(
            self.archs, self.activations, self.scalers, self.optimizers, self.losses, self.frames, self.siamese
        ):
            if siam and k < 2:
                continue  # a Siamese network of one frame is a plain network
            if arch == "wls" and siam:
                if False in self.siamese:
                    continue  # wls shares its frame encoder anyway: one run, not two
                siam = False
            sizes = (
                {"depth": base.model.depth, "width": base.model.width}
                if arch in SIZED
                else {"depth": None, "width": None}
            )
            model = dataclasses.replace(base.model, arch=arch, activation=act, frames=k, siamese=siam, **sizes)
            out.append(dataclasses.replace(base, model=model, scaler=scaler, optimizer=opt, loss=loss))
        return out


ENGINES = ("sequential", "ray")


SWEEP_RECORD = "sweep.json"
"""The settings of a sweep in its folder (grid, run settings, dataset fingerprint), checked by ``resume``."""


def sweep_record(grid: Grid, base: TrainConfig, ds: Dataset) -> dict:
    """What ``OUT/sweep.json`` holds: the grid, the run settings and the dataset's fingerprint (JSON types)."""
    return json.loads(
        json.dumps({"grid": dataclasses.asdict(grid), "run settings": base.to_dict(), "dataset": ds.fingerprint()})
    )


def check_sweep_folder(
    ds: Dataset, grid: Grid, base: TrainConfig, out_dir: str | Path, *, overwrite: bool = False, resume: bool = False
) -> dict:
    """Whether :func:`sweep` may write ``out_dir`` (called by it; the CLI calls it before its progress bar).

    Returns:
        The sweep's record (:func:`sweep_record`).

    Raises:
        TrainingError: a trial folder holds a run and neither ``overwrite`` nor ``resume``;
            ``resume`` of a folder without a sweep, or with another grid, other run
            settings or another dataset.
    """
    out_dir = Path(out_dir)
    record = sweep_record(grid, base, ds)
    if resume:
        try:
            saved = read_json(out_dir / SWEEP_RECORD, "the sweep record")
        except (IneidError, OSError, ValueError):
            raise TrainingError(
                f"{out_dir} holds no sweep to resume (no readable {SWEEP_RECORD}); start it without --resume"
            ) from None
        differs = {
            "grid": "a different grid",
            "run settings": "different run settings",
            "dataset": "a different dataset",
        }
        for key, what in differs.items():
            if not isinstance(saved, dict) or saved.get(key) != record[key]:
                raise TrainingError(
                    f"{out_dir} holds a sweep with {what}; resume it with the same settings and "
                    "dataset, or use a new folder"
                )
    elif not overwrite:
        names = [run_name(c) for c in grid.configs(base)]
        busy = [n for n in names if (out_dir / n).is_dir() and any((out_dir / n).iterdir())]
        if busy:
            raise TrainingError(
                f"{out_dir / busy[0]} holds a run; pass --overwrite to replace the sweep's runs, or "
                "--resume to continue the sweep"
            )
    return record


def sweep(
    ds: Dataset,
    grid: Grid,
    base: TrainConfig,
    out_dir: str | Path,
    dataset_path: str | None = None,
    model: RobotModel | None = None,
    progress=None,
    overwrite: bool = False,
    physics_mode: str = "cached",
    *,
    engine: str = "sequential",
    address: str | None = None,
    cpus_per_trial: float = 1.0,
    gpus_per_trial: float = 0.0,
    ray_init: dict | None = None,
    resume: bool = False,
) -> list[SweepRow]:
    """Train and evaluate every configuration of ``grid`` into ``out_dir/<name>``; rows ranked
    by the test median relative error of the standard parameters, failed trials last.

    Trials that share a network's shapes and sizes (they differ in seeds, scalers, learning rates,
    loss weights) train together as one population (:func:`ineid.learn.trials.populations`); each
    trial's folder and numbers are those of training it alone.

    A trial that fails (an :class:`ineid.IneidError` such as a diverging loss; with Ray, any
    error in the trial) becomes a row with ``status = "failed: <why>"`` and NaN errors; the
    sweep goes on.

    The settings go to ``out_dir/sweep.json`` first. An interrupted sweep leaves its
    finished trials, and the interrupted ones up to their last checkpoint (a trial replacing
    an older run leaves the older run until it finishes): ``resume`` continues it, keeping
    finished trials (:func:`trial_state`), resuming interrupted ones and running the rest;
    ``sweep.csv`` and ``sweep.png`` are then written over all the trials. The folder's
    lock (:func:`ineid._atomic.output_lock`) is held throughout.

    Args:
        ds: the dataset (with the truth).
        grid, base: the settings to combine, and the rest of each run's settings.
        out_dir: one run folder per trial, ``sweep.csv`` and ``sweep.png``.
        dataset_path: recorded in each run's ``config.json``.
        model: the robot model (default: rebuilt from the dataset).
        progress: ``progress(done, total, row)`` after each trial.
        overwrite: replace run folders that hold runs (else refused before any training);
            each is replaced when its new run is finished.
        physics_mode: ``"cached"`` or ``"inline"`` (see :func:`ineid.learn.train`).
        engine: ``"sequential"`` (this process, one population after another) or ``"ray"``
            (:mod:`ineid.learn.ray_engine`: one Ray task per population).
        address: the Ray cluster to join; None starts a local one for the sweep and stops it.
        cpus_per_trial, gpus_per_trial: Ray resources each population reserves.
        ray_init: extra keyword arguments of ``ray.init`` for the local cluster (e.g. ``num_cpus``).
        resume: continue the sweep in ``out_dir`` (the same grid, settings and dataset).

    Raises:
        ValueError: an empty grid or an unknown engine.
        TrainingError: a run folder holds a run and neither ``overwrite`` nor ``resume`` is on;
            ``resume`` of a folder without a sweep or with other settings.
        OutputBusyError: another process is writing ``out_dir``.
        OptionalDependencyError: ``engine="ray"`` without Ray installed.
    """
    ray = dict(address=address, cpus_per_trial=cpus_per_trial, gpus_per_trial=gpus_per_trial, ray_init=ray_init)
    (rows,) = sweep_many(
        ds,
        [SweepSpec(grid, base, Path(out_dir), resume)],
        dataset_path=dataset_path,
        model=model,
        progress=progress,
        overwrite=overwrite,
        physics_mode=physics_mode,
        engine=engine,
        **ray,
    )
    return rows


@dataclass(frozen=True)
class SweepSpec:
    """One sweep of :func:`sweep_many`: its grid, run settings, folder, and whether it is resumed."""

    grid: Grid
    base: TrainConfig
    out_dir: Path
    resume: bool = False


def sweep_many(
    ds: Dataset,
    sweeps: list[SweepSpec],
    *,
    dataset_path: str | None = None,
    model: RobotModel | None = None,
    progress=None,
    overwrite: bool = False,
    physics_mode: str = "cached",
    engine: str = "sequential",
    **ray,
) -> list[list[SweepRow]]:
    """Several sweeps on one dataset, each as :func:`sweep` runs it, their trials trained together: populations
    are formed across the sweeps (the seeds of a study, each its own sweep folder, train as one).

    Returns:
        Each sweep's rows, ranked (:func:`sweep`).
    """
    from contextlib import ExitStack

    from ineid._atomic import output_lock

    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    cfgs = [sw.grid.configs(sw.base) for sw in sweeps]
    if not all(cfgs):
        raise ValueError(
            "the grid is empty (a Siamese network needs more than one frame: add --sample-frames values > 1)"
        )
    jobs, owner = [], []
    with ExitStack() as locks:
        for k, sw in enumerate(sweeps):
            sw.out_dir.parent.mkdir(parents=True, exist_ok=True)
            locks.enter_context(output_lock(sw.out_dir))
            record = check_sweep_folder(ds, sw.grid, sw.base, sw.out_dir, overwrite=overwrite, resume=sw.resume)
            sw.out_dir.mkdir(parents=True, exist_ok=True)
            atomic_write(sw.out_dir / SWEEP_RECORD, json.dumps(record, indent=1))
            for cfg in cfgs[k]:
                run_dir = sw.out_dir / run_name(cfg)
                jobs.append((cfg, run_dir, trial_state(run_dir, cfg, record["dataset"]) if sw.resume else "new"))
                owner.append(k)
        rows = _run_jobs(engine, ds, jobs, dataset_path, model, physics_mode, progress, ray)
        out = [[r for r, o in zip(rows, owner, strict=True) if o == k] for k in range(len(sweeps))]
        for sw, sweep_rows in zip(sweeps, out, strict=True):
            _write_ranked(sweep_rows, sw.out_dir)
    return out


def _run_jobs(
    engine: str,
    ds: Dataset,
    jobs: list[tuple[TrainConfig, Path, str]],
    dataset_path: str | None,
    model: RobotModel | None,
    physics_mode: str,
    progress,
    ray: dict,
) -> list[SweepRow]:
    """Every trial ``(cfg, run folder, state)``, one row each in order (a failed one: its status): one Ray task a
    population (``ray``: the cluster's keyword arguments of :func:`ineid.learn.ray_engine.ray_trials`), or one
    population after another in this process, on data held once for all of them."""
    groups = populations([cfg for cfg, _, _ in jobs])
    if engine == "ray":
        from ineid.learn.ray_engine import ray_populations

        return ray_populations(
            ds, jobs, groups, dataset_path=dataset_path, physics_mode=physics_mode, progress=progress, **ray
        )
    model = model or ds.model()
    shared = _shared(ds, model, [cfg for cfg, _, state in jobs if state in ("new", "checkpoint")], physics_mode)
    rows: list[SweepRow | None] = [None] * len(jobs)
    done = 0
    for group in groups:
        got = run_population(ds, [jobs[i] for i in group], dataset_path, model, physics_mode, shared)
        for i, row in zip(group, got, strict=True):
            rows[i] = row
            done += 1
            if progress is not None:
                progress(done, len(jobs), row)
    return rows


def _shared(ds: Dataset, model, cfgs: list[TrainConfig], physics_mode: str) -> dict:
    """The data every trial of ``cfgs`` trains on, held once (:func:`ineid.learn.train.shared_data`); a trial whose
    split fails is left out (its error is reported when it runs)."""
    from ineid.learn.train import default_split, shared_data

    pairs = []
    for cfg in cfgs:
        try:
            pairs.append((cfg, default_split(ds, cfg)))
        except IneidError:
            continue
    return shared_data(ds, model, pairs, physics_mode) if pairs else {}


def _write_ranked(rows: list[SweepRow], out_dir: Path) -> None:
    """Rank ``rows`` in place (finished trials by the test median relative error, then failed ones), and write
    ``sweep.csv`` and ``sweep.png``."""
    rows.sort(key=lambda r: (r.status != "ok", np.nan_to_num(r.test_standard_median, nan=np.inf), r.name))
    write_csv(
        out_dir / "sweep.csv", [f.name for f in dataclasses.fields(SweepRow)], [dataclasses.asdict(r) for r in rows]
    )
    plot(rows, out_dir / "sweep.png")


def plot(rows: list[SweepRow], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(rows) + 2), 4.5), constrained_layout=True)
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r.test_standard_median for r in rows], 0.4, label="standard parameters")
    ax.bar(x + 0.2, [r.test_base_median for r in rows], 0.4, label="base parameters")
    ok = [r for r in rows if r.status == "ok"]
    if ok and np.isfinite(ok[0].floor_standard_median):
        ax.axhline(ok[0].floor_standard_median, color="k", linestyle="--", label="null-space floor (standard)")
    if ok and len({r.frames for r in ok}) == 1 and np.isfinite(ok[0].linear_standard_median):
        # the same frames for every run: one LS line
        ax.axhline(ok[0].linear_standard_median, color="C3", linestyle=":", label="linear least squares (standard)")
    # Run names are literal text: mathtext off (the y axis keeps it for its log-scale labels).
    ax.set_xticks(x, [r.name for r in rows], rotation=60, ha="right", fontsize=7, parse_math=False)
    ax.set_ylabel("test median relative error")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
