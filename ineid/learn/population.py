"""Trials trained together: the host's side of a population (:mod:`ineid.learn.program` is the device's).

A :class:`Population` drives one compiled program over its trials' epochs: it draws each trial's
frame groups for the next epoch in a thread while the device runs the current one, dispatches
the next epoch before it reads the last one's numbers (a few per trial), and then writes each
trial's metrics record, its checkpoint and its progress, as :func:`ineid.learn.train.train` does
after every epoch. On a CPU every epoch is checkpointed; on an accelerator, where an epoch of a
small network takes milliseconds, checkpoints are at most every :data:`CHECKPOINT_SECONDS` (and at a
trial's end), so the host's writing does not hold the device up.

Trials that cannot share a program (:func:`program_key`: other shapes, optimizer, loss, batches)
are split into populations of their own (:func:`group_runs`), and a population the device's memory
cannot hold is halved until it fits, with one line saying so.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ineid.errors import IneidError, TrainingError
from ineid.learn.data import epoch_groups, fixed_groups
from ineid.learn.program import (
    ProgramSpec,
    build_epoch,
    checkpoint_state,
    device_state,
    stack,
    unstack,
)

log = logging.getLogger(__name__)

CHECKPOINT_SECONDS = 5.0
"""On an accelerator, the least time between two checkpoints of a population's trials."""
MAX_POPULATION = 64
"""The most trials in one program (a larger group is trained as several populations)."""
CPU_STEP_FLOPS = 1.2e7
"""On a CPU, the most a step of one trial may cost (forward multiply-adds x 2, about ``2 x parameters x samples``)
for its trials to train as a population. XLA's CPU runs the trials' stacked (batched) matrix products slower
than the same products one at a time (about 1.5x at Table 1's wider networks, measured by
``benchmarks/learn.py``), so a population pays only where a step is small and its fixed costs, shared, dominate;
the trials of a larger network train one a program there (on an accelerator they always share one)."""


class TrialRun:
    """A trial while it is trained: its folder (entered), split, constants, network, state and counters."""

    def __init__(self, trial) -> None:
        self.trial = trial
        self.folder = None
        self.work = None
        self.resumed = None
        self.split = None
        self.error: IneidError | None = None
        self.closed = False
        self.shared = self.data = self.consts = self.net = self.state = self.metrics = None
        self.batch = self.steps = 0
        self.seconds = 0.0
        self.stopped = False

    def enter(self, folder) -> None:
        """Enter ``folder`` (:func:`ineid.learn.runs.writing_run`): the folder to train in is ``self.work``."""
        self.folder = folder
        self.work = folder.__enter__()

    def setup(self, shared, data, consts, net, state, batch: int, steps: int) -> None:
        self.shared, self.data, self.consts, self.net, self.state = shared, data, consts, net, state
        self.batch, self.steps = batch, steps
        self.train_local = shared.local(data.split.train)
        cfg = self.trial.cfg
        self.stopped = bool(cfg.patience) and int(state["bad_epochs"]) >= cfg.patience  # stopped early before

    @property
    def going_on(self) -> bool:
        """Whether the run has epochs left to train."""
        return not self.stopped and int(self.state["epoch"]) < self.trial.cfg.epochs

    def fail(self, error: IneidError) -> None:
        """The trial stops on ``error``: its folder is closed on it (left as that error leaves a run)."""
        self.error = error
        self.close(error)

    def close(self, exc: BaseException | None) -> None:
        """Leave the folder (once): normally (a replacement swapped in), or on ``exc``."""
        if self.closed or self.folder is None:
            self.closed = True
            return
        self.closed = True
        if exc is None:
            self.folder.__exit__(None, None, None)
        else:
            self.folder.__exit__(type(exc), exc, exc.__traceback__)

    def key(self) -> tuple:
        """What its population shares (:func:`program_key`)."""
        return program_key(self)

    def spec(self) -> ProgramSpec:
        cfg = self.trial.cfg
        return ProgramSpec(
            net=self.net,
            uses_regressor=cfg.model.uses_regressor,
            optimizer=cfg.optimizer,
            schedule=cfg.schedule,
            decay_steps=cfg.epochs * self.steps,
            physics_loss=cfg.loss == "physics",
            batch=self.batch,
            steps=self.steps,
            frames=cfg.model.frames,
            n_axes=len(self.data.wrench_scale),
        )

    def hyper(self) -> dict:
        """The settings its program reads as numbers (:data:`ineid.learn.program.HYPER`, patience, epochs)."""
        cfg = self.trial.cfg
        dt = np.dtype(cfg.dtype)
        h = {k: np.asarray(getattr(cfg, k), dtype=dt) for k in ("lr", "momentum", "weight_decay", "alpha")}
        h["beta"] = np.asarray(cfg.effective_beta, dtype=dt)
        h["patience"] = np.asarray(cfg.patience, dtype=np.int32)
        h["epochs"] = np.asarray(cfg.epochs, dtype=np.int32)
        return h


