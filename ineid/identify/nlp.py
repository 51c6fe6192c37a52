"""Nonlinear and physically consistent identification with IPOPT through CasADi.

Both solvers minimize, over their own unknowns ``x`` per link,

    f(x) = ||R (B theta(x)) - z||^2 / (r s^2)  +  lam * ||N^T ((theta(x) - theta_prior) / scale)||^2

The first term is the least-squares cost of the frames, written through the base fit
(:class:`ineid.identify.linear.BaseFit`: ``||D (W theta - y)||^2 = ||R (B theta - beta_hat)||^2
+ rss``, ``z = R beta_hat``), so its size does not grow with the number of frames and one
compiled solver serves every configuration; ``s^2`` is the residual variance (floored for
noise-free data at ``1e-5`` (nonlinear) or ``1e-3`` (consistent) of the data's RMS: a
tighter floor leaves IPOPT chasing round-off near the boundary of the physical set; no
force/torque sensor is better than 0.1 % of its signal), so one unit of cost is about one
standard deviation of the data. The
second is the pull towards the prior (CAD values by default): ``N`` is an orthonormal basis
of the null space in scaled coordinates, so the pull acts only on the directions the data
cannot see and picks, among the best fits, the one closest to the prior (the same rule as
the linear solver). ``lam = 1e-2`` by default. The ``nonlinear`` solver applies the rule
exactly instead, as the equality constraints ``N^T ((theta(x) - theta_prior) / scale) = 0``:
its data term and the null-space part are independent, and a penalty that weak against
noise-free data would leave IPOPT stopping before the null-space part has moved. The consistent solver adds
``eps * sum_links D(J, J_prior)``, the log-det divergence of each link's scaled
pseudo-inertia from the prior's (``eps = 1e-3``): a barrier that keeps estimates off the
degenerate bodies at the boundary of the physical set, where noise would otherwise push
them and where IPOPT converges slowly.

* ``nonlinear`` (the paper's form): per link ``x = (m, c, I_C)``, mass, centre of mass in
  the link frame and the six entries of the inertia about it, ``theta(x) = (m, m c,
  I_C + m S(c)^T S(c))``; bounds ``m >= 1e-6 * scale``. Its minimizer is the linear one
  whenever the mass bound is inactive: the parameterization changes nothing the data see.
* ``consistent``: per link the log-Cholesky factor of the pseudo-inertia,
  ``J = U U^T``, ``U = e^a [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3],
  [0, 0, 0, 1]]`` (Rucker & Wensing 2022), in units scaled by the link's mass and length,
  so every estimate has a positive definite pseudo-inertia: a rigid body, even with noise.

With the channels' extra kept columns (:mod:`ineid.identify.extras`) the unknowns are
``[x_links, x_e]`` and ``theta(x) = [theta_links(x_links), s_e x_e]`` (``s_e`` the extras'
scales): the extra parameters are free linear unknowns in both methods, except that
``consistent`` bounds the dissipative ones (friction, armature) below by 0
(:func:`ineid.identify.extras.nonnegative`).

The problem is a CasADi ``MX`` graph: the factor ``R`` one matrix symbol applied to the scalar (``SX``)
graph of the links' ``theta(x)``, so building it grows about as the unknowns, not as ``r^2 n``
(:mod:`ineid.identify.nlp_matrix`). Exact first derivatives come from CasADi, the exact Hessian of
the Lagrangian from its pieces (``theta(x)``'s Jacobian and second derivatives, and the data's
``(R B)^T (R B)`` given per configuration); IPOPT's status is reported per configuration, and a failed
solve never passes as an estimate.

References:
    Wensing, Kim, Slotine (2017), Linear matrix inequalities for physically consistent
    inertial parameter identification. Rucker & Wensing (2022), Smooth parameterization of
    rigid-body inertia.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.errors import CodegenError, IdentificationError
from ineid.identify.extras import nonnegative
from ineid.identify.identifiability import BaseParameters
from ineid.identify.ipopt import nlpsol
from ineid.identify.linear import BaseFit, Estimate, standard_std
from ineid.identify.nlp_matrix import data_parameters, matrix_problem
from ineid.identify.settings import DEFAULT_ENTROPIC, DEFAULT_PULL, NLP_METHODS
from ineid.params import N_PARAMS_PER_LINK, inertial_from_theta, pseudo_inertia

SIGMA_FLOOR_REL = {"nonlinear": 1e-5, "consistent": 1e-3}
"""Noise-free data: the residual variance is floored at (this x RMS of the data)^2."""
ACCEPTED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
MAX_ITER = 3000
"""IPOPT's iteration cap. Near the boundary of the physical set the log-Cholesky problem is not convex (IPOPT
regularizes its Hessian) and IPOPT creeps: on simulated 8 s recordings at 1 kHz (UR5, Panda) ``consistent``
took 625 and 726 iterations from the CAD start, its last 500 changing the objective by 0.4 % (0.1 in
chi-square units), and on five UR5 configurations of 60 noise-free frames up to 434. Where the data are
weak the barrier keeps it off the boundary and it takes 35-80. Offsets estimated worsen the conditioning
(``sweaty-arm``: 52 -> 279 iterations); the MuJoCo test recording took 807."""


def _link_lengths(scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = scales.reshape(-1, N_PARAMS_PER_LINK)
    mass = s[:, 0]
    return mass, s[:, 1] / mass  # first-moment scale is m*l


def null_basis_scaled(base: BaseParameters) -> np.ndarray:
    """Orthonormal basis (10 n_u, k) of the null space in scaled coordinates ``theta / scale``."""
    if base.null_basis.shape[1] == 0:
        return np.zeros((base.n_params, 0))
    q, _ = np.linalg.qr(base.null_basis / base.scales[:, None])
    return q


def _theta_nonlinear(x, mass_s, length):
    import casadi as ca

    out = []
    for k in range(len(mass_s)):
        xs = x[10 * k : 10 * k + 10]
        m = xs[0] * mass_s[k]
        c = xs[1:4] * length[k]
        i_s = mass_s[k] * length[k] ** 2
        ixx, ixy, iyy, ixz, iyz, izz = (xs[4 + j] * i_s for j in range(6))
        cx, cy, cz = c[0], c[1], c[2]
        out += [
            m,
            m * cx,
            m * cy,
            m * cz,
            ixx + m * (cy * cy + cz * cz),
            ixy - m * cx * cy,
            iyy + m * (cx * cx + cz * cz),
            ixz - m * cx * cz,
            iyz - m * cy * cz,
            izz + m * (cx * cx + cy * cy),
        ]
    return ca.vertcat(*out)


def _log_cholesky_factor(x, k):
    import casadi as ca

    a, d1, d2, d3, s12, s23, s13, t1, t2, t3 = (x[10 * k + j] for j in range(10))
    u = ca.SX.zeros(4, 4)
    u[0, 0], u[1, 1], u[2, 2], u[3, 3] = ca.exp(d1), ca.exp(d2), ca.exp(d3), 1
    u[0, 1], u[1, 2], u[0, 2] = s12, s23, s13
    u[0, 3], u[1, 3], u[2, 3] = t1, t2, t3
    return ca.exp(a) * u, 2 * (4 * a + d1 + d2 + d3)  # U, log det(U U^T)


def entropic_divergence(x, prior_j_inv: list[np.ndarray]):
    """sum over links of tr(Jp^-1 J) - log det(Jp^-1 J) - 4 (scaled units; zero at the prior)."""
    import casadi as ca

    total = 0
    for k, jp_inv in enumerate(prior_j_inv):
        u, logdet = _log_cholesky_factor(x, k)
        j = ca.mtimes(u, u.T)
        total += ca.trace(ca.mtimes(ca.DM(jp_inv), j)) - logdet - float(np.linalg.slogdet(jp_inv)[1]) - 4
    return total


def _theta_log_cholesky(x, mass_s, length):
    import casadi as ca

    out = []
    for k in range(len(mass_s)):
        u, _ = _log_cholesky_factor(x, k)
        j = ca.mtimes(u, u.T)
        m = j[3, 3] * mass_s[k]
        h = j[0:3, 3] * mass_s[k] * length[k]
        sigma = j[0:3, 0:3] * mass_s[k] * length[k] ** 2
        tr = sigma[0, 0] + sigma[1, 1] + sigma[2, 2]
        out += [
            m,
            h[0],
            h[1],
            h[2],
            tr - sigma[0, 0],
            -sigma[0, 1],
            tr - sigma[1, 1],
            -sigma[0, 2],
            -sigma[1, 2],
            tr - sigma[2, 2],
        ]
    return ca.vertcat(*out)


def scaled_pseudo_inertia(theta: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Pseudo-inertias (n_u, 4, 4) in each link's mass and length units."""
    mass_s, length = _link_lengths(scales)
    out = []
    for k, t in enumerate(np.asarray(theta, dtype=np.float64).reshape(-1, 10)):
        d = np.array([1 / length[k]] * 3 + [1.0])
        out.append(d[:, None] * pseudo_inertia(t) * d[None, :] / mass_s[k])
    return np.array(out)


