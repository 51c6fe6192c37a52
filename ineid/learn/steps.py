"""The compiled pieces of a training run: batches, the jitted steps, validation.

:func:`build_functions` makes the jitted ``train_steps`` (several optimizer steps per call)
and ``eval_batch`` of a run; :func:`run_epoch` and :func:`evaluate_groups` drive them over
an epoch's batches. The loop around them (splits, checkpoints, early stopping) is
:func:`ineid.learn.train.train`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ineid.learn.losses import make_loss

if TYPE_CHECKING:
    from ineid.learn.config import TrainConfig
    from ineid.learn.losses import Physics
    from ineid.learn.models import ModelSpec
    from ineid.learn.scalers import Scaler


@dataclass
class Prepared:
    """The configurations of a run made ready: scalers and device arrays.

    Arrays hold only the configurations in ``rows`` (dataset indices), in that order;
    ``local(indices)`` maps dataset indices to positions in them.
    """

    rows: np.ndarray
    x_scaler: Scaler
    y_scaler: Scaler
    arrays: dict
    physics: Physics
    n_out: int
    n_frames: int

    def local(self, dataset_indices: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.rows, dataset_indices)


def gather_samples(arrays, mode, rows, frames, n_axes: int = 6):
    """Batch of samples: positions (B,) and frame indices (B, K) -> (x, z, physics inputs).

    ``n_axes``: the measured axes of a frame (:attr:`ineid.learn.losses.Physics.n_axes`), the
    first numbers of a compact row.

    Per-frame arrays are gathered by one flat index ``row * n_frames + frame`` along their
    first axis: a single-axis ``take``, much cheaper on the CPU than a two-axis gather.
    """
    import jax.numpy as jnp

    n_frames = arrays["x"].shape[1]
    flat = rows[:, None] * n_frames + frames

    def take(a):
        return jnp.take(a.reshape((-1,) + a.shape[2:]), flat, axis=0)

    if "compact" in arrays:  # compact cached rows: y / s and the kept entries in one gather
        row = take(arrays["compact"])
        return take(arrays["x"]), arrays["z"][rows], (row[..., n_axes:], row[..., :n_axes])
    if mode == "cached":
        inputs = (take(arrays["psi"]), take(arrays["yres"]))
    else:
        inputs = tuple(take(arrays[k]) for k in ("q", "qd", "qdd", "wrench"))
    return take(arrays["x"]), arrays["z"][rows], inputs


def forward(net, spec: ModelSpec, physics: Physics):
    """``f(params, x, inputs) -> z_hat``: the network on a batch, given its physics inputs when it takes them."""
    if spec.uses_regressor:
        return lambda params, x, inputs: net.apply(params, x, *physics.system(inputs))
    return lambda params, x, inputs: net.apply(params, x)


def init_params(net, spec: ModelSpec, prep: Prepared, key):
    """Initial parameters of ``net`` from the shapes of one sample of ``prep``."""
    k = spec.frames
    x, _, inputs = gather_samples(
        prep.arrays, prep.physics.mode, np.zeros(1, dtype=np.int64), np.arange(k)[None], prep.physics.n_axes
    )
    return net.init(key, x, *prep.physics.system(inputs)) if spec.uses_regressor else net.init(key, x)


def build_functions(net, cfg: TrainConfig, prep: Prepared, optimizer):
    """Jitted ``train_steps`` (with ``.single`` for one step) and ``eval_batch`` for a run."""
    import jax
    import jax.numpy as jnp
    import optax

    loss_fn = make_loss(net.apply, cfg.alpha, cfg.effective_beta, prep.physics, cfg.model.uses_regressor)
    apply = forward(net, cfg.model, prep.physics)
    mode, n_axes = prep.physics.mode, prep.physics.n_axes

    def one_step(params, opt_state, arrays, rows, frames):
        x, z, inputs = gather_samples(arrays, mode, rows, frames, n_axes)
        (total, (mse, phys)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, x, z, inputs)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, jnp.stack([total, mse, phys])

    @jax.jit
    def train_steps(params, opt_state, arrays, rows, frames):
        """``STEPS_PER_CALL`` steps in one call (a scan): rows (S, B), frames (S, B, K).

        Small networks spend most of a step in dispatch; one call per few steps removes it.
        """

        def body(carry, batch):
            p, o, losses = one_step(*carry, arrays, *batch)
            return (p, o), losses

        (params, opt_state), losses = jax.lax.scan(body, (params, opt_state), (rows, frames))
        return params, opt_state, losses.sum(axis=0)

    train_steps.single = jax.jit(one_step)

    @jax.jit
    def eval_batch(params, arrays, rows, frames, mask):
        """Sums over the masked samples of (mse, phys) and the predictions."""
        x, z, inputs = gather_samples(arrays, mode, rows, frames, n_axes)
        z_hat = apply(params, x, inputs)
        se = jnp.mean((z_hat - z) ** 2, axis=1)
        r = prep.physics.residual(z_hat * prep.y_scaler.scale + prep.y_scaler.center, inputs)
        ph = jnp.mean(r * r, axis=(1, 2))
        return jnp.sum(se * mask), jnp.sum(ph * mask), z_hat

    return train_steps, eval_batch


STEPS_PER_CALL = 16
"""Training steps per compiled call (see ``train_steps``); the remainder runs one by one."""


def run_epoch(train_steps, params, opt_state, arrays, rows, frames, batch: int, n_steps: int):
    """``n_steps`` steps over consecutive batches; returns params, state and summed losses."""
    sums = np.zeros(3)
    full = n_steps - n_steps % STEPS_PER_CALL
    for s0 in range(0, full, STEPS_PER_CALL):
        sl = slice(s0 * batch, (s0 + STEPS_PER_CALL) * batch)
        r = rows[sl].reshape(STEPS_PER_CALL, batch)
        f = frames[sl].reshape(STEPS_PER_CALL, batch, -1)
        params, opt_state, losses = train_steps(params, opt_state, arrays, r, f)
        sums += np.asarray(losses)
    for s in range(full, n_steps):
        sl = slice(s * batch, (s + 1) * batch)
        params, opt_state, losses = train_steps.single(params, opt_state, arrays, rows[sl], frames[sl])
        sums += np.asarray(losses)
    return params, opt_state, sums


def evaluate_groups(eval_batch, params, arrays, rows, frames, batch: int):
    """Mean MSE, mean physics term and scaled predictions (S, n_out) over sample groups."""
    n = len(rows)
    se = ph = 0.0
    preds = []
    for start in range(0, n, batch):
        r, f = rows[start : start + batch], frames[start : start + batch]
        m = np.ones(len(r))
        if len(r) < batch:  # pad to one compiled shape
            pad = batch - len(r)
            r = np.concatenate([r, np.repeat(r[-1:], pad)])
            f = np.concatenate([f, np.repeat(f[-1:], pad, axis=0)])
            m = np.concatenate([m, np.zeros(pad)])
        a, b, z = eval_batch(params, arrays, r, f, m)
        se += float(a)
        ph += float(b)
        preds.append(np.asarray(z)[: int(m.sum())])
    return se / n, ph / n, np.concatenate(preds)
