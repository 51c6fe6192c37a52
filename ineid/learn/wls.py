"""A network that outputs a weighted least-squares estimate (``--arch wls``).

The paper's networks see 18 raw numbers per frame and must learn the rigid-body physics;
this one is given it. For one sample, K frames ``j`` of a configuration with the known
links' share subtracted (``y_j = R_j - Psi_k,j theta_k``, :mod:`ineid.identify.systems`),
``W_j theta = W_b,j beta`` holds with ``W_b,j`` the base columns of the unknown links'
regressor and ``beta = B theta`` the base parameters (:mod:`ineid.identify.identifiability`).
The model returns

    beta_hat = argmin_beta  sum_j || D_j (y_j - W_b,j beta) ||^2  +  || Gamma (L^-1 (beta - mu_beta) - m) ||^2

    theta_hat = mu_theta + G (beta_hat - mu_beta)            (the null-space rule of the floor)

where a per-frame encoder (the same weights on every frame, as in the Siamese networks)
gives the row weights ``D_j = diag(d_j)``, ``d_ja = exp(delta_ja) / sigma_a``, one per frame
and wrench axis, and a configuration-level head gives the prior: a mean ``m`` and a
diagonal precision ``Gamma^2 = diag(exp(2 lambda))`` in *whitened* base coordinates
``L^-1 (beta - mu_beta)``. The constants come from the training split (:class:`WlsContext`):

* ``mu_beta``, ``L``: mean and Cholesky factor of the covariance of the true ``beta`` over
  the training configurations. A diagonal precision in these coordinates can be the
  training distribution itself (``m = 0``, ``Gamma = I``), whose covariance is not
  diagonal in ``beta``; a diagonal precision in ``beta`` could not represent it.
* ``sigma``: the per-axis RMS of the residual ``y - W theta`` at the true parameters over
  the training frames (the wrench noise plus what kinematic noise adds), floored at
  ``1e-13`` of the wrench's spread (some 100 times the rounding of the wrench) so that
  clean data give large finite weights that outweigh any prior the head can set.
* ``mu_theta``, ``G``: the linear minimum-mean-square-error map from ``beta`` to
  ``theta`` fitted on the training truth (evaluate's floor); ``B G = I``, so
  ``B theta_hat = beta_hat`` exactly: the null space is filled in, the base parameters
  are the solve's.

The last layers of the encoder and the head start at zero, so an untrained model *is* the
Gaussian-prior estimate (``delta = 0``, ``m = 0``, ``lambda = 0``: the posterior mean
under the training distribution and the noise model), and with ``prior=False`` it is the
noise-weighted least squares. The encoder sees each frame's scaled features and its
normalized residual under a first, fixed solve (``delta = 0``): frames that a glitching
sensor corrupted stand out there, and the learned weights can discount them.

**The solve** runs inside the jitted model, differentiable: in the scaled unknowns
``u = (beta - mu_beta) / s`` (``s``: the base parameters' scales, so the columns have
like magnitudes), with rows ``A_j = W_b,j diag(s)`` and ``e_j = y_j - W_b,j mu_beta``,

    N = sum_j A_j^T D_j^2 A_j + P^T P,   P = Gamma L^-1 diag(s),   N u = sum_j A_j^T D_j^2 e_j + P^T Gamma m

by a Cholesky factorization of the Jacobi-equilibrated ``r x r`` matrix ``N``, then one
step of iterative refinement from the residuals of the least-squares problem itself (the
corrected semi-normal equations, Björck 1996, sec. 2.5): the accuracy of a QR solve for
the conditioning met here, at the cost of two more triangular solves.

References:
    Björck (1996), Numerical methods for least squares problems, SIAM.
    Gautier & Khalil (1990), Direct calculation of minimum set of inertial parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from ineid.learn.layers import ACTIVATIONS, Encoder

WLS_DEPTH, WLS_WIDTH = 2, 32
"""Default hidden layers of the wls encoder and their width (``--depth``, ``--width``)."""

SIGMA_FLOOR = 1e-13
"""Smallest residual RMS per axis, relative to the wrench's spread (clean data)."""

LOG_WEIGHT_RANGE = 8.0
"""The learned log-weights ``delta`` and log-precisions ``lambda`` stay within +-8 (soft bound)."""


