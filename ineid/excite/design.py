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

import contextlib
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
from ineid.excite.feasibility import Feasibility, always_touching, check_feasibility, sample_poses
from ineid.excite.lanes import Lanes, LanesUnavailable, default_workers
from ineid.excite.safety import SafetyConstraints, SafetyLimits, check_limits, verify
from ineid.excite.search import Status, random_candidates, solve_starts
from ineid.excite.settings import MAX_SAMPLES, MAX_STARTS, ExcitationResult, ExcitationSettings, StartRecord
from ineid.excite.states import state_errors, states_record
from ineid.excite.trajectory import Bounds, DesignProblem, design_bounds
from ineid.progress import Progress

log = logging.getLogger(__name__)


# -- the public API -------------------------------------------------------------------------


def design_excitation(
    model,
    settings: ExcitationSettings,
    noise: NoiseModel | None = None,
    progress: Progress | None = None,
    status: Status | None = None,
    workers: int | None = None,
) -> ExcitationResult:
    """Design a periodic excitation trajectory for ``model``'s unknown links (module doc).

    Args:
        model: the :class:`ineid.RobotModel`; its unknown links and gravity set the design.
        settings: duration, harmonics, criterion, bounds, candidates, starts (:class:`ExcitationSettings`).
        noise: the wrench noise of the expected standard deviations (default
            :data:`DESIGN_NOISE`); it also weights the axes in the criterion.
        progress: ``progress(starts_done, starts)``.
        status: ``status(line)``, what the design is doing (the candidates, each start's evaluations and
            criterion), called often: the caller shows it as often as it likes.
        workers: processes solving the starts, this one included (None: one per usable CPU, at most one per
            start, :func:`ineid.excite.lanes.default_workers`); the design does not depend on it
            (:mod:`ineid.excite.lanes`).

    Returns:
        The :class:`ExcitationResult`: the best design over the starts, or the best random candidate when
        no start beats it, with the best and a typical (median) random candidate for comparison.

    Raises:
        ExcitationError: infeasible bounds (refused before any optimisation: no sampled pose keeps the floor,
            box and self-collision), a duration that is too short or not a whole number of periods (or of
            samples), too few harmonics, or a design that leaves base parameters undetermined (rank
            deficient); each with what to change.
    """
    s = settings
    t_start = time.perf_counter()
    timing = _checked_timing(model, s)
    workers = default_workers(s.starts) if workers is None else int(workers)
    if workers < 1:
        raise ExcitationError(f"workers must be at least 1, got {workers}", reason="settings")
    with _started_lanes(model, s, noise, timing, min(workers, s.starts) - 1) as lanes:
        return _design(model, s, noise, timing, t_start, progress, status, lanes)


def _started_lanes(model, s: ExcitationSettings, noise: NoiseModel | None, timing: _Timing, count: int):
    """``count`` worker processes for the starts (:mod:`ineid.excite.lanes`), or a context of None when there are
    none to start or they cannot run here (then the starts run in this process, with an INFO line saying why)."""
    if count < 1:
        return contextlib.nullcontext()
    try:
        return Lanes(_lane_problem, (model, s, noise, timing), count)
    except LanesUnavailable as e:
        log.info("every start in this process: %s", e)
        return contextlib.nullcontext()


def _lane_problem(model, s: ExcitationSettings, noise: NoiseModel | None, timing: _Timing):
    """A worker process's copy of the problem (:mod:`ineid.excite.lanes`): ``(problem, safety, max_iter, tol)``."""
    setup = _problem_setup(model, s, noise, timing)
    return setup.problem, setup.safety, s.max_iter, s.tol


