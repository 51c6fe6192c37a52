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
the gradient needs no extra term, since the centred rows sum to zero. With ``M = (1/N) sum_k Phi_k^T Phi_k`` (the
information per sample) the criteria are

    d-opt:  f = -log det M                (D-optimality; the volume of the confidence ellipsoid)
    cond:   f = log cond(Phi) = (1/2) log(lambda_max(M) / lambda_min(M))

D-optimality is invariant to any fixed column scaling (it shifts ``f`` by a constant), so
its optimum does not depend on ``S`` at all; the condition number does, and is reported
for the scaled ``Phi`` ("scaled condition number"). The expected covariance of the
weighted least-squares estimate with wrench noise ``sigma`` is
``cov(beta) = S (sum_k Phi_k^T Phi_k)^-1 S`` (the Cramer-Rao bound; joint states exact,
unless ``sensors`` name the lab's encoders and IMUs: their state errors inflate ``sigma`` to
first order, :mod:`ineid.excite.states`).

**Trajectory.** Per joint a finite Fourier series (:mod:`ineid.data.synthesis.trajectory`) with ``H``
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
All constraints are linear in the coefficients. A floor, a workspace box and self-collision
(nonlinear: forward kinematics) are kept at every instant the same way, on a denser grid
with a margin from a bound of the motion between its points
(:mod:`ineid.excite.safety`, :mod:`ineid.excite.collision`).

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

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from ineid.data.synthesis.noise import NoiseModel
from ineid.data.synthesis.trajectory import FourierTrajectory, whole_count
from ineid.errors import ExcitationError
from ineid.excite.collision import CollisionPairs
from ineid.excite.criterion import (  # noqa: F401  (also the names of the old path ineid.identify.excite, until ineid 0.3)
    CRITERIA,
    DESIGN_NOISE,
    DesignBase,
    DesignEvaluation,
    centred,
    criterion_and_gradient,
    design_base,
    design_noise,
    evaluate_design,
    scaled_regressor,
)
from ineid.excite.safety import (
    SafetyConstraints,
    SafetyLimits,
    check_limits,
    make_safe,
    verify,
)
from ineid.excite.settings import MAX_SAMPLES, MAX_STARTS, ExcitationResult, ExcitationSettings, StartRecord
from ineid.excite.states import state_errors, states_record
from ineid.excite.trajectory import Bounds, DesignProblem, design_bounds, ipopt_solver
from ineid.progress import Progress

log = logging.getLogger(__name__)


