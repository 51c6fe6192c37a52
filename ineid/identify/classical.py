"""The paper's classical solvers, as MATLAB ran them: ``lsqlin`` and ``lsqnonlin`` over every standard parameter.

The paper fits all ``10 n_u`` standard parameters of the unknown links, with no base parameters
and no prior, twice: linear least squares with the first moments ``m c`` as atomic unknowns
(MATLAB's ``lsqlin``), and nonlinear least squares with the mass, the centre of mass and the
inertia as separate unknowns (``lsqnonlin``, trust region from the CAD values). Both are rank
deficient: the regressor ``W`` of any frames has the structural rank ``r < 10 n_u``
(:mod:`ineid.identify.identifiability`), so the data decide only ``beta = B theta`` and each
solver lands, along the ``10 n_u - r`` null directions, where its own algorithm leaves it. They
are here as the paper's reference, not as the recommended path (``linear``, ``consistent``).

**The data term through the base fit.** For every ``theta``, ``W = W_b B`` gives
``||D (W theta - y)||^2 = ||R (B theta - beta_hat)||^2 + rss`` (:class:`ineid.identify.linear.BaseFit`:
``R`` the triangular factor of the weighted base columns, from the generated regressor through the
fused kernels). So both solvers work on the ``r``-row system ``A theta = b``, ``A = R B``,
``b = R beta_hat``, whatever the number of frames: the same objective, gradient ``J^T r`` and
Gauss-Newton matrix ``J^T J`` as on the ``AF`` rows of the frames, hence the same iterates, at a
cost that does not grow with the frames. ``D`` follows ``SolveSettings.weights``; the paper's
plain objective is ``weights="none"`` (on clean data every weighting gives the same fit).

* ``lsqlin`` (:func:`lsqlin_theta`): without bounds, the minimum-norm least-squares solution
  ``theta = W^+ y = B^+ beta_hat`` (the Euclidean norm in SI units, as MATLAB's ``lsqminnorm`` /
  ``pinv`` give it; ``W_b`` has full column rank, so the least-squares solutions are exactly
  ``B theta = beta_hat`` and the one of least norm is ``B^+ beta_hat``). An assumption: what
  MATLAB's ``lsqlin`` itself returns on a rank-deficient problem depends on its algorithm
  (backslash gives a basic solution with at most ``r`` nonzeros, the interior-point method
  another point of the solution set); the minimum norm is the one well-defined choice, and the
  one the issue names. With bounds (``lb <= theta <= ub``, :func:`cad_bounds`): bounded least
  squares by :func:`scipy.optimize.lsq_linear` (trust-region reflective, as MATLAB's
  ``lsqlin`` with bounds), per configuration.
* ``lsqnonlin`` (:func:`lsqnonlin_theta`): per link ``x = (m, c, I_C)``, ``theta(x) = (m, m c,
  I_C + m S(c)^T S(c))`` (the form of :mod:`ineid.identify.nlp`'s ``nonlinear``), the channels'
  extra parameters as they are; scipy's ``least_squares(method="trf")`` (MATLAB's
  trust-region-reflective default, no bounds, no scaling) from the CAD values, the exact
  Jacobian ``A dtheta/dx`` (:func:`theta_jacobian`), run for every configuration at once by
  :func:`trf`, scipy's iteration step for step in batched NumPy (the same iterates as
  :func:`scipy.optimize.least_squares`, ``engine="scipy"``, to round-off; some ten times
  faster, since scipy's loop costs milliseconds a step in Python). Tolerances :data:`LSQNONLIN_TOL`,
  far below MATLAB's defaults (1e-6), so that a fit stops at round-off and every spread of
  its standard parameters is the null space, not an early stop.

On clean data both fit the frames exactly (``B theta = beta_hat``, the wrench residual at
round-off) and their standard parameters differ from the truth along the null directions only:
the paper's "wide range of accuracies" of the inertia entries, explained by identifiability.
The standard deviations reported are those of the identifiable parameters (the same for every
point of the solution set); NaN elsewhere. ``lsqnonlin`` and the unbounded ``lsqlin`` fit ``beta_hat``
exactly, so theirs are the linear fit's; the bounded ``lsqlin``'s account for the bounds it stops at
(:mod:`ineid.identify.constrained_std`).

References:
    MathWorks, ``lsqlin`` and ``lsqnonlin`` (Optimization Toolbox); Coleman & Li (1996), An
    interior trust region approach for nonlinear minimization subject to bounds.
"""

