"""The paper's network exploration, re-run at its scale over the sweep engine (``ineid study networks``).

The paper (section 3.3 and 4) trained its networks on 3,000 of its 10,000 generated
configurations "for at least one-hundred epochs each" and found that "under otherwise
identical constraints, the tanh activation function, the robust scaler, and the SGD
optimizer produced the most promising results", and that "the most promising result was
produced by the Siamese network with eight hidden layers and a width factor of eight".
It names no other activation, scaler or optimizer; the grid takes the usual alternatives
of its tools (Keras, scikit-learn): activations :data:`ACTIVATIONS`, scalers
:data:`SCALERS`, optimizers :data:`OPTIMIZERS`.

A study is a list of :class:`Part` (a :class:`ineid.learn.sweep.Grid` with its epochs and
batch), each run once per seed into ``OUT/<part>/seed-<seed>`` (an ``ineid sweep`` folder,
resumable; a part's seeds by one :func:`ineid.learn.sweep.sweep_many`, so its trials that
share a network train as one population), on the paper's dataset (``DatasetSpec()``: 100 x 100
factorial configurations x 100 frames) split 3,000 / 500 / 500 configurations. Plans:

* ``full``: every activation x scaler x optimizer on the simple network, Table 1's
  networks and the funnel (single frame), and on Table 1's networks as Siamese networks
  of K = 10 frames; the grid the paper describes (576 trials for 2 seeds).
* ``decisive``: one factor at a time around the paper's best (tanh, robust, SGD) on
  Network 1, at the paper's size and epochs; and the Siamese claim's cells (Network 1
  and Network 6, single-frame and Siamese K = 10) at :attr:`Size.siamese_epochs`.
* ``quick``: a 2 x 2 x 2 grid on the simple network, tiny data, 2 epochs, one seed (CI).

The rows (:class:`StudyRow`: a sweep row with its part, seed, epochs and training size)
go to ``OUT/networks.csv``; :func:`ineid.studies.paper_claims.check_claims` judges the paper's
claims on them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from ineid._atomic import write_csv
from ineid.data import Combination, DatasetSpec
from ineid.learn.models import ModelSpec
from ineid.learn.sweep import SWEEP_RECORD, Grid, SweepRow, SweepSpec, check_sweep_folder, sweep_many
from ineid.learn.train import TrainConfig
from ineid.learn.trials import run_name

ACTIVATIONS = ("tanh", "relu", "sigmoid")
"""The paper names tanh (its best) among "different activation functions"; relu and sigmoid are the other usual ones."""
SCALERS = ("robust", "standard", "minmax")
"""The paper names the robust scaler among "various scaling methods"; scikit-learn's other two."""
OPTIMIZERS = ("sgd", "adam")
"""The paper names SGD as the best; Adam is the usual alternative (ineid's default)."""
PAPER_BEST = {"activation": "tanh", "scaler": "robust", "optimizer": "sgd"}
"""The paper's best settings, the centre of the one-factor-at-a-time plan."""
SIAMESE_BEST = "net6"
"""Table 1's Network 6 (8 hidden layers, width factor 8): the paper's best network, as a Siamese network."""
SIAMESE_FRAMES = 10
"""Frames per Siamese sample (the paper does not say; ineid's documented choice)."""
TABLE1_ARCHS = ("net1", "net2", "net3", "net4", "net5", "net6", "net7")
PLANS = ("full", "decisive", "quick")
FILE = "networks.csv"


@dataclass(frozen=True)
class Size:
    """The data and training size of a study.

    Attributes:
        dataset: what to generate (the paper's: ``DatasetSpec()``).
        n_train, n_val, n_test: configurations per split.
        epochs: epochs of every trial (no early stopping: patience 0), except
        siamese_epochs: epochs of the ``decisive`` plan's Siamese-claim cells.
        seeds: one sweep per seed (the split and the initialisation); >= 2 to decide a claim.
        batch, siamese_batch: samples per step, single-frame and K-frame.
        lr, momentum: the one learning rate of every optimizer, SGD's momentum.
    """

    dataset: DatasetSpec
    n_train: int
    n_val: int
    n_test: int
    epochs: int
    siamese_epochs: int
    seeds: tuple[int, ...]
    batch: int = 1024
    siamese_batch: int = 256
    lr: float = 1e-3
    momentum: float = 0.9


