"""Training: splits, scalers, Optax optimizers, a jit-compiled step, validation every epoch,
early stopping, exact resumption from checkpoints, metrics per epoch.

The run folder's files (config, scalers, metrics, checkpoint, model) are
:mod:`ineid.learn.runs`, the compiled steps :mod:`ineid.learn.steps`; this module is the
loop that fills them.

Everything random is seeded: initialization by ``seed``, the split by ``(seed, 11)``, the
frame groups of epoch ``e`` by ``(seed, 12, e)``; so a run resumed from its checkpoint
ends bit for bit where the uninterrupted run would have.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.errors import DatasetError, TrainingError
from ineid.learn.config import OPTIMIZERS, SCHEDULES, TrainConfig  # noqa: F401  (public here too)
from ineid.learn.data import epoch_groups, fixed_groups, frame_features, split_configs
from ineid.learn.losses import PHYSICS_MODES, CompactRegressor, Physics
from ineid.learn.runs import MetricsLog, load_state, save_state, start_run, write_config, writing_run
from ineid.learn.scalers import Scaler
from ineid.learn.steps import (  # noqa: F401  (public here too: what a training script or benchmark uses)
    STEPS_PER_CALL,
    Prepared,
    build_functions,
    evaluate_groups,
    forward,
    gather_samples,
    init_params,
    run_epoch,
)
from ineid.progress import EpochProgress

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.robots import RobotModel


def make_optimizer(cfg: TrainConfig, steps_per_epoch: int):
    import optax

    if cfg.schedule == "cosine":
        lr = optax.cosine_decay_schedule(cfg.lr, decay_steps=max(1, cfg.epochs * steps_per_epoch))
    else:
        lr = cfg.lr
    if cfg.optimizer == "sgd":
        return optax.sgd(lr, momentum=cfg.momentum)
    if cfg.optimizer == "adam":
        return optax.adam(lr)
    return optax.adamw(lr, weight_decay=cfg.weight_decay)


CACHE_LIMIT_BYTES = 6 * 2**30
"""A cached physics term larger than this falls back to the inline regressor."""


def prepare(
    ds: Dataset,
    cfg: TrainConfig,
    rows: np.ndarray,
    model: RobotModel,
    scalers=None,
    fit_rows: np.ndarray | None = None,
    wrench_scale: np.ndarray | None = None,
    physics_mode: str = "cached",
) -> Prepared:
    """Scalers (fitted on ``fit_rows`` unless given) and device arrays of configurations ``rows``.

    Args:
        ds: the dataset (with the truth).
        cfg: the run's settings.
        rows: sorted dataset indices of the configurations to hold.
        model: the robot model.
        scalers: ``(x_scaler, y_scaler)`` of an existing run, or None to fit.
        fit_rows: configurations to fit the scalers and the wrench scale on (the training split).
        wrench_scale: the physics term's per-axis normalization of an existing run.
        physics_mode: ``"cached"`` or ``"inline"`` (see :class:`ineid.learn.losses.Physics`).

    The physics term is over the dataset's measurement channels (``ds.meta.channels``: their
    rows, their values stacked, one normalization per axis).
    """
    import jax.numpy as jnp

    ds.require_truth("training")
    k = cfg.model.frames
    if ds.n_frames < k:
        raise DatasetError(f"{k} frames per sample but the dataset has {ds.n_frames} frames per configuration")
    if physics_mode not in PHYSICS_MODES:
        raise ValueError(f"physics_mode must be one of {', '.join(PHYSICS_MODES)}, got {physics_mode!r}")
    rows = np.asarray(rows, dtype=np.int64)
    sub = ds.select(rows)
    channels = ds.meta.channels
    n_axes = channels.n_axes(model)
    values = sub.measured(channels)  # (C, F, A): the wrench itself for one base wrench
    feats = frame_features(sub)
    if scalers is None:
        fit_local = np.searchsorted(rows, fit_rows)
        x_scaler = Scaler.fit(cfg.scaler, feats[fit_local].reshape(-1, feats.shape[-1]))
        y_scaler = Scaler.fit(cfg.scaler, sub.theta_unknown[fit_local])
        ws = values[fit_local].reshape(-1, n_axes).std(axis=0)
        wrench_scale = np.where(ws > 0, ws, 1.0)
    else:
        x_scaler, y_scaler = scalers
    n_u = sub.theta_unknown.shape[1]
    if physics_mode == "cached":
        need = sub.n_configs * sub.n_frames * n_axes * (n_u + 1) * 8
        if need > CACHE_LIMIT_BYTES:
            physics_mode = "inline"
    compact, physics_arrays = None, {}
    if physics_mode == "cached":
        compact, physics_arrays = _cached_physics(model, cfg, sub, values, wrench_scale)
    physics = Physics(
        mode=physics_mode,
        regressor=channels.jax_rows_function(model),  # the base wrench: the generated regressor itself
        gravity=np.asarray(model.gravity),
        unknown_index=np.asarray(model.unknown_index),
        known_index=np.asarray(model.known_index),
        theta_known=np.asarray(sub.theta_known),
        wrench_scale=np.asarray(wrench_scale, dtype=np.float64),
        y_center=y_scaler.center,
        y_scale=y_scaler.scale,
        compact=compact,
    )
    x = x_scaler.transform(feats)
    arrays = {"x": jnp.asarray(x), "z": jnp.asarray(y_scaler.transform(sub.theta_unknown))}
    if physics_mode == "cached":
        arrays.update(physics_arrays)
    else:
        arrays.update(
            q=jnp.asarray(sub.q), qd=jnp.asarray(sub.qd), qdd=jnp.asarray(sub.qdd), wrench=jnp.asarray(values)
        )
    return Prepared(rows, x_scaler, y_scaler, arrays, physics, n_u, sub.n_frames)


def _cached_physics(model, cfg: TrainConfig, sub, values: np.ndarray, wrench_scale: np.ndarray):
    """The physics term's numbers of configurations ``sub``, computed once (the ``"cached"`` mode).

    Args:
        model: the robot model.
        cfg: the run's settings (does its network read the regressor?).
        sub: the configurations held (:meth:`ineid.data.Dataset.select`).
        values: (C, F, A) their channels' values (``sub.meta.channels``).
        wrench_scale: (A,) the per-axis normalization of the physics term.

    Returns:
        ``(compact, arrays)``: for a network that does not read the regressor, the
        :class:`ineid.learn.losses.CompactRegressor` and ``{"compact": its numbers, one row a frame}``;
        else None and ``{"psi": (C, F, A, n_u) the unknown links' rows, "yres": (C, F, A) the values less
        the known links' part}``.
    """
    import jax.numpy as jnp

    from ineid.identify.systems import stack

    channels = sub.meta.channels
    n_axes, n_u = channels.n_axes(model), sub.theta_unknown.shape[1]
    w, y = stack(model, sub.q, sub.qd, sub.qdd, values, sub.theta_known, channels)  # (C, AF, n_u), (C, AF)
    w = w.reshape(sub.n_configs, sub.n_frames, n_axes, n_u)
    y = y.reshape(sub.n_configs, sub.n_frames, n_axes)
    if not cfg.model.uses_regressor:  # a network that does not read Psi: the compact rows
        from ineid.identify.identifiability import base_parameters

        compact, rows_compact = CompactRegressor.from_frames(
            w, y, base_parameters(model, channels=channels), wrench_scale
        )
        del w, y
        return compact, {"compact": jnp.asarray(rows_compact)}
    return None, {"psi": jnp.asarray(w), "yres": jnp.asarray(y)}


def wls_context(ds, train_rows: np.ndarray, model, y_scaler: Scaler, wrench_scale: np.ndarray):
    """The constants of a ``wls`` network from the training configurations (:func:`ineid.learn.wls.fit_context`).

    The noise model is the per-axis RMS of the residual of the dataset's channels (the wrench) at
    the true parameters over every training frame (:func:`ineid.learn.wls.residual_sigma`), computed a chunk of
    configurations at a time.
    """
    from ineid.identify import base_parameters
    from ineid.learn.wls import SIGMA_FLOOR, fit_context, iter_systems

    sub = ds.select(np.asarray(train_rows))
    channels = ds.meta.channels
    n_axes = channels.n_axes(model)
    sq, n = np.zeros(n_axes), 0
    for sl, w, y in iter_systems(
        model, sub.q, sub.qd, sub.qdd, sub.measured(channels), sub.theta_known, channels=channels
    ):
        res = (y - np.einsum("cnp,cp->cn", w, sub.theta_unknown[sl])).reshape(-1, n_axes)
        sq += np.sum(res**2, axis=0)
        n += len(res)
    sigma = np.maximum(np.sqrt(sq / max(n, 1)), SIGMA_FLOOR * np.asarray(wrench_scale))
    return fit_context(
        sub.theta_unknown, sigma, base_parameters(model, channels=channels), y_scaler.center, y_scaler.scale
    )


@dataclass
class TrainResult:
    """What :func:`train` returns: epochs run, the best epoch and its validation MSE, early stop, wall-clock seconds."""

    run_dir: Path
    epochs_run: int
    best_epoch: int
    best_val_mse: float
    stopped_early: bool
    seconds: float


def train(
    ds: Dataset,
    cfg: TrainConfig,
    run_dir: str | Path,
    *,
    dataset_path: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: EpochProgress | None = None,
    model: RobotModel | None = None,
    physics_mode: str = "cached",
    finish: Callable[[Path], None] | None = None,
) -> TrainResult:
    """Train a network on ``ds`` into ``run_dir`` (see module doc).

    Args:
        ds: a synthetic :class:`ineid.data.Dataset` (with the truth).
        cfg: the settings.
        run_dir: the run folder; must be new or empty unless ``resume`` or ``overwrite``.
        dataset_path: recorded in ``config.json`` (for ``ineid evaluate``).
        resume: continue the run in ``run_dir`` from its checkpoint (same settings).
        overwrite: replace the run the folder holds, once the new one is finished (an
            interruption leaves the old run untouched; see :func:`ineid.learn.runs.writing_run`).
        progress: ``progress(epoch, epochs, metrics)`` after every epoch.
        model: the dataset's robot model (default: rebuilt from the dataset).
        physics_mode: ``"cached"`` or ``"inline"`` regressor in the physics loss.
        finish: ``finish(folder)`` once training is done, with the folder the run was trained
            in (the hidden one of a replacement): what it writes there (``ineid train``'s
            evaluation) is part of the run, swapped in with it.

    Raises:
        TrainingError: the folder holds another run, or a resume does not match it.
        OutputBusyError: another process is writing the run folder.
    """
    ds.require_truth("training")
    kwargs = {
        "dataset_path": dataset_path,
        "resume": resume,
        "overwrite": overwrite,
        "progress": progress,
        "model": model,
        "physics_mode": physics_mode,
    }
    with writing_run(run_dir, resume=resume, overwrite=overwrite) as work:
        result = _train_into(ds, cfg, work, **kwargs)
        if finish is not None:
            finish(work)
    result.run_dir = Path(run_dir)
    return result


def _train_into(
    ds: Dataset,
    cfg: TrainConfig,
    run_dir: Path,
    *,
    dataset_path: str | None,
    resume: bool,
    overwrite: bool,
    progress: EpochProgress | None,
    model: RobotModel | None,
    physics_mode: str,
) -> TrainResult:
    """:func:`train` in ``run_dir``: the run folder itself, or the hidden folder of a replacement."""
    import jax

    from ineid.cache import enable_compilation_cache

    enable_compilation_cache()
    resumed = start_run(run_dir, cfg, ds, resume=resume, overwrite=overwrite)
    model = model or ds.model()
    if resumed is None:
        split = split_configs(ds.n_configs, cfg.n_train, cfg.n_val, cfg.n_test, cfg.seed)
        scalers = wrench_scale = None
    else:
        split, scalers, wrench_scale = resumed.split, resumed.scalers, resumed.wrench_scale
    rows = np.union1d(split.train, split.val)
    prep = prepare(ds, cfg, rows, model, scalers, split.train, wrench_scale, physics_mode)
    k = cfg.model.frames
    n_samples = len(split.train) * (prep.n_frames // k)
    batch = min(cfg.batch, n_samples)
    steps_per_epoch = n_samples // batch
    context = _wls_targets(ds, cfg, split, model, prep, resumed)
    net = cfg.model.build(prep.n_out, context)
    params = init_params(net, cfg.model, prep, jax.random.key(cfg.seed))
    optimizer = make_optimizer(cfg, steps_per_epoch)
    opt_state = optimizer.init(params)
    state = {
        "params": params,
        "opt_state": opt_state,
        "best_params": params,
        "epoch": 0,
        "best_val": float("inf"),
        "best_epoch": 0,
        "bad_epochs": 0,
    }
    if resumed is not None:
        state = load_state(run_dir, state, cfg.epochs)
    else:
        meta = _run_record(ds, cfg, split, prep, dataset_path, steps_per_epoch, batch)
        if context is not None:
            meta["wls"] = context.to_dict()
        write_config(run_dir, meta, prep.x_scaler, prep.y_scaler)
    metrics = MetricsLog(run_dir, keep_through_epoch=int(state["epoch"]))

    train_steps, eval_batch = build_functions(net, cfg, prep, optimizer)
    val_pos, val_frames = fixed_groups(len(split.val), prep.n_frames, k)
    train_local, val_rows = prep.local(split.train), prep.local(split.val)[val_pos]
    loop = _EpochLoop(cfg, prep, train_steps, eval_batch, train_local, val_rows, val_frames, batch, steps_per_epoch)
    t_start = time.perf_counter()
    epoch, stopped = _train_epochs(loop, state, run_dir, metrics, progress)
    save_state(run_dir, state, final=True)
    return TrainResult(
        run_dir, epoch, int(state["best_epoch"]), float(state["best_val"]), stopped, time.perf_counter() - t_start
    )


def _wls_targets(ds: Dataset, cfg: TrainConfig, split, model, prep: Prepared, resumed):
    """For a network that reads the regressor (``wls``): its constants (those of the resumed run, else fitted on
    the training configurations), with the targets ``prep.arrays["z"]`` replaced by their identifiable part;
    None for any other network."""
    import jax.numpy as jnp

    if not cfg.model.uses_regressor:
        return None
    from ineid.learn.wls import WlsContext

    context = (
        WlsContext.from_dict(resumed.config["wls"])
        if resumed is not None
        else wls_context(ds, split.train, model, prep.y_scaler, prep.physics.wrench_scale)
    )
    # Train on the identifiable part of the targets: the rest (along the null directions) no
    # wrench can tell, and fitting it would only teach the network the training configurations.
    truth = context.identifiable_part(ds.theta_unknown[prep.rows])
    prep.arrays["z"] = jnp.asarray(prep.y_scaler.transform(truth))
    return context


def _run_record(
    ds: Dataset, cfg: TrainConfig, split, prep: Prepared, dataset_path: str | None, steps_per_epoch: int, batch: int
) -> dict:
    """The run's ``config.json``: its settings, split, physics mode, dataset, outputs and batches."""
    return {
        "train": cfg.to_dict(),
        "split": split.to_dict(),
        "physics_mode": prep.physics.mode,
        "dataset": {
            "path": dataset_path,
            "robot": ds.meta.robot,
            "n_configs": ds.n_configs,
            "n_frames": ds.n_frames,
            "seed": ds.meta.seed,
            "noise": ds.meta.noise,
            "fingerprint": ds.fingerprint(),
            "channels": ds.meta.channels.to_list(),
        },
        "n_out": prep.n_out,
        "param_names": ds.meta.unknown_param_names,
        "unknown_links": list(ds.meta.unknown_links),
        "wrench_scale": prep.physics.wrench_scale.tolist(),
        "steps_per_epoch": steps_per_epoch,
        "batch": batch,
    }


@dataclass(frozen=True)
class _EpochLoop:
    """What every epoch of a run reads: its settings, the prepared arrays, the compiled steps, the training
    configurations' local rows, the fixed validation groups (local rows and frames), the batch size and the
    steps of an epoch."""

    cfg: TrainConfig
    prep: Prepared
    train_steps: Callable
    eval_batch: Callable
    train_local: np.ndarray
    val_rows: np.ndarray
    val_frames: np.ndarray
    batch: int
    steps_per_epoch: int

    def run(self, state: dict, epoch: int) -> dict:
        """Epoch ``epoch`` from ``state`` (updated: the parameters, the best ones, the epochs without improvement).

        Returns:
            The epoch's metrics record.

        Raises:
            TrainingError: the training loss is not finite.
        """
        cfg, prep, steps = self.cfg, self.prep, self.steps_per_epoch
        t0 = time.perf_counter()
        pos, frames = epoch_groups(len(self.train_local), prep.n_frames, cfg.model.frames, cfg.seed, epoch)
        rows = self.train_local[pos]
        params, opt_state, sums = run_epoch(
            self.train_steps, state["params"], state["opt_state"], prep.arrays, rows, frames, self.batch, steps
        )
        train_loss = sums / max(steps, 1)
        if not np.all(np.isfinite(train_loss)):
            raise TrainingError(f"the training loss diverged (non-finite) at epoch {epoch}; lower --lr")
        val_mse, val_phys, _ = evaluate_groups(
            self.eval_batch, params, prep.arrays, self.val_rows, self.val_frames, self.batch
        )
        improved = val_mse < state["best_val"]
        state.update(params=params, opt_state=opt_state, epoch=epoch)
        if improved:
            state.update(best_params=params, best_val=val_mse, best_epoch=epoch, bad_epochs=0)
        else:
            state["bad_epochs"] = int(state["bad_epochs"]) + 1
        return {
            "epoch": epoch,
            "train_loss": float(train_loss[0]),
            "train_mse": float(train_loss[1]),
            "train_phys": float(train_loss[2]),
            "val_mse": float(val_mse),
            "val_phys": float(val_phys),
            "best_epoch": int(state["best_epoch"]),
            "seconds": time.perf_counter() - t0,
        }


def _train_epochs(
    loop: _EpochLoop, state: dict, run_dir: Path, metrics: MetricsLog, progress: EpochProgress | None
) -> tuple[int, bool]:
    """The epochs after ``state["epoch"]`` up to ``cfg.epochs``, each recorded and checkpointed, until the
    validation error has not improved for ``cfg.patience`` epochs.

    Returns:
        ``(epoch, stopped)``: the last epoch begun and whether the run stopped early.
    """
    cfg = loop.cfg
    done = int(state["epoch"])
    stopped = False
    epoch = done
    finished = bool(cfg.patience) and int(state["bad_epochs"]) >= cfg.patience  # stopped early before
    for epoch in range(done + 1, cfg.epochs + 1):
        if finished:
            stopped = True
            break
        record = loop.run(state, epoch)
        metrics.append(record)
        save_state(run_dir, state)
        if progress is not None:
            progress(epoch, cfg.epochs, record)
        if cfg.patience and state["bad_epochs"] >= cfg.patience:
            stopped = True
            break
    return epoch, stopped
