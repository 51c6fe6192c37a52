"""The least-squares fit of the base parameters, with row weights per measured axis.

With the known links' share subtracted, the frames of a configuration give
``y = W theta + e``. Only the base parameters ``beta = B theta`` reach the data
(:mod:`ineid.identify.identifiability`), and ``W theta = W_b beta`` with ``W_b`` the base
columns, so

    beta_hat = argmin || D (W_b beta - y) ||^2         (QR of D W_b)

with ``D`` row weights, one per measured axis (``A`` a frame: the stacked axes of
the measurement channels, six for the base wrench): estimated from the residuals per axis
(the default, below: an unweighted fit, then :data:`ESTIMATE_ROUNDS` reweighted refits),
``1/sigma_axis`` from known noise levels, or none (equal noise on every axis assumed). The
residual variance ``s^2 = ||D r||^2 / (AF - r)`` gives ``cov(beta_hat) = s^2 (R^T R)^-1``, plus,
for estimated weights, what estimating them adds (:func:`estimated_weights_inflation`). The
standard parameters come from ``beta_hat`` by a rule (:mod:`ineid.identify.linear`) or a solver.

**Two routes, the same numbers.** :func:`fit_base` factors the stacked ``D W_b`` (QR); it
is the reference. :func:`fit_base_blocks` solves the normal equations
``(W_b^T D^2 W_b) beta = W_b^T D^2 y`` from per-axis blocks that a fused kernel accumulates
without forming the stacks (:mod:`ineid.identify.fused`): one batched Cholesky
factorization of the column-scaled information matrix, its eigenvalues for the rank and
condition checks, and reweighting rounds that reuse the blocks. Normal equations lose
``cond^2`` where QR loses ``cond``, so a configuration whose scaled base regressor has a
condition number above :data:`NORMAL_MAX_COND` (or is rank-deficient) is flagged, and
:func:`ineid.identify.steps.fused_fit` refits it through the reference; below it the two
agree to about ``1e-10`` relative in the scaled parameters (``eps * cond^2``).

**Estimated weights** (``weights="estimate"``, the default) are feasible weighted least
squares: the noise of each measured axis ``a`` is estimated from the residuals, the rows are
weighted by ``d_a = 1 / sigma_a`` and refitted, :data:`ESTIMATE_ROUNDS` times from an unweighted
fit. Two things make the reported covariance honest where a plain ``(W_b^T D^2 W_b)^-1`` is not:

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

All of this assumes independent frames. A filtered recording's residuals are correlated in time, and the
covariance of its fits comes from :mod:`ineid.identify.time_correlation` (each axis's long-run variance, and
the filter's own error), which sets :attr:`BaseFit.axis_long_run`.

What remains is that a standard deviation estimated from ``nu`` residual degrees of freedom
makes ``error / std`` a Student-t variable, whose spread is ``sqrt(nu / (nu - 2))``: about
1.015 at 80 frames, 1.15 at 20 (``docs/identification.md`` has the Monte Carlo).

References:
    Gautier & Khalil (1990); Khalil & Dombre (2002), ch. 12; Kackar & Harville (1984); Kenward & Roger (1997).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ineid.identify.identifiability import BaseParameters, numerical_rank
from ineid.identify.settings import WEIGHT_MODES

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


NORMAL_MAX_COND = 1e3
"""Largest condition number of the scaled base regressor solved through the normal
equations (error ``~ eps * cond^2 <= 2e-10``); above it, through QR of the stacks."""


@dataclass
class BaseFit:
    """Least-squares fit of the base parameters for a batch of configurations.

    ``||D (W_b beta - y)||^2 = ||R (beta - beta_hat)||^2 + rss`` for any ``beta``: the
    nonlinear and consistent solvers minimize over ``beta = B theta(x)`` with this form.

    Attributes:
        beta: (C, r) estimates.
        R: (C, r, r) upper-triangular factor of the weighted base regressor.
        rss: (C,) weighted residual sum of squares.
        dof: degrees of freedom ``AF - r`` (less the offsets, when identified).
        sigma2: (C,) residual variance in weighted units (1 when weights are exact).
        cov_beta: (C, r, r).
        rank: (C,) numerical rank of the base columns for these frames.
        cond: (C,) condition number of the scaled base regressor (exact from QR; from the
            normal equations an upper bound at most ``sqrt(r)`` above it; inf when not
            full rank).
        axis_weights: (C, A) the row weights ``D`` per measured axis.
        axis_long_run: (C, A) each axis's long-run variance (its residuals' autocovariances summed,
            :mod:`ineid.identify.time_correlation`) over its variance, for frames correlated in time
            (a filtered recording); None: independent frames.
    """

    beta: np.ndarray
    R: np.ndarray
    rss: np.ndarray
    dof: int
    sigma2: np.ndarray
    cov_beta: np.ndarray
    rank: np.ndarray
    cond: np.ndarray
    axis_weights: np.ndarray
    axis_long_run: np.ndarray | None = None

    @property
    def full_rank(self) -> np.ndarray:
        return self.rank == self.beta.shape[1]


def _weighted_fit(w_b: np.ndarray, y: np.ndarray, axis_w: np.ndarray, base_scales: np.ndarray):
    c, n, r = w_b.shape
    rows = np.tile(axis_w, (1, n // axis_w.shape[1]))  # (C, N): frame-major rows, the axes per frame
    a = w_b * rows[:, :, None]
    b = y * rows
    q, rr = np.linalg.qr(a)
    z = np.einsum("cnr,cn->cr", q, b)
    sv = np.linalg.svd(rr * base_scales[None, None, :], compute_uv=False)
    rank = np.array([numerical_rank(s) for s in sv])
    ok = rank == r
    safe_r = np.where(ok[:, None, None], rr, np.eye(r)[None])
    beta = np.linalg.solve(safe_r, z[..., None])[..., 0]
    beta[~ok] = np.nan
    resid = b - np.einsum("cnr,cr->cn", a, np.nan_to_num(beta))
    rss = np.einsum("cn,cn->c", resid, resid)
    cond = np.where(ok, sv[:, 0] / np.maximum(sv[:, -1], 1e-300), np.inf)
    return beta, safe_r, rss, rank, cond, resid


def axis_weights(weights: str, axis_sigma, c: int, n_axes: int = 6) -> np.ndarray:
    """(C, A) row weights ``d_a`` of a weight mode before any fit: ones, or ``1 / sigma_a`` for ``noise``
    (``estimate`` starts from ones); ``A = n_axes``."""
    if weights not in WEIGHT_MODES:
        raise ValueError(f"weights must be one of {WEIGHT_MODES}, got {weights!r}")
    if weights != "noise":
        return np.ones((c, n_axes))
    if axis_sigma is None:
        raise ValueError("weights='noise' needs axis_sigma, the noise per measured axis")
    try:
        sig = np.broadcast_to(np.asarray(axis_sigma, dtype=np.float64), (c, n_axes))
    except ValueError:
        raise ValueError(
            f"axis_sigma must hold {n_axes} numbers (one per measured axis), got {np.asarray(axis_sigma).tolist()}"
        ) from None
    if np.any(sig <= 0) or not np.all(np.isfinite(sig)):
        raise ValueError(f"axis_sigma must be positive and finite, got {np.asarray(axis_sigma).tolist()}")
    return 1.0 / sig


def fit_base(
    w: np.ndarray,
    y: np.ndarray,
    base: BaseParameters,
    weights: str = "estimate",
    axis_sigma: np.ndarray | None = None,
    n_axes: int = 6,
    axis_offsets: np.ndarray | None = None,
) -> BaseFit:
    """Least-squares base parameters of each configuration.

    Args:
        w: (C, AF, 10 n_u) stacked regressors of the unknown links (:func:`ineid.identify.systems.stack`).
        y: (C, AF) measured values minus the known links' share.
        base: the base parameters (which columns, which combinations).
        weights: ``"estimate"``: per-axis noise estimated from an unweighted fit, then refit
            (module doc); ``"noise"``: rows weighted by ``1/axis_sigma``;
            ``"none"``: equal noise on every axis assumed.
        axis_sigma: (A,) or (C, A) noise standard deviations per measured axis, for ``"noise"``.
        n_axes: ``A``, the measured axes a frame (six: the base wrench).
        axis_offsets: (A,) offsets taken out of each axis before the fit (the frames centred:
            1 per recording on axes with offsets), each one residual degree of freedom of that
            axis; None: none.
    """
    c, n, _ = w.shape
    axis_w = axis_weights(weights, axis_sigma, c, n_axes)
    r = base.rank
    w_b = w[:, :, base.base_index]
    scales_b = base.scales[base.base_index]
    beta, rr, rss, rank, cond, resid = _weighted_fit(w_b, y, axis_w, scales_b)
    dof = n - r
    frames = axis_frames(n // n_axes, n_axes, axis_offsets)
    g = None
    if weights == "estimate" and dof > 0:
        # Feasible weighted least squares (module doc): per-axis noise from the
        # residuals with each axis's own degrees of freedom, refit, a few rounds.
        w4 = w_b.reshape(c, n // n_axes, n_axes, r)
        g = np.einsum("cfar,cfas->cars", w4, w4)
        signal = np.einsum("cfa,cfa->ca", y.reshape(c, -1, n_axes), y.reshape(c, -1, n_axes))
        for _ in range(ESTIMATE_ROUNDS):
            per_axis = resid.reshape(c, n // n_axes, n_axes) / axis_w[:, None, :]
            axis_w = estimated_axis_weights(
                np.einsum("cfa,cfa->ca", per_axis, per_axis), g, axis_w, r_inverse(rr), frames, signal
            )
            beta, rr, rss, rank, cond, resid = _weighted_fit(w_b, y, axis_w, scales_b)
    return triangular_fit(beta, rr, rss, dof, rank, cond, axis_w, g, frames)


def triangular_fit(beta, rr, rss, dof: int, rank, cond, axis_w, g: np.ndarray | None, frames) -> BaseFit:
    """The :class:`BaseFit` of a weighted fit by its triangular factor ``rr`` (C, r, r): ``sigma2 = rss / dof``,
    ``cov = sigma2 (R^T R)^-1`` plus, with estimated weights (``g``: the per-axis blocks (C, A, r, r), ``frames``:
    each axis's degrees of freedom), what estimating them adds; NaN where the rank is short."""
    sigma2 = rss / max(dof, 1)
    a_inv = r_inverse(rr)
    if g is not None:
        a_inv = a_inv + estimated_weights_inflation(g, axis_w, a_inv, frames)
    cov = sigma2[:, None, None] * a_inv
    cov[rank < rr.shape[-1]] = np.nan
    return BaseFit(beta, rr, rss, dof, sigma2, cov, rank, cond, axis_w)


def r_inverse(rr: np.ndarray) -> np.ndarray:
    """``(R^T R)^-1`` of upper-triangular factors (C, r, r)."""
    r_inv = np.linalg.solve(rr, np.broadcast_to(np.eye(rr.shape[-1]), rr.shape))
    return r_inv @ np.swapaxes(r_inv, -1, -2)


def axis_frames(n_frames: int, n_axes: int, axis_offsets: np.ndarray | None) -> np.ndarray:
    """(A,) ``F_a``: the frames of each axis less the offsets taken out of it."""
    frames = np.full(n_axes, float(n_frames))
    return frames if axis_offsets is None else frames - np.asarray(axis_offsets, dtype=np.float64)


NORMAL_CHUNK = 256
"""Configurations per batched solve in :func:`_normal_fit`: the temporaries (a few
``256 x r x r`` arrays) stay in cache instead of faulting in fresh memory for every step."""


def _normal_fit(blocks, axis_w: np.ndarray, scales_b: np.ndarray):
    """:func:`_normal_fit_chunk` over chunks of :data:`NORMAL_CHUNK` configurations."""
    c = blocks.e.shape[0]
    if c <= NORMAL_CHUNK:
        return _normal_fit_chunk(blocks, axis_w, scales_b)
    parts = [
        _normal_fit_chunk(blocks.select(slice(i, i + NORMAL_CHUNK)), axis_w[i : i + NORMAL_CHUNK], scales_b)
        for i in range(0, c, NORMAL_CHUNK)
    ]
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def _normal_fit_chunk(blocks, axis_w: np.ndarray, scales_b: np.ndarray):
    """One weighted solve of the normal equations of every configuration (column-scaled).

    ``A_s = S A S = L L^T`` (Cholesky), ``beta = S A_s^-1 S b``, ``R = L^T S^-1`` (upper
    triangular, ``R^T R = A``), ``rss = y^T D^2 y - 2 beta.b + beta^T A beta``. The
    condition number of the scaled regressor is estimated as
    ``sqrt(||A_s||_1 ||A_s^-1||_1)``, an upper bound (symmetric ``A_s``: ``||.||_2 <=
    ||.||_1``) at most ``sqrt(r)`` above the true one; rows where it exceeds
    :data:`NORMAL_MAX_COND`, or where the Cholesky factorization fails, are flagged and
    get placeholders (the identity for ``A_s``, NaN estimates).
    """
    a, b, yy = blocks.weighted(axis_w)
    c, r = b.shape
    a_s = a * scales_b[None, :, None] * scales_b[None, None, :]
    b_s = b * scales_b
    eye = np.eye(r)[None]
    finite = np.all(np.isfinite(a_s), axis=(1, 2)) & np.isfinite(yy)
    a_s = np.where(finite[:, None, None], a_s, eye)
    try:
        chol = np.linalg.cholesky(a_s)
        pd = np.ones(c, dtype=bool)
    except np.linalg.LinAlgError:  # some not positive definite: find them one by one
        pd = np.array([_is_positive_definite(m) for m in a_s])
        chol = np.linalg.cholesky(np.where(pd[:, None, None], a_s, eye))
    l_inv = np.linalg.inv(chol)
    a_s_inv = np.swapaxes(l_inv, -1, -2) @ l_inv
    norm1 = np.abs(a_s).sum(axis=1).max(axis=1) * np.abs(a_s_inv).sum(axis=1).max(axis=1)
    cond = np.sqrt(norm1)
    ok = finite & pd & (cond <= NORMAL_MAX_COND)
    if not np.all(ok):
        bad = ~ok
        a_s[bad], chol[bad], a_s_inv[bad] = eye, eye, eye
        cond[bad] = np.inf
    beta_s = np.matmul(a_s_inv, b_s[:, :, None])[..., 0]
    beta = beta_s * scales_b
    quad = np.matmul(beta_s[:, None, :], np.matmul(a_s, beta_s[:, :, None]))[:, 0, 0]
    rss = np.maximum(yy - 2.0 * np.sum(beta_s * b_s, axis=1) + quad, 0.0)
    rr = np.swapaxes(chol, -1, -2) / scales_b[None, None, :]
    a_inv = a_s_inv * scales_b[None, :, None] * scales_b[None, None, :]
    beta[~ok] = np.nan
    rank = np.where(ok, r, -1)  # flagged rows: the reference fit supplies the rank
    return beta, rr, rss, rank, cond, a_inv, ~ok


def _is_positive_definite(m: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return False
    return True


def fit_base_blocks(
    blocks,
    base: BaseParameters,
    weights: str = "estimate",
    axis_sigma: np.ndarray | None = None,
    axis_offsets: np.ndarray | None = None,
) -> tuple[BaseFit, np.ndarray]:
    """:func:`fit_base` from per-axis normal-equation blocks (:func:`ineid.identify.fused.information_blocks`).

    The same estimates as :func:`fit_base` on the stacks the blocks summarize (to about
    1e-10 relative in the scaled parameters), from ``A r^2`` numbers per configuration:
    ``A = sum_a d_a^2 G_a``, ``b = sum_a d_a^2 h_a``, solved by one batched Cholesky
    factorization; ``weights="estimate"`` reweights from the per-axis residual sums
    ``e_a - 2 beta.h_a + beta^T G_a beta`` and the leverage ``d_a^2 tr(G_a A^-1)`` without
    touching the frames again.

    Args:
        blocks: an :class:`ineid.identify.fused.InformationBlocks` of C configurations.
        base, weights, axis_sigma, axis_offsets: as in :func:`fit_base`.

    Returns:
        ``(fit, refit)``: the fit, and a (C,) mask of configurations whose normal equations
        are rank-deficient or have a condition number above :data:`NORMAL_MAX_COND` in any
        round; their rows of ``fit`` are placeholders (NaN estimates) to be replaced by
        :func:`fit_base` on their stacks.
    """
    c, n_axes = blocks.e.shape
    axis_w = axis_weights(weights, axis_sigma, c, n_axes)
    r = base.rank
    n = n_axes * blocks.n_frames
    scales_b = base.scales[base.base_index]
    beta, rr, rss, rank, cond, a_inv, refit = _normal_fit(blocks, axis_w, scales_b)
    dof = n - r
    estimated = weights == "estimate" and dof > 0
    frames = axis_frames(blocks.n_frames, n_axes, axis_offsets)
    if estimated:
        for _ in range(ESTIMATE_ROUNDS):
            axis_w = estimated_axis_weights(
                blocks.axis_rss(np.nan_to_num(beta)), blocks.G, axis_w, a_inv, frames, blocks.e
            )
            beta, rr, rss, rank, cond, a_inv, bad = _normal_fit(blocks, axis_w, scales_b)
            refit |= bad
        a_inv = a_inv + estimated_weights_inflation(blocks.G, axis_w, a_inv, frames)
    sigma2 = rss / max(dof, 1)
    cov = sigma2[:, None, None] * a_inv
    cov[refit] = np.nan
    return BaseFit(beta, rr, rss, dof, sigma2, cov, rank, cond, axis_w), refit


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


def with_exact_rss(fit: BaseFit, axis_rss: np.ndarray) -> BaseFit:
    """``fit`` with ``rss = sum_a d_a^2 axis_rss_a`` and the variance and covariance that follow.

    ``axis_rss`` (C, A): per measured axis, the residual sum of squares of the fitted frames
    at the estimate, evaluated directly (:func:`ineid.identify.fused.residual_sums`), where
    the normal equations only give ``y^T D^2 y - beta^T b``, a difference that loses
    ``eps * ||D y||^2`` (all of it on noise-free data). Rows that are not full rank are kept.
    """
    ok = fit.full_rank & np.all(np.isfinite(axis_rss), axis=1)
    rss = fit.rss.copy()
    rss[ok] = np.einsum("ca,ca->c", fit.axis_weights[ok] ** 2, axis_rss[ok])
    sigma2 = rss / max(fit.dof, 1)
    # cov = sigma^2 (R^T R)^-1: rescale where the old sigma^2 was positive, else invert R
    scale = np.divide(sigma2, fit.sigma2, out=np.ones_like(sigma2), where=ok & (fit.sigma2 > 0))
    cov = fit.cov_beta * scale[:, None, None]
    redo = ok & ~(fit.sigma2 > 0)
    if np.any(redo):
        r_inv = np.linalg.inv(fit.R[redo])
        cov[redo] = sigma2[redo, None, None] * (r_inv @ np.swapaxes(r_inv, -1, -2))
    return dataclasses.replace(fit, rss=rss, sigma2=sigma2, cov_beta=cov)


def subtract_offset_dof(fit: BaseFit, n_offsets: int = 6) -> None:
    """Count ``n_offsets`` more fitted unknowns in ``fit``, in place (the offsets; six for the base wrench):
    ``s^2 = rss / (AF - r - n_offsets)``, covariance alike."""
    scale = fit.dof / max(fit.dof - n_offsets, 1)
    fit.dof -= n_offsets
    fit.sigma2 *= scale
    fit.cov_beta *= scale


def concat_fits(fits: list[BaseFit]) -> BaseFit:
    """One :class:`ineid.identify.linear.BaseFit` of the configurations of ``fits``, in order (one ``dof``)."""
    if len(fits) == 1:
        return fits[0]
    cat = {
        f.name: np.concatenate([getattr(x, f.name) for x in fits])
        for f in dataclasses.fields(BaseFit)
        if f.name != "dof" and getattr(fits[0], f.name) is not None
    }
    return BaseFit(dof=fits[0].dof, **cat)
