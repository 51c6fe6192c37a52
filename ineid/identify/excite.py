"""Excitation design: a finite-Fourier trajectory whose base wrench identifies the arm well.

**What is optimized.** Along a trajectory sampled at times ``t_k`` the identification
solves ``y = W_b beta + e`` with ``W_b`` the regressor's base columns
(:mod:`ineid.identify.identifiability`). The design works on the *scaled* regressor of
each sample

    Phi_k = D^-1 Psi(q_k, qd_k, qdd_k)[:, base columns] S

with ``D = diag(sigma)`` the wrench sensor noise per axis (N, N*m) and ``S`` the
characteristic scale of each base parameter (:func:`ineid.identify.systems.parameter_scales`:
``m``, ``m l``, ``m l^2`` per link, from the CAD values). ``Phi`` is dimensionless, so
nothing below depends on units. With ``bias=True`` (``ineid solve --bias estimate``: six
constant sensor offsets identified jointly) the samples are centred per axis,
``Phi_k - mean_j Phi_j``, which profiles the offsets out exactly, and the base parameters
are those of the centred regressor (:func:`ineid.identify.base_parameters` with ``bias``);
the gradient needs no extra term, since the centred rows sum to zero. With ``M = (1/N) sum_k Phi_k^T Phi_k`` (the information
per sample) the criteria are

    d-opt:  f = -log det M                (D-optimality; the volume of the confidence ellipsoid)
    cond:   f = log cond(Phi) = (1/2) log(lambda_max(M) / lambda_min(M))

D-optimality is invariant to any fixed column scaling (it shifts ``f`` by a constant), so
its optimum does not depend on ``S`` at all; the condition number does, and is reported
for the scaled ``Phi`` ("scaled condition number"). The expected covariance of the
weighted least-squares estimate with wrench noise ``sigma`` is
``cov(beta) = S (sum_k Phi_k^T Phi_k)^-1 S`` (the Cramer-Rao bound; noise on ``q, qd,
qdd`` is not modelled in the design).

**Trajectory.** Per joint a finite Fourier series (:mod:`ineid.data.trajectory`) with ``H``
harmonics of ``f0``, at rest at ``t = 0`` and at every whole period: the coefficients
live in the null space of ``sum_l a_l = 0, sum_l l b_l = 0``, so rest holds exactly for
any design variable. The information is integrated over one period on ``design_points``
equally spaced samples (periodic trapezoid rule, spectrally accurate); the reported
values use the samples at the output rate over the whole duration.

**Constraints over the whole trajectory, not at samples.** Joint positions within their
limits less a margin, ``|qd| <= qd_max``, ``|qdd| <= qdd_max`` are imposed on a grid of
``N_c`` points per period, tightened so that they hold for every ``t``: a trigonometric
polynomial ``p`` of degree ``H`` obeys ``|p''| <= (w H)^2 max|p|`` (Bernstein), and at its
extremum ``t*`` the nearest grid point lies within ``dt/2``, so
``max|p| <= max_k |p(t_k)| / (1 - kappa)`` with ``kappa = (2 pi H / N_c)^2 / 8``; velocity
and acceleration grid bounds are therefore scaled by ``1 - kappa``, and the position
bounds shrink by ``dt^2 qdd_max / 8`` (Taylor at the extremum of ``q``, where ``qd = 0``).
All constraints are linear in the coefficients.

**Solver.** IPOPT through CasADi: the constraints as one sparse constant matrix, the
objective and its exact gradient through a :class:`casadi.Callback` that evaluates the
generated JAX regressor and its derivatives with respect to the states at the design
samples (forward mode, ``jax.jvp`` vmapped over the ``3 n`` state directions, jitted once
per robot), contracts them with ``df/dPhi``, then maps through the linear map from
coefficients to states; L-BFGS Hessian. Several random feasible starts; the best design is kept. The solution is
projected back onto the tightened grid constraints (scaling each joint's amplitude about
its mean) so IPOPT's constraint tolerance cannot leak out.

References:
    Swevers, Ganseman, Tukel, De Schutter & Van Brussel (1997), Optimal robot excitation
    and identification, IEEE T-RA 13(5).
    Gautier & Khalil (1992), Exciting trajectories for the identification of base
    inertial parameters of robots, IJRR 11(4).
    Borwein & Erdelyi (1995), Polynomials and polynomial inequalities (Bernstein's inequality).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ineid.data.noise import NoiseModel
from ineid.data.trajectory import FourierTrajectory, state_matrices, whole_count
from ineid.errors import ExcitationError
from ineid.identify.identifiability import BaseParameters, base_parameters, numerical_rank
from ineid.progress import Progress

CRITERIA = ("d-opt", "cond")
DEFAULT_CHUNK = 160
"""Samples per call of the compiled regressor and its derivatives (the design grid of 5 harmonics)."""
DESIGN_NOISE = {"force": 0.5, "moment": 0.05}
MAX_STARTS = 10_000
"""At most this many random starts (each an IPOPT solve of seconds; all are drawn up front)."""
MAX_SAMPLES = 1_000_000
"""At most this many samples (``duration * rate``): the design is evaluated on every one (the
regressor of each, about 1 KB), and the trajectory CSV has one row each."""
"""Default wrench noise of the design (N, N*m), the reference level of ``ineid study noise``."""



# -- base parameters of a design ------------------------------------------------------------


@dataclass(frozen=True)
class DesignBase:
    """The base parameters a design is for: the unknown links', with or without sensor offsets.

    Attributes:
        names: (r,) base parameter names.
        columns: (r,) each one's column in ``[I_6 | Psi]`` (``6 +`` its column in the
            ``10 n_links`` regressor columns).
        scales: (r,) characteristic scales ``S`` (SI units of each parameter).
        cad: (r,) the CAD values ``B theta_cad``.
        base: the underlying :class:`BaseParameters`.
        bias: six constant offsets are identified too (the regressor is centred per axis).
    """

    names: tuple[str, ...]
    columns: np.ndarray
    scales: np.ndarray
    cad: np.ndarray
    base: BaseParameters
    bias: bool

    @property
    def rank(self) -> int:
        return len(self.names)


def design_base(model, bias: bool = False) -> DesignBase:
    """The structural base parameters of ``model``'s unknown links, as ``ineid solve`` identifies
    them (:func:`ineid.identify.base_parameters`, with ``bias`` for ``--bias estimate``)."""
    base = base_parameters(model, bias=bias)
    idx = base.base_index
    return DesignBase(
        names=base.names,
        columns=6 + model.unknown_index[idx],
        scales=base.scales[idx],
        cad=base.B @ model.theta_cad[model.unknown_index],
        base=base,
        bias=bool(bias),
    )


def centred(phi: np.ndarray) -> np.ndarray:
    """``Phi_k - mean_j Phi_j`` (N, 6, r): the offsets of every axis profiled out."""
    return phi - phi.mean(axis=0, keepdims=True)


def design_noise(noise: NoiseModel | None = None) -> np.ndarray:
    """(6,) wrench noise std per axis of the design: ``noise.wrench``, default :data:`DESIGN_NOISE`."""
    if noise is None:
        return np.array([DESIGN_NOISE["force"]] * 3 + [DESIGN_NOISE["moment"]] * 3)
    sigma = np.asarray(noise.wrench, dtype=np.float64)
    if sigma.shape != (6,) or not np.all(sigma > 0):
        raise ExcitationError(
            f"the design needs a positive wrench noise on every axis, got {sigma.tolist()}; give force= and moment= levels",
            reason="noise",
        )
    return sigma


# -- criteria -----------------------------------------------------------------------------


def scaled_regressor(y_full: np.ndarray, base: DesignBase, sigma: np.ndarray) -> np.ndarray:
    """``Phi_k = D^-1 [I_6 | Psi_k][:, columns] S``: (N, 6, 10 n_links) -> (N, 6, r)."""
    n = y_full.shape[0]
    ext = np.concatenate([np.broadcast_to(np.eye(6), (n, 6, 6)), y_full], axis=-1)
    return ext[..., base.columns] * base.scales / sigma[:, None]


def criterion_and_gradient(phi: np.ndarray, criterion: str, gradient: bool = True):
    """``(f, df/dPhi)`` of the per-sample information ``M = Phi^T Phi / N`` (see module doc).

    Args:
        phi: (N, 6, r) scaled regressor.
        criterion: ``"d-opt"`` (``-log det M``) or ``"cond"`` (``log cond Phi``).

    Returns:
        ``f`` (inf where ``M`` is singular) and (N, 6, r) ``df/dPhi`` (None without
        ``gradient`` or where ``f`` is inf). With ``dM = df/dM`` symmetric,
        ``df/dPhi_k = (2/N) Phi_k dM``.
    """
    n, _, r = phi.shape
    a = phi.reshape(-1, r)
    m = a.T @ a / n
    if criterion == "d-opt":
        try:
            chol = np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            return math.inf, None
        f = -2.0 * float(np.sum(np.log(np.diag(chol))))
        if not gradient:
            return f, None
        inv_l = np.linalg.solve(chol, np.eye(r))
        dm = -(inv_l.T @ inv_l)
    elif criterion == "cond":
        lam, vec = np.linalg.eigh(m)
        if not lam[0] > 0:
            return math.inf, None
        f = 0.5 * float(np.log(lam[-1] / lam[0]))
        if not gradient:
            return f, None
        dm = 0.5 * (np.outer(vec[:, -1], vec[:, -1]) / lam[-1] - np.outer(vec[:, 0], vec[:, 0]) / lam[0])
    else:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    return f, (2.0 / n) * phi @ dm


@dataclass(frozen=True)
class DesignEvaluation:
    """How well the samples of one trajectory identify the base parameters.

    Attributes:
        n_samples: samples (frames) used.
        d_opt: ``-log det M`` of the per-sample scaled information.
        condition_number: ``cond(Phi)`` of the scaled regressor (inf when rank deficient).
        rank: numerical rank of ``Phi`` (relative tolerance ``RANK_RTOL``).
        std: (r,) expected standard deviations of the base parameters (their units)
            under the design's wrench noise, from all the samples.
        rel_std: (r,) ``std / scales``.
    """

    n_samples: int
    d_opt: float
    condition_number: float
    rank: int
    std: np.ndarray
    rel_std: np.ndarray

    def criterion(self, name: str) -> float:
        return self.d_opt if name == "d-opt" else math.log(self.condition_number)

    def to_dict(self) -> dict:
        return {"n_samples": self.n_samples, "d_opt": self.d_opt, "condition_number": self.condition_number,
                "rank": self.rank, "std": self.std.tolist(), "rel_std": self.rel_std.tolist()}


def evaluate_design(model, q, qd, qdd, base: DesignBase, sigma: np.ndarray) -> DesignEvaluation:
    """Criteria, rank and expected base-parameter std of frames ``q, qd, qdd`` (F, n_dof)."""
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    f = len(q)
    psi, _ = regressor_and_derivatives(model, q, qd, qdd, derivatives=False)
    phi = scaled_regressor(psi, base, sigma)
    phi = centred(phi) if base.bias else phi
    a = phi.reshape(-1, base.rank)
    sv = np.linalg.svd(a, compute_uv=False)
    rank = numerical_rank(sv)
    r = base.rank
    ok = rank >= r and sv[r - 1] > 0
    d_opt = criterion_and_gradient(phi, "d-opt", gradient=False)[0] if ok else math.inf
    cond = float(sv[0] / sv[r - 1]) if ok else math.inf
    if ok:
        inv = np.linalg.inv(a.T @ a)
        rel = np.sqrt(np.maximum(np.diag(inv), 0.0))
    else:
        rel = np.full(r, np.inf)
    return DesignEvaluation(f, d_opt, cond, rank, rel * base.scales, rel)


# -- the optimization problem ---------------------------------------------------------------


@functools.cache
def _regressor_jet(jax_regressor):
    """Jitted ``(q, qd, qdd, g) -> (Psi, dPsi)``: the regressor and its exact derivatives.

    ``Psi`` (N, 6, 10 n_links); ``dPsi[d]`` (3 n_dof, N, 6, 10 n_links) its derivative along
    state coordinate ``d`` of every sample (``q_1..q_n, qd_1..qd_n, qdd_1..qdd_n``), by
    forward-mode AD (``jax.jvp``, vmapped over the ``3 n`` directions). Cached per
    generated module: every design of a robot shares the one compilation. Measured on the
    7-joint Z1 (2-core machine, CPU time): forward mode compiles in 46 s and runs in 20 ms
    for 160 samples; the reverse-mode pull-back (``jax.vjp``) compiled in 47 s and ran in
    54 ms (both under the same load).
    """
    import jax  # noqa: PLC0415
    import jax.numpy as jnp  # noqa: PLC0415

    def jet(q, qd, qdd, gravity):
        n = q.shape[-1]

        def along(direction):
            tangents = tuple(jnp.broadcast_to(direction[k * n : (k + 1) * n], q.shape) for k in range(3))
            return jax.jvp(lambda a, b, c: jax_regressor(a, b, c, gravity), (q, qd, qdd), tangents)

        psi, _ = along(jnp.zeros(3 * n))
        return psi, jax.vmap(lambda d: along(d)[1])(jnp.eye(3 * n))

    return jax.jit(jet)


def regressor_and_derivatives(model, q, qd, qdd, chunk: int = DEFAULT_CHUNK, derivatives: bool = True):
    """``Psi(q_k, qd_k, qdd_k)`` (F, 6, 10 n_links) and, with ``derivatives``, ``dPsi`` (3 n_dof, F, 6, 10 n_links).

    Evaluated in padded chunks of ``chunk`` samples, so one compilation serves every size.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (q, qd, qdd))
    fn = _regressor_jet(model.jax_regressor)
    gravity = np.asarray(model.gravity, dtype=np.float64)
    f = len(q)
    psis, jets = [], []
    for start in range(0, f, chunk):
        part = [a[start : start + chunk] for a in (q, qd, qdd)]
        m = len(part[0])
        if m < chunk:
            part = [np.concatenate([a, np.zeros((chunk - m, a.shape[1]))]) for a in part]
        psi, jet = fn(*part, gravity)
        psis.append(np.asarray(psi)[:m])
        if derivatives:
            jets.append(np.asarray(jet)[:, :m])
    psi = np.concatenate(psis)
    return (psi, np.concatenate(jets, axis=1)) if derivatives else (psi, None)


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


