"""Standard deviations of the constrained estimates (``consistent``, ``nonlinear``, bounded ``lsqlin``).

The constrained estimate is a function ``beta_c(beta_hat)`` of the base least-squares fit. Where no
constraint is active it is the linear one (``B theta = beta_hat``) and so is its covariance:
``cov(beta_hat)``, :class:`ineid.identify.linear.BaseFit`'s ``cov_beta`` as the fit carries it. Where
constraints are active the estimate moves along the boundary only, and its covariance is the sandwich of
the estimator's derivative,

    cov_c = G V G^T,   G = d beta_c / d beta_hat,   V = cov(beta_hat),

``V`` taken as given. ``consistent`` (an unconstrained log-Cholesky parameterization with a barrier) uses
its own solver's derivative, the implicit function theorem on its optimality condition
(:func:`estimator_gain`): it carries the cone's curvature and the coupling of several zero eigenvalues,
which the half-spaces below leave free (``docs/identification.md`` has the measured difference).
``nonlinear`` and the bounded ``lsqlin`` (linear bounds) use the optimality (KKT) conditions of the
quadratic model the solver minimizes, with its active constraints held as equalities (:func:`sensitivity`):

    [ H  C^T ] [ d theta ]   [ B^T M ]
    [ C   0  ] [ d mu    ] = [   0   ] d beta_hat,     H = B^T M B + lam Q,

``M = R^T R / (s^2 r)`` the solver's data metric, ``lam Q`` the pull of the null-space part towards the
prior (``consistent``; ``nonlinear`` holds it exactly, as equality rows of ``C``; the bounded ``lsqlin``
leaves it free), ``C`` the active constraints' rows. When the active constraints do not involve the null
space this is the projection ``P = I - M^-1 J^T (J M^-1 J^T)^-1 J`` onto the tangent space of the active
constraints in the information metric, ``cov_c = P V P^T`` (``J`` their rows in base parameters); with
``V = s^2 (R^T R)^-1`` it is ``P V``. ``V`` is taken as given, never recomputed from the residuals, so
``cov_c`` inherits whatever the linear fit's covariance accounts for (weights, known-link uncertainty,
correlation in time).

**The active constraints.** Each link's pseudo-inertia ``J(theta)`` must be positive semidefinite; at the
estimate, in the link's mass and length units, each eigenvector ``v`` gives the constraint
``v^T J(theta) v >= 0``, linear in ``theta`` (the cone's supporting half-space there). The bounds are
linear already: ``consistent``'s friction and armature ``>= 0``, ``nonlinear``'s mass ``>= 1e-6`` of its
scale, ``lsqlin``'s box. Which hold with equality is decided as the hard-constrained problem would: the
active set of the quadratic model's minimum over these half-spaces (:func:`active_set`; the unconstrained
minimum is the linear estimate), so a constraint is active where the data push the estimate through it.
``consistent`` keeps its estimates a little inside the boundary (the log-det barrier, a strictly positive
definite parameterization): the rule reads through it, to the boundary it approximates.

**A truth on the boundary** (a point mass, a thin rod: a zero eigenvalue) gives an estimate on the boundary
in about half the configurations. There the error is ``P e`` (``e`` the linear fit's error), independent of
the error across the boundary, with covariance ``cov_c``; in the other half the constraint is inactive and
the error is ``e`` conditioned on lying inside, whose second moment across the boundary is still ``V``'s.
So the z-scores' RMS is 1 in both halves, while their distribution across the boundary is a half-normal
(the estimates lean inwards): calibration is checked on the RMS (``docs/identification.md``).
"""

from __future__ import annotations

import numpy as np

from ineid.identify.identifiability import BaseParameters
from ineid.identify.linear import standard_from_base
from ineid.params import N_PARAMS_PER_LINK, pseudo_inertia

MAX_ACTIVE_ROUNDS = 20
"""Rounds of the active-set search per configuration (a constraint added or dropped each)."""
FREE_NULL_RIDGE = 1e-10
"""``lsqlin``'s free null space: a ridge this small (relative to the data metric) makes the model's minimum unique."""