@dataclass(frozen=True, eq=False)
class WlsContext:
    """The constants of a wls model, fitted on the training split (see the module doc).

    Compared by identity (``eq=False``), so a Flax module can hold it as an attribute.

    Attributes:
        base_index: (r,) columns of the unknown links' regressor kept as base columns.
        base_scale: (r,) ``s``, scales of the base parameters (SI units of each).
        mu_beta: (r,) training mean of the true base parameters.
        l_inv: (r, r) ``L^-1``, the inverse Cholesky factor of their training covariance.
        sigma: (A,) per-axis residual RMS at the truth (the wrench: N, N*m): the noise model.
        mu_theta: (n_u,) training mean of the true standard parameters.
        gain: (n_u, r) ``G``, the null-space rule ``theta = mu_theta + G (beta - mu_beta)``.
        b: (r, n_u) ``B``, the base parameters ``beta = B theta``.
        y_center, y_scale: (n_u,) the run's target scaler (the model outputs scaled targets).
    """

    base_index: np.ndarray
    base_scale: np.ndarray
    mu_beta: np.ndarray
    l_inv: np.ndarray
    sigma: np.ndarray
    mu_theta: np.ndarray
    gain: np.ndarray
    b: np.ndarray
    y_center: np.ndarray
    y_scale: np.ndarray

    @property
    def rank(self) -> int:
        return len(self.base_index)

    @property
    def prior_rows(self) -> np.ndarray:
        """``L^-1 diag(s)``: (r, r), the prior's rows in the scaled unknowns ``u``."""
        return self.l_inv * self.base_scale[None, :]

    def identifiable_part(self, theta: np.ndarray) -> np.ndarray:
        """``mu_theta + G (B theta - mu_beta)``: what of ``theta`` (..., n_u) its wrenches can tell.

        The rest, ``theta`` minus this, lies along the null directions and is uncorrelated
        with ``beta`` over the training set: no estimator that sees only wrenches can
        predict it, so a wls network is trained on this part alone (see :func:`ineid.learn.train.train`).
        """
        return self.mu_theta + (np.asarray(theta) @ self.b.T - self.mu_beta) @ self.gain.T

    def to_dict(self) -> dict:
        return {k: np.asarray(getattr(self, k)).tolist() for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, d: dict) -> WlsContext:
        arrays = {k: np.asarray(d[k], dtype=np.float64) for k in cls.__dataclass_fields__}
        arrays["base_index"] = arrays["base_index"].astype(np.int64)
        return cls(**arrays)


def null_space_map(theta_fit: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mu_theta, mu_beta, G)`` of the linear MMSE estimate ``theta = mu_theta + G (beta - mu_beta)``.

    Fitted on true parameters ``theta_fit`` (C, n_u) with ``beta = B theta``:
    ``G = C_theta,beta C_beta,beta^-1`` (least squares, so a singular ``C_beta,beta``
    still gives the minimum-norm gain). ``B G = I`` where ``C_beta,beta`` is regular.
    """
    beta = theta_fit @ b.T
    mu_t, mu_b = theta_fit.mean(axis=0), beta.mean(axis=0)
    ct = (theta_fit - mu_t).T @ (beta - mu_b) / max(len(theta_fit) - 1, 1)
    cb = np.cov(beta, rowvar=False).reshape(len(mu_b), len(mu_b))
    gain = np.linalg.lstsq(cb, ct.T, rcond=None)[0].T
    return mu_t, mu_b, gain


def _whitening(beta_fit: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``L^-1`` of the covariance of ``beta_fit`` (C, r), regularized in the scaled units.

    A direction without spread in the training truth (or too few configurations) gets a
    variance of ``1e-10`` times the mean scaled variance: the prior then all but fixes it.
    """
    r = beta_fit.shape[1]
    cov = np.cov(beta_fit / scale, rowvar=False).reshape(r, r) if len(beta_fit) > 1 else np.zeros((r, r))
    jitter = 1e-10 * max(float(np.trace(cov)) / r, 1e-30)
    chol = np.linalg.cholesky(cov + jitter * np.eye(r))  # of the scaled covariance
    return np.linalg.inv(chol) / scale[None, :]  # L^-1 = (S L_s)^-1 = L_s^-1 S^-1


def residual_sigma(w, y, theta, wrench_scale: np.ndarray) -> np.ndarray:
    """Per-axis RMS of ``y - W theta`` over every frame: (A,), floored (see :data:`SIGMA_FLOOR`).

    Args:
        w: (C, AF, n_u) stacked regressors; y: (C, AF); theta: (C, n_u) true parameters.
        wrench_scale: (A,) the measured values' spread per axis (the wrench: six).
    """
    res = (y - np.einsum("cnp,cp->cn", w, theta)).reshape(-1, len(wrench_scale))
    rms = np.sqrt(np.mean(res**2, axis=0))
    return np.maximum(rms, SIGMA_FLOOR * np.asarray(wrench_scale))