class _Problem:
    """Design variables, the linear maps to states, the objective and the constraints.

    Per joint ``j`` the variables are ``z_j = [u_j, alpha_j]`` (2H - 1 numbers):
    ``q0_j = mid_j + half_j u_j`` (``u`` in [-1, 1]: the mean inside the tightened
    limits) and ``[a_j; b_j] = v_j R alpha_j`` (``R`` the rest basis, ``v_j`` the
    velocity bound: variables of order one).
    """

    def __init__(self, model, base: DesignBase, sigma, criterion, bounds: Bounds, f0: float, harmonics: int,
                 design_points: int, constraint_points: int) -> None:
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
        return FourierTrajectory(self.f0, self.mid + self.half * u, coef[:, : self.h], coef[:, self.h :],
                                 duration, tuple(joint_names))

    def design_states(self, x: np.ndarray):
        u, alpha = self.split(x)
        ca = alpha.T * self.v_scale  # (2H-2, n)
        q = self.mid + self.half * u + self.dq @ ca
        return q, self.dqd @ ca, self.dqdd @ ca

    # -- objective -------------------------------------------------------------------------
    def _evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, dPhi)`` on the design grid: (N, 6, r) and (3 n_dof, N, 6, r) (last one cached)."""
        key = np.asarray(x, dtype=np.float64).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        q, qd, qdd = self.design_states(x)
        psi, dpsi = regressor_and_derivatives(self.model, q, qd, qdd)
        self.n_evals += 1
        phi = scaled_regressor(psi, self.base, self.sigma)
        # centring: df/dPhi_k = G_k - mean(G) = G_k, as G_k = (2/N) Phi_c_k dM sums to zero
        phi = centred(phi) if self.base.bias else phi
        sel = self.base.columns >= 6  # every column (the offsets are profiled out, not columns)
        weight = (self.base.scales[sel] / self.sigma[:, None])  # (6, r)
        dphi = dpsi[..., self.base.columns[sel] - 6] * weight
        self._last = (key, (phi, dphi, sel))
        return self._last[1]

    def value(self, x: np.ndarray) -> float:
        return criterion_and_gradient(self._evaluate(x)[0], self.criterion, gradient=False)[0]

    def gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """``(f, df/dx)`` exactly: ``df/dPhi`` contracted with ``dPhi/dstate`` (forward-mode AD of the
        generated regressor), then the linear map from the variables ``x`` to the states."""
        phi, dphi, sel = self._evaluate(x)
        f, g_phi = criterion_and_gradient(phi, self.criterion)
        if g_phi is None:
            return f, np.full(self.n * self.nz, np.nan)
        g_state = np.einsum("dkij,kij->kd", dphi, g_phi[..., sel])  # (N, 3 n_dof)
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
        return (np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), r0,
                np.concatenate(lo), np.concatenate(hi))

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
            s = np.minimum.reduce([
                np.ones(self.n),
                np.where(e.max(0) > 0, (self.q_hi - q0) / e.max(0), np.inf),
                np.where(e.min(0) < 0, (self.q_lo - q0) / e.min(0), np.inf),
                self.qd_bound / np.abs(v).max(0),
                self.qdd_bound / np.abs(acc).max(0),
            ])
        s = np.maximum(s, 0.0) * (1.0 - 1e-12)
        return np.concatenate([u[:, None], alpha * s[:, None]], axis=1).ravel()

    def random_start(self, rng: np.random.Generator) -> np.ndarray:
        """A random feasible design: ``alpha ~ U(-1, 1)``, each joint scaled to its tightest
        bound, its mean drawn uniformly where the swing fits (like ``--frame-mode fourier``,
        but scaled on the grid instead of by the coarser amplitude sum)."""
        alpha = rng.uniform(-1.0, 1.0, (self.n, self.nz - 1))
        ca = alpha.T * self.v_scale
        e, v, acc = self.cq @ ca, self.cqd @ ca, self.cqdd @ ca
        swing = e.max(0) - e.min(0)
        s = np.minimum.reduce([self.qd_bound / np.abs(v).max(0), self.qdd_bound / np.abs(acc).max(0),
                               (self.q_hi - self.q_lo) / swing]) * (1.0 - 1e-9)
        lo = self.q_lo - s * e.min(0)
        hi = self.q_hi - s * e.max(0)
        q0 = lo + (hi - lo) * rng.random(self.n)
        u = (q0 - self.mid) / self.half
        return np.concatenate([u[:, None], alpha * s[:, None]], axis=1).ravel()


def _ipopt_solver(problem: _Problem, max_iter: int, tol: float):
    """A CasADi nlpsol (IPOPT) for ``problem``: linear constraints, callback objective."""
    import casadi as ca  # noqa: PLC0415

    nx = problem.n * problem.nz

    class Gradient(ca.Callback):
        def __init__(self, name, opts):
            ca.Callback.__init__(self)
            self.construct(name, opts)

        def get_n_in(self):
            return 2

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(nx, 1) if i == 0 else ca.Sparsity.dense(1, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(1, nx)

        def eval(self, arg):
            _, g = problem.gradient(np.asarray(arg[0]).ravel())
            return [ca.DM(g).T]

    class Objective(ca.Callback):
        def __init__(self, name, opts):
            ca.Callback.__init__(self)
            self._jac = None
            self.construct(name, opts)

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(nx, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(1, 1)

        def eval(self, arg):
            return [problem.value(np.asarray(arg[0]).ravel())]

        def has_jacobian(self):
            return True

        def get_jacobian(self, name, inames, onames, opts):
            self._jac = Gradient(name, opts)
            return self._jac

    objective = Objective("excitation_criterion", {"enable_fd": False})
    rows, cols, vals, nrows, lo, hi = problem.constraint_matrix()
    a = ca.DM.triplet(rows.tolist(), cols.tolist(), vals.tolist(), nrows, nx)
    x = ca.MX.sym("x", nx)
    nlp = {"x": x, "f": objective(x), "g": ca.mtimes(a, x)}
    opts = {
        "print_time": False,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": int(max_iter),
        "ipopt.tol": float(tol),
        "ipopt.hessian_approximation": "limited-memory",
        "ipopt.jac_d_constant": "yes",
        "ipopt.jac_c_constant": "yes",
    }
    solver = ca.nlpsol("excitation", "ipopt", nlp, opts)
    lbx = np.concatenate([np.r_[-1.0, np.full(problem.nz - 1, -np.inf)] for _ in range(problem.n)])
    ubx = -lbx
    return solver, objective, {"lbx": lbx, "ubx": ubx, "lbg": lo, "ubg": hi}


# -- the public API -------------------------------------------------------------------------


@dataclass(frozen=True)
class StartRecord:
    """One random start: its criterion before and after, IPOPT's status, iterations, seconds."""

    start_value: float
    final_value: float
    status: str
    iterations: int
    seconds: float


