"""Training: splits, scalers, Optax optimizers, one compiled program an epoch, validation every epoch,
early stopping, exact resumption from checkpoints, metrics per epoch; one run, or many at once.

:func:`train` trains one run; :func:`train_population` trains several, each into its own run folder
exactly as :func:`train` would (the same files, the same numbers to round-off): those that share a
network's shapes and sizes (:func:`program_key`) train as one population in one compiled program
(:mod:`ineid.learn.program`), on data held once (:mod:`ineid.learn.shared`); the others are split off
into populations of their own. The run folder's files are :mod:`ineid.learn.runs`.

Everything random is seeded: initialization by ``seed``, the split by ``(seed, 11)``, the
frame groups of epoch ``e`` by ``(seed, 12, e)``; so a run resumed from its checkpoint
ends bit for bit where the uninterrupted run would have.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.errors import DatasetError, IneidError, TrainingError  # noqa: F401  (TrainingError: public here too)
from ineid.learn.config import DTYPES, OPTIMIZERS, SCHEDULES, TrainConfig  # noqa: F401  (public here too)
from ineid.learn.data import split_configs
from ineid.learn.population import Population, TrialRun, group_runs
from ineid.learn.program import initial_state, make_optimizer_for
from ineid.learn.runs import MetricsLog, load_state, save_state, start_run, write_config, writing_run
from ineid.learn.shared import CACHE_LIMIT_BYTES, SharedData, build_shared, fit_trial, gather, prepare  # noqa: F401
from ineid.learn.steps import Prepared, gather_samples  # noqa: F401  (public here too: what tests and benchmarks use)
from ineid.progress import EpochProgress

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.robots import RobotModel

log = logging.getLogger(__name__)


def wls_context(ds, train_rows: np.ndarray, model, y_scaler, wrench_scale: np.ndarray):
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
    """What :func:`train` returns: epochs run, the best epoch and its validation MSE, early stop, wall-clock seconds
    (of a run trained in a population: its share of the population's)."""

    run_dir: Path
    epochs_run: int
    best_epoch: int
    best_val_mse: float
    stopped_early: bool
    seconds: float


@dataclass
class Trial:
    """One run for :func:`train_population`: its settings and folder, and what :func:`train` takes besides.

    Attributes:
        cfg: the settings.
        run_dir: the run folder (new or empty unless ``resume`` or ``overwrite``).
        resume, overwrite: as :func:`train`'s.
        dataset_path: recorded in ``config.json``.
        progress: ``progress(epoch, epochs, metrics)`` after every epoch of this run.
        finish: ``finish(folder)`` once the population is trained, with the folder this run was trained in.
    """

    cfg: TrainConfig
    run_dir: Path
    resume: bool = False
    overwrite: bool = False
    dataset_path: str | None = None
    progress: EpochProgress | None = None
    finish: Callable[[Path], None] | None = None


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
    trial = Trial(cfg, Path(run_dir), resume, overwrite, dataset_path, progress, finish)
    (outcome,) = train_population(ds, [trial], model=model, physics_mode=physics_mode)
    if isinstance(outcome, BaseException):
        raise outcome
    return outcome


def train_population(
    ds: Dataset,
    trials: list[Trial],
    *,
    model: RobotModel | None = None,
    physics_mode: str = "cached",
    shared: dict | None = None,
) -> list[TrainResult | IneidError]:
    """Train every trial into its run folder, as :func:`train` would, those that share a program together.

    Args:
        ds: the dataset (with the truth).
        trials: the runs.
        model: the dataset's robot model (default: rebuilt from the dataset).
        physics_mode: ``"cached"`` or ``"inline"`` regressor in the physics loss.
        shared: data already held (:func:`shared_data`), reused where they hold a trial's configurations;
            what is built here is added.

    Returns:
        Per trial, its :class:`TrainResult`, or the :class:`ineid.IneidError` that stopped it (a folder
        that holds another run, a diverging loss, ...): that trial's folder is left as :func:`train` leaves
        it on that error, and the others go on.

    Raises:
        Any other error, or an interruption: every trial's folder is left as :func:`train` leaves it then.
    """
    from ineid.cache import enable_compilation_cache

    ds.require_truth("training")
    enable_compilation_cache()
    model = model or ds.model()
    shared = {} if shared is None else shared
    runs: list[TrialRun] = []
    try:
        for trial in trials:
            runs.append(_open(ds, trial))
        started = [r for r in runs if r.error is None]
        held = shared_data(ds, model, [(r.trial.cfg, r.split) for r in started], physics_mode, shared)
        for r in started:
            _start(ds, r, held[(r.trial.cfg.dtype, r.trial.cfg.model.uses_regressor)], model)
        _check_float32(ds, model, [r for r in started if r.error is None])
        for group in group_runs([r for r in runs if r.error is None]):
            Population(group, checkpoint=_checkpoint).train()
        return [_finish(r) for r in runs]
    except BaseException as e:
        for r in runs:
            r.close(e)
        raise


def shared_data(
    ds: Dataset, model, cfg_splits: list, physics_mode: str = "cached", held: dict | None = None
) -> dict[tuple[str, bool], SharedData]:
    """The data for trials ``(cfg, split)``: one :class:`SharedData` per dtype and regressor form, holding
    every configuration the trials train or validate on (those of ``held`` kept where they do)."""
    held = {} if held is None else held
    wanted: dict[tuple[str, bool], np.ndarray] = {}
    for cfg, split in cfg_splits:
        key = (cfg.dtype, cfg.model.uses_regressor)
        wanted[key] = np.union1d(wanted.get(key, np.zeros(0, dtype=np.int64)), np.union1d(split.train, split.val))
    for key, rows in wanted.items():
        if key not in held or not held[key].holds(rows) or held[key].physics.mode not in (physics_mode, "inline"):
            held[key] = build_shared(ds, model, rows, physics_mode=physics_mode, full_regressor=key[1], dtype=key[0])
    return held


def _check_float32(ds: Dataset, model, runs: list[TrialRun]) -> None:
    """One line when a float32 physics loss cannot resolve the data's wrench residual (clean data: round-off),
    measured on the first such run's training configurations (:func:`ineid.learn.shared.float32_resolution`)."""
    from ineid.learn.shared import float32_resolution

    for r in runs:
        if r.trial.cfg.dtype == "float32" and r.trial.cfg.loss == "physics":
            residual, rounding = float32_resolution(ds, model, r.split.train, r.data.wrench_scale)
            if residual < 10 * rounding:
                log.warning(
                    f"float32 cannot resolve this dataset's wrench residual: {residual:.2g} at the true parameters "
                    f"(RMS, normalized), float32 rounds it by {rounding:.2g}; the physics term stops improving "
                    "there (--dtype float64 fits it further)"
                )
            return


def default_split(ds: Dataset, cfg: TrainConfig):
    """The split of a new run of ``cfg`` on ``ds`` (seeded; a resumed run reads its own)."""
    return split_configs(ds.n_configs, cfg.n_train, cfg.n_val, cfg.n_test, cfg.seed)


def _open(ds: Dataset, trial: Trial) -> TrialRun:
    """A trial's folder entered (:func:`ineid.learn.runs.writing_run`) and checked; its split. An
    :class:`IneidError` becomes the trial's (its folder closed on it)."""
    run = TrialRun(trial)
    try:
        run.enter(writing_run(trial.run_dir, resume=trial.resume, overwrite=trial.overwrite))
        cfg = trial.cfg
        run.resumed = start_run(run.work, cfg, ds, resume=trial.resume, overwrite=trial.overwrite)
        k = cfg.model.frames
        if ds.n_frames < k:
            raise DatasetError(f"{k} frames per sample but the dataset has {ds.n_frames} frames per configuration")
        run.split = default_split(ds, cfg) if run.resumed is None else run.resumed.split
    except IneidError as e:
        run.fail(e)
    return run


def _start(ds: Dataset, run: TrialRun, shared: SharedData, model) -> None:
    """A trial's constants, network, initial (or resumed) state, ``config.json`` and metrics log."""
    import jax

    cfg, resumed = run.trial.cfg, run.resumed
    try:
        saved = None if resumed is None else (*resumed.scalers, resumed.wrench_scale)
        data = fit_trial(shared, cfg, run.split, saved)
        k = cfg.model.frames
        n_samples = len(run.split.train) * (shared.n_frames // k)
        batch = min(cfg.batch, n_samples)
        steps = n_samples // batch
        if cfg.model.uses_regressor:
            _wls_targets(ds, cfg, run, shared, data, model)
        net = cfg.model.build(shared.n_out, data.context, cfg.dtype)
        consts = data.constants(shared)
        x, _, inputs = gather(
            shared.arrays,
            consts,
            shared.physics.mode,
            np.zeros(1, dtype=np.int64),
            np.arange(k)[None],
            len(data.wrench_scale),
        )
        key = jax.random.key(cfg.seed)
        if cfg.model.uses_regressor:
            params = net.init(key, x, *shared.physics.system(inputs))
        else:  # drawn in float64 and rounded: a float32 run starts where the float64 run of its seed starts
            params = cfg.model.build(shared.n_out).init(key, x.astype(np.float64))
            params = jax.tree_util.tree_map(lambda p: p.astype(cfg.dtype), params)
        state = initial_state(params, make_optimizer_for(cfg, steps).init(params))
        if resumed is not None:
            state = load_state(run.work, state, cfg.epochs)
        else:
            meta = _run_record(ds, cfg, run.split, shared, data, run.trial.dataset_path, steps, batch)
            if data.context is not None:
                meta["wls"] = data.context.to_dict()
            write_config(run.work, meta, data.x_scaler, data.y_scaler)
        run.metrics = MetricsLog(run.work, keep_through_epoch=int(state["epoch"]))
        run.setup(shared, data, consts, net, state, batch, steps)
    except IneidError as e:
        run.fail(e)


def _wls_targets(ds: Dataset, cfg: TrainConfig, run: TrialRun, shared: SharedData, data, model) -> None:
    """A ``wls`` network's constants (those of the resumed run, else fitted on the training configurations), with
    its targets replaced by their identifiable part."""
    from ineid.learn.wls import WlsContext

    context = (
        WlsContext.from_dict(run.resumed.config["wls"])
        if run.resumed is not None
        else wls_context(ds, run.split.train, model, data.y_scaler, data.wrench_scale)
    )
    # Train on the identifiable part of the targets: the rest (along the null directions) no
    # wrench can tell, and fitting it would only teach the network the training configurations.
    data.z = data.y_scaler.transform(context.identifiable_part(shared.theta_unknown))
    data.context = context


def _run_record(
    ds: Dataset, cfg: TrainConfig, split, shared: SharedData, data, dataset_path: str | None, steps: int, batch: int
) -> dict:
    """The run's ``config.json``: its settings, split, physics mode, dataset, outputs and batches."""
    return {
        "train": cfg.to_dict(),
        "split": split.to_dict(),
        "physics_mode": shared.physics.mode,
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
        "n_out": shared.n_out,
        "param_names": ds.meta.unknown_param_names,
        "unknown_links": list(ds.meta.unknown_links),
        "wrench_scale": np.asarray(data.wrench_scale).tolist(),
        "steps_per_epoch": steps,
        "batch": batch,
    }


def _checkpoint(run: TrialRun, state: dict, record: dict | None, final: bool) -> None:
    """After an epoch of ``run``: its metrics record, its checkpoint (``state``, None: not due), its progress; with
    ``final`` also its model (the best parameters). The checkpoint is written by this module's ``save_state``."""
    if record is not None:
        run.metrics.append(record)
    if state is not None:
        save_state(run.work, state)
        if final:
            save_state(run.work, state, final=True)
    if record is not None and run.trial.progress is not None:
        run.trial.progress(record["epoch"], run.trial.cfg.epochs, record)


def _finish(run: TrialRun) -> TrainResult | IneidError:
    """A trained trial's ``finish`` and its folder closed (a replacement swapped in); its result or error."""
    if run.error is not None:
        return run.error
    try:
        if run.trial.finish is not None:
            run.trial.finish(run.work)
    except IneidError as e:
        run.fail(e)
        return e
    run.close(None)
    state = run.state
    return TrainResult(
        run.trial.run_dir,
        int(state["epoch"]),
        int(state["best_epoch"]),
        float(state["best_val"]),
        run.stopped,
        run.seconds,
    )