def program_key(run: TrialRun) -> tuple:
    """What trials must share to train in one program: the network (architecture, sizes, activation, frames),
    optimizer and schedule, the loss's form, the batches of an epoch, the validation set's size, the dtype and
    the data. A wls network's constants are its own: it trains alone."""
    cfg = run.trial.cfg
    return (
        cfg.model,
        cfg.optimizer,
        cfg.schedule,
        cfg.epochs * run.steps if cfg.schedule == "cosine" else 0,
        cfg.loss == "physics",
        run.batch,
        run.steps,
        len(run.split.val),
        cfg.dtype,
        id(run.shared),
        id(run) if cfg.model.uses_regressor else 0,
    )


def group_runs(runs: list[TrialRun]) -> list[list[TrialRun]]:
    """The runs in populations: those of one :func:`program_key` together, in the order first met."""
    groups: dict[tuple, list[TrialRun]] = {}
    for r in runs:
        groups.setdefault(r.key(), []).append(r)
    return list(groups.values())


def population_limit(run: TrialRun, backend: str | None = None) -> int:
    """The most trials of ``run``'s program to train at once on ``backend`` (default: JAX's): :data:`MAX_POPULATION`,
    or on a CPU one where a step costs more than :data:`CPU_STEP_FLOPS`."""
    import jax

    if (backend or jax.default_backend()) != "cpu":
        return MAX_POPULATION
    n_params = sum(int(np.size(p)) for p in jax.tree_util.tree_leaves(run.state["params"]))
    model = run.trial.cfg.model
    flops = 2 * n_params * run.batch * (model.frames if model.siamese else 1)
    return MAX_POPULATION if flops <= CPU_STEP_FLOPS else 1


def out_of_memory(err: BaseException) -> bool:
    """Whether ``err`` is the device running out of memory (XLA's ``RESOURCE_EXHAUSTED``)."""
    text = str(err)
    return "RESOURCE_EXHAUSTED" in text or "Out of memory" in text or "out of memory" in text


class Population:
    """Trials of one program trained together (see the module doc).

    Args:
        runs: the trials (set up: :meth:`TrialRun.setup`), one :func:`program_key`.
        checkpoint: ``checkpoint(run, state, record, final)`` after an epoch of a run: its metrics ``record``, its
            ``state`` (None: no checkpoint due), the model with ``final``.
        max_size: the most trials in one program (None: :func:`population_limit`).
    """

    def __init__(self, runs: list[TrialRun], checkpoint: Callable, max_size: int | None = None) -> None:
        self.runs = runs
        self.checkpoint = checkpoint
        self.max_size = max_size

    def train(self) -> None:
        """Train every run to its end (or its error)."""
        for r in self.runs:
            if not r.going_on:  # a resumed run with nothing left: its model written again, as it was
                self.checkpoint(r, r.state, None, True)
        going = [r for r in self.runs if r.going_on]
        size = self.max_size or (population_limit(going[0]) if going else 1)
        for start in range(0, len(going), size):
            self._train(going[start : start + size])

    def _train(self, runs: list[TrialRun]) -> None:
        """Train ``runs`` (one program) epoch by epoch, the next epoch dispatched before the last is written."""
        import jax

        program, fixed = self._program(runs)
        state = jax.device_put(stack([device_state(r.state, True) for r in runs]))
        epochs = [int(r.state["epoch"]) + 1 for r in runs]
        active = [True] * len(runs)
        cadence = _Cadence(jax.default_backend() == "cpu")
        pending, last = None, time.perf_counter()
        with ThreadPoolExecutor(max_workers=1) as pool:  # the next epoch's batches drawn while this one runs
            ahead = pool.submit(_batches, runs, epochs)
            while True:
                rows, frames = ahead.result()
                ran, epochs = epochs, [e + 1 for e in epochs]
                if pending is not None:
                    active = [a and e <= r.trial.cfg.epochs for a, e, r in zip(active, ran, runs, strict=True)]
                ahead = pool.submit(_batches, runs, [e if a else None for e, a in zip(epochs, active, strict=True)])
                try:
                    state, out = program(state, *fixed, rows, frames)
                    if pending is None:
                        jax.block_until_ready(out)
                except Exception as e:  # the first epoch allocates: a population too big for the device
                    if pending is not None or len(runs) < 2 or not out_of_memory(e):
                        raise
                    self._halve(runs)
                    return
                if pending is not None:
                    last = self._record(runs, pending, active, last, cadence)
                pending = (state, out, ran)
                if not any(a and e <= r.trial.cfg.epochs for a, e, r in zip(active, epochs, runs, strict=True)):
                    break
            self._record(runs, pending, active, last, cadence)

    def _program(self, runs: list[TrialRun]) -> tuple[Callable, tuple]:
        """The compiled epoch of ``runs`` (built once per program and data) and its arguments besides the state and
        the batches: the trials' constants and settings, the shared arrays, the validation groups."""
        import jax

        first = runs[0]
        shared, key = first.shared, first.key()
        if key not in shared.programs:
            shared.programs[key] = build_epoch(first.spec(), shared.physics)
        consts = jax.device_put(stack([r.consts for r in runs]))
        hyper = jax.device_put(stack([r.hyper() for r in runs]))
        return shared.programs[key], (consts, hyper, shared.arrays, *_validation(runs))

    def _halve(self, runs: list[TrialRun]) -> None:
        half = (len(runs) + 1) // 2
        log.warning(
            f"a population of {len(runs)} trials does not fit in the device's memory; training it as populations "
            f"of {half} and {len(runs) - half}"
        )
        self._train(runs[:half])
        self._train(runs[half:])

    def _record(self, runs: list[TrialRun], pending, active: list[bool], last: float, cadence) -> float:
        """Epoch ``pending`` of ``runs`` written (records, checkpoints, progress); ``active`` updated. Returns when."""
        import jax

        state, out, epochs = pending
        host = jax.device_get(out)
        counters = jax.device_get({k: state[k] for k in ("best_epoch", "bad_epochs", "active")})
        now = time.perf_counter()
        share = (now - last) / max(int(np.sum(host["ran"])), 1)
        due, full = cadence.due(now), None
        for i, r in enumerate(runs):
            if not host["ran"][i] or r.error is not None:
                continue
            if not host["finite"][i]:
                active[i] = False
                r.fail(TrainingError(f"the training loss diverged (non-finite) at epoch {epochs[i]}; lower --lr"))
                continue
            r.seconds += share
            losses, val = host["losses"][i], host["val"][i]
            record = {
                "epoch": int(epochs[i]),
                "train_loss": float(losses[0]),
                "train_mse": float(losses[1]),
                "train_phys": float(losses[2]),
                "val_mse": float(val[0]),
                "val_phys": float(val[1]),
                "best_epoch": int(counters["best_epoch"][i]),
                "seconds": share,
            }
            active[i] = bool(counters["active"][i])
            cfg = r.trial.cfg
            r.stopped = bool(cfg.patience) and int(counters["bad_epochs"][i]) >= cfg.patience
            saved = None
            if due or not active[i]:
                full = jax.device_get(state) if full is None else full
                saved = r.state = checkpoint_state(unstack(full, i))
            try:
                self.checkpoint(r, saved, record, not active[i])
            except IneidError as e:
                active[i] = False
                r.fail(e)
        if due:
            cadence.saved(time.perf_counter())
        return now


