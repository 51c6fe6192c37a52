"""The run folder of a training run: what it holds, starting, resuming and loading one.

A run lives in a folder::

    RUN_DIR/config.json         everything needed to rebuild the run (settings, split, sizes, dataset)
    RUN_DIR/scalers.json        the feature and target scalers (fitted on the training split)
    RUN_DIR/metrics.jsonl       one JSON line per epoch
    RUN_DIR/checkpoint.msgpack  params, optimizer state, best params, counters (each epoch)
    RUN_DIR/model.msgpack       the best parameters (lowest validation MSE)
    RUN_DIR/evaluation.json     written by ``ineid evaluate``

Every file is written atomically (:mod:`ineid._atomic`), so an interrupted run leaves the
previous epoch's files whole, and ``--resume`` continues from them; a run that replaces
another is built beside it and swapped in when finished (:func:`writing_run`).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid._atomic import atomic_write
from ineid.errors import TrainingError
from ineid.learn.data import Split
from ineid.learn.run_checks import (
    check_state,
    read_config,
    read_metrics,
    read_msgpack,
    read_scalers,
)
from ineid.learn.scalers import Scaler

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.learn.config import TrainConfig

CONFIG, SCALERS, METRICS, CHECKPOINT, MODEL, EVALUATION = (
    "config.json",
    "scalers.json",
    "metrics.jsonl",
    "checkpoint.msgpack",
    "model.msgpack",
    "evaluation.json",
)
RUN_FILES = (CONFIG, SCALERS, METRICS, CHECKPOINT, MODEL, EVALUATION)


@dataclass
class Resumed:
    """What a run folder holds for ``--resume``: its config, split and fitted scalers."""

    config: dict
    split: Split
    scalers: tuple[Scaler, Scaler]
    wrench_scale: np.ndarray


def start_run(run_dir: Path, cfg: TrainConfig, ds: Dataset, *, resume: bool, overwrite: bool) -> Resumed | None:
    """Check ``run_dir`` for a new run (empty, or ``overwrite``) or a resumed one (same settings and data).

    A new run's folder is created and emptied of an earlier run's files; a resumed run's
    saved state is returned.

    Raises:
        TrainingError: the folder holds another run, or a resume does not match it.
    """
    if not resume:
        if run_dir.exists() and any(run_dir.iterdir()) and not overwrite:
            raise TrainingError(
                f"{run_dir} is not empty; pass --overwrite to replace the run, or --resume to continue it"
            )
        run_dir.mkdir(parents=True, exist_ok=True)
        for name in RUN_FILES:
            (run_dir / name).unlink(missing_ok=True)
        return None
    if not (run_dir / CHECKPOINT).is_file() or not (run_dir / CONFIG).is_file():
        raise TrainingError(f"{run_dir} holds no checkpoint to resume; start the run without --resume")
    saved, _, split = read_config(run_dir)
    if saved["train"] != cfg.to_dict():
        raise TrainingError(
            f"{run_dir} holds a run with other settings; resume it with the same settings, or use a new folder"
        )
    if saved.get("dataset", {}).get("fingerprint") != ds.fingerprint():
        raise TrainingError(
            f"{run_dir} was trained on another dataset (robot, sizes, seed, sampling or noise differ); "
            "resume it with the same dataset"
        )
    if not (run_dir / SCALERS).is_file():
        raise TrainingError(f"{run_dir} holds no {SCALERS} to resume with; start the run again with --overwrite")
    return Resumed(saved, split, read_scalers(run_dir), np.asarray(saved["wrench_scale"]))


def write_config(run_dir: Path, meta: dict, x_scaler: Scaler, y_scaler: Scaler) -> None:
    """Write ``config.json`` and ``scalers.json`` of a new run."""
    atomic_write(run_dir / CONFIG, json.dumps(meta, indent=1))
    atomic_write(run_dir / SCALERS, json.dumps({"x": x_scaler.to_dict(), "y": y_scaler.to_dict()}))


class MetricsLog:
    """``metrics.jsonl``: one JSON record per epoch, rewritten atomically after each epoch.

    A resumed run keeps the records up to its checkpoint's epoch and drops later ones (an
    interrupted epoch after the last checkpoint).
    """

    def __init__(self, run_dir: Path, keep_through_epoch: int = 0) -> None:
        self.path = run_dir / METRICS
        self.lines: list[str] = []
        if keep_through_epoch and self.path.is_file():
            self.lines = read_metrics(self.path, keep_through_epoch)
        self._flush()

    def append(self, record: dict) -> None:
        self.lines.append(json.dumps(record))
        self._flush()

    def _flush(self) -> None:
        atomic_write(self.path, "".join(line + "\n" for line in self.lines))


def save_state(run_dir: Path, state: dict, final: bool = False) -> None:
    """Write the checkpoint (``state``), or with ``final`` the best parameters as ``model.msgpack``."""
    from flax import serialization

    if final:
        atomic_write(run_dir / MODEL, serialization.to_bytes(state["best_params"]))
    else:
        atomic_write(run_dir / CHECKPOINT, serialization.to_bytes(state))


def load_state(run_dir: Path, template: dict, epochs: int | None = None) -> dict:
    """The checkpoint of ``run_dir``, restored into the structure of ``template``.

    Raises:
        TrainingError: the checkpoint is truncated, corrupt, of another network, or (with
            ``epochs``) its counters are out of range.
    """
    state = read_msgpack(run_dir / CHECKPOINT, template)
    return state if epochs is None else check_state(run_dir / CHECKPOINT, state, epochs)


@dataclass
class Run:
    """A finished run loaded from its folder: settings, scalers, best parameters, split."""

    run_dir: Path
    config: TrainConfig
    meta: dict
    x_scaler: Scaler
    y_scaler: Scaler
    params: object
    split: Split

    @property
    def net(self):
        """The Flax module: ``apply(params, x)`` with x (batch, frames, features), or for a
        ``wls`` run ``apply(params, x, psi_u, y)`` (see :class:`ineid.learn.wls.WLS`)."""
        return build_net(self.config, self.meta)


def build_net(cfg: TrainConfig, meta: dict):
    """The Flax module of a run from its settings and ``config.json`` (a wls run's constants)."""
    context = None
    if cfg.model.uses_regressor:
        from ineid.learn.wls import WlsContext

        if "wls" not in meta:
            raise TrainingError("the run's config.json lacks the wls constants; the run folder is damaged")
        context = WlsContext.from_dict(meta["wls"])
    return cfg.model.build(meta["n_out"], context)


def load_run(run_dir: str | Path) -> Run:
    """Read ``config.json``, ``scalers.json`` and ``model.msgpack`` of a run folder.

    Raises:
        TrainingError: a file is missing (an unfinished run says how to finish it) or does
            not match the run's network.
    """
    import jax

    run_dir = Path(run_dir)
    files = [run_dir / n for n in (CONFIG, SCALERS, MODEL)]
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        hint = (
            " (training was interrupted: finish it with `ineid train ... --resume`)"
            if (run_dir / CHECKPOINT).is_file()
            else ""
        )
        raise TrainingError(f"{run_dir} is not a finished training run: {', '.join(missing)} missing{hint}")
    meta, cfg, split = read_config(run_dir)
    x_scaler, y_scaler = read_scalers(run_dir)
    net = build_net(cfg, meta)
    x = np.zeros((1, cfg.model.frames, len(x_scaler.center)))
    if cfg.model.uses_regressor:
        n_u = meta["n_out"]
        n_axes = len(meta["wrench_scale"])  # the measured axes of a frame (the wrench: six)
        template = net.init(
            jax.random.key(0), x, np.zeros((1, cfg.model.frames, n_axes, n_u)), np.zeros((1, cfg.model.frames, n_axes))
        )
    else:
        template = net.init(jax.random.key(0), x)
    params = read_msgpack(files[2], template)
    return Run(run_dir, cfg, meta, x_scaler, y_scaler, params, split)


# -- writing a run folder safely ------------------------------------------------------------------


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` is a folder with anything in it (a new run needs ``overwrite`` there)."""
    return run_dir.is_dir() and any(run_dir.iterdir())


@contextmanager
def writing_run(run_dir: str | Path, *, resume: bool, overwrite: bool) -> Iterator[Path]:
    """Yield the folder to train the run of ``run_dir`` in; what an interruption leaves is decided here.

    The run folder's lock (:func:`ineid._atomic.output_lock`) is held throughout, and
    temporaries of its files that killed runs left are removed first.

    - ``overwrite`` of a folder holding a run: the new run is trained in a hidden folder
      beside it (:func:`ineid._atomic.staging_folder`) and swapped in when the block ends
      normally (:func:`ineid._atomic.replace_folder`, the last step; other files of the old
      folder are carried over). An exception, Ctrl-C or SIGTERM before the swap leaves the
      old run untouched; one during the swap is raised once the new run is in place.
    - A new run (a new or empty folder) is written in place: Ctrl-C or SIGTERM after its
      first checkpoint leaves a run to continue with ``resume``; before it, nothing. An
      error (a full disk, a diverged loss) leaves nothing: the files of the run are
      removed, and the folder if the run made it.
    - ``resume``: in place, each file replaced atomically.

    Raises:
        OutputBusyError: another process is writing ``run_dir``.
    """
    import shutil

    from ineid._atomic import Terminated, output_lock, remove_stale_temporaries, replace_folder, staging_folder

    run_dir = Path(run_dir)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    with output_lock(run_dir):
        if run_dir.is_dir():
            for name in RUN_FILES:
                remove_stale_temporaries(run_dir / name)
        held, created = holds_run(run_dir), not run_dir.exists()
        staged = overwrite and not resume and held
        work = staging_folder(run_dir) if staged else run_dir
        try:
            yield work
            if staged:
                replace_folder(work, run_dir, keep=RUN_FILES)
        except BaseException as e:
            if staged:
                shutil.rmtree(work, ignore_errors=True)
            elif not resume and not held:
                _discard_new(run_dir, created, resumable=isinstance(e, (KeyboardInterrupt, Terminated)))
            raise


def _discard_new(run_dir: Path, created: bool, resumable: bool) -> None:
    """Remove what a new run that stopped wrote: everything after an error, and after an interruption
    unless it reached its first checkpoint (``resumable``: that is kept to continue with ``resume``)."""
    if resumable and (run_dir / CHECKPOINT).is_file():
        return
    for name in RUN_FILES:
        (run_dir / name).unlink(missing_ok=True)
    if created:
        try:
            run_dir.rmdir()
        except OSError:  # something else was put there meanwhile
            pass
