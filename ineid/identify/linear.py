"""Linear identification: base parameters by least squares, standard ones by a prior rule.

With the known links' share subtracted, the frames of a configuration give
``y = W theta + e``. Only the base parameters ``beta = B theta`` reach the data
(:mod:`ineid.identify.identifiability`), and ``W theta = W_b beta`` with ``W_b`` the base
columns, so

    beta_hat = argmin || D (W_b beta - y) ||^2         (QR of D W_b)

with ``D`` optional row weights, one per wrench axis: ``1/sigma_axis`` from known noise
levels, or estimated from the residuals per axis (an unweighted fit, then
``ESTIMATE_ROUNDS`` reweighted refits). The residual
variance ``s^2 = ||D r||^2 / (6F - r)`` gives ``cov(beta_hat) = s^2 (R^T R)^-1``.

**Null-space rule.** The standard parameters are the solution closest to a prior
(default: the CAD values) in the scaled metric, among all that reproduce ``beta_hat``:

    theta_hat = argmin || (theta - theta_prior) / scale ||   s.t.   B theta = beta_hat
              = theta_prior + T (beta_hat - B theta_prior),   T = S (B S)^+

with ``S = diag(scale)`` (:func:`ineid.identify.systems.parameter_scales`). Individually
identifiable parameters do not depend on the prior; their standard deviations are
``sqrt(diag(T cov(beta) T^T))``; the others get NaN, because the data say nothing about them.

References:
    Gautier & Khalil (1990); Khalil & Dombre (2002), ch. 12; Atkeson, An, Hollerbach (1986).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.identify.identifiability import BaseParameters, numerical_rank

WEIGHT_MODES = ("none", "noise", "estimate")
ESTIMATE_ROUNDS = 3
"""Reweighting rounds of ``weights="estimate"``."""


@dataclass
class BaseFit:
    """Least-squares fit of the base parameters for a batch of configurations.

    ``||D (W_b beta - y)||^2 = ||R (beta - beta_hat)||^2 + rss`` for any ``beta``: the
    nonlinear and consistent solvers minimize over ``beta = B theta(x)`` with this form.

    Attributes:
        beta: (C, r) estimates.
        R: (C, r, r) upper-triangular factor of the weighted base regressor.
        rss: (C,) weighted residual sum of squares.
        dof: degrees of freedom ``6F - r``.
        sigma2: (C,) residual variance in weighted units (1 when weights are exact).
        cov_beta: (C, r, r).
        rank: (C,) numerical rank of the base columns for these frames.
        cond: (C,) condition number of the scaled base regressor.
        axis_weights: (C, 6) the row weights ``D`` per wrench axis.
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

    @property
    def full_rank(self) -> np.ndarray:
        return self.rank == self.beta.shape[1]


