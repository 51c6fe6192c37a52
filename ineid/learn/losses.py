"""Losses: the parameter MSE and the physics-informed loss of the paper's equation 5.

    L = alpha * mean_i (z_hat_i - z_i)^2  +  beta * mean_{j, a} ((R_ja - [Psi_j theta_hat]_a) / s_a)^2

* ``z`` are the targets in scaled units (the output scaler), so the first term is the MSE
  the network is trained on anyway;
* the second is the wrench residual of the predicted parameters over the sample's K
  frames, in physical units: ``theta_hat`` is the unscaled prediction of the unknown
  links, completed by the known links' CAD values, ``Psi_j`` is the rows of the dataset's
  measurement channels (:meth:`ineid.channels.ChannelSet.jax_rows_function`: for the base
  wrench the generated JAX regressor of the robot; see :class:`Physics` for the cached and
  inline forms), and ``s_a`` is the standard deviation of the measured
  values on axis ``a`` over the training set (N for forces, N*m for moments), so each
  axis counts alike and the term is dimensionless: 1 means "as large as the wrench's
  spread". At the true parameters of clean data it is zero (round-off). On the built-in
  arm it is small, about 0.016 for an untrained network or the training-mean parameters
  against a scaled MSE of about 1, because the known links and the average unknown links
  already explain most of the wrench: ``beta`` of 50-100 makes the two terms comparable.

The whole loss is one jit-compiled function; its gradient flows through the regressor.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

LOSSES = ("mse", "physics")


PHYSICS_MODES = ("cached", "inline")


@dataclass(frozen=True)
class Physics:
    """What the physics term needs besides the batch (all constants of a run).

    Two ways to get ``Psi``, with identical values:

    * ``"cached"`` (default): the unknown links' regressor ``Psi_u`` of every training frame
      and ``y = R - Psi_k theta_k`` are computed once by the generated JAX regressor
      (:func:`ineid.identify.systems.stack`); a step gathers its frames' blocks, so the
      physics term costs one small contraction (126 numbers a frame in memory for two
      unknown links: ``Psi_u`` and ``y``).
    * ``"inline"``: the generated regressor runs inside the jitted loss on the batch's
      frames (no memory, more compute and compile time), for datasets too big to cache.

    The data do not depend on the network's parameters, so ``Psi`` is a constant of the
    gradient: ``d/d theta ||y - Psi_u theta||^2 = -2 Psi_u^T r``.

    A cached loss for a network that does not read the regressor itself keeps less a frame
    (``compact``, :class:`CompactRegressor`): ``Psi_u theta = Psi_b beta`` with the base
    columns ``Psi_b`` and ``beta = B theta`` (the structural base parameters), only the
    entries that are not zero in every frame, divided by ``s_a``, gathered with the
    network's inputs in one row: 75 numbers a frame instead of 126 on the built-in arm
    (the gather is what a step of a small network waits for on a large training set).
    Equal to the full form to round-off (``Psi_u = Psi_b B`` to about 1e-14).

    Attributes:
        mode: ``"cached"`` or ``"inline"``.
        regressor: the channels' jit-safe rows ``f(q, qd, qdd, gravity) -> (..., A, 10 n_links)`` (inline;
            the base wrench: the generated regressor, ``A = 6``).
        gravity: (3,) m/s^2.
        unknown_index, known_index: columns of ``theta`` of the unknown and known links.
        theta_known: (10 n_known,) known links' parameters.
        wrench_scale: (A,) per-axis normalization ``s_a``.
        y_center, y_scale: the output scaler, to unscale predictions.
        compact: the compact cached form (see above), or None.
    """

    mode: str
    regressor: object
    gravity: np.ndarray
    unknown_index: np.ndarray
    known_index: np.ndarray
    theta_known: np.ndarray
    wrench_scale: np.ndarray
    y_center: np.ndarray
    y_scale: np.ndarray
    compact: CompactRegressor | None = None

    @property
    def n_axes(self) -> int:
        """``A``, the measured axes of a frame."""
        return len(self.wrench_scale)

    def system(self, inputs):
        """``(psi_u (B, K, A, 10 n_u), y (B, K, A))``: the batch's frames as ``y = Psi_u theta_u``.

        Args:
            inputs: ``(psi_u, y)`` when cached, else ``(q, qd, qdd, wrench)`` of the frames.
        """
        import jax

        if self.compact is not None:
            raise ValueError(
                "the compact cached regressor holds Psi_b's entries, not Psi_u: a network that "
                "reads the regressor is prepared with the full one"
            )
        if self.mode == "cached":
            return inputs
        q, qd, qdd, wrench = inputs
        psi = jax.lax.stop_gradient(self.regressor(q, qd, qdd, jnp.asarray(self.gravity)))
        return psi[..., self.unknown_index], wrench - psi[..., self.known_index] @ jnp.asarray(self.theta_known)

    def residual(self, theta_unknown, inputs):
        """Normalized residual ``(R - Psi theta) / s``: (B, K, A).

        Args:
            theta_unknown: (B, 10 n_u) physical units.
            inputs: ``(psi_u (B, K, A, 10 n_u), y (B, K, A))`` when cached, else
                ``(q, qd, qdd, wrench)`` of the batch's frames; compact: ``(values, y / s)``
                (:meth:`CompactRegressor.residual`).
        """
        if self.compact is not None:
            return self.compact.residual(theta_unknown, inputs)
        psi_u, y = self.system(inputs)
        predicted = jnp.einsum("bkij,bj->bki", psi_u, theta_unknown)
        return (y - predicted) / jnp.asarray(self.wrench_scale)

    def term(self, z_hat, inputs):
        """``mean ((R - Psi theta_hat) / s)^2`` from scaled predictions ``z_hat`` (B, n_out)."""
        theta_u = z_hat * jnp.asarray(self.y_scale) + jnp.asarray(self.y_center)
        r = self.residual(theta_u, inputs)
        return jnp.mean(r * r)


@dataclass(frozen=True)
class CompactRegressor:
    """The compact cached regressor of the physics term (see :class:`Physics`).

    The measured axes are grouped by the base columns they use (on the built-in arm's wrench: the
    forces use 6, the moments all 17); a frame keeps, per group ``g``, the entries
    ``Psi_b[a, c] / s_a`` for its axes ``a`` and columns ``c`` (axis-major), and ``y / s``
    with the axes in group order. Then, with ``beta = B theta``,

        ((R - Psi theta) / s)[axes_g] = (y / s)[axes_g] - V_g beta[cols_g]    (one batched dot per group)

    Attributes:
        base_map: (r, 10 n_u) ``B``.
        groups: ``(cols, axes)`` per group, index tuples.
    """

    base_map: np.ndarray
    groups: tuple[tuple[tuple[int, ...], tuple[int, ...]], ...]

    @property
    def axis_order(self) -> np.ndarray:
        """The measured axes in the order the compact rows hold them."""
        return np.array([a for _, axes in self.groups for a in axes])

    @property
    def n_axes(self) -> int:
        """``A``: the first ``A`` numbers of a compact row are ``y / s``."""
        return sum(len(a) for _, a in self.groups)

    @property
    def width(self) -> int:
        """Numbers a frame: ``y / s`` and the kept entries."""
        return self.n_axes + sum(len(c) * len(a) for c, a in self.groups)

    @staticmethod
    def from_frames(psi_u: np.ndarray, y: np.ndarray, base, wrench_scale: np.ndarray):
        """``(compact, rows (..., width))`` from ``psi_u`` (..., A, 10 n_u) and ``y`` (..., A) of every frame."""
        scale = np.asarray(wrench_scale, dtype=np.float64)
        n_axes, n_p = psi_u.shape[-2:]
        flat = psi_u.reshape(-1, n_axes * n_p)
        nonzero = np.zeros(n_axes * n_p, dtype=bool)
        for start in range(0, len(flat), 65536):  # a chunk at a time: no frames-long temporary of booleans
            nonzero |= np.any(flat[start : start + 65536] != 0, axis=0)
        kept = nonzero.reshape(n_axes, n_p)[:, base.base_index]  # (A, r): not zero in some frame
        by_cols: dict[tuple[int, ...], list[int]] = {}
        for a in range(n_axes):
            by_cols.setdefault(tuple(int(c) for c in np.flatnonzero(kept[a])), []).append(a)
        groups = tuple((cols, tuple(axes)) for cols, axes in by_cols.items())
        compact = CompactRegressor(np.asarray(base.B, dtype=np.float64), groups)
        # the entries of each group, axis-major: Psi_b[a, c] = Psi_u[a, base_index[c]], each divided by s_a
        entries = [a * n_p + int(base.base_index[c]) for cols, axes in groups for a in axes for c in cols]
        divisors = np.concatenate([np.repeat(scale[list(axes)], len(cols)) for cols, axes in groups])
        lead = psi_u.shape[:-2]
        values = np.take(flat, entries, axis=1) / divisors
        y_s = (y / scale)[..., compact.axis_order].reshape(-1, n_axes)
        return compact, np.concatenate([y_s, values], axis=-1).reshape(lead + (-1,))

    def residual(self, theta_unknown, inputs):
        """(B, K, A) normalized residual from ``theta_unknown`` (B, 10 n_u) and ``(values, y / s)``."""
        values, y_s = inputs
        beta = theta_unknown @ jnp.asarray(self.base_map.T)  # (B, r)
        predicted, start = [], 0
        for cols, axes in self.groups:
            n = len(cols) * len(axes)
            v = values[..., start : start + n].reshape(values.shape[:-1] + (len(axes), len(cols)))
            predicted.append(jnp.einsum("bkac,bc->bka", v, beta[:, list(cols)]))
            start += n
        r = y_s - jnp.concatenate(predicted, axis=-1)
        order = self.axis_order
        if np.array_equal(order, np.arange(len(order))):
            return r
        return r[..., np.argsort(order)]


def make_loss(apply_fn, alpha: float, beta: float, physics: Physics | None, uses_regressor: bool = False):
    """``loss(params, x, z, inputs) -> (total, (mse, phys))`` for one batch.

    Args:
        apply_fn: the model's ``apply(params, x) -> z_hat``, or with ``uses_regressor``
            ``apply(params, x, psi_u, y) -> z_hat`` (the ``wls`` network).
        alpha, beta: weights of the parameter MSE and the physics term (``beta = 0``: plain MSE).
        physics: constants of the physics term (required when ``beta > 0`` or
            ``uses_regressor``); ``inputs`` are its per-batch arrays (see :meth:`Physics.residual`).
        uses_regressor: the model takes the frames' regressor and wrench (:meth:`Physics.system`).
    """
    if beta > 0 and physics is None:
        raise ValueError("the physics loss needs the robot's regressor (physics=...)")
    if uses_regressor and physics is None:
        raise ValueError("a network that uses the regressor (wls) needs the robot's regressor (physics=...)")

    def loss(params, x, z, inputs):
        z_hat = apply_fn(params, x, *physics.system(inputs)) if uses_regressor else apply_fn(params, x)
        mse = jnp.mean((z_hat - z) ** 2)
        if beta > 0:
            phys = physics.term(z_hat, inputs)
        else:
            phys = jnp.zeros((), dtype=mse.dtype)
        return alpha * mse + beta * phys, (mse, phys)

    return loss
