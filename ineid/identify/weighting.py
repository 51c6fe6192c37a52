"""Row weights per measured axis estimated from the residuals, and the covariance that goes with them.

``weights="estimate"`` (the default) is feasible weighted least squares: the noise of each
measured axis ``a`` (``A`` axes a frame, six for the base wrench) is estimated from the
residuals, the rows are weighted by ``d_a = 1 / sigma_a`` and refitted, :data:`ESTIMATE_ROUNDS`
times from an unweighted fit. Two things make the reported covariance honest where a
plain ``(W_b^T D^2 W_b)^-1`` is not:

**The degrees of freedom of each axis.** At weights ``D`` the residuals of axis ``a`` satisfy
``E[rss_a] = sigma_a^2 (F_a - h_a)`` with ``h_a = d_a^2 tr(G_a (W_b^T D^2 W_b)^-1)`` the
axis's share of the leverage (``sum_a h_a = r``) and ``F_a`` its frames (less one where an
offset was taken out): exact for the true weights, whatever ``G_a``. The leverage is far
from equal: on ``sweaty-arm`` with per-axis noise 13.5 of the 17 base parameters' leverage
sits on ``mx``. Dividing by ``F - r/A`` instead (what ineid 0.2 did) underestimated the
noise of the informative axes, over-weighted them and reported standard deviations 8 %
too small (50 % at 10 frames).

**The weights are estimates.** With estimated weights the estimator's covariance exceeds
``V = (W_b^T D^2 W_b)^-1``, and ``V`` computed from the estimated weights is itself biased
low, each by ``V Q V`` to first order (Kackar & Harville 1984; Kenward & Roger 1997, their
``Phi_A`` for a covariance linear in the variances ``sigma_a^2``):

    cov(beta_hat) ~ V + 2 V Q V,     Q = sum_ab C_ab (delta_ab P_a - P_a V P_b),   P_a = d_a^2 G_a

with ``C`` the covariance of the relative variance estimates ``sigma_hat_a^2 / sigma_a^2``,
the inverse of the REML information ``I_ab = (delta_ab (F_a - 2 h_a) + tr(P_a V P_b V)) / 2``.
Everything comes from the per-axis blocks ``G_a`` (:mod:`ineid.identify.fused`): nothing
new is read from the frames.

What remains is that a standard deviation estimated from ``nu`` residual degrees of freedom
makes ``error / std`` a Student-t variable, whose spread is ``sqrt(nu / (nu - 2))``: about
1.015 at 80 frames, 1.15 at 20 (``docs/identification.md`` has the Monte Carlo).
"""

from __future__ import annotations

import numpy as np

ESTIMATE_ROUNDS = 5
"""Reweighting rounds of ``weights="estimate"`` after the unweighted fit. A few rounds, not
iteration to convergence: with few frames the converged (REML) weights feed back on the
residuals they came from (an axis that happened to fit well gets more weight and fits
better still), and the z-spread at 20 frames grew from 1.05 (5 rounds) to 1.25 (converged)
in the Monte Carlo of ``docs/identification.md``; from about 40 frames both agree."""
SIGNAL_FLOOR = 1e-8
"""An axis's estimated noise is at least this share of its own RMS signal: on noise-free data
the residuals are round-off, and weights from round-off would only make the fit
ill-conditioned."""


def axis_leverage(g: np.ndarray, axis_w: np.ndarray, a_inv: np.ndarray) -> np.ndarray:
    """(C, A) each axis's share of the leverage, ``h_a = d_a^2 tr(G_a A^-1)`` (``sum_a h_a = r``).

    Args:
        g: (C, A, r, r) per-axis blocks ``G_a = W_b[:, a]^T W_b[:, a]``.
        axis_w: (C, A) row weights ``d_a``.
        a_inv: (C, r, r) the inverse of ``A = sum_a d_a^2 G_a``.
    """
    return axis_w**2 * np.einsum("cars,csr->ca", g, a_inv)


def estimated_axis_weights(
    axis_rss: np.ndarray,
    g: np.ndarray,
    axis_w: np.ndarray,
    a_inv: np.ndarray,
    axis_frames: np.ndarray,
    axis_signal: np.ndarray,
) -> np.ndarray:
    """(C, A) new row weights ``1 / sigma_a`` with ``sigma_a^2 = rss_a / (F_a - h_a)``.

    Args:
        axis_rss: (C, A) unweighted residual sum of squares per axis of the fit at ``axis_w``.
        g, axis_w, a_inv: as in :func:`axis_leverage` (the fit's weights and information).
        axis_frames: (A,) or (C, A) ``F_a``: frames per axis, less one on axes whose offset
            was taken out (per recording fitted).
        axis_signal: (C, A) ``sum y_a^2`` of the fitted (centred) data: the floor
            :data:`SIGNAL_FLOOR` is relative to its RMS.
    """
    frames = np.broadcast_to(np.asarray(axis_frames, dtype=np.float64), axis_rss.shape)
    nu = np.maximum(frames - axis_leverage(g, axis_w, a_inv), 1.0)  # an axis the fit absorbs whole: >= 1
    sig = np.sqrt(np.maximum(axis_rss / nu, 0.0))
    floor = SIGNAL_FLOOR * np.sqrt(np.maximum(axis_signal, 0.0) / np.maximum(frames, 1.0))
    sig = np.maximum(sig, floor)
    sig = np.maximum(sig, 1e-9 * np.max(sig, axis=1, keepdims=True))  # an axis without signal or noise
    return 1.0 / np.maximum(sig, 1e-300)


def estimated_weights_inflation(
    g: np.ndarray, axis_w: np.ndarray, a_inv: np.ndarray, axis_frames: np.ndarray
) -> np.ndarray:
    """(C, r, r) ``2 V Q V``: what estimating the weights adds to ``V = A^-1`` (module doc).

    Args:
        g, axis_w, a_inv: as in :func:`axis_leverage`, at the final weights.
        axis_frames: (A,) or (C, A) ``F_a`` as in :func:`estimated_axis_weights`.
    """
    c, n_axes = axis_w.shape
    frames = np.broadcast_to(np.asarray(axis_frames, dtype=np.float64), (c, n_axes))
    out = np.empty_like(a_inv)
    for i in range(0, c, CHUNK):  # (CHUNK, A, r, r) temporaries stay in cache
        sl = slice(i, i + CHUNK)
        out[sl] = _inflation(g[sl], axis_w[sl], a_inv[sl], frames[sl])
    return out


CHUNK = 256
"""Configurations per batch of :func:`estimated_weights_inflation`."""


def _inflation(g, axis_w, a_inv, frames):
    n_axes = axis_w.shape[1]
    p = axis_w[:, :, None, None] ** 2 * g  # P_a (C, A, r, r)
    m = np.matmul(p, a_inv[:, None])  # P_a V
    h = np.trace(m, axis1=2, axis2=3)
    info = 0.5 * (np.einsum("cars,cbsr->cab", m, m) + np.eye(n_axes)[None] * (frames - 2.0 * h)[:, :, None])
    cw = np.linalg.pinv(info, hermitian=True)  # an axis the fit absorbs whole has no information
    n = np.einsum("cab,cbrs->cars", cw, p)  # N_a = sum_b C_ab P_b
    q = np.einsum("ca,cars->crs", np.diagonal(cw, axis1=1, axis2=2), p) - np.matmul(m, n).sum(axis=1)
    q = 0.5 * (q + np.swapaxes(q, -1, -2))
    return 2.0 * a_inv @ q @ a_inv
