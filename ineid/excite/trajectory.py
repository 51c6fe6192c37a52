"""The excitation design's trajectory and its bounds: variables, states, and constraints at every instant.

A finite-Fourier trajectory per joint at rest at both ends (:func:`_rest_basis`), the
bounds it must keep (:class:`Bounds`, :func:`design_bounds`), and the optimization problem
over its coefficients (:class:`DesignProblem`: the linear maps to the states on the design and
constraint grids, the criterion and its exact gradient, the tightened linear constraints,
projection and random feasible starts), and the IPOPT solver of it (:func:`ipopt_solver`, with
the floor, box and self-collision of :mod:`ineid.excite.safety` when asked). The maths is in
:mod:`ineid.excite.design`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.data.synthesis.trajectory import FourierTrajectory, state_matrices
from ineid.errors import ExcitationError
from ineid.excite.callbacks import numpy_function
from ineid.excite.criterion import DesignBase, centred, criterion_and_gradient, design_phi, design_rows
from ineid.excite.safety import casadi_constraint
from ineid.identify.ipopt import nlpsol

ACCEPTABLE_TOL = 1e-3
"""IPOPT's ``acceptable_tol``: a start whose optimality error stays below it for 5 iterations while the
criterion changes by less than :data:`ACCEPTABLE_CHANGE` (relative) has converged ("acceptable")."""
ACCEPTABLE_CHANGE = 1e-5


def _rest_basis(harmonics: int) -> np.ndarray:
    """(2H, 2H - 2) orthonormal basis of ``{[a; b]: sum_l a_l = 0, sum_l l b_l = 0}``."""
    h = harmonics
    c = np.zeros((2, 2 * h))
    c[0, :h] = 1.0
    c[1, h:] = np.arange(1, h + 1)
    _, _, vt = np.linalg.svd(c)
    return vt[2:].T


@dataclass(frozen=True)
class Bounds:
    """Bounds a design must keep at every instant (SI units, per joint, chain order).

    Attributes:
        q_lower, q_upper: (n_dof,) position limits less the margin.
        qd_max, qdd_max: (n_dof,) velocity and acceleration bounds.
    """

    q_lower: np.ndarray
    q_upper: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray

    def violation(self, q, qd, qdd) -> float:
        """Largest relative violation over samples (0 when every bound holds), (F, n_dof) each."""
        span = self.q_upper - self.q_lower
        v = [
            np.max((q - self.q_upper) / span),
            np.max((self.q_lower - q) / span),
            np.max(np.abs(qd) / self.qd_max - 1.0),
            np.max(np.abs(qdd) / self.qdd_max - 1.0),
        ]
        return max(0.0, float(max(v)))

    def to_dict(self) -> dict:
        return {k: getattr(self, k).tolist() for k in ("q_lower", "q_upper", "qd_max", "qdd_max")}


class DesignProblem:
    """Design variables, the linear maps to states, the objective and the constraints of one excitation design.

    Per joint ``j`` the variables are ``z_j = [u_j, alpha_j]`` (2H - 1 numbers):
    ``q0_j = mid_j + half_j u_j`` (``u`` in [-1, 1]: the mean inside the tightened
    limits) and ``[a_j; b_j] = v_j R alpha_j`` (``R`` the rest basis, ``v_j`` the
    velocity bound: variables of order one).
    """

    def __init__(
        self,
        model,
        base: DesignBase,
        sigma,
        criterion,
        bounds: Bounds,
        f0: float,
        harmonics: int,
        design_points: int,
        constraint_points: int,
    ) -> None:
        self.model, self.base, self.sigma, self.criterion = model, base, sigma, criterion
        self.f0, self.h, self.n = f0, harmonics, model.n_dof
        self.rest = _rest_basis(harmonics)  # (2H, 2H-2)
        self.nz = 2 * harmonics - 1
        period = 1.0 / f0
        # Constraint grid and its tightening (module doc).
        nc = constraint_points
        kappa = (2.0 * np.pi * harmonics / nc) ** 2 / 8.0
        dt = period / nc
        shrink = dt * dt * bounds.qdd_max / 8.0
        self.kappa = kappa
        self.q_lo = bounds.q_lower + shrink
        self.q_hi = bounds.q_upper - shrink
        if kappa >= 0.5:
            raise ExcitationError(
                f"{constraint_points} constraint points per period are too few for {harmonics} harmonics; "
                f"use more than pi H = {math.pi * harmonics:.1f} (default 32 per harmonic)",
                reason="settings",
            )
        if np.any(self.q_hi <= self.q_lo):
            bad = int(np.argmax(self.q_lo - self.q_hi))
            raise ExcitationError(
                f"joint {model.joint_names[bad]!r}: its range less the margin is too small to move in; "
                "lower the margin or the acceleration bound",
                reason="infeasible_bounds",
            )
        self.mid = 0.5 * (self.q_lo + self.q_hi)
        self.half = 0.5 * (self.q_hi - self.q_lo)
        self.v_scale = bounds.qd_max.copy()
        self.qd_bound = (1.0 - kappa) * bounds.qd_max
        self.qdd_bound = (1.0 - kappa) * bounds.qdd_max
        t_c = np.arange(nc) * (period / nc)
        self.cq, self.cqd, self.cqdd = (p @ self.rest for p in state_matrices(t_c, f0, harmonics))
        t_d = np.arange(design_points) * (period / design_points)
        self.dq, self.dqd, self.dqdd = (p @ self.rest for p in state_matrices(t_d, f0, harmonics))
        self.n_evals = 0
        self.n_grads = 0
        self._last: tuple[bytes, tuple] | None = None

    # -- variables <-> coefficients ------------------------------------------------------
    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = np.asarray(x, dtype=np.float64).reshape(self.n, self.nz)
        return z[:, 0], z[:, 1:]

    def trajectory(self, x: np.ndarray, duration: float, joint_names) -> FourierTrajectory:
        u, alpha = self.split(x)
        coef = self.v_scale[:, None] * (alpha @ self.rest.T)  # (n, 2H)
        return FourierTrajectory(
            self.f0, self.mid + self.half * u, coef[:, : self.h], coef[:, self.h :], duration, tuple(joint_names)
        )

    def design_states(self, x: np.ndarray):
        u, alpha = self.split(x)
        ca = alpha.T * self.v_scale  # (2H-2, n)
        q = self.mid + self.half * u + self.dq @ ca
        return q, self.dqd @ ca, self.dqdd @ ca

    # -- objective -------------------------------------------------------------------------
    def _phi(self, x: np.ndarray) -> np.ndarray:
        """``Phi`` (N, A, r) on the design grid, centred with offsets (the last one cached)."""
        key = np.asarray(x, dtype=np.float64).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        phi = design_phi(self.model, self.base, self.sigma, *self.design_states(x))
        self.n_evals += 1
        phi = centred(phi) if self.base.bias else phi
        self._last = (key, phi)
        return phi

    def reweigh(self, sigma: np.ndarray) -> None:
        """Weigh the axes by ``sigma`` from now on (the noise inflated by the state errors)."""
        self.sigma, self._last = np.asarray(sigma, dtype=np.float64), None

    def value(self, x: np.ndarray) -> float:
        return criterion_and_gradient(self._phi(x), self.criterion, gradient=False)[0]

    def values(self, xs: np.ndarray) -> np.ndarray:
        """(K,) the criterion of designs ``xs`` (K, n_dof (2H - 1)), their samples in one CasADi call."""
        xs = np.atleast_2d(xs)
        states = [self.design_states(x) for x in xs]
        q, qd, qdd = (np.concatenate([s[i] for s in states]) for i in range(3))
        phi = design_phi(self.model, self.base, self.sigma, q, qd, qdd)
        phi = phi.reshape(len(xs), -1, *phi.shape[1:])
        return np.array(
            [
                criterion_and_gradient(centred(p) if self.base.bias else p, self.criterion, gradient=False)[0]
                for p in phi
            ]
        )

    def gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """``(f, df/dx)`` exactly: ``df/dPhi`` pulled back through the rows to the states (reverse-mode AD
        of the generated regressor, :class:`ineid.excite.criterion.DesignRows`), then the linear map from the
        variables ``x`` to the states."""
        phi = self._phi(x)
        f, g_phi = criterion_and_gradient(phi, self.criterion)
        if g_phi is None:
            return f, np.full(self.n * self.nz, np.nan)
        # centring: df/dPhi_k = G_k - mean(G) = G_k, as G_k = (2/N) Phi_c_k dM sums to zero
        a = self.base.n_axes
        sel = self.base.columns >= a  # the offsets' identity columns do not move
        g_y = g_phi[..., sel] * (self.base.scales[sel] / self.sigma[:, None])
        q, qd, qdd = self.design_states(x)
        g_state = design_rows(self.model, self.base).pullback(q, qd, qdd, g_y)  # (N, 3 n_dof)
        n = self.n
        gq, gqd, gqdd = g_state[:, :n], g_state[:, n : 2 * n], g_state[:, 2 * n :]
        self.n_grads += 1
        du = self.half * gq.sum(0)
        dalpha = (self.dq.T @ gq + self.dqd.T @ gqd + self.dqdd.T @ gqdd).T * self.v_scale[:, None]  # (n, 2H-2)
        return f, np.concatenate([du[:, None], dalpha], axis=1).ravel()

    # -- constraints -------------------------------------------------------------------------
    def constraint_matrix(self):
        """``(rows, cols, values, n_rows, lower, upper)`` of ``lower <= A x <= upper`` (sparse)."""
        rows, cols, vals, lo, hi = [], [], [], [], []
        nc = self.cq.shape[0]
        r0 = 0
        for j in range(self.n):
            c0 = j * self.nz
            for mat, kind in ((self.cq, "q"), (self.cqd, "qd"), (self.cqdd, "qdd")):
                block = mat * self.v_scale[j]
                rr, cc = np.meshgrid(np.arange(nc), np.arange(block.shape[1]), indexing="ij")
                rows.append((r0 + rr).ravel())
                cols.append((c0 + 1 + cc).ravel())
                vals.append(block.ravel())
                if kind == "q":
                    rows.append(r0 + np.arange(nc))
                    cols.append(np.full(nc, c0))
                    vals.append(np.full(nc, self.half[j]))
                    lo.append(np.full(nc, self.q_lo[j] - self.mid[j]))
                    hi.append(np.full(nc, self.q_hi[j] - self.mid[j]))
                else:
                    b = self.qd_bound[j] if kind == "qd" else self.qdd_bound[j]
                    lo.append(np.full(nc, -b))
                    hi.append(np.full(nc, b))
                r0 += nc
        return (
            np.concatenate(rows),
            np.concatenate(cols),
            np.concatenate(vals),
            r0,
            np.concatenate(lo),
            np.concatenate(hi),
        )

    def linear_constraints(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, lower, upper)`` of :meth:`constraint_matrix` with ``A`` dense (rows, n_dof (2H - 1))."""
        rows, cols, vals, n_rows, lo, hi = self.constraint_matrix()
        a = np.zeros((n_rows, self.n * self.nz))
        np.add.at(a, (rows, cols), vals)
        return a, lo, hi

    def project(self, x: np.ndarray) -> np.ndarray:
        """The nearest design along each joint's amplitude that meets the tightened grid bounds.

        ``u`` is clipped to [-1, 1]; each joint's ``alpha`` is scaled by the largest
        ``s <= 1`` that keeps its grid states within bounds (the rest conditions are
        linear, so they still hold).
        """
        u, alpha = self.split(x)
        u = np.clip(u, -1.0, 1.0)
        q0 = self.mid + self.half * u
        ca = alpha.T * self.v_scale
        e, v, acc = self.cq @ ca, self.cqd @ ca, self.cqdd @ ca
        with np.errstate(divide="ignore"):
            s = np.minimum.reduce(
                [
                    np.ones(self.n),
                    np.where(e.max(0) > 0, (self.q_hi - q0) / e.max(0), np.inf),
                    np.where(e.min(0) < 0, (self.q_lo - q0) / e.min(0), np.inf),
                    self.qd_bound / np.abs(v).max(0),
                    self.qdd_bound / np.abs(acc).max(0),
                ]
            )
        s = np.maximum(s, 0.0) * (1.0 - 1e-12)
        return np.concatenate([u[:, None], alpha * s[:, None]], axis=1).ravel()

    def random_start(self, rng: np.random.Generator, pose: np.ndarray | None = None) -> np.ndarray:
        """A random design that keeps the joint bounds: ``alpha ~ U(-1, 1)``, each joint scaled to its tightest
        bound on the grid; its mean ``pose`` (n_dof,) when given (the swing then scaled to fit around it), else
        drawn uniformly where the swing fits (like ``--frame-mode fourier``, but scaled on the grid instead of
        by the coarser amplitude sum)."""
        alpha = rng.uniform(-1.0, 1.0, (self.n, self.nz - 1))
        ca = alpha.T * self.v_scale
        e, v, acc = self.cq @ ca, self.cqd @ ca, self.cqdd @ ca
        with np.errstate(divide="ignore", invalid="ignore"):
            limits = [self.qd_bound / np.abs(v).max(0), self.qdd_bound / np.abs(acc).max(0)]
            if pose is None:
                limits.append((self.q_hi - self.q_lo) / (e.max(0) - e.min(0)))
            else:
                pose = np.clip(pose, self.q_lo, self.q_hi)
                limits += [np.where(e.min(0) < 0, (pose - self.q_lo) / -e.min(0), np.inf)]
                limits += [np.where(e.max(0) > 0, (self.q_hi - pose) / e.max(0), np.inf)]
        s = np.minimum.reduce(limits) * (1.0 - 1e-9)
        if pose is None:
            lo = self.q_lo - s * e.min(0)
            hi = self.q_hi - s * e.max(0)
            pose = lo + (hi - lo) * rng.random(self.n)
        u = (pose - self.mid) / self.half
        return np.concatenate([u[:, None], alpha * s[:, None]], axis=1).ravel()