def nonlinear_start(theta: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Scaled ``(m, c, I_C)`` unknowns of the nonlinear form from parameters (10 n_u,)."""
    mass_s, length = _link_lengths(scales)
    x = []
    for k, t in enumerate(np.asarray(theta, dtype=np.float64).reshape(-1, 10)):
        m, c, ic = inertial_from_theta(t)
        i_s = mass_s[k] * length[k] ** 2
        x += [m / mass_s[k], *(c / length[k]), *(ic[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]] / i_s)]
    return np.array(x)


def log_cholesky_start(theta: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Log-Cholesky unknowns from physically valid parameters (10 n_u,); inverse of the map."""
    x = []
    for j in scaled_pseudo_inertia(theta, scales):
        p = np.eye(4)[::-1]
        try:
            lower = np.linalg.cholesky(p @ j @ p)
        except np.linalg.LinAlgError:
            raise IdentificationError(
                "the start of the consistent solver is not a rigid body (pseudo-inertia not positive definite); "
                "start from physically valid parameters",
                status="invalid_start",
            ) from None
        u = p @ lower @ p  # upper triangular, J = U U^T
        ea = u[3, 3]
        u = u / ea
        x += [np.log(ea), np.log(u[0, 0]), np.log(u[1, 1]), np.log(u[2, 2]), u[0, 1], u[1, 2], u[0, 2], *u[0:3, 3]]
    return np.array(x)


def _prior_pseudo_inertia_inverses(prior: np.ndarray, scales: np.ndarray) -> list[np.ndarray]:
    """The inverses of the prior links' scaled pseudo-inertias ``Jp^-1`` (the entropic term's reference).

    Raises:
        IdentificationError: the prior is not a rigid body (status ``invalid_prior``).
    """
    try:
        jp_inv = [np.linalg.inv(j) for j in scaled_pseudo_inertia(prior, scales)]
        log_cholesky_start(prior, scales)
    except (np.linalg.LinAlgError, IdentificationError):
        raise IdentificationError(
            "the prior of the consistent solver is not a rigid body; give physically valid prior parameters",
            status="invalid_prior",
        ) from None
    return jp_inv


def _solver_options(ipopt_options: dict | None, compiled: bool) -> dict:
    """CasADi's options of an IPOPT problem: quiet, the tolerances, ``ipopt_options`` over them; ``compiled``:
    the problem's functions printed as C and compiled (CasADi's ``jit``).

    Raises:
        CodegenError: ``compiled`` without a C compiler.
    """
    opts = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": False,
        "show_eval_warnings": False,  # IPOPT backs off from a trial point with inf; no noise
        "ipopt.tol": 1e-8,
        "ipopt.acceptable_tol": 1e-5,
        "ipopt.max_iter": MAX_ITER,
    }
    opts.update({f"ipopt.{k}": v for k, v in (ipopt_options or {}).items()})
    if compiled:
        from ineid.identify.casadi_c import c_compiler

        cc = c_compiler()
        if cc is None:
            raise CodegenError(
                "compiled IPOPT problems need a C compiler (cc, gcc or clang on PATH, or $CC); "
                "install one or use the default backend"
            )
        opts.update(
            {"jit": True, "compiler": "shell", "jit_options": {"compiler": cc, "flags": ["-O2"], "verbose": False}}
        )
    return opts


