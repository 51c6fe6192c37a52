"""Train a grid of networks one after another and rank them by test error (``ineid sweep``)."""

from __future__ import annotations

import dataclasses
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid._atomic import atomic_write, save_figure, write_csv
from ineid.learn.evaluate import evaluate
from ineid.learn.runs import EVALUATION, load_run
from ineid.learn.train import TrainConfig, train

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
            sizes = {"depth": base.model.depth, "width": base.model.width} if arch == "mlp" else {"depth": None, "width": None}
            model = dataclasses.replace(base.model, arch=arch, activation=act, frames=k, siamese=siam, **sizes)
            out.append(dataclasses.replace(base, model=model, scaler=scaler, optimizer=opt, loss=loss))
        return out


def run_name(cfg: TrainConfig) -> str:
    return f"{cfg.model.name}-{cfg.scaler}-{cfg.optimizer}-{cfg.loss}"


@dataclass
class SweepRow:
    """One trained run of a sweep: its settings, training time, and test errors beside the floor and least squares.

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


def sweep(ds: Dataset, grid: Grid, base: TrainConfig, out_dir: str | Path, dataset_path: str | None = None,
          model: RobotModel | None = None,
          progress=None, overwrite: bool = False, physics_mode: str = "cached") -> list[SweepRow]:
    """Train and evaluate every configuration of ``grid`` into ``out_dir/<name>``; rows ranked
    by the test median relative error of the standard parameters."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model = model or ds.model()
    rows = []
    cfgs = grid.configs(base)
    if not cfgs:
        raise ValueError("the grid is empty (a Siamese network needs more than one frame: add --frames-list values > 1)")
    for i, cfg in enumerate(cfgs):
        name = run_name(cfg)
        result = train(ds, cfg, out_dir / name, dataset_path=dataset_path, overwrite=overwrite, model=model,
                       physics_mode=physics_mode)
        ev = evaluate(load_run(out_dir / name), ds, model=model)
        atomic_write(out_dir / name / EVALUATION, json.dumps(ev.to_dict(), indent=1))
        rows.append(SweepRow(
            name=name, arch=cfg.model.arch, activation=cfg.model.activation, scaler=cfg.scaler,
            optimizer=cfg.optimizer, loss=cfg.loss, frames=cfg.model.frames, siamese=cfg.model.siamese,
            epochs_run=result.epochs_run, seconds=result.seconds,
            test_standard_median=ev.network["overall_median"], test_base_median=ev.network_base["overall_median"],
            floor_standard_median=ev.floor["overall_median"],
            linear_standard_median=ev.linear["overall_median"] if ev.linear else float("nan"),
            linear_base_median=ev.linear_base["overall_median"] if ev.linear_base else float("nan"),
            physical_share=ev.physical_share,
        ))  # fmt: skip
        if progress is not None:
            progress(i + 1, len(cfgs), rows[-1])
    rows.sort(key=lambda r: (np.nan_to_num(r.test_standard_median, nan=np.inf), r.name))
    write_csv(out_dir / "sweep.csv", [f.name for f in dataclasses.fields(SweepRow)], [dataclasses.asdict(r) for r in rows])
    plot(rows, out_dir / "sweep.png")
    return rows


def plot(rows: list[SweepRow], path: Path) -> Path:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(rows) + 2), 4.5), constrained_layout=True)
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r.test_standard_median for r in rows], 0.4, label="standard parameters")
    ax.bar(x + 0.2, [r.test_base_median for r in rows], 0.4, label="base parameters")
    if rows and np.isfinite(rows[0].floor_standard_median):
        ax.axhline(rows[0].floor_standard_median, color="k", linestyle="--", label="null-space floor (standard)")
    if rows and len({r.frames for r in rows}) == 1:  # the same frames for every run: one LS line
        ax.axhline(rows[0].linear_standard_median, color="C3", linestyle=":", label="linear least squares (standard)")
    ax.set_xticks(x, [r.name for r in rows], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("test median relative error")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