def _weighted_fit(w_b: np.ndarray, y: np.ndarray, axis_w: np.ndarray, base_scales: np.ndarray):
    c, n, r = w_b.shape
    rows = np.tile(axis_w, (1, n // 6))  # (C, N): frame-major rows, fx..mz per frame
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


def fit_base(
    w: np.ndarray,
    y: np.ndarray,
    base: BaseParameters,
    weights: str = "none",
    axis_sigma: np.ndarray | None = None,
) -> BaseFit:
    """Least-squares base parameters of each configuration.

    Args:
        w: (C, 6F, 10 n_u) stacked regressors of the unknown links.
        y: (C, 6F) measured wrenches minus the known links' share.
        base: the base parameters (which columns, which combinations).
        weights: ``"none"``; ``"noise"``: rows weighted by ``1/axis_sigma``;
            ``"estimate"``: per-axis noise estimated from an unweighted fit, then refit.
        axis_sigma: (6,) or (C, 6) wrench noise standard deviations, for ``"noise"``.
    """
    if weights not in WEIGHT_MODES:
        raise ValueError(f"weights must be one of {WEIGHT_MODES}, got {weights!r}")
    c, n, _ = w.shape
    r = base.rank
    w_b = w[:, :, base.base_index]
    scales_b = base.scales[base.base_index]
    axis_w = np.ones((c, 6))
    if weights == "noise":
        if axis_sigma is None:
            raise ValueError("weights='noise' needs axis_sigma, the wrench noise per axis")
        sig = np.broadcast_to(np.asarray(axis_sigma, dtype=np.float64), (c, 6))
        if np.any(sig <= 0) or not np.all(np.isfinite(sig)):
            raise ValueError(f"axis_sigma must be positive and finite, got {np.asarray(axis_sigma).tolist()}")
        axis_w = 1.0 / sig
    beta, rr, rss, rank, cond, resid = _weighted_fit(w_b, y, axis_w, scales_b)
    dof = n - r
    if weights == "estimate" and dof > 0:
        # Feasible weighted least squares: per-axis noise from the residuals, refit,
        # repeat (a few rounds remove the leakage of noisy axes into the others' residuals).
        for _ in range(ESTIMATE_ROUNDS):
            per_axis = resid.reshape(c, n // 6, 6) / axis_w[:, None, :]
            ms = np.einsum("cfa,cfa->ca", per_axis, per_axis) / ((n // 6) * dof / n)
            sig = np.sqrt(np.maximum(ms, 1e-300))
            sig = np.maximum(sig, 1e-9 * np.max(sig, axis=1, keepdims=True))  # an axis that fits exactly
            axis_w = 1.0 / sig
            beta, rr, rss, rank, cond, resid = _weighted_fit(w_b, y, axis_w, scales_b)
    sigma2 = rss / max(dof, 1)
    r_inv = np.linalg.solve(rr, np.broadcast_to(np.eye(r), rr.shape))
    cov = sigma2[:, None, None] * r_inv @ np.swapaxes(r_inv, -1, -2)
    cov[rank < r] = np.nan
    return BaseFit(beta, rr, rss, dof, sigma2, cov, rank, cond, axis_w)


def prior_map(base: BaseParameters) -> np.ndarray:
    """``T = S (B S)^+`` (10 n_u, r): the null-space rule's map from base to standard parameters."""
    s = base.scales
    return s[:, None] * np.linalg.pinv(base.B * s[None, :])


def standard_from_base(beta: np.ndarray, base: BaseParameters, theta_prior: np.ndarray) -> np.ndarray:
    """``theta = theta_prior + T (beta - B theta_prior)``: closest to the prior, reproducing ``beta``.

    Args:
        beta: (..., r).
        theta_prior: (10 n_u,) or (..., 10 n_u).
    """
    t = prior_map(base)
    prior = np.asarray(theta_prior, dtype=np.float64)
    return prior + (beta - prior @ base.B.T) @ t.T


def standard_std(cov_beta: np.ndarray, base: BaseParameters) -> np.ndarray:
    """Standard deviations of the standard parameters; NaN where not identifiable. (C, 10 n_u)."""
    t = prior_map(base)
    var = np.einsum("pr,crs,ps->cp", t, cov_beta, t)
    std = np.sqrt(np.maximum(var, 0.0))
    std[:, ~base.identifiable] = np.nan
    return std


@dataclass
class Estimate:
    """Estimates of a batch of configurations, the same for every method.

    Attributes:
        theta: (C, 10 n_u) standard parameters of the unknown links (NaN where failed).
        theta_std: (C, 10 n_u) standard deviations, NaN where not identifiable.
        beta: (C, r) base parameters ``B theta``.
        beta_std: (C, r).
        success: (C,) bool.
        status: (C,) text: "ok", or why not (solver status, rank deficiency).
        fit: the base least-squares fit behind them.
    """

    theta: np.ndarray
    theta_std: np.ndarray
    beta: np.ndarray
    beta_std: np.ndarray
    success: np.ndarray
    status: np.ndarray
    fit: BaseFit


def linear_estimate(fit: BaseFit, base: BaseParameters, theta_prior: np.ndarray) -> Estimate:
    """Standard parameters from a base fit by the null-space rule (see module doc)."""
    theta = standard_from_base(np.nan_to_num(fit.beta), base, theta_prior)
    ok = fit.full_rank
    theta[~ok] = np.nan
    std = standard_std(np.nan_to_num(fit.cov_beta), base)
    std[~ok] = np.nan
    beta_std = np.sqrt(np.maximum(np.diagonal(fit.cov_beta, axis1=1, axis2=2), 0.0))
    status = np.where(ok, "ok", [f"rank_deficient ({k} of {base.rank})" for k in fit.rank]).astype(object)
    return Estimate(theta, std, fit.beta.copy(), beta_std, ok.copy(), status, fit)


def fit_base_casadi(w: np.ndarray, y: np.ndarray, base: BaseParameters, axis_w: np.ndarray | None = None):
    """One configuration's base fit through CasADi's QR (an independent route); (r,) beta.

    ``w`` (6F, 10 n_u) and ``y`` (6F,); ``axis_w`` (6,) optional row weights.
    """
    import casadi as ca  # noqa: PLC0415

    n = w.shape[0]
    rows = np.tile(np.ones(6) if axis_w is None else np.asarray(axis_w, dtype=np.float64), n // 6)
    a = ca.DM(w[:, base.base_index] * rows[:, None])
    b = ca.DM(y * rows)
    q, r = ca.qr(a)
    beta = ca.solve(r, ca.mtimes(q.T, b))
    return np.array(beta).ravel()
