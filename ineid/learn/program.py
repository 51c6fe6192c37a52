"""The compiled epoch of a population: trials that share a network's shapes, trained at once.

One call of :func:`build_epoch`'s function runs a whole epoch of every trial of a population: its
steps as one ``lax.scan``, then its validation (a second scan over the fixed validation groups),
then the bookkeeping of early stopping, all on the device, ``jax.vmap``-ped over the trials'
parameters, optimizer states and constants. What a trial's epoch computes is what it computes
alone: its batches (its own split and seed), its scalers, its learning rate and loss weights (numbers
the program reads, not constants compiled in). A trial that has stopped (early, at its last
epoch, or with a non-finite loss) keeps its state: its updates are masked.

The state of a trial (:func:`initial_state`) is the run's checkpoint (:mod:`ineid.learn.runs`)
with one more entry, ``active``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ineid.learn.losses import Physics
from ineid.learn.shared import gather, trial_physics

HYPER = ("lr", "momentum", "weight_decay", "alpha", "beta")
"""A trial's settings that the program reads as numbers (the rest are compiled in)."""


def make_optimizer(kind: str, schedule: str, lr, momentum, weight_decay, decay_steps: int):
    """The Optax optimizer ``kind`` (sgd with momentum, adam, adamw); ``lr`` constant or decayed to 0 over
    ``decay_steps`` (``schedule="cosine"``). The numbers may be traced arrays (one per trial of a population)."""
    import optax

    if schedule == "cosine":
        lr = optax.cosine_decay_schedule(lr, decay_steps=max(1, decay_steps))
    if kind == "sgd":
        return optax.sgd(lr, momentum=momentum)
    if kind == "adam":
        return optax.adam(lr)
    return optax.adamw(lr, weight_decay=weight_decay)


@dataclass(frozen=True)
class ProgramSpec:
    """What the trials of one compiled program share.

    Attributes:
        net: the Flax module (one architecture, activation and dtype).
        uses_regressor: the network also reads each frame's regressor (``wls``).
        optimizer, schedule: Optax's kind and the learning rate's schedule.
        decay_steps: the cosine schedule's steps (epochs x steps per epoch).
        physics_loss: the loss has the physics term (else the MSE alone; the term is still validated).
        batch, steps: samples per step, steps per epoch.
        frames: frames per sample (K).
        n_axes: measured axes of a frame.
    """

    net: object
    uses_regressor: bool
    optimizer: str
    schedule: str
    decay_steps: int
    physics_loss: bool
    batch: int
    steps: int
    frames: int
    n_axes: int


def apply_fn(spec: ProgramSpec, physics: Physics) -> Callable:
    """``f(params, x, inputs) -> z_hat``: the network on a batch, given its physics inputs when it reads them."""
    if spec.uses_regressor:
        return lambda params, x, inputs: spec.net.apply(params, x, *physics.system(inputs))
    return lambda params, x, inputs: spec.net.apply(params, x)


def _where(flag, new, old):
    import jax
    import jax.numpy as jnp

    return jax.tree_util.tree_map(lambda a, b: jnp.where(flag, a, b), new, old)


def build_epoch(spec: ProgramSpec, physics: Physics) -> Callable:
    """The jitted epoch of a population (see the module doc).

    Returns:
        ``epoch(state, consts, hyper, arrays, val_rows, val_frames, val_mask, rows, frames) -> (state, out)``:
        ``state``, ``consts`` (:meth:`ineid.learn.shared.TrialData.constants`) and ``hyper`` (:data:`HYPER`,
        ``patience``, ``epochs``) stacked over the trials; ``arrays`` the shared data's; ``rows`` (P, S, B) and
        ``frames`` (P, S, B, K) each trial's batches; ``val_rows`` (P, N, B) its validation groups in chunks,
        ``val_frames`` (N, B, K) and ``val_mask`` (N, B) theirs. ``out``: per trial ``losses`` (3,) the
        epoch's mean loss, MSE and physics term, ``val`` (2,) the validation MSE and physics term,
        ``ran`` whether it trained this epoch, ``finite`` whether its loss stayed finite.
    """
    import jax

    one = _trial_epoch(spec, physics)
    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, 0, None, None, 0, 0)))