@dataclass
class ExcitationResult:
    """A designed excitation trajectory and how it compares with a random one.

    Attributes:
        trajectory: the design (coefficients; evaluate or sample it).
        criterion: ``"d-opt"`` or ``"cond"``, what was minimized.
        value: the criterion of the design on the design grid (one period).
        optimized, random: :class:`DesignEvaluation` of the design and of a random
            Fourier trajectory with the same period, harmonics and bounds (the start with
            the median criterion), both from the samples at ``rate`` over the duration.
        random_trajectory: that random trajectory.
        base: the base parameters designed for.
        sigma: (6,) wrench noise std of the expected standard deviations (N, N*m).
        bounds: the bounds the design keeps at every instant.
        rate: Hz of the samples that the evaluations use (and a CSV has).
        starts: one record per random start.
        seconds: wall time of the design, compilation included.
        compile_seconds: of that, the first call of the compiled regressor and its derivatives
            (compilation, unless the same robot was designed for before in this process).
        settings: the arguments, JSON-able.
    """

    trajectory: FourierTrajectory
    criterion: str
    value: float
    optimized: DesignEvaluation
    random: DesignEvaluation
    random_trajectory: FourierTrajectory
    base: DesignBase
    sigma: np.ndarray
    bounds: Bounds
    rate: float
    starts: list[StartRecord] = field(default_factory=list)
    seconds: float = 0.0
    compile_seconds: float = 0.0
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The design record a ``traj.json`` carries beside the coefficients."""
        return {
            "criterion": self.criterion,
            "value": self.value,
            "rate": self.rate,
            "base_parameters": list(self.base.names),
            "base_scales": self.base.scales.tolist(),
            "base_cad": self.base.cad.tolist(),
            "bias": self.base.bias,
            "wrench_noise_std": self.sigma.tolist(),
            "bounds": self.bounds.to_dict(),
            "optimized": self.optimized.to_dict(),
            "random_fourier": self.random.to_dict(),
            "starts": [vars(s) for s in self.starts],
            "seconds": self.seconds,
            "settings": self.settings,
        }


def design_bounds(model, margin: float = 0.05, velocity_scale: float = 1.0, acceleration_scale: float = 1.0) -> Bounds:
    """The model's bounds for a design: position limits less ``margin`` of each joint's range at
    each end; ``velocity_scale``, ``acceleration_scale`` fractions of ``qd_max``, ``qdd_max``.

    Raises:
        ExcitationError: a margin that leaves no range, or a scale outside (0, 1].
    """
    if not 0.0 <= margin < 0.5:
        raise ExcitationError(
            f"margin {margin:g} of each joint's range at each end leaves no room to move; use a margin in [0, 0.5)",
            reason="infeasible_bounds",
        )
    for name, v in (("velocity_scale", velocity_scale), ("acceleration_scale", acceleration_scale)):
        if not 0.0 < v <= 1.0:
            raise ExcitationError(f"{name} must be in (0, 1], got {v:g}", reason="infeasible_bounds")
    lo, hi = np.asarray(model.q_lower, float), np.asarray(model.q_upper, float)
    span = hi - lo
    return Bounds(lo + margin * span, hi - margin * span, np.asarray(model.qd_max, float) * velocity_scale,
                  np.asarray(model.qdd_max, float) * acceleration_scale)


@dataclass(frozen=True)
class ExcitationSettings:
    """What to design (the defaults of ``ineid excite``).

    Attributes:
        duration: s, a whole number of periods ``1 / base_frequency`` (required).
        harmonics: ``H >= 2`` per joint (two are the fewest that can start and stop at rest).
        base_frequency: ``f0`` Hz; None: ``1 / duration`` (one period).
        criterion: ``"d-opt"`` (``-log det M``) or ``"cond"`` (``log cond Phi``).
        starts: random starts; the best design is kept.
        rate: Hz of the samples (the CSV rows, and the reported evaluations).
        margin: fraction of each joint's range kept free at each end, in [0, 0.5).
        velocity_scale, acceleration_scale: fractions of the model's bounds, in (0, 1].
        bias: design for identification with six constant sensor offsets estimated
            jointly (``ineid solve --bias estimate``).
        seed: of the random starts.
        design_points: samples per period of the criterion (None: ``32 H`` rounded up to a
            multiple of :data:`DEFAULT_CHUNK`, the compiled block size).
        constraint_points: grid points per period of the bounds (None: ``32 H``).
        max_iter, tol: IPOPT's, per start.
    """

    duration: float
    harmonics: int = 5
    base_frequency: float | None = None
    criterion: str = "d-opt"
    starts: int = 4
    rate: float = 100.0
    margin: float = 0.05
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    bias: bool = False
    seed: int = 0
    design_points: int | None = None
    constraint_points: int | None = None
    max_iter: int = 150
    tol: float = 1e-6

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def design_excitation(
    model,
    settings: ExcitationSettings,
    noise: NoiseModel | None = None,
    progress: Progress | None = None,
) -> ExcitationResult:
    """Design a periodic excitation trajectory for ``model``'s unknown links (module doc).

    Args:
        model: the :class:`ineid.RobotModel`; its unknown links and gravity set the design.
        settings: duration, harmonics, criterion, bounds, starts (:class:`ExcitationSettings`).
        noise: the wrench noise of the expected standard deviations (default
            :data:`DESIGN_NOISE`); it also weights the axes in the criterion.
        progress: ``progress(starts_done, starts)``.

    Returns:
        The :class:`ExcitationResult`: the best design over the starts and, for
        comparison, the random start with the median criterion.

    Raises:
        ExcitationError: infeasible bounds, a duration that is too short or not a whole
            number of periods (or of samples), too few harmonics, or a design that leaves
            base parameters undetermined (rank deficient); each with what to change.
    """
    s = settings
    duration, harmonics, base_frequency, criterion, starts, rate = (
        s.duration, s.harmonics, s.base_frequency, s.criterion, s.starts, s.rate)
    margin, velocity_scale, acceleration_scale, bias, seed = (
        s.margin, s.velocity_scale, s.acceleration_scale, s.bias, s.seed)
    design_points, constraint_points, max_iter, tol = s.design_points, s.constraint_points, s.max_iter, s.tol
    t_start = time.perf_counter()
    if criterion not in CRITERIA:
        raise ExcitationError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}", reason="settings")
    if not model.unknown_links:
        raise ExcitationError("the model has no unknown links; choose the links to identify", reason="settings")
    duration = float(duration)
    if not (math.isfinite(duration) and duration > 0):
        raise ExcitationError(f"duration must be a positive number of seconds, got {duration!r}", reason="duration")
    if harmonics < 2:
        raise ExcitationError(
            f"{harmonics} harmonic cannot start and end at rest and still move; use --harmonics 2 or more",
            reason="harmonics",
        )
    f0 = 1.0 / duration if base_frequency is None else float(base_frequency)
    if not (math.isfinite(f0) and f0 > 0):
        raise ExcitationError(f"base frequency must be positive, got {base_frequency!r}", reason="duration")
    periods = whole_count(duration * f0)
    if periods is None:
        raise ExcitationError(
            f"duration {duration:g} s is not a whole number of periods of {1 / f0:g} s (base frequency {f0:g} Hz); "
            "make the duration a multiple of the period, or leave --base-frequency at its default 1/duration",
            reason="duration",
        )
    if not (math.isfinite(rate) and rate > 0):
        raise ExcitationError(f"rate must be a positive number of Hz, got {rate!r}", reason="settings")
    n_rate = whole_count(duration * rate)
    if n_rate is None:
        raise ExcitationError(
            f"duration {duration:g} s is not a whole number of samples at {rate:g} Hz; choose a multiple of {1 / rate:g} s",
            reason="duration",
        )
    if n_rate > MAX_SAMPLES:
        raise ExcitationError(
            f"{duration:g} s at {rate:g} Hz is {n_rate:,} samples, more than the {MAX_SAMPLES:,} a design is evaluated "
            "on; shorten --duration or lower --rate",
            reason="settings",
        )
    if harmonics * f0 >= rate / 2.0:
        raise ExcitationError(
            f"the highest harmonic ({harmonics} x {f0:g} Hz = {harmonics * f0:g} Hz) is at or above half the sample rate "
            f"({rate:g} Hz): the duration is too short for {harmonics} harmonics; lengthen --duration (or lower "
            "--base-frequency), use fewer --harmonics, or raise --rate",
            reason="duration",
        )
    if not 1 <= starts <= MAX_STARTS:
        raise ExcitationError(f"starts must be in 1..{MAX_STARTS:,}, got {starts}", reason="settings")
    bounds = design_bounds(model, margin, velocity_scale, acceleration_scale)
    sigma = design_noise(noise)
    design_points = design_points or DEFAULT_CHUNK * math.ceil(32 * harmonics / DEFAULT_CHUNK)
    constraint_points = constraint_points or 32 * harmonics
    base = design_base(model, bias)
    samples = n_rate + 1
    if 6 * samples < base.rank:
        raise ExcitationError(
            f"{samples} samples give {6 * samples} equations for {base.rank} base parameters; lengthen --duration "
            "or raise --rate",
            reason="duration",
        )
    problem = _Problem(model, base, sigma, criterion, bounds, f0, harmonics, design_points, constraint_points)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 12]))
    x0s = [problem.random_start(rng) for _ in range(starts)]
    t_compile = time.perf_counter()
    problem.gradient(x0s[0])  # the first call of the compiled regressor and its derivatives
    compile_seconds = time.perf_counter() - t_compile


    solver, _keep, bnds = _ipopt_solver(problem, max_iter, tol)
    records: list[StartRecord] = []
    best_x, best_f = None, math.inf
    for k, x0 in enumerate(x0s):
        t0 = time.perf_counter()
        f_start = problem.value(x0)
        if not math.isfinite(f_start):
            records.append(StartRecord(f_start, f_start, "rank_deficient_start", 0, time.perf_counter() - t0))
        else:
            sol = solver(x0=x0, **bnds)
            stats = solver.stats()
            x = problem.project(np.asarray(sol["x"]).ravel())
            f = problem.value(x)
            records.append(StartRecord(f_start, f, str(stats.get("return_status")), int(stats.get("iter_count", 0)),
                                       time.perf_counter() - t0))
            if f < best_f:
                best_x, best_f = x, f
        if progress is not None:
            progress(k + 1, starts)
    if best_x is None:
        raise ExcitationError(
            f"every random start leaves base parameters undetermined (the information matrix of the "
            f"{base.rank} base parameters is singular); widen the bounds (--margin), add --harmonics or lengthen --duration",
            reason="rank_deficient",
        )
    names = model.joint_names
    traj = problem.trajectory(best_x, duration, names)
    start_values = np.array([r.start_value for r in records])
    median_start = int(np.argsort(start_values)[(len(start_values) - 1) // 2])
    random_traj = problem.trajectory(x0s[median_start], duration, names)
    _, q, qd, qdd = traj.sample(rate)
    optimized = evaluate_design(model, q, qd, qdd, base, sigma)
    _, rq, rqd, rqdd = random_traj.sample(rate)
    random = evaluate_design(model, rq, rqd, rqdd, base, sigma)
    if optimized.rank < base.rank:
        raise ExcitationError(
            f"the design determines only {optimized.rank} of the {base.rank} base parameters at {rate:g} Hz; "
            "add --harmonics, lengthen --duration or widen the bounds",
            reason="rank_deficient",
        )
    record = dict(s.to_dict(), base_frequency=f0, design_points=design_points, constraint_points=constraint_points,
                  unknown_links=list(model.unknown_links), robot=model.name)
    return ExcitationResult(
        trajectory=traj, criterion=criterion, value=best_f, optimized=optimized, random=random,
        random_trajectory=random_traj, base=base, sigma=sigma, bounds=bounds, rate=float(rate), starts=records,
        seconds=time.perf_counter() - t_start, compile_seconds=compile_seconds, settings=record,
    )