# -- the public API -------------------------------------------------------------------------


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
    t_start = time.perf_counter()
    timing = _checked_timing(model, s)
    setup = _problem_setup(model, s, noise, timing)
    problem = setup.problem
    rng = np.random.default_rng(np.random.SeedSequence([int(s.seed), 12]))
    x0s = [problem.random_start(rng) for _ in range(s.starts)]
    t_compile = time.perf_counter()
    problem.gradient(x0s[0])  # the first call of the compiled regressor and its derivatives
    compile_seconds = time.perf_counter() - t_compile
    weights = None
    if s.sensors is not None:  # the state errors' noise, once, on the first start: IPOPT's objective stays as is
        first = problem.trajectory(x0s[0], timing.duration, model.joint_names)
        weights = state_errors(model, s.sensors, first, s.rate, setup.sigma, setup.base.channels, s.seed)
        problem.reweigh(weights.sigma)
    starts = _solve_starts(setup, x0s, s.max_iter, s.tol, progress)
    if starts.best_x is None:
        raise _no_design_error(starts.unsafe, setup.base)
    names = model.joint_names
    traj = problem.trajectory(starts.best_x, timing.duration, names)
    start_values = np.array([r.start_value for r in starts.records])
    median_start = int(np.argsort(start_values)[(len(start_values) - 1) // 2])
    random_traj = problem.trajectory(x0s[median_start], timing.duration, names)
    optimized, random, states, q = _evaluate_pair(model, s, setup, traj, random_traj, weights)
    safety = _safety_record(setup, traj, q, timing)
    record = dict(
        s.to_dict(),
        base_frequency=timing.f0,
        design_points=setup.design_points,
        constraint_points=setup.constraint_points,
        unknown_links=list(model.unknown_links),
        robot=model.name,
    )
    return ExcitationResult(
        trajectory=traj,
        criterion=s.criterion,
        value=starts.best_f,
        optimized=optimized,
        random=random,
        random_trajectory=random_traj,
        base=setup.base,
        sigma=setup.sigma,
        bounds=setup.bounds,
        rate=float(s.rate),
        starts=starts.records,
        seconds=time.perf_counter() - t_start,
        compile_seconds=compile_seconds,
        settings=record,
        safety=safety,
        states=states,
    )


# -- the steps of a design ------------------------------------------------------------------


@dataclass(frozen=True)
class _Timing:
    """The design's times, checked: ``duration`` s, ``f0`` Hz, whole ``periods`` of ``1 / f0`` and whole
    ``n_rate`` samples at the settings' rate in the duration."""

    duration: float
    f0: float
    periods: int
    n_rate: int


def _checked_timing(model, s: ExcitationSettings) -> _Timing:
    """Check the settings that need no bounds (criterion, links, duration, harmonics, rate, starts), in that order.

    Raises:
        ExcitationError: the first setting that fails, with what to change.
    """
    if s.criterion not in CRITERIA:
        raise ExcitationError(f"criterion must be one of {', '.join(CRITERIA)}, got {s.criterion!r}", reason="settings")
    if not model.unknown_links:
        raise ExcitationError("the model has no unknown links; choose the links to identify", reason="settings")
    duration, harmonics, rate = float(s.duration), s.harmonics, s.rate
    if not (math.isfinite(duration) and duration > 0):
        raise ExcitationError(f"duration must be a positive number of seconds, got {duration!r}", reason="duration")
    if harmonics < 2:
        raise ExcitationError(
            f"{harmonics} harmonic cannot start and end at rest and still move; use --harmonics 2 or more",
            reason="harmonics",
        )
    f0 = 1.0 / duration if s.base_frequency is None else float(s.base_frequency)
    if not (math.isfinite(f0) and f0 > 0):
        raise ExcitationError(f"base frequency must be positive, got {s.base_frequency!r}", reason="duration")
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
            f"duration {duration:g} s is not a whole number of samples at {rate:g} Hz; choose a multiple of "
            f"{1 / rate:g} s",
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
            f"the highest harmonic ({harmonics} x {f0:g} Hz = {harmonics * f0:g} Hz) is at or above half the sample "
            "rate "
            f"({rate:g} Hz): the duration is too short for {harmonics} harmonics; lengthen --duration (or lower "
            "--base-frequency), use fewer --harmonics, or raise --rate",
            reason="duration",
        )
    if not 1 <= s.starts <= MAX_STARTS:
        raise ExcitationError(f"starts must be in 1..{MAX_STARTS:,}, got {s.starts}", reason="settings")
    return _Timing(duration, f0, periods, n_rate)


@dataclass(frozen=True)
class _Setup:
    """One design problem: the joint bounds, the safety limits and their constraints (None: none kept),
    the noise ``sigma`` (A,) weighing the axes, the base parameters, the grids' sizes and the problem."""

    bounds: Bounds
    limits: SafetyLimits
    pairs: CollisionPairs | None
    safety: SafetyConstraints | None
    sigma: np.ndarray
    base: DesignBase
    design_points: int
    constraint_points: int
    problem: DesignProblem


def _problem_setup(model, s: ExcitationSettings, noise: NoiseModel | None, timing: _Timing) -> _Setup:
    """The bounds, the safety limits (checked), the base parameters and the problem over the coefficients.

    Raises:
        ExcitationError: bounds or limits no motion keeps, or too few samples for the base parameters.
    """
    bounds = design_bounds(model, s.margin, s.velocity_scale, s.acceleration_scale)
    limits = SafetyLimits(s.floor, None if s.workspace is None else tuple(float(v) for v in s.workspace))
    if limits.active:
        check_limits(model, limits)
    sigma = design_noise(noise, s.channels, model)
    harmonics = s.harmonics
    design_points = s.design_points or 32 * harmonics
    constraint_points = s.constraint_points or 32 * harmonics
    base = design_base(model, s.bias, s.channels)
    samples = timing.n_rate + 1
    if base.n_axes * samples < base.rank:
        raise ExcitationError(
            f"{samples} samples give {base.n_axes * samples} equations for {base.rank} base parameters; "
            "lengthen --duration "
            "or raise --rate",
            reason="duration",
        )
    problem = DesignProblem(
        model, base, sigma, s.criterion, bounds, timing.f0, harmonics, design_points, constraint_points
    )
    safety = None
    pairs = CollisionPairs(model, bounds.qd_max) if s.self_collision else None
    if limits.active or (pairs is not None and pairs.n):
        safety = SafetyConstraints(
            model,
            limits,
            bounds.qd_max,
            bounds.qdd_max,
            timing.f0,
            harmonics,
            problem.rest,
            problem.mid,
            problem.half,
            problem.v_scale,
            pairs,
        )
    return _Setup(bounds, limits, pairs, safety, sigma, base, design_points, constraint_points, problem)


@dataclass
class _Starts:
    """What the starts gave: one record each, the best safe design ``best_x`` (None: none) and its criterion,
    and the smallest grid slack (m) of the best rejected start with its constraint (None: none rejected)."""

    records: list[StartRecord]
    best_x: np.ndarray | None = None
    best_f: float = math.inf
    unsafe: tuple[float, str] | None = None


def _solve_starts(setup: _Setup, x0s: list[np.ndarray], max_iter: int, tol: float, progress) -> _Starts:
    """IPOPT from each start, projected onto the grid bounds and made safe; the best design kept."""
    problem, safety = setup.problem, setup.safety
    solver, _keep, bnds = ipopt_solver(problem, max_iter, tol, safety)
    out = _Starts([])
    log.info("IPOPT: %d start%s of %d variables", len(x0s), "" if len(x0s) == 1 else "s", len(x0s[0]))
    for k, x0 in enumerate(x0s):
        t0 = time.perf_counter()
        f_start = problem.value(x0)
        if not math.isfinite(f_start):
            out.records.append(StartRecord(f_start, f_start, "rank_deficient_start", 0, time.perf_counter() - t0))
        else:
            sol = solver(x0=x0, **bnds)
            stats = solver.stats()
            x = problem.project(np.asarray(sol["x"]).ravel())
            status = str(stats.get("return_status"))
            if safety is not None:
                safe = make_safe(safety, x)
                if safe is None:
                    slack = safety.grid_slack(x)
                    worst = int(np.argmin(slack))
                    if out.unsafe is None or slack[worst] > out.unsafe[0]:
                        out.unsafe = (float(slack[worst]), safety.labels()[worst])
                    status = f"unsafe ({status})"
                x = safe
            f = problem.value(x) if x is not None else math.inf
            iterations = int(stats.get("iter_count", 0))
            out.records.append(StartRecord(f_start, f, status, iterations, time.perf_counter() - t0))
            if x is not None and f < out.best_f:
                out.best_x, out.best_f = x, f
        if progress is not None:
            progress(k + 1, len(x0s))
    return out


def _no_design_error(unsafe: tuple[float, str] | None, base: DesignBase) -> ExcitationError:
    """Why no start gave a design: a safety constraint none kept (``unsafe``), else a singular information."""
    if unsafe is not None:
        return ExcitationError(
            f"IPOPT found no design that keeps every bound: {unsafe[1]} stays violated (by {-unsafe[0]:.3g} m "
            "on the grid, margin between samples included); "
            + (
                "pass --no-self-collision if those shapes are too coarse"
                if unsafe[1].endswith("self-collision")
                else "relax that bound"
            )
            + ", or lower --velocity-scale and --acceleration-scale (smaller motions), "
            "or try more --starts",
            reason="infeasible_workspace",
        )
    return ExcitationError(
        f"every random start leaves base parameters undetermined (the information matrix of the "
        f"{base.rank} base parameters is singular); widen the bounds (--margin), add --harmonics or lengthen "
        "--duration",
        reason="rank_deficient",
    )


def _evaluate_pair(
    model, s: ExcitationSettings, setup: _Setup, traj: FourierTrajectory, random_traj: FourierTrajectory, weights
) -> tuple[DesignEvaluation, DesignEvaluation, dict | None, np.ndarray]:
    """The design and the random trajectory evaluated on their samples at the rate, each with its own state
    errors when ``s.sensors`` are given (``weights``: those of the first start).

    Returns:
        ``(optimized, random, states, q)``: the evaluations, the state-error record (None: joint states exact)
        and the design's sampled positions (F, n_dof).

    Raises:
        ExcitationError: the design leaves base parameters undetermined at the rate.
    """
    base, rate = setup.base, s.rate
    sig_opt = sig_rnd = setup.sigma
    states = None
    if s.sensors is not None:  # each trajectory's own state errors
        st_opt, st_rnd = (
            state_errors(model, s.sensors, tr, rate, setup.sigma, base.channels, s.seed) for tr in (traj, random_traj)
        )
        sig_opt, sig_rnd = st_opt.sigma, st_rnd.sigma
        states = states_record(s.sensors, weights, st_opt, st_rnd)
    _, q, qd, qdd = traj.sample(rate)
    optimized = evaluate_design(model, q, qd, qdd, base, sig_opt)
    _, rq, rqd, rqdd = random_traj.sample(rate)
    random = evaluate_design(model, rq, rqd, rqdd, base, sig_rnd)
    if optimized.rank < base.rank:
        raise ExcitationError(
            f"the design determines only {optimized.rank} of the {base.rank} base parameters at {rate:g} Hz; "
            "add --harmonics, lengthen --duration or widen the bounds",
            reason="rank_deficient",
        )
    return optimized, random, states, q


def _safety_record(setup: _Setup, traj: FourierTrajectory, q: np.ndarray, timing: _Timing) -> dict | None:
    """The limits kept and the smallest clearances of the design's samples ``q`` and of a grid ten times
    denser (None: no self-collision and no floor or box).

    Raises:
        ExcitationError: a clearance below zero (the guarantee of :mod:`ineid.excite.safety` failed): such a
            design is never written.
    """
    safety, pairs = setup.safety, setup.pairs
    record = None if pairs is None else dict(setup.limits.to_dict(), self_collision=pairs.describe())
    if safety is None:
        return record
    # check the written samples themselves, and a grid ten times denser, against the bounds (no margins)
    dense_t = np.linspace(0.0, 1.0 / timing.f0, 10 * timing.n_rate // timing.periods + 1)
    record = dict(safety.describe(), samples=verify(safety, q), dense=verify(safety, traj.evaluate(dense_t)[0]))
    if min(record["samples"]["min_clearance"], record["dense"]["min_clearance"]) < 0:
        raise ExcitationError(
            f"the design breaks {record['dense']['constraint']}; please report this; meanwhile "
            "give the bound more room",
            reason="infeasible_workspace",
        )
    return record


__all__ = [
    "MAX_SAMPLES",
    "MAX_STARTS",
    "ExcitationResult",
    "ExcitationSettings",
    "StartRecord",
    "design_excitation",
]