class _Cadence:
    """When a population's checkpoints are due: every epoch (``every_epoch``), else every :data:`CHECKPOINT_SECONDS`."""

    def __init__(self, every_epoch: bool) -> None:
        self.every_epoch = every_epoch
        self.last = time.perf_counter()

    def due(self, now: float) -> bool:
        return self.every_epoch or now - self.last >= CHECKPOINT_SECONDS

    def saved(self, now: float) -> None:
        self.last = now


def _batches(runs: list[TrialRun], epochs: list[int | None]) -> tuple[np.ndarray, np.ndarray]:
    """Each run's batches of its epoch (None: none, zeros): positions (P, S, B) and frames (P, S, B, K)."""
    first = runs[0]
    s, b, k = first.steps, first.batch, first.trial.cfg.model.frames
    n_frames = first.shared.n_frames
    rows = np.zeros((len(runs), s, b), dtype=np.int32)
    frames = np.zeros((len(runs), s, b, k), dtype=np.int32)
    for i, (r, e) in enumerate(zip(runs, epochs, strict=True)):
        if e is None:
            continue
        pos, fr = epoch_groups(len(r.train_local), n_frames, k, r.trial.cfg.seed, e)
        rows[i] = r.train_local[pos[: s * b]].reshape(s, b)
        frames[i] = fr[: s * b].reshape(s, b, k)
    return rows, frames


def _validation(runs: list[TrialRun]):
    """The fixed validation groups in chunks of a batch: positions (P, N, B), frames (N, B, K), mask (N, B)."""
    first = runs[0]
    b, k, n_frames = first.batch, first.trial.cfg.model.frames, first.shared.n_frames
    pos, frames = fixed_groups(len(first.split.val), n_frames, k)
    n = len(pos)
    chunks = -(-n // b)
    pad = chunks * b - n
    mask = np.concatenate([np.ones(n), np.zeros(pad)]).astype(first.shared.dtype)
    frames = np.concatenate([frames, np.repeat(frames[-1:], pad, axis=0)]).astype(np.int32)
    rows = []
    for r in runs:
        local = r.shared.local(r.split.val)[pos]
        rows.append(np.concatenate([local, np.repeat(local[-1:], pad)]).reshape(chunks, b))
    return np.stack(rows).astype(np.int32), frames.reshape(chunks, b, k), mask.reshape(chunks, b)