def iter_systems(model, q, qd, qdd, wrench, theta_known, max_frames: int = 200_000, channels=None):
    """``(slice, W (c, AF, n_u), y (c, AF))`` of chunks of configurations, about ``max_frames`` frames
    at a time (:func:`ineid.identify.systems.stack` of ``channels``, default the base wrench, which
    holds a whole chunk in memory); ``wrench`` (C, F, A) the channels' values."""
    from ineid.identify.systems import stack

    n_configs, n_frames = q.shape[:2]
    per = max(1, max_frames // max(n_frames, 1))
    for start in range(0, n_configs, per):
        sl = slice(start, min(start + per, n_configs))
        yield (sl, *stack(model, q[sl], qd[sl], qdd[sl], wrench[sl], theta_known, channels))


def fit_context(
    theta_fit: np.ndarray, sigma: np.ndarray, base, y_center: np.ndarray, y_scale: np.ndarray
) -> WlsContext:
    """The :class:`WlsContext` from training truth ``theta_fit`` (C, n_u) and the noise model ``sigma`` (A,), one per
    measured axis (the wrench: six).

    Args:
        base: the :class:`ineid.identify.BaseParameters` of the unknown links.
    """
    theta_fit = np.asarray(theta_fit, dtype=np.float64)
    mu_t, mu_b, gain = null_space_map(theta_fit, base.B)
    scale = base.scales[base.base_index]
    return WlsContext(
        base_index=np.asarray(base.base_index, dtype=np.int64),
        base_scale=np.asarray(scale, dtype=np.float64),
        mu_beta=mu_b,
        l_inv=_whitening(theta_fit @ base.B.T, scale),
        sigma=np.asarray(sigma, dtype=np.float64),
        mu_theta=mu_t,
        gain=gain,
        b=np.asarray(base.B, dtype=np.float64),
        y_center=np.asarray(y_center, dtype=np.float64),
        y_scale=np.asarray(y_scale, dtype=np.float64),
    )


def wls_solve(a, e, d, p, g, m):
    """``u = argmin ||d * (e - A u)||^2 + ||g * (P u - m)||^2`` for a batch (see the module doc).

    Cholesky of the Jacobi-equilibrated normal matrix, then one refinement step from the
    residuals (corrected semi-normal equations). Differentiable in every argument.

    Args:
        a: (..., n, r) rows; e: (..., n) targets; d: (..., n) row weights (> 0).
        p: (r, r) prior rows; g: (..., r) prior weights (>= 0; zero: no prior);
        m: (..., r) the prior's target for ``P u``.

    Returns:
        (..., r). NaN where the normal matrix is singular (too few rows and no prior).
    """
    ad = a * d[..., :, None]
    pg = p * g[..., :, None]  # (..., r, r)
    n = jnp.einsum("...ni,...nj->...ij", ad, ad) + jnp.einsum("...ki,...kj->...ij", pg, pg)
    s = jax.lax.rsqrt(jnp.maximum(jnp.diagonal(n, axis1=-2, axis2=-1), jnp.finfo(n.dtype).tiny))
    chol = jnp.linalg.cholesky(n * s[..., :, None] * s[..., None, :])

    def solve(rhs):
        z = jax.scipy.linalg.solve_triangular(chol, (s * rhs)[..., None], lower=True)
        return s * jax.scipy.linalg.solve_triangular(chol, z, lower=True, trans="T")[..., 0]

    def gradient_rhs(u):  # A^T D (D (e - A u)) + P^T G (G (m - P u))
        rd = d * (e - jnp.einsum("...nr,...r->...n", a, u))
        rp = g * (m - jnp.einsum("kr,...r->...k", p, u))
        return jnp.einsum("...nr,...n->...r", ad, rd) + jnp.einsum("...kr,...k->...r", pg, rp)

    u0 = solve(gradient_rhs(jnp.zeros(a.shape[:-2] + a.shape[-1:], a.dtype)))
    return u0 + solve(gradient_rhs(u0))


def _soft_bound(x):
    return LOG_WEIGHT_RANGE * jnp.tanh(x / LOG_WEIGHT_RANGE)


class WLS(nn.Module):
    """Learned weighted least squares with a learned prior; (B, K, F), (B, K, A, n_u), (B, K, A) -> (B, n_u).

    ``A`` is the measured axes of a frame (the base wrench: six; the context's ``sigma`` has one per axis).

    Inputs: ``x`` the K frames' scaled features (as every ineid network takes), ``psi_u``
    the unknown links' regressor of each frame and ``y`` its wrench minus the known links'
    share (SI). Output: the scaled standard parameters (the run's target scaler), like the
    other networks, so the MSE and physics losses apply unchanged.

    Attributes:
        hidden: widths of the per-frame encoder's hidden layers.
        context: the constants fitted on the training split.
        activation: of the hidden layers.
        prior: learn a prior (False: ``Gamma = 0``, the weighted least squares alone).
    """

    hidden: Sequence[int]
    context: WlsContext
    activation: str = "tanh"
    prior: bool = True

    @nn.compact
    def __call__(self, x, psi_u, y):
        c = self.context
        act = ACTIVATIONS[self.activation]
        idx = jnp.asarray(c.base_index)
        bsz, k = x.shape[:2]
        r = c.rank
        n_axes = len(c.sigma)
        w_b = jnp.take(psi_u, idx, axis=-1)  # (B, K, A, r)
        a = (w_b * jnp.asarray(c.base_scale)).reshape(bsz, n_axes * k, r)
        e = (y - w_b @ jnp.asarray(c.mu_beta)).reshape(bsz, n_axes * k)
        inv_sigma = jnp.tile(1.0 / jnp.asarray(c.sigma), k)  # frame-major rows, the axes (fx..mz) per frame
        d0 = jnp.broadcast_to(inv_sigma, (bsz, n_axes * k))
        p = jnp.asarray(c.prior_rows)
        g0 = jnp.full((bsz, r), 1.0 if self.prior else 0.0)
        zero_m = jnp.zeros((bsz, r))
        u0 = wls_solve(a, e, d0, p, g0, zero_m)  # the Gaussian-prior (or weighted LS) estimate
        r0 = ((e - jnp.einsum("bnr,br->bn", a, u0)) * d0).reshape(bsz, k, n_axes)  # normalized residuals
        feats = jnp.concatenate([x, r0, jnp.log1p(r0 * r0)], axis=-1)
        h = Encoder(tuple(self.hidden), self.activation, name="encoder")(feats)  # (B, K, H): shared weights
        zeros = nn.initializers.zeros
        delta = _soft_bound(nn.Dense(n_axes, param_dtype=jnp.float64, kernel_init=zeros, name="log_weight")(h))
        d = d0 * jnp.exp(delta).reshape(bsz, n_axes * k)
        if self.prior:
            v0 = u0 @ p.T  # whitened first estimate
            pooled = jnp.concatenate([h.mean(axis=1), v0], axis=-1)
            hh = act(nn.Dense(self.hidden[-1], param_dtype=jnp.float64, name="head_hidden")(pooled))
            out = nn.Dense(2 * r, param_dtype=jnp.float64, kernel_init=zeros, name="prior")(hh)
            m, g = out[:, :r], jnp.exp(_soft_bound(out[:, r:]))
        else:
            m, g = zero_m, jnp.zeros((bsz, r))
        u = wls_solve(a, e, d, p, g, m)
        theta = jnp.asarray(c.mu_theta) + (u * jnp.asarray(c.base_scale)) @ jnp.asarray(c.gain).T
        return (theta - jnp.asarray(c.y_center)) / jnp.asarray(c.y_scale)


def prior_estimate(
    context: WlsContext, w: np.ndarray, y: np.ndarray, prior: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The untrained model by another route: the Gaussian-prior (posterior-mean) estimate.

    ``beta = argmin ||D (y - W_b beta)||^2 + ||L^-1 (beta - mu_beta)||^2`` with
    ``D = diag(1 / sigma)`` per measured axis, by a QR factorization of the stacked weighted
    rows (NumPy, batched), and ``theta = mu_theta + G (beta - mu_beta)``. With
    ``prior=False`` it is the noise-weighted least squares.

    Args:
        context: the constants (prior, noise model, null-space rule).
        w: (C, AF, n_u) stacked regressors; y: (C, AF) measured values minus the known links' share.

    Returns:
        ``(theta (C, n_u), beta (C, r))``.
    """
    c, n, _ = w.shape
    wb = w[:, :, context.base_index]
    d = np.tile(1.0 / context.sigma, n // len(context.sigma))
    a = wb * context.base_scale * d[None, :, None]
    e = (y - wb @ context.mu_beta) * d
    if prior:
        a = np.concatenate([a, np.broadcast_to(context.prior_rows, (c,) + context.prior_rows.shape)], axis=1)
        e = np.concatenate([e, np.zeros((c, context.rank))], axis=1)
    q, r = np.linalg.qr(a)
    u = np.linalg.solve(r, np.einsum("cnr,cn->cr", q, e)[..., None])[..., 0]
    step = u * context.base_scale
    return context.mu_theta + step @ context.gain.T, context.mu_beta + step