def _trial_epoch(spec: ProgramSpec, template: Physics) -> Callable:
    import jax
    import jax.numpy as jnp
    import optax

    def epoch(state, consts, hyper, arrays, val_rows, val_frames, val_mask, rows, frames):
        physics = trial_physics(template, consts)
        apply = apply_fn(spec, physics)
        opt = make_optimizer(
            spec.optimizer, spec.schedule, hyper["lr"], hyper["momentum"], hyper["weight_decay"], spec.decay_steps
        )

        def loss_fn(params, x, z, inputs):
            z_hat = apply(params, x, inputs)
            mse = jnp.mean((z_hat - z) ** 2)
            if not spec.physics_loss:
                return hyper["alpha"] * mse, (mse, jnp.zeros((), mse.dtype))
            term = physics.term(z_hat, inputs)
            return hyper["alpha"] * mse + hyper["beta"] * term, (mse, term)

        def step(carry, batch):
            params, opt_state = carry
            x, z, inputs = gather(arrays, consts, physics.mode, *batch, spec.n_axes)
            (total, (mse, term)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, x, z, inputs)
            updates, opt_state = opt.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), jnp.stack([total, mse, term])

        active = state["active"]
        (params, opt_state), losses = jax.lax.scan(step, (state["params"], state["opt_state"]), (rows, frames))
        losses = losses.sum(axis=0) / max(spec.steps, 1)
        finite = jnp.all(jnp.isfinite(losses))
        ran = active
        keep = active & finite
        params = _where(keep, params, state["params"])
        opt_state = _where(keep, opt_state, state["opt_state"])
        val = _validate(spec, physics, apply, params, consts, arrays, val_rows, val_frames, val_mask)
        new = _bookkeeping(state, hyper, params, opt_state, val[0], keep)
        new["active"] = new["active"] & finite
        return new, {"losses": losses, "val": val, "ran": ran, "finite": finite}

    return epoch


def _validate(spec, physics, apply, params, consts, arrays, val_rows, val_frames, val_mask):
    """(2,) the mean MSE and physics term over a trial's validation groups (masked chunks)."""
    import jax
    import jax.numpy as jnp

    def chunk(acc, part):
        r, f, m = part
        x, z, inputs = gather(arrays, consts, physics.mode, r, f, spec.n_axes)
        z_hat = apply(params, x, inputs)
        se = jnp.mean((z_hat - z) ** 2, axis=1)
        res = physics.residual(z_hat * consts["y_scale"] + consts["y_center"], inputs)
        ph = jnp.mean(res * res, axis=(1, 2))
        return acc + jnp.stack([jnp.sum(se * m), jnp.sum(ph * m)]), None

    sums, _ = jax.lax.scan(chunk, jnp.zeros(2, dtype=consts["z"].dtype), (val_rows, val_frames, val_mask))
    return sums / jnp.sum(val_mask)


def _bookkeeping(state, hyper, params, opt_state, val_mse, ran):
    """The state after an epoch of a trial that ``ran``: the best parameters, the counters, whether it goes on."""
    import jax.numpy as jnp

    epoch = state["epoch"] + ran.astype(state["epoch"].dtype)
    val = val_mse.astype(state["best_val"].dtype)
    improved = ran & (val < state["best_val"])
    bad = jnp.where(improved, 0, state["bad_epochs"] + 1)
    bad = jnp.where(ran, bad, state["bad_epochs"])
    patience = hyper["patience"]
    go_on = ran & ~((patience > 0) & (bad >= patience)) & (epoch < hyper["epochs"])
    return {
        "params": params,
        "opt_state": opt_state,
        "best_params": _where(improved, params, state["best_params"]),
        "epoch": epoch,
        "best_val": jnp.where(improved, val, state["best_val"]),
        "best_epoch": jnp.where(improved, epoch, state["best_epoch"]),
        "bad_epochs": bad,
        "active": go_on,
    }


def initial_state(params, opt_state) -> dict:
    """A new trial's state (the checkpoint's entries, and ``active``)."""
    return {
        "params": params,
        "opt_state": opt_state,
        "best_params": params,
        "epoch": 0,
        "best_val": float("inf"),
        "best_epoch": 0,
        "bad_epochs": 0,
    }


COUNTERS = {"epoch": np.int32, "best_val": np.float64, "best_epoch": np.int32, "bad_epochs": np.int32}


def device_state(state: dict, active: bool) -> dict:
    """A checkpoint's state (Python counters) as the program's: counters as typed arrays, ``active`` added."""
    out = {k: v for k, v in state.items() if k not in COUNTERS}
    out.update({k: np.asarray(state[k], dtype=t) for k, t in COUNTERS.items()})
    out["active"] = np.asarray(active)
    return out


def checkpoint_state(state: dict) -> dict:
    """The program's state of one trial (host arrays) as a checkpoint's: Python counters, no ``active``."""
    out = {k: v for k, v in state.items() if k not in COUNTERS and k != "active"}
    out.update({k: (float if t is np.float64 else int)(state[k]) for k, t in COUNTERS.items()})
    return out


def stack(trees: list):
    """The trials' pytrees stacked along a first axis (NumPy)."""
    import jax

    return jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def unstack(tree, i: int):
    """Trial ``i`` of a stacked pytree (host arrays)."""
    import jax

    return jax.tree_util.tree_map(lambda a: np.asarray(a)[i], tree)


def make_optimizer_for(cfg, steps_per_epoch: int):
    """The Optax optimizer of a run's settings (:class:`ineid.learn.config.TrainConfig`), its schedule over
    ``cfg.epochs * steps_per_epoch`` steps."""
    return make_optimizer(
        cfg.optimizer, cfg.schedule, cfg.lr, cfg.momentum, cfg.weight_decay, cfg.epochs * steps_per_epoch
    )