SIZES = {
    "paper": Size(DatasetSpec(seed=0), 3000, 500, 500, epochs=100, siamese_epochs=10, seeds=(0, 1)),
    "quick": Size(
        DatasetSpec(Combination("random", n_configs=24), n_frames=20, seed=0),
        12,
        6,
        6,
        epochs=2,
        siamese_epochs=2,
        seeds=(0,),
        batch=64,
        siamese_batch=16,
    ),
}


@dataclass(frozen=True)
class Part:
    """One grid of a study, run once per seed into ``OUT/<name>/seed-<seed>``."""

    name: str
    grid: Grid
    siamese_size: bool = False
    """Train with :attr:`Size.siamese_epochs` (else :attr:`Size.epochs`)."""


def plan(name: str) -> list[Part]:
    """The parts of plan ``name`` (:data:`PLANS`, see the module doc)."""
    best = {"activations": ("tanh",), "scalers": ("robust",), "optimizers": ("sgd",)}
    every = {"activations": ACTIVATIONS, "scalers": SCALERS, "optimizers": OPTIMIZERS}
    if name == "full":
        return [
            Part("single", Grid(archs=("simple", *TABLE1_ARCHS, "funnel"), **every)),
            Part("siamese", Grid(archs=TABLE1_ARCHS, frames=(SIAMESE_FRAMES,), siamese=(True,), **every)),
        ]
    if name == "decisive":
        net1 = ("net1",)
        return [
            Part("activations", Grid(archs=net1, **{**best, "activations": ACTIVATIONS})),
            Part("scalers", Grid(archs=net1, **{**best, "scalers": SCALERS[1:]})),
            Part("optimizers", Grid(archs=net1, **{**best, "optimizers": OPTIMIZERS[1:]})),
            Part("siamese-single", Grid(archs=("net1", SIAMESE_BEST), **best), siamese_size=True),
            Part(
                "siamese",
                Grid(archs=("net1", SIAMESE_BEST), frames=(SIAMESE_FRAMES,), siamese=(True,), **best),
                siamese_size=True,
            ),
        ]
    if name == "quick":
        return [
            Part(
                "grid", Grid(archs=("simple",), activations=ACTIVATIONS[:2], scalers=SCALERS[:2], optimizers=OPTIMIZERS)
            )
        ]
    raise ValueError(f"plan must be one of {', '.join(PLANS)}, got {name!r}")


def base_config(size: Size, part: Part, seed: int) -> TrainConfig:
    """The settings of a part's trials besides the grid's (patience 0: every trial runs all its epochs)."""
    k_frames = max(part.grid.frames) > 1
    return TrainConfig(
        model=ModelSpec("simple"),
        lr=size.lr,
        momentum=size.momentum,
        patience=0,
        seed=int(seed),
        epochs=size.siamese_epochs if part.siamese_size else size.epochs,
        batch=size.siamese_batch if k_frames else size.batch,
        n_train=size.n_train,
        n_val=size.n_val,
        n_test=size.n_test,
    )


@dataclass
class StudyRow(SweepRow):
    """A sweep row (:class:`ineid.learn.sweep.SweepRow`) with its part, seed, epochs asked for and training size."""

    part: str = ""
    seed: int = 0
    epochs: int = 0
    n_train: int = 0

    @classmethod
    def of(cls, row: SweepRow, part: str, cfg: TrainConfig) -> StudyRow:
        return cls(**dataclasses.asdict(row), part=part, seed=cfg.seed, epochs=cfg.epochs, n_train=cfg.n_train or 0)


def trials(parts: list[Part], size: Size) -> int:
    """Trials of a study (each part's grid, once per seed)."""
    return sum(len(p.grid.configs(base_config(size, p, 0))) for p in parts) * len(size.seeds)


def sweep_folders(parts: list[Part], size: Size, out_dir: str | Path) -> list[Path]:
    """The sweep folders of a study, ``OUT/<part>/seed-<seed>``, in the order they run."""
    return [Path(out_dir) / p.name / f"seed-{s}" for p in parts for s in size.seeds]