@dataclass
class NlpSolver:
    """A compiled IPOPT problem for one base structure, method and prior; reused for every fit.

    Its parameters are the per-configuration data ``(R, z, 1/s^2)``; the prior is fixed
    when it is built.
    """

    method: str
    base: BaseParameters
    theta_prior: np.ndarray
    pull: float
    entropic: float
    solver: object
    theta_fn: object
    expressions: tuple = ()
    """``(x, p, f, theta, z)``: the problem's CasADi expressions."""
    derivatives_fn: object = None

    @property
    def n_params(self) -> int:
        return self.base.n_params

    def derivatives(self, x: np.ndarray, r_factor: np.ndarray, beta_hat: np.ndarray, inv_s2: float):
        """``(H, H_xz, dtheta/dx)`` at ``x``: the objective's Hessian in the unknowns (n, n), the derivative of its
        gradient in ``z = R beta_hat`` (n, r), and the parameters' Jacobian (n, n) (the function built on first use)."""
        import casadi as ca

        if self.derivatives_fn is None:  # the solver's Hessian of the Lagrangian; theta's Jacobian
            xs = ca.SX.sym("x", self.n_params)
            jac_fn = ca.Function("theta_jacobian", [xs], [ca.jacobian(self.theta_fn(xs), xs)])
            self.derivatives_fn = (self.solver.solver.get_function("nlp_hess_l"), jac_fn)
        hess, jac_fn = self.derivatives_fn
        p = data_parameters(r_factor, beta_hat, inv_s2, self.base.B)
        h = np.array(hess(x, p, 1.0, np.zeros(hess.size1_in(3))))  # the objective's: lam_f = 1, lam_g = 0
        jac = np.array(jac_fn(x))
        h_xz = -2 * inv_s2 / self.base.rank * jac.T @ (r_factor @ self.base.B).T  # the data term's gradient in z
        return h + np.triu(h, 1).T, h_xz, jac

    @classmethod
    def build(
        cls,
        method: str,
        base: BaseParameters,
        theta_prior: np.ndarray,
        pull: float = DEFAULT_PULL,
        entropic: float = DEFAULT_ENTROPIC,
        ipopt_options: dict | None = None,
        compiled: bool = False,
    ) -> NlpSolver:
        """Compile the problem (a fraction of a second).

        Args:
            method: ``"nonlinear"`` or ``"consistent"``.
            base: the base parameters of the unknown links.
            theta_prior: (10 n_u,) the prior (CAD values by default upstream).
            pull: weight of the quadratic pull of the null-space part towards the prior.
            entropic: ``consistent`` only: weight of the log-det divergence
                ``tr(Jp^-1 J) - log det(Jp^-1 J) - 4`` of each link's scaled pseudo-inertia
                from the prior's; a barrier that keeps estimates off degenerate bodies
                (Lee & Wensing 2019). Zero disables it.
            ipopt_options: extra IPOPT options (``{"max_iter": 1000}``).
            compiled: print the problem's functions (objective, constraints and their
                derivatives) as C and compile them with the system's compiler (CasADi's
                ``jit``): several seconds once per solver, then faster solves (see
                ``benchmarks/identify.py``). Needs a C compiler.
        """
        import casadi as ca

        if method not in NLP_METHODS:
            raise ValueError(f"method must be one of {NLP_METHODS}, got {method!r}")
        if not pull > 0 or not entropic >= 0:
            raise ValueError(f"pull must be > 0 and entropic >= 0, got {pull} and {entropic}")
        prior = np.asarray(theta_prior, dtype=np.float64)
        if prior.shape != (base.n_params,) or not np.all(np.isfinite(prior)):
            raise ValueError(f"theta_prior must be {base.n_params} finite numbers, got shape {prior.shape}")
        n, n_lp = base.n_params, base.n_link_params
        mass_s, length = _link_lengths(base.scales[:n_lp])
        xs = ca.SX.sym("x", n)
        theta = (_theta_nonlinear if method == "nonlinear" else _theta_log_cholesky)(xs[:n_lp], mass_s, length)
        if base.n_extra:  # the extra parameters: free, in units of their scales
            theta = ca.vertcat(theta, xs[n_lp:] * ca.DM(base.scales[n_lp:]))
        pull_term, entropic_term, g = ca.SX(0), ca.SX(0), ca.SX.zeros(0, 1)
        nb = null_basis_scaled(base)
        if nb.shape[1]:
            null_part = ca.mtimes(ca.DM(nb.T), theta / ca.DM(base.scales) - ca.DM(prior / base.scales))
            if method == "nonlinear":
                g = null_part  # the rule exactly: the null-space part equals the prior's
            else:
                pull_term = pull * ca.sumsqr(null_part)
        if method == "consistent" and entropic > 0:
            jp_inv = _prior_pseudo_inertia_inverses(prior[:n_lp], base.scales[:n_lp])
            entropic_term = entropic * entropic_divergence(xs, jp_inv)
        theta_fn = ca.Function("theta", [xs], [theta])
        opts = _solver_options(ipopt_options, compiled)
        null_map = nb / base.scales[:, None] if method == "nonlinear" else np.zeros((n, 0))
        pull_matrix = (method == "consistent") * pull * (nb @ nb.T) / np.outer(base.scales, base.scales)
        jit = {k: opts[k] for k in ("jit", "compiler", "jit_options") if k in opts}
        nlp, hess_lag, theta_x, zp = matrix_problem(
            xs, theta, pull_term, entropic_term, g, base, prior, pull_matrix, null_map, jit
        )
        solver = nlpsol(f"ineid_{method}", nlp, dict(opts, hess_lag=hess_lag))  # stops on SIGINT, SIGTERM
        x, p, f = nlp["x"], nlp["p"], nlp["f"]
        return cls(method, base, prior, pull, entropic, solver, theta_fn, (x, p, f, theta_x, zp))

    def start(self, theta: np.ndarray) -> np.ndarray:
        n_lp, scales = self.base.n_link_params, self.base.scales
        x = (nonlinear_start if self.method == "nonlinear" else log_cholesky_start)(theta[:n_lp], scales[:n_lp])
        return (
            np.concatenate([x, np.asarray(theta[n_lp:], dtype=np.float64) / scales[n_lp:]]) if self.base.n_extra else x
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lb, ub = np.full(self.n_params, -np.inf), np.full(self.n_params, np.inf)
        n_lp = self.base.n_link_params
        if self.method == "nonlinear":
            lb[0:n_lp:10] = 1e-6  # positive mass, in units of the link's mass scale
        elif self.base.n_extra:  # dissipative friction and armature are >= 0
            lb[n_lp:][nonnegative(self.base.param_names[n_lp:])] = 0.0
        return lb, ub

    def solve_one(
        self, r_factor: np.ndarray, beta_hat: np.ndarray, sigma2: float, data_rms: float, theta_start: np.ndarray
    ) -> tuple[np.ndarray, bool, str, int]:
        """One configuration: ``(theta, success, IPOPT status, iterations)``."""
        s2 = max(float(sigma2), (SIGMA_FLOOR_REL[self.method] * max(float(data_rms), 1e-300)) ** 2)
        p = data_parameters(r_factor, beta_hat, 1.0 / s2, self.base.B)
        lb, ub = self.bounds()
        x0 = np.clip(self.start(theta_start), lb, ub)
        sol = self.solver(x0=x0, p=p, lbx=lb, ubx=ub, lbg=0, ubg=0)
        stats = self.solver.stats()
        status = str(stats.get("return_status", "unknown"))
        x = sol["x"]
        if self.base.n_extra:  # IPOPT relaxes bounds by ~1e-8: friction and armature exactly >= 0
            x = np.clip(np.array(x).ravel(), lb, ub)
        theta = np.array(self.theta_fn(x)).ravel()
        ok = status in ACCEPTED and bool(np.all(np.isfinite(theta)))
        return theta, ok, status, int(stats.get("iter_count", -1))


def nlp_estimate(
    fit: BaseFit,
    solver: NlpSolver,
    data_rms: np.ndarray,
    theta_start: np.ndarray | None = None,
    progress=None,
) -> Estimate:
    """Nonlinear or consistent estimates of a batch from its base fit.

    Args:
        fit: the base least-squares fit of every configuration.
        solver: the compiled problem (method, base parameters, prior).
        data_rms: (C,) RMS of the weighted data, for the noise-free floor of the variance.
        theta_start: start, (10 n_u,) or (C, 10 n_u); default the prior.
        progress: ``progress(done, total)``.
    """
    base = solver.base
    c = fit.beta.shape[0]
    start = solver.theta_prior if theta_start is None else theta_start
    start = np.broadcast_to(np.asarray(start, dtype=np.float64), (c, base.n_params))
    theta = np.full((c, base.n_params), np.nan)
    success = np.zeros(c, dtype=bool)
    status = np.empty(c, dtype=object)
    for i in range(c):
        if not fit.full_rank[i]:
            status[i] = f"rank_deficient ({fit.rank[i]} of {base.rank})"
        else:
            th, ok, st, _ = solver.solve_one(fit.R[i], fit.beta[i], fit.sigma2[i], data_rms[i], start[i])
            status[i] = "ok" if ok else st
            success[i] = ok
            if ok:
                theta[i] = th
        if progress is not None:
            progress(i + 1, c)
    return estimate_from_solves(theta, success, status, fit, base, solver, data_rms)


def estimate_from_solves(
    theta,
    success,
    status,
    fit: BaseFit,
    base: BaseParameters,
    solver: NlpSolver | None = None,
    data_rms: np.ndarray | None = None,
) -> Estimate:
    """An :class:`Estimate` of IPOPT solutions: ``beta = B theta``, NaN where a solve failed; standard
    deviations from the base fit's covariance, through the active constraints of ``solver``'s method
    (:func:`ineid.identify.constrained_std.constrained_cov`; ``consistent``: the solver's own derivative
    where one is active, :func:`ineid.identify.constrained_std.estimator_gain`): the linear fit's where
    none is active, and everywhere without ``solver``.

    Args:
        solver: the problem solved (method, prior, pull); data_rms: (C,) the data's RMS (the floor of the
            solver's residual variance).
    """
    beta = theta @ base.B.T
    cov, n_active = np.nan_to_num(fit.cov_beta), None
    if solver is not None:
        from ineid.identify.constrained_std import constrained_cov, estimator_gain

        method = solver.method
        rms = np.ones(len(beta)) if data_rms is None else np.asarray(data_rms, dtype=np.float64)
        s2 = np.maximum(fit.sigma2, (SIGMA_FLOOR_REL[method] * np.maximum(rms, 1e-300)) ** 2)

        def gain(i):
            return estimator_gain(solver, theta[i], fit.R[i], fit.beta[i], 1.0 / s2[i])

        cov, n_active = constrained_cov(
            theta,
            success,
            fit,
            base,
            null="exact" if method == "nonlinear" else "pull",
            psd=method == "consistent",
            prior=solver.theta_prior,
            pull=solver.pull,
            data_weight=1.0 / (s2 * base.rank),
            bounds=tuple(v * base.scales for v in solver.bounds()),  # x's bounds scale to theta's
            gain=gain if method == "consistent" else None,
        )
    std = standard_std(cov, base)
    std[~success] = np.nan
    beta_std = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
    beta_std[~success] = np.nan
    return Estimate(theta, std, beta, beta_std, success, status, fit, n_active)