from __future__ import annotations

import time

import numpy as np

from ineid.identify.constrained_std import constrained_cov
from ineid.identify.identifiability import BaseParameters
from ineid.identify.linear import BaseFit, Estimate, MethodEstimate, SharedFit, standard_std
from ineid.identify.settings import SolveSettings
from ineid.identify.systems import MASSLESS_KG
from ineid.params import N_PARAMS_PER_LINK
from ineid.progress import Progress

LSQNONLIN_TOL = 1e-14
"""``ftol``, ``xtol`` and ``gtol`` of ``lsqnonlin`` (scipy's trust region): a fit stops at round-off."""
LSQNONLIN_MAX_NFEV = 100
"""Function evaluations per configuration, per unknown (scipy's default ``100 n``; MATLAB's is ``100 n`` too)."""
_EPS = np.finfo(np.float64).eps
_PAIRS = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
"""Pinocchio's inertia entries (xx, xy, yy, xz, yz, zz) as index pairs."""


def cad_bounds(prior: np.ndarray, scales: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """``lb, ub = theta_cad -/+ fraction * max(|theta_cad|, scale)`` (n,), the box of ``lsqlin``'s bounds.

    Per parameter a band around its CAD value, relative to the value, or to the parameter's scale
    (:func:`ineid.identify.systems.parameter_scales`) where the CAD value is near zero (products of
    inertia, a centred first moment); the channels' extra parameters (prior 0) get their scale.
    """
    width = float(fraction) * np.maximum(np.abs(prior), scales)
    return prior - width, prior + width


def _box_system(fit: BaseFit, base: BaseParameters) -> tuple[np.ndarray, np.ndarray]:
    """``A = R B`` (C, r, n) and ``b = R beta_hat`` (C, r): the data term of every configuration."""
    a = np.einsum("crs,sn->crn", fit.R, base.B)
    b = np.einsum("crs,cs->cr", fit.R, np.nan_to_num(fit.beta))
    return a, b


def lsqlin_theta(
    fit: BaseFit, base: BaseParameters, bounds: tuple[np.ndarray, np.ndarray] | None = None, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's linear least squares over every standard parameter: ``theta`` (C, n) and ``status`` (C,).

    Without ``bounds``: ``theta = B^+ beta_hat``, the minimum-norm solution (module doc), one
    matrix product for every configuration. With ``bounds = (lb, ub)`` (n,): per configuration
    :func:`scipy.optimize.lsq_linear` on ``A theta = b`` (trust-region reflective), within the box.
    Configurations whose frames are rank deficient get NaN and ``"rank_deficient"``.
    """
    c = fit.beta.shape[0]
    status = np.array(["ok"] * c, dtype=object)
    status[~fit.full_rank] = "rank_deficient"
    theta = np.nan_to_num(fit.beta) @ np.linalg.pinv(base.B).T
    if bounds is not None:
        from scipy.optimize import lsq_linear

        lb, ub = (np.asarray(v, dtype=np.float64) for v in bounds)
        a, b = _box_system(fit, base)
        for i in range(c):
            if fit.full_rank[i]:
                sol = lsq_linear(
                    a[i], b[i], bounds=(lb, ub), method="trf", lsq_solver="exact", tol=1e-13, max_iter=1000
                )
                theta[i] = np.clip(sol.x, lb, ub)
                if sol.status <= 0:  # -1: failed; 0: max_iter reached
                    status[i] = f"lsqlin: {sol.message}"
            if progress is not None:
                progress(i + 1, c)
    theta[~fit.full_rank] = np.nan
    return theta, status


def theta_from_x(x: np.ndarray, n_links: int) -> np.ndarray:
    """``theta(x)`` (..., n): per link ``(m, m c, I_C + m S(c)^T S(c))`` from ``x = (m, c, I_C)``; the rest as is.

    ``x`` (..., n), per link ``[m, cx, cy, cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (kg, m, kg m^2; the
    inertia about the centre of mass, link axes), the channels' extra parameters after the links.
    """
    x = np.asarray(x, dtype=np.float64)
    theta = x.copy()
    k = N_PARAMS_PER_LINK * n_links
    links = x[..., :k].reshape(*x.shape[:-1], n_links, N_PARAMS_PER_LINK)
    m, c = links[..., 0], links[..., 1:4]
    cc = np.einsum("...i,...i->...", c, c)
    out = theta[..., :k].reshape(links.shape)
    out[..., 1:4] = m[..., None] * c
    for j, (a, b) in enumerate(_PAIRS):
        out[..., 4 + j] = links[..., 4 + j] + m * ((a == b) * cc - c[..., a] * c[..., b])
    theta[..., :k] = out.reshape(*x.shape[:-1], k)
    return theta


def x_from_theta(theta: np.ndarray, n_links: int) -> np.ndarray:
    """The inverse of :func:`theta_from_x`: ``c = (m c) / m`` (0 for a massless link), ``I_C = I_O - m S(c)^T S(c)``."""
    theta = np.asarray(theta, dtype=np.float64)
    x = theta.copy()
    k = N_PARAMS_PER_LINK * n_links
    links = theta[..., :k].reshape(*theta.shape[:-1], n_links, N_PARAMS_PER_LINK)
    m = links[..., 0]
    safe = np.where(np.abs(m) > MASSLESS_KG, m, 1.0)
    c = np.where((np.abs(m) > MASSLESS_KG)[..., None], links[..., 1:4] / safe[..., None], 0.0)
    cc = np.einsum("...i,...i->...", c, c)
    out = x[..., :k].reshape(links.shape)
    out[..., 1:4] = c
    for j, (a, b) in enumerate(_PAIRS):
        out[..., 4 + j] = links[..., 4 + j] - m * ((a == b) * cc - c[..., a] * c[..., b])
    x[..., :k] = out.reshape(*theta.shape[:-1], k)
    return x


def theta_jacobian(x: np.ndarray, n_links: int) -> np.ndarray:
    """``d theta / d x`` (..., n, n) of :func:`theta_from_x` at ``x`` (..., n), exact: block-diagonal per link
    (``d(m c)/dm = c``, ``d(m c)/dc = m 1``, ``d I_O/dm = |c|^2 1 - c c^T``, ``d I_O/dc_k = m (2 c_k 1 -
    e_k c^T - c e_k^T)``, ``d I_O/d I_C = 1``), the identity on the extra parameters."""
    x = np.asarray(x, dtype=np.float64)
    jac = np.broadcast_to(np.eye(x.shape[-1]), (*x.shape, x.shape[-1])).copy()
    eye3 = np.eye(3)
    for link in range(n_links):
        o = N_PARAMS_PER_LINK * link
        m, c = x[..., o], x[..., o + 1 : o + 4]
        cc = np.einsum("...i,...i->...", c, c)
        jac[..., o + 1 : o + 4, o] = c
        jac[..., o + 1 : o + 4, o + 1 : o + 4] = m[..., None, None] * eye3
        for j, (a, b) in enumerate(_PAIRS):
            row = o + 4 + j
            jac[..., row, o] = (a == b) * cc - c[..., a] * c[..., b]
            jac[..., row, o + 1 : o + 4] = m[..., None] * (
                2 * c * (a == b) - eye3[a] * c[..., b, None] - c[..., a, None] * eye3[b]
            )
    return jac


def _tr_step(uf, s, v, delta, alpha, m: int, n: int, rtol: float = 0.01, max_iter: int = 10):
    """scipy's ``solve_lsq_trust_region`` (More's method on one SVD ``J = U diag(s) V^T``) for a batch: the step
    ``p`` (B, n) with ``(J^T J + alpha 1) p = -J^T f``, ``|p| = delta`` unless the Gauss-Newton step fits, and
    ``alpha`` (B,)."""
    suf = s * uf
    full = (s[:, -1] > _EPS * m * s[:, 0]) if m >= n else np.zeros(len(s), dtype=bool)

    def phi(a):
        denom = s**2 + a[:, None]
        p_norm = np.linalg.norm(suf / denom, axis=1)
        return p_norm - delta, -np.sum(suf**2 / denom**3, axis=1) / np.where(p_norm > 0, p_norm, 1.0)

    safe_s = np.where(s > 0, s, 1.0)
    p_gn = -np.einsum("bnk,bk->bn", v, uf / safe_s)
    gn = full & (np.linalg.norm(p_gn, axis=1) <= delta)
    upper = np.linalg.norm(suf, axis=1) / delta
    lower = np.zeros_like(upper)
    if np.any(full):
        ph, dph = phi(np.zeros_like(upper))
        lower = np.where(full, -ph / np.where(dph != 0, dph, 1.0), 0.0)
    alpha = np.where(~full & (alpha == 0), np.maximum(0.001 * upper, np.sqrt(lower * upper)), alpha)
    running = ~gn
    for _ in range(max_iter):
        if not running.any():
            break
        out = (alpha < lower) | (alpha > upper)
        alpha = np.where(running & out, np.maximum(0.001 * upper, np.sqrt(lower * upper)), alpha)
        ph, dph = phi(alpha)
        upper = np.where(running & (ph < 0), alpha, upper)
        ratio = ph / np.where(dph != 0, dph, 1.0)
        lower = np.where(running, np.maximum(lower, alpha - ratio), lower)
        alpha = np.where(running, alpha - (ph + delta) * ratio / delta, alpha)
        running = running & ~(np.abs(ph) < rtol * delta)
    p = -np.einsum("bnk,bk->bn", v, suf / (s**2 + alpha[:, None]))
    p *= (delta / np.maximum(np.linalg.norm(p, axis=1), 1e-300))[:, None]
    return np.where(gn[:, None], p_gn, p), np.where(gn, 0.0, alpha)


def _tr_update(reduction, predicted, step_norm, delta, x_norm, cost, finite, tol: float):
    """scipy's ``update_tr_radius`` and ``check_termination`` after one step of a batch: the new radius
    (B,) from the ratio of the actual to the predicted ``reduction``, and the termination code (B,) (0: go on;
    2: ``ftol``; 3: ``xtol``; 4: both; 0 where the step's residual is not ``finite``)."""
    ratio = np.where(
        predicted > 0,
        reduction / np.where(predicted > 0, predicted, 1.0),
        np.where((predicted == 0) & (reduction == 0), 1.0, 0.0),
    )
    delta_new = np.where(
        ratio < 0.25,
        0.25 * step_norm,
        np.where((ratio > 0.75) & (step_norm > 0.95 * delta), 2.0 * delta, delta),
    )
    ftol_ok = (reduction < tol * cost) & (ratio > 0.25)
    xtol_ok = step_norm < tol * (tol + x_norm)
    return delta_new, np.where(ftol_ok & xtol_ok, 4, np.where(ftol_ok, 2, np.where(xtol_ok, 3, 0))) * finite


def trf(
    a: np.ndarray, b: np.ndarray, x0: np.ndarray, n_links: int, tol: float = LSQNONLIN_TOL, max_nfev: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``min_x ||a theta(x) - b||^2`` for a batch of problems by scipy's trust-region reflective method without
    bounds (``least_squares(method="trf", x_scale=1.0, tr_solver="exact")``: ``trf_no_bounds``), step for step.

    Every problem runs scipy's own iteration (the SVD of its Jacobian, More's trust-region step, the radius
    update, the ``ftol``/``xtol``/``gtol`` tests), the batch advancing together: one NumPy call per step for all
    the problems still running, where scipy's Python loop costs a few milliseconds per problem and step.
    (One function, a little over 80 lines: it follows scipy's loop step for step, and reads best beside it.)

    Args:
        a: (C, m, n), b: (C, m) the linear data term (``A = R B``, ``b = R beta_hat``).
        x0: (C, n) starts (:func:`x_from_theta`).
        n_links: links in ``x`` (:func:`theta_from_x`).
        tol: ``ftol = xtol = gtol``.
        max_nfev: function evaluations per problem (default ``100 n``, scipy's).

    Returns:
        ``x`` (C, n), ``status`` (C,) scipy's codes (0: ``max_nfev`` reached; 1: ``gtol``; 2: ``ftol``;
        3: ``xtol``; 4: both), ``nfev`` (C,).
    """
    c, m, n = a.shape
    max_nfev = 100 * n if max_nfev is None else int(max_nfev)

    def fun(idx, x):
        return np.einsum("cmn,cn->cm", a[idx], theta_from_x(x, n_links)) - b[idx]

    x = np.array(x0, dtype=np.float64)
    every = np.arange(c)
    f = fun(every, x)
    jac = a @ theta_jacobian(x, n_links)
    cost = 0.5 * np.einsum("cm,cm->c", f, f)
    g = np.einsum("cmn,cm->cn", jac, f)
    delta = np.linalg.norm(x, axis=1)
    delta[delta == 0] = 1.0
    alpha = np.zeros(c)
    nfev = np.ones(c, dtype=np.int64)
    status = np.zeros(c, dtype=np.int64)
    done = np.zeros(c, dtype=bool)
    fresh = np.ones(c, dtype=bool)  # at the top of scipy's outer loop: a new Jacobian
    k = min(m, n)
    uf, sv, v = np.zeros((c, k)), np.zeros((c, k)), np.zeros((c, n, k))
    while True:
        top = np.flatnonzero(fresh & ~done)
        if top.size:
            status[top[np.max(np.abs(g[top]), axis=1) < tol]] = 1
            done[top] = (status[top] != 0) | (nfev[top] >= max_nfev)
            top = top[~done[top]]
            u, sv[top], vt = np.linalg.svd(jac[top], full_matrices=False)
            uf[top] = np.einsum("cmk,cm->ck", u, f[top])
            v[top] = np.swapaxes(vt, -1, -2)
        fresh[:] = False
        idx = np.flatnonzero(~done)
        if not idx.size:
            break
        step, alpha[idx] = _tr_step(uf[idx], sv[idx], v[idx], delta[idx], alpha[idx], m, n)
        js = np.einsum("cmn,cn->cm", jac[idx], step)
        predicted = -(0.5 * np.einsum("cm,cm->c", js, js) + np.einsum("cn,cn->c", g[idx], step))
        x_new = x[idx] + step
        f_new = fun(idx, x_new)
        nfev[idx] += 1
        step_norm = np.linalg.norm(step, axis=1)
        finite = np.all(np.isfinite(f_new), axis=1)
        cost_new = 0.5 * np.einsum("cm,cm->c", f_new, f_new)
        reduction = np.where(finite, cost[idx] - cost_new, -1.0)
        delta_new, term = _tr_update(
            reduction, predicted, step_norm, delta[idx], np.linalg.norm(x[idx], axis=1), cost[idx], finite, tol
        )
        move = finite & (term == 0)
        alpha[idx[move]] *= delta[idx[move]] / delta_new[move]
        delta[idx] = np.where(move, delta_new, np.where(finite, delta[idx], 0.25 * step_norm))
        accept = finite & (reduction > 0)
        status[idx] = np.where(term > 0, term, status[idx])
        ok = idx[accept]
        x[ok], f[ok], cost[ok] = x_new[accept], f_new[accept], cost_new[accept]
        jac[ok] = a[ok] @ theta_jacobian(x[ok], n_links)
        g[ok] = np.einsum("cmn,cm->cn", jac[ok], f[ok])
        fresh[ok] = True
        stuck = idx[~accept & ((term > 0) | (nfev[idx] >= max_nfev))]
        done[stuck] = True
    return x, status, nfev


def lsqnonlin_theta(fit: BaseFit, base: BaseParameters, start: np.ndarray, progress=None, engine: str = "batched"):
    """The paper's nonlinear least squares: per configuration ``min_x ||A theta(x) - b||^2`` from ``start``.

    Args:
        fit: the base fit (``A = R B``, ``b = R beta_hat``; module doc).
        base: the base parameters.
        start: (n,) or (C, n) the start as standard parameters (the CAD values: the paper's).
        progress: ``progress(done, total)`` over configurations (``engine="scipy"``).
        engine: ``"batched"`` (:func:`trf`, every configuration at once) or ``"scipy"``
            (:func:`scipy.optimize.least_squares` per configuration: the reference, same iterates).

    Returns:
        ``theta`` (C, n), ``success`` (C,) bool, ``status`` (C,) text, ``nfev`` (C,) function evaluations.
    """
    n_links = base.n_link_params // N_PARAMS_PER_LINK
    a, b = _box_system(fit, base)
    c = len(b)
    x0 = x_from_theta(np.broadcast_to(np.asarray(start, dtype=np.float64), (c, base.n_params)), n_links)
    run = fit.full_rank & np.all(np.isfinite(x0), axis=1)
    x = np.full((c, base.n_params), np.nan)
    code = np.full(c, -1, dtype=np.int64)
    nfev = np.zeros(c, dtype=np.int64)
    max_nfev = LSQNONLIN_MAX_NFEV * base.n_params
    if engine == "batched":
        rows = np.flatnonzero(run)
        if rows.size:
            x[rows], code[rows], nfev[rows] = trf(a[rows], b[rows], x0[rows], n_links, LSQNONLIN_TOL, max_nfev)
        if progress is not None:
            progress(c, c)
    elif engine == "scipy":
        from scipy.optimize import least_squares

        for i in range(c):
            if run[i]:
                ai, bi = a[i], b[i]
                sol = least_squares(
                    lambda x, ai=ai, bi=bi: ai @ theta_from_x(x, n_links) - bi,
                    x0[i],
                    jac=lambda x, ai=ai: ai @ theta_jacobian(x, n_links),
                    method="trf",
                    ftol=LSQNONLIN_TOL,
                    xtol=LSQNONLIN_TOL,
                    gtol=LSQNONLIN_TOL,
                    max_nfev=max_nfev,
                )
                x[i], code[i], nfev[i] = sol.x, sol.status, sol.nfev
            if progress is not None:
                progress(i + 1, c)
    else:
        raise ValueError(f"engine must be 'batched' or 'scipy', got {engine!r}")
    success = (code > 0) & np.all(np.isfinite(x), axis=1)
    status = np.where(success, "ok", np.where(run, "lsqnonlin: too many function evaluations", "rank_deficient"))
    theta = theta_from_x(x, n_links)
    theta[~success] = np.nan
    return theta, success, status.astype(object), nfev


def _classical_estimate(theta, success, status, shared: SharedFit, t0: float, bounds=None) -> MethodEstimate:
    """The :class:`MethodEstimate` of a classical solver's ``theta`` (C, n), NaN where it failed; the seconds
    since ``t0`` shared out over the configurations. With ``bounds`` (``lsqlin``'s box) the standard
    deviations are those of the bounded estimate (:func:`ineid.identify.constrained_std.constrained_cov`)."""
    fit, base = shared.fit, shared.base
    c = fit.beta.shape[0]
    theta[~success] = np.nan
    cov, n_active = fit.cov_beta, None
    if bounds is not None:
        cov, n_active = constrained_cov(theta, success, fit, base, null="free", psd=False, bounds=bounds)
    std = standard_std(np.nan_to_num(cov), base)
    std[~success] = np.nan
    beta_std = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
    est = Estimate(theta, std, theta @ base.B.T, beta_std, success, np.asarray(status, dtype=object), fit, n_active)
    return MethodEstimate(est, np.full(c, (time.perf_counter() - t0) / max(c, 1)))


def lsqlin_method(shared: SharedFit, settings: SolveSettings, progress: Progress | None = None) -> MethodEstimate:
    """``lsqlin`` on the shared fit (:func:`lsqlin_theta`), within :func:`cad_bounds` of ``settings.bounds``
    (unbounded when None)."""
    t0 = time.perf_counter()
    fit, base = shared.fit, shared.base
    bounds = None if settings.bounds is None else cad_bounds(shared.prior, base.scales, settings.bounds)
    theta, status = lsqlin_theta(fit, base, bounds, progress)
    return _classical_estimate(theta, fit.full_rank & (status == "ok"), status, shared, t0, bounds)


def lsqnonlin_method(shared: SharedFit, settings: SolveSettings, progress: Progress | None = None) -> MethodEstimate:
    """``lsqnonlin`` on the shared fit (:func:`lsqnonlin_theta`), from the CAD values (``settings.start="prior"``,
    the paper's) or the linear estimate (``"linear"``)."""
    t0 = time.perf_counter()
    fit, prior = shared.fit, shared.prior
    start = prior if settings.start == "prior" else np.where(fit.full_rank[:, None], shared.theta_lin, prior)
    theta, success, status, _ = lsqnonlin_theta(fit, shared.base, start, progress)
    return _classical_estimate(theta, success, status, shared, t0)