def check_study_folder(
    ds, parts: list[Part], size: Size, out_dir: str | Path, *, resume: bool = False, overwrite: bool = False
) -> None:
    """Whether :func:`run_study` may write ``out_dir`` (called by it; the CLI calls it before its progress bar).

    Raises:
        TrainingError: a sweep folder holds runs and neither ``resume`` nor ``overwrite``, or
            ``resume`` of a sweep of other settings or another dataset.
    """
    for part in parts:
        for seed in size.seeds:
            folder = Path(out_dir) / part.name / f"seed-{seed}"
            check_sweep_folder(
                ds,
                part.grid,
                base_config(size, part, seed),
                folder,
                overwrite=overwrite,
                resume=resume and (folder / SWEEP_RECORD).is_file(),
            )


def run_study(
    ds,
    parts: list[Part],
    size: Size,
    out_dir: str | Path,
    *,
    model=None,
    progress=None,
    resume: bool = False,
    overwrite: bool = False,
    engine: str = "sequential",
    **engine_kw,
) -> list[StudyRow]:
    """Run every part once per seed (part by part, so the first parts' claims are decided first) and write
    ``OUT/networks.csv`` after each part; each sweep folder is an ordinary ``ineid sweep`` folder. A part's seeds
    run together (:func:`ineid.learn.sweep.sweep_many`): the trials that differ only in their seed, scaler or
    learning rate train as one population.

    Args:
        ds: the dataset (:attr:`Size.dataset` generated, or a user's).
        parts, size: what to run (:func:`plan`, :data:`SIZES`).
        out_dir: the study's folder.
        progress: ``progress(done, total, row)`` after each trial.
        resume: continue the sweeps already in ``out_dir`` (their finished trials kept); a sweep
            folder not started yet simply runs.
        overwrite: replace trials already there (else a folder holding runs is refused).
        engine, engine_kw: :func:`ineid.learn.sweep.sweep`'s engine and its Ray settings.

    Raises:
        TrainingError: as :func:`ineid.learn.sweep.sweep` (a folder holds runs without
            ``resume``/``overwrite``, or another sweep to resume).
    """
    out_dir = Path(out_dir)
    check_study_folder(ds, parts, size, out_dir, resume=resume, overwrite=overwrite)
    model = model or ds.model()
    total, done, rows = trials(parts, size), 0, []
    for part in parts:
        specs = []
        for seed in size.seeds:
            folder = out_dir / part.name / f"seed-{seed}"
            again = resume and (folder / SWEEP_RECORD).is_file()
            specs.append(SweepSpec(part.grid, base_config(size, part, seed), folder, again))
        offset = done

        def step(i, _n, row, offset=offset):
            if progress is not None:
                progress(offset + i, total, row)

        got = sweep_many(ds, specs, model=model, progress=step, overwrite=overwrite, engine=engine, **engine_kw)
        for spec, sweep_rows in zip(specs, got, strict=True):
            by_name = {r.name: r for r in sweep_rows}
            cfgs = spec.grid.configs(spec.base)
            rows += [StudyRow.of(by_name[run_name(c)], part.name, c) for c in cfgs]
            done += len(cfgs)
        write_rows(rows, out_dir / FILE)  # the rows so far: an interrupted study keeps them
    return rows


def write_rows(rows: list[StudyRow], path: str | Path) -> None:
    write_csv(Path(path), [f.name for f in dataclasses.fields(StudyRow)], [dataclasses.asdict(r) for r in rows])


def read_rows(path: str | Path) -> list[StudyRow]:
    """The rows of a ``networks.csv`` (as :func:`write_rows` wrote them)."""
    import csv

    types = {f.name: f.type for f in dataclasses.fields(StudyRow)}
    out = []
    with open(path, newline="") as fh:
        for rec in csv.DictReader(fh):
            kw = {}
            for k, v in rec.items():
                t = types[k]
                kw[k] = (
                    (v == "True")
                    if t in ("bool", bool)
                    else int(v)
                    if t in ("int", int)
                    else float(v)
                    if t in ("float", float)
                    else v
                )
            out.append(StudyRow(**kw))
    return out