def unit_pseudo_inertias(base: BaseParameters) -> np.ndarray:
    """(n_links, 10, 4, 4): each link's pseudo-inertia of a unit step in each of its parameters, in the link's
    mass and length units (linear in theta: ``J_s(theta_k) = sum_p theta_kp U[k, p]``)."""
    s = base.scales[: base.n_link_params].reshape(-1, N_PARAMS_PER_LINK)
    mass, length = s[:, 0], s[:, 1] / s[:, 0]
    out = np.zeros((len(s), N_PARAMS_PER_LINK, 4, 4))
    for k in range(len(s)):
        d = np.array([1 / length[k]] * 3 + [1.0])
        for p in range(N_PARAMS_PER_LINK):
            e = np.zeros(N_PARAMS_PER_LINK)
            e[p] = 1.0
            out[k, p] = d[:, None] * pseudo_inertia(e) * d[None, :] / mass[k]
    return out


def candidate_constraints(
    theta: np.ndarray, base: BaseParameters, unit: np.ndarray | None, bounds: tuple[np.ndarray, np.ndarray] | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(A, b)``: the half-spaces ``A theta >= b`` that linearize the constraints at ``theta`` (n,).

    Per link the four ``v^T J(theta) v >= 0`` of its pseudo-inertia's eigenvectors (scaled units), then
    ``theta_i >= lb_i`` and ``-theta_i >= -ub_i`` for the finite bounds. ``unit``
    (:func:`unit_pseudo_inertias`) None: the bounds only.
    """
    n = base.n_params
    rows, rhs = [], []
    for k in range(0 if unit is None else len(unit)):
        jk = np.einsum("p,pij->ij", theta[10 * k : 10 * k + 10], unit[k])
        _, vecs = np.linalg.eigh(jk)
        for v in vecs.T:
            a = np.zeros(n)
            a[10 * k : 10 * k + 10] = np.einsum("i,pij,j->p", v, unit[k], v)
            rows.append(a)
            rhs.append(0.0)
    if bounds is not None:
        for sign, lim in ((1.0, bounds[0]), (-1.0, bounds[1])):
            for i in np.flatnonzero(np.isfinite(lim)):
                a = np.zeros(n)
                a[i] = sign
                rows.append(a)
                rhs.append(sign * lim[i])
    return np.array(rows).reshape(-1, n), np.array(rhs)


def solve_or_lstsq(k: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``k x = rhs`` by LU, or by least squares where ``k`` is singular (dependent constraint rows): LAPACK's
    least squares runs an SVD, some hundred times slower than LU at these sizes on a busy machine."""
    try:
        x = np.linalg.solve(k, rhs)
        if np.all(np.isfinite(x)) and np.linalg.norm(k @ x - rhs) <= 1e-8 * (np.linalg.norm(rhs) + 1e-300):
            return x
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(k, rhs, rcond=1e-13)[0]


def _kkt_solve(h: np.ndarray, c: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x, mu)`` of ``[H C^T; C 0] [x; mu] = [rhs_x; rhs_c]`` (dependent rows allowed)."""
    n, m = len(h), len(c)
    k = np.block([[h, c.T], [c, np.zeros((m, m))]])
    sol = solve_or_lstsq(k, rhs)
    return sol[:n], sol[n:]


def active_set(h: np.ndarray, theta_free: np.ndarray, a: np.ndarray, b: np.ndarray, eq: np.ndarray) -> np.ndarray:
    """Indices of the half-spaces ``a theta >= b`` active at the minimum of ``(theta - theta_free)^T H
    (theta - theta_free)`` over them (with the equalities ``eq theta = eq theta_free``): the primal active-set
    method from the violated ones, a constraint dropped (negative multiplier) or added (violated) per round."""
    active = [int(i) for i in np.flatnonzero(a @ theta_free < b)]
    if not active:
        return np.zeros(0, dtype=int)
    tol = 1e-9 * (1.0 + np.abs(b))
    for _ in range(MAX_ACTIVE_ROUNDS):
        c = np.vstack([eq, a[active]])
        rhs = np.concatenate([np.zeros(len(h)), np.zeros(len(eq)), b[active] - a[active] @ theta_free])
        d, mu = _kkt_solve(h, c, rhs[:, None])
        theta = theta_free + d[:, 0]
        mu_a = -mu[len(eq) :, 0]  # the multipliers of a theta >= b (sign: H d = -C^T mu)
        if len(mu_a) and mu_a.min() < -1e-12 * (1.0 + np.abs(mu_a).max()):
            active.pop(int(np.argmin(mu_a)))
            if not active:
                break
            continue
        slack = a @ theta - b
        slack[active] = 0.0
        worst = int(np.argmin(slack + tol))
        if slack[worst] < -tol[worst]:
            active.append(worst)
            continue
        break
    return np.array(sorted(active), dtype=int)


def sensitivity(h: np.ndarray, data: np.ndarray, c: np.ndarray, b_mat: np.ndarray) -> np.ndarray:
    """``G = d beta_c / d beta_hat`` (r, r): ``B dtheta`` with ``dtheta`` from the KKT system (module doc);
    ``data = B^T M`` (n, r), ``c`` the rows held as equalities."""
    d, _ = _kkt_solve(h, c, np.vstack([data, np.zeros((len(c), data.shape[1]))]))
    return b_mat @ d


def constrained_cov(
    theta: np.ndarray,
    success: np.ndarray,
    fit,
    base: BaseParameters,
    *,
    null: str,
    psd: bool = True,
    prior: np.ndarray | None = None,
    pull: float = 0.0,
    data_weight: np.ndarray | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    gain=None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(cov_c, n_active)``: (C, r, r) the covariance of each configuration's constrained base estimate and
    (C,) how many constraints are active there (module doc). ``cov_c`` is ``fit.cov_beta`` itself where none is.

    Args:
        theta: (C, n) the constrained estimates (NaN where failed).
        success: (C,) bool.
        fit: the base fit (``R``, ``beta``, ``cov_beta``).
        base: the base parameters.
        null: how the solver fixes the null-space part: ``"pull"`` (``pull`` times the squared scaled
            distance to the prior's, ``consistent``), ``"exact"`` (the prior's, ``nonlinear``), ``"free"``
            (``lsqlin``).
        psd: whether the links' pseudo-inertias are constrained (``consistent``), or the bounds only.
        prior: (n,) the prior the null-space part is pulled to or held at (``"pull"``, ``"exact"``).
        pull: the pull's weight against the data term ``||R (beta - beta_hat)||^2 * data_weight``.
        data_weight: (C,) the data term's weight in the solver's cost, ``1 / (s^2 r)`` (``"pull"`` only).
        bounds: ``(lb, ub)`` (n,) bounds on theta, ``-inf``/``inf`` where none.
        gain: ``gain(i)``, the estimator's own derivative ``G`` (r, r) of configuration ``i``
            (:func:`estimator_gain`), or None where it has none: used instead of the quadratic model's
            where a constraint is active.
    """
    c_n, r = fit.beta.shape
    n = base.n_params
    cov = np.array(np.nan_to_num(fit.cov_beta), dtype=np.float64, copy=True)
    n_active = np.zeros(c_n, dtype=np.int64)
    unit = unit_pseudo_inertias(base) if psd else None
    s = base.scales
    bs = base.B * s[None, :]  # scaled coordinates phi = theta / s
    nb = np.linalg.svd(bs)[2][r:].T  # orthonormal null space of B S (n, n - r)
    q = nb @ nb.T
    eq = nb.T if null == "exact" else np.zeros((0, n))
    for i in np.flatnonzero(success & fit.full_rank):
        m = fit.R[i].T @ fit.R[i]
        w = 1.0 if data_weight is None else float(data_weight[i])
        h = w * bs.T @ m @ bs
        if null == "pull":
            h = h + pull * q
        elif null == "free":
            h = h + FREE_NULL_RIDGE * np.trace(h) / n * np.eye(n)
        # the model's unconstrained minimum: the linear estimate (lsqlin: the one nearest the estimate)
        free = standard_from_base(fit.beta[i], base, theta[i] if null == "free" else prior) / s
        a, b = candidate_constraints(theta[i], base, unit, bounds)
        act = active_set(h, free, a * s[None, :], b, eq)
        n_active[i] = len(act)
        if len(act):
            g = None if gain is None else gain(i)
            if g is None:
                g = sensitivity(h, w * bs.T @ m, np.vstack([eq, a[act] * s[None, :]]), bs)
            cov[i] = g @ cov[i] @ g.T
    return cov, n_active


def estimator_gain(solver, theta: np.ndarray, r_factor: np.ndarray, beta_hat: np.ndarray, inv_s2: float):
    """``G = d beta_c / d beta_hat`` (r, r) of an unconstrained parameterization's solver at its estimate
    ``theta`` (``consistent``: the log-Cholesky unknowns, barrier and pull included): the implicit function
    theorem on its optimality condition, ``dx = -H^-1 H_xz R d beta_hat``, unknowns at a bound held. None
    where the estimate has no unknowns (a pseudo-inertia not positive definite in floating point).

    Args:
        solver: an :class:`ineid.identify.nlp.NlpSolver` (``start``, ``bounds``, ``derivatives``).
        theta: (n,) its estimate; r_factor, beta_hat: the configuration's base fit; inv_s2: the data term's
            ``1 / s^2``.
    """
    from ineid.errors import IdentificationError

    try:
        x = solver.start(theta)
    except IdentificationError:
        return None
    lb, ub = solver.bounds()
    x = np.clip(x, lb, ub)
    h, h_xz, jac = solver.derivatives(x, r_factor, beta_hat, inv_s2)
    moving = (x > lb + 1e-9) & (x < ub - 1e-9)
    dx = np.zeros((len(x), len(beta_hat)))
    dx[moving] = -solve_or_lstsq(h[np.ix_(moving, moving)], h_xz[moving] @ r_factor)
    g = solver.base.B @ jac @ dx
    return g if np.all(np.isfinite(g)) else None


CONSTRAINED_METHODS = ("consistent", "nonlinear", "lsqlin")
"""The methods whose std runs through their active constraints (``lsqlin`` with bounds)."""


def std_record(datasets, est) -> dict:
    """What a result's standard deviations were computed from (the results file's ``std``): ``filtered``, the
    low-pass of each filtered recording fitted (``{"cutoff", "rate"}`` Hz; empty: independent frames), and
    ``active``, (C,) how many constraints each configuration's std runs through (None: an unconstrained method)."""
    from ineid.identify.time_correlation import filtered_frames

    found = [filtered_frames(ds) for ds in datasets]
    filtered = [{"cutoff": f.cutoff, "rate": f.rate} for f in found if f is not None]
    active = None if est.n_active is None else [int(a) for a in est.n_active]
    return {"filtered": filtered, "active": active}


def _numbers(values) -> str:
    """``a/b/...``: the distinct values to 3 significant digits, without an exponent below 1e6 (1000, not 1e+03)."""
    return "/".join(f"{v:g}" for v in sorted({float(f"{v:.3g}") for v in values}))


def frames_note(record: dict | None) -> str:
    """How the std takes the frames (:func:`std_record`): correlated over a filter's cut-off, or independent; empty
    without a record (an older results file)."""
    if not record:
        return ""
    filtered = record.get("filtered") or []
    if not filtered:
        return "; frames independent"
    cut, rate = _numbers(f["cutoff"] for f in filtered), _numbers(f["rate"] for f in filtered)
    return (
        f"; a filtered recording: frames correlated over the {cut} Hz cut-off at {rate} Hz (band density of the "
        "residuals per axis, the filter's and differentiation's error included)"
    )


def active_note(record: dict | None) -> str:
    """How many constraints the std runs through (:func:`std_record`), or empty without a count."""
    active = (record or {}).get("active")
    if not active:
        return ""
    if len(active) == 1:
        return f"{active[0]} active; "
    bound = sum(a > 0 for a in active)
    return f"active in {bound} of {len(active)} configurations, up to {max(active)}; "


def std_note(method: str, record: dict | None = None) -> str:
    """One line on what a method's standard deviations are (``results info``, the ``solve`` summary, the report),
    from the results' ``std`` record (:func:`std_record`) where it has one."""
    frames = frames_note(record)
    if method in CONSTRAINED_METHODS:
        return (
            "std: the linear fit's covariance through the active constraints of the estimate ("
            f"{active_note(record)}the linear fit's where none is active; docs/identification.md){frames}"
        )
    return f"std: the linear fit's covariance{frames}"