def design_bounds(model, margin: float = 0.05, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> Bounds:
    """The model's bounds for a design: position limits less ``margin`` of each joint's range at
    each end; ``velocity_scale``, ``acceleration_scale`` times ``qd_max``, ``qdd_max`` (a scale above 1
    goes beyond the URDF's bounds, or the defaults where it gives none: the caller warns).

    Raises:
        ExcitationError: a margin that leaves no range, or a scale that is not positive and finite.
    """
    if not 0.0 <= margin < 0.5:
        raise ExcitationError(
            f"margin {margin:g} of each joint's range at each end leaves no room to move; use a margin in [0, 0.5)",
            reason="infeasible_bounds",
        )
    for name, v in (("velocity_scale", velocity_scale), ("acceleration_scale", acceleration_scale)):
        if not (0.0 < v and math.isfinite(v)):
            raise ExcitationError(f"{name} must be positive, got {v:g}", reason="infeasible_bounds")
    lo, hi = np.asarray(model.q_lower, float), np.asarray(model.q_upper, float)
    span = hi - lo
    return Bounds(
        lo + margin * span,
        hi - margin * span,
        np.asarray(model.qd_max, float) * velocity_scale,
        np.asarray(model.qdd_max, float) * acceleration_scale,
    )


def ipopt_solver(problem: DesignProblem, max_iter: int, tol: float, safety=None, barrier: float = 0.0, on_value=None):
    """A CasADi nlpsol (IPOPT) for ``problem``: linear constraints, callback objective, and the floor, box and
    self-collision of ``safety`` (:class:`ineid.excite.safety.SafetyConstraints`) when given.

    With ``barrier > 0`` the floor, box and self-collision enter the objective as the barrier
    ``-barrier * sum_c log g_c(x)`` of their smooth lower bounds (:mod:`ineid.excite.search`): the objective is
    infinite outside, IPOPT backs off, and every iterate keeps them; with 0 they are IPOPT's constraints
    ``g_c(x) >= 1e-6``. ``on_value(f, x)`` is called with the criterion at every evaluation (progress, and the
    best feasible point seen).

    Returns:
        ``(solver, callbacks, bounds)``: the solver (:func:`ineid.identify.ipopt.nlpsol`: stops on SIGINT and
        SIGTERM), the CasADi callbacks it calls (the objective, the safety constraints or None), and the
        keyword arguments ``lbx, ubx, lbg, ubg`` of each call.
    """
    import casadi as ca

    nx = problem.n * problem.nz
    inside = barrier > 0 and safety is not None

    def value(x):
        if inside and safety.breaks(x):  # outside, found on a sparse subset of the grid: no criterion needed
            return math.inf
        f = problem.value(x)
        if on_value is not None:
            on_value(f, x)
        if not inside:
            return f
        g = safety.values(x)
        return f - barrier * float(np.sum(np.log(g))) if np.all(g > 0) else math.inf

    def gradient(x):
        f, df = problem.gradient(x)
        if not inside:
            return df
        g = safety.values(x)
        if not np.all(g > 0):
            return np.full(nx, np.nan)
        return df - barrier * (safety.jacobian(x) / g[:, None]).sum(axis=0)

    objective = numpy_function("excitation_criterion", nx, 1, value, gradient)
    rows, cols, vals, nrows, lo, hi = problem.constraint_matrix()
    a = ca.DM.triplet(rows.tolist(), cols.tolist(), vals.tolist(), nrows, nx)
    x = ca.MX.sym("x", nx)
    g = ca.mtimes(a, x)
    extra = None
    if safety is not None and not inside:
        extra = casadi_constraint(safety)
        g = ca.vertcat(g, extra(x))
        # a little inside the bound, so that IPOPT's constraint tolerance lands on the safe side
        lo = np.concatenate([lo, np.full(safety.n_constraints, 1e-6)])
        hi = np.concatenate([hi, np.full(safety.n_constraints, np.inf)])
    nlp = {"x": x, "f": objective(x), "g": g}
    opts = {
        "print_time": False,
        "show_eval_warnings": False,  # the barrier's infinite values are expected: IPOPT backs off
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": int(max_iter),
        "ipopt.tol": float(tol),
        "ipopt.acceptable_tol": ACCEPTABLE_TOL,
        "ipopt.acceptable_iter": 5,
        "ipopt.acceptable_obj_change_tol": ACCEPTABLE_CHANGE,
        "ipopt.hessian_approximation": "limited-memory",
        "ipopt.jac_d_constant": "no" if extra is not None else "yes",
        "ipopt.jac_c_constant": "yes",
        # the starts keep every bound: stay near them instead of pushing into the interior first
        "ipopt.mu_strategy": "adaptive",
        "ipopt.mu_init": 1e-3,
        "ipopt.bound_push": 1e-8,
        "ipopt.bound_frac": 1e-8,
        "ipopt.slack_bound_push": 1e-8,
        "ipopt.slack_bound_frac": 1e-8,
        # a step out of the floor, box and self-collision is an infinite barrier: back off fast (measured on UR5:
        # half the rejected trial points of IPOPT's default 0.5, the same criteria)
        "ipopt.alpha_red_factor": 0.2,
        # a longer memory of the L-BFGS Hessian: measured on UR5 (150 iterations, 3 starts), every start reached
        # -log det -317 to -320 with 20 pairs where IPOPT's default 6 left them between -269 and -308
        "ipopt.limited_memory_max_history": 20,
    }
    solver = nlpsol("excitation", nlp, opts, keep=(objective, extra))  # stops on SIGINT, SIGTERM
    lbx = np.concatenate([np.r_[-1.0, np.full(problem.nz - 1, -np.inf)] for _ in range(problem.n)])
    ubx = -lbx
    return solver, (objective, extra), {"lbx": lbx, "ubx": ubx, "lbg": lo, "ubg": hi}
