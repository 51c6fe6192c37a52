"""The trials of a sweep: their names, their state on disk, running them, and their rows in the table.

Trials that can share a compiled program (:func:`population_key`) are trained together as one
population (:func:`ineid.learn.train.train_population`, :func:`run_population`); each is then
evaluated on its test split. Shared by the engines that run a sweep's trials: here
(:func:`ineid.learn.sweep.sweep`) or one population a Ray task (:mod:`ineid.learn.ray_engine`).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from ineid._atomic import atomic_write
from ineid._inputs import parse_json, read_json
from ineid.errors import IneidError
from ineid.learn.evaluate import evaluate
from ineid.learn.run_checks import damaged, read_metrics
from ineid.learn.run_checks import read_json as read_run_json
from ineid.learn.runs import CHECKPOINT, CONFIG, EVALUATION, METRICS, MODEL, load_run
from ineid.learn.train import TrainConfig, Trial, train, train_population


def run_name(cfg: TrainConfig) -> str:
    return f"{cfg.model.name}-{cfg.scaler}-{cfg.optimizer}-{cfg.loss}"


@dataclass
class SweepRow:
    """One trial of a sweep: its settings, training time, and test errors beside the floor and least squares (NaN
    and ``status = "failed: <why>"`` when it failed).

    Errors are median relative errors over the test split's parameters (standard and base).
    """

    name: str
    arch: str
    activation: str
    scaler: str
    optimizer: str
    loss: str
    frames: int
    siamese: bool
    epochs_run: int
    seconds: float
    test_standard_median: float
    test_base_median: float
    floor_standard_median: float
    linear_standard_median: float
    linear_base_median: float
    physical_share: float
    gaussian_standard_median: float = float("nan")
    gaussian_base_median: float = float("nan")
    status: str = "ok"

    @classmethod
    def from_evaluation(cls, cfg: TrainConfig, epochs_run: int, seconds: float, ev: dict) -> SweepRow:
        """The row of a trained trial from its evaluation (:meth:`ineid.learn.Evaluation.to_dict`)."""
        nan = float("nan")

        def median(key: str) -> float:
            return ev[key]["overall_median"] if ev.get(key) else nan

        return cls(
            name=run_name(cfg),
            arch=cfg.model.arch,
            activation=cfg.model.activation,
            scaler=cfg.scaler,
            optimizer=cfg.optimizer,
            loss=cfg.loss,
            frames=cfg.model.frames,
            siamese=cfg.model.siamese,
            epochs_run=epochs_run,
            seconds=seconds,
            test_standard_median=median("network"),
            test_base_median=median("network_base"),
            floor_standard_median=median("floor"),
            linear_standard_median=median("linear"),
            linear_base_median=median("linear_base"),
            physical_share=ev["physical_share"],
            gaussian_standard_median=median("gaussian"),
            gaussian_base_median=median("gaussian_base"),
        )

    @classmethod
    def failed(cls, cfg: TrainConfig, message: str) -> SweepRow:
        nan = float("nan")
        return cls(
            name=run_name(cfg),
            arch=cfg.model.arch,
            activation=cfg.model.activation,
            scaler=cfg.scaler,
            optimizer=cfg.optimizer,
            loss=cfg.loss,
            frames=cfg.model.frames,
            siamese=cfg.model.siamese,
            epochs_run=0,
            seconds=nan,
            test_standard_median=nan,
            test_base_median=nan,
            floor_standard_median=nan,
            linear_standard_median=nan,
            linear_base_median=nan,
            physical_share=nan,
            status=f"failed: {message}",
        )


TRIAL_STATES = ("new", "checkpoint", "evaluate", "finished")


def trial_state(run_dir: Path, cfg: TrainConfig, fingerprint: str) -> str:
    """What resuming a sweep does with a trial's folder.

    ``"finished"``: a run of these settings and dataset with its evaluation (kept);
    ``"evaluate"``: finished training, no evaluation yet; ``"checkpoint"``: interrupted
    training, continued from its checkpoint; ``"new"``: nothing usable (missing, empty,
    unreadable, or a run of other settings or data: trained afresh, replacing it).
    """
    try:
        saved = read_json(run_dir / CONFIG, "the run file")
        same = saved["train"] == cfg.to_dict() and saved["dataset"]["fingerprint"] == fingerprint
    except (IneidError, OSError, ValueError, KeyError, TypeError):
        return "new"
    if not same:
        return "new"
    if (run_dir / MODEL).is_file():
        return "finished" if (run_dir / EVALUATION).is_file() else "evaluate"
    return "checkpoint" if (run_dir / CHECKPOINT).is_file() else "new"


def _trained(run_dir: Path) -> tuple[int, float]:
    """Epochs run and training seconds of a run, from its ``metrics.jsonl``."""
    path = run_dir / METRICS
    records = [parse_json(line) for line in read_metrics(path, sys.maxsize)]  # each a record with an epoch
    try:
        return (int(records[-1]["epoch"]) if records else 0), float(sum(r["seconds"] for r in records))
    except (KeyError, TypeError, ValueError):
        raise damaged(path, "a record lacks its seconds") from None


def run_trial(
    ds,
    cfg: TrainConfig,
    run_dir: Path,
    dataset_path: str | None = None,
    model=None,
    physics_mode: str = "cached",
    state: str = "new",
) -> SweepRow:
    """Train one grid point into ``run_dir``, evaluate it on the test split and write its ``evaluation.json``.

    ``state`` (:func:`trial_state`) says how much of it is done: ``"new"`` trains afresh
    (replacing a run there only once the new one is finished), ``"checkpoint"`` resumes the
    training, ``"evaluate"`` only evaluates, ``"finished"`` only reads the evaluation back.
    """
    if state not in TRIAL_STATES:
        raise ValueError(f"state must be one of {', '.join(TRIAL_STATES)}, got {state!r}")
    result = None
    if state in ("new", "checkpoint"):
        result = train(
            ds,
            cfg,
            run_dir,
            dataset_path=dataset_path,
            resume=state == "checkpoint",
            overwrite=True,
            model=model,
            physics_mode=physics_mode,
        )
    return _evaluated(ds, cfg, run_dir, state, result, model)


def population_key(cfg: TrainConfig) -> tuple:
    """What the settings of trials that can train as one population share (the rest of
    :func:`ineid.learn.population.program_key` follows from them on one dataset): the network, optimizer,
    schedule (and its epochs), loss form, batch, split sizes, dtype. A wls network trains alone."""
    unique = id(cfg) if cfg.model.uses_regressor else 0
    epochs = cfg.epochs if cfg.schedule == "cosine" else 0
    return (
        cfg.model,
        cfg.optimizer,
        cfg.schedule,
        epochs,
        cfg.loss,
        cfg.batch,
        cfg.n_train,
        cfg.n_val,
        cfg.dtype,
        unique,
    )


def populations(cfgs: list[TrainConfig], max_size: int | None = None) -> list[list[int]]:
    """The indices of ``cfgs`` in populations (:func:`population_key`), in the order first met, each of at
    most ``max_size`` trials (None: :data:`ineid.learn.population.MAX_POPULATION`)."""
    from ineid.learn.population import MAX_POPULATION

    size = max_size or MAX_POPULATION
    groups: dict[tuple, list[int]] = {}
    for i, cfg in enumerate(cfgs):
        groups.setdefault(population_key(cfg), []).append(i)
    return [g[s : s + size] for g in groups.values() for s in range(0, len(g), size)]


def run_population(
    ds,
    jobs: list[tuple[TrainConfig, Path, str]],
    dataset_path: str | None = None,
    model=None,
    physics_mode: str = "cached",
    shared: dict | None = None,
    failed_text=str,
) -> list[SweepRow]:
    """Train the trials ``(cfg, run folder, state)`` that need it as one population, evaluate each on its test
    split (``evaluation.json``), and return their rows in order (a trial that failed: its status,
    ``failed_text(error)``).

    ``state`` (:func:`trial_state`) says how much of each is done, as for :func:`run_trial`; ``shared`` data
    (:func:`ineid.learn.train.shared_data`) are reused and added to.
    """
    for _, _, state in jobs:
        if state not in TRIAL_STATES:
            raise ValueError(f"state must be one of {', '.join(TRIAL_STATES)}, got {state!r}")
    todo = [i for i, (_, _, state) in enumerate(jobs) if state in ("new", "checkpoint")]
    trials = [Trial(jobs[i][0], jobs[i][1], jobs[i][2] == "checkpoint", True, dataset_path) for i in todo]
    outcomes = train_population(ds, trials, model=model, physics_mode=physics_mode, shared=shared)
    trained = dict(zip(todo, outcomes, strict=True))
    rows = []
    for i, (cfg, run_dir, state) in enumerate(jobs):
        result = trained.get(i)
        if isinstance(result, IneidError):
            rows.append(SweepRow.failed(cfg, failed_text(result)))
            continue
        try:
            rows.append(_evaluated(ds, cfg, run_dir, state, result, model))
        except IneidError as e:
            rows.append(SweepRow.failed(cfg, failed_text(e)))
    return rows


def _evaluated(ds, cfg: TrainConfig, run_dir: Path, state: str, result, model) -> SweepRow:
    """A trained trial's row: its evaluation (written to ``evaluation.json``, or read back when finished)."""
    if state == "finished":
        ev = read_run_json(run_dir / EVALUATION)
    else:
        ev = evaluate(load_run(run_dir), ds, model=model).to_dict()
        atomic_write(run_dir / EVALUATION, json.dumps(ev, indent=1))
    epochs_run, seconds = (result.epochs_run, result.seconds) if state == "new" else _trained(run_dir)
    return SweepRow.from_evaluation(cfg, epochs_run, seconds, ev)