def _design(model, s, noise, timing, t_start, progress, status, lanes) -> ExcitationResult:
    """:func:`design_excitation` once the settings are checked and the worker processes (``lanes``) started."""
    if status is not None:
        status("checking the bounds on a sample of the joint space")
    setup = _problem_setup(model, s, noise, timing)
    problem = setup.problem
    rng = np.random.default_rng(np.random.SeedSequence([int(s.seed), 12]))
    t_compile = time.perf_counter()
    problem.gradient(problem.random_start(np.random.default_rng(0)))  # the CasADi functions built
    compile_seconds = time.perf_counter() - t_compile
    weights = None
    if s.sensors is not None:  # the state errors' noise, once, on a random start: IPOPT's objective stays as is
        first = problem.trajectory(problem.random_start(rng), timing.duration, model.joint_names)
        weights = state_errors(model, s.sensors, first, s.rate, setup.sigma, setup.base.channels, s.seed)
        problem.reweigh(weights.sigma)
    poses = setup.feasibility.poses if setup.safety is not None else None
    cands = random_candidates(problem, setup.safety, poses, s.candidates, rng, status)
    usable = np.isfinite(cands.values)
    if not usable.any():
        raise _no_candidate_error(cands.drawn, len(cands.xs), setup.base)
    starts = solve_starts(
        problem, setup.safety, list(cands.xs[usable][: s.starts]), s.max_iter, s.tol, progress, status, lanes
    )
    best_random_x, best_random_f = cands.xs[0], float(cands.values[0])
    answer = "optimized" if starts.best_x is not None and starts.best_f < best_random_f else "best random"
    best_x, best_f = (starts.best_x, starts.best_f) if answer == "optimized" else (best_random_x, best_random_f)
    names = model.joint_names
    traj = problem.trajectory(best_x, timing.duration, names)
    finite = np.flatnonzero(usable)
    median = int(finite[(len(finite) - 1) // 2])
    random_traj = problem.trajectory(cands.xs[median], timing.duration, names)
    best_random_traj = problem.trajectory(best_random_x, timing.duration, names)
    optimized, random, states, q = _evaluate_pair(model, s, setup, traj, random_traj, weights)
    best_random = _evaluate(model, s, setup, best_random_traj)
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
        value=best_f,
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
        best_random=best_random,
        best_random_trajectory=best_random_traj,
        n_candidates=len(cands.xs),
        answer=answer,
        feasibility=setup.feasibility.to_dict() if setup.safety is not None else None,
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
    if not 1 <= s.candidates <= MAX_STARTS:
        raise ExcitationError(f"candidates must be in 1..{MAX_STARTS:,}, got {s.candidates}", reason="settings")
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
    feasibility: Feasibility


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
    constraint_points = s.constraint_points or 16 * harmonics
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
    sample = sample_poses(
        model, problem.q_lo, problem.q_hi, np.random.default_rng(np.random.SeedSequence([s.seed, 34]))
    )
    pairs = CollisionPairs(model, bounds.qd_max) if s.self_collision else None

    def constraints(pairs):
        if not (limits.active or (pairs is not None and pairs.n)):
            return None
        return SafetyConstraints(
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

    safety = constraints(pairs)
    if pairs is not None and pairs.n:  # left out, one line each in pairs.notes; the grid then chosen again
        pairs = always_touching(pairs, sample, safety.pair_margin)
        safety = constraints(pairs)
    feasibility = check_feasibility(sample, safety, pairs)  # refuses an ask no sampled pose keeps
    return _Setup(bounds, limits, pairs, safety, sigma, base, design_points, constraint_points, problem, feasibility)


def _no_candidate_error(drawn: int, found: int, base: DesignBase) -> ExcitationError:
    """Why no random candidate is usable: none could be made to keep the grid bounds (``found`` 0 of ``drawn``),
    else every one leaves base parameters undetermined (a singular information)."""
    if found == 0:
        return ExcitationError(
            f"none of {drawn} random trajectories about the feasible poses keeps the floor, box and self-collision "
            "with their margins between samples; relax the bound that the summary of a design with fewer bounds "
            "shows closest, or pass --no-self-collision if the bounding shapes are too coarse",
            reason="infeasible_workspace",
        )
    return ExcitationError(
        f"every random candidate leaves base parameters undetermined (the information matrix of the "
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


def _evaluate(model, s: ExcitationSettings, setup: _Setup, traj: FourierTrajectory) -> DesignEvaluation:
    """One trajectory evaluated on its samples at the rate, with its own state errors when ``s.sensors`` are given."""
    sigma = setup.sigma
    if s.sensors is not None:
        sigma = state_errors(model, s.sensors, traj, s.rate, setup.sigma, setup.base.channels, s.seed).sigma
    _, q, qd, qdd = traj.sample(s.rate)
    return evaluate_design(model, q, qd, qdd, setup.base, sigma)


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
