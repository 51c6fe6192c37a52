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

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ineid.channels import ChannelSet
from ineid.data.synthesis.imu_rehearsal import ImuRehearsal
from ineid.data.synthesis.noise import NoiseModel
from ineid.data.synthesis.trajectory import FourierTrajectory, whole_count
from ineid.errors import ExcitationError
from ineid.excite.collision import CollisionPairs
from ineid.excite.criterion import (  # noqa: F401  (re-exported: they were defined here)
    CRITERIA,
    DEFAULT_CHUNK,
    DESIGN_NOISE,
    DesignBase,
    DesignEvaluation,
    _regressor_jet,
    centred,
    criterion_and_gradient,
    design_base,
    design_noise,
    evaluate_design,
    regressor_and_derivatives,
    scaled_regressor,
)
from ineid.excite.safety import (
    SafetyConstraints,
    SafetyLimits,
    check_limits,
    make_safe,
    verify,
)
from ineid.excite.states import state_errors, states_record
from ineid.excite.trajectory import Bounds, _ipopt_solver, _Problem, _rest_basis, design_bounds  # noqa: F401  (re-exported)
from ineid.progress import Progress

log = logging.getLogger(__name__)

MAX_STARTS = 10_000
"""At most this many random starts (each an IPOPT solve of seconds; all are drawn up front)."""
MAX_SAMPLES = 1_000_000
"""At most this many samples (``duration * rate``): the design is evaluated on every one (the
regressor of each, about 1 KB), and the trajectory CSV has one row each."""


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
        sigma: (A,) noise std per measured axis of the expected standard deviations (the wrench: N, N*m).
        bounds: the bounds the design keeps at every instant.
        rate: Hz of the samples that the evaluations use (and a CSV has).
        starts: one record per random start.
        seconds: wall time of the design, compilation included.
        compile_seconds: of that, the first call of the compiled regressor and its derivatives
            (compilation, unless the same robot was designed for before in this process).
        settings: the arguments, JSON-able.
        safety: the floor, box and self-collision pairs kept (None: ``self_collision`` off and no
            floor or box): their settings, the grid and margins, the capsules and what had none,
            and the smallest clearance found on the samples at ``rate`` and on a grid ten times
            denser (:func:`ineid.excite.safety.verify`).
        states: with ``settings.sensors``: the sensors, the state errors each trajectory's rehearsal gives and
            the inflated noise (:func:`ineid.excite.states.states_record`); None: joint states exact.
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
    safety: dict | None = None
    states: dict | None = None

    def to_dict(self) -> dict:
        """The design record a ``traj.json`` carries beside the coefficients."""
        d = {
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
            "workspace": self.safety,
        }
        if self.states is not None:
            d["joint_state_errors"] = self.states
        return d


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
        velocity_scale, acceleration_scale: fractions of the model's bounds, positive (above 1:
            beyond the URDF's bounds, see :func:`design_bounds`).
        bias: design for identification with six constant sensor offsets estimated
            jointly (``ineid solve --bias estimate``).
        channels: the measurement channels designed for (:class:`ineid.channels.ChannelSet`,
            their rows); None: the base wrench.
        seed: of the random starts.
        design_points: samples per period of the criterion (None: ``32 H`` rounded up to a
            multiple of :data:`DEFAULT_CHUNK`, the compiled block size).
        constraint_points: grid points per period of the bounds (None: ``32 H``).
        max_iter, tol: IPOPT's, per start.
        floor: m, every link frame origin and welded frame (the tool) at ``z >= floor`` of the
            base frame at every instant (:mod:`ineid.excite.safety`); None: no floor.
        workspace: ``(xmin, xmax, ymin, ymax, zmin, zmax)`` m, base frame: the same points kept
            in that box at every instant; None: no box.
        self_collision: keep the bounding capsules of non-adjacent bodies apart at every instant
            (:mod:`ineid.excite.collision`), where the URDF has collision geometry.
        sensors: the lab's encoders and link IMUs (:class:`ineid.data.synthesis.imu_rehearsal.ImuRehearsal`): the
            design accounts for the joint-state errors they cause (:mod:`ineid.excite.states`);
            None: joint states exact.
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
    channels: ChannelSet | None = None
    floor: float | None = None
    workspace: tuple[float, float, float, float, float, float] | None = None
    self_collision: bool = True
    sensors: ImuRehearsal | None = None

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if self.channels is None:
            del d["channels"]  # the base wrench: the record of ineid 0.1
        else:
            d["channels"] = self.channels.to_list()
        if self.workspace is not None:
            d["workspace"] = list(self.workspace)
        if self.sensors is None:
            del d["sensors"]  # joint states exact: the record as before
        else:
            d["sensors"] = self.sensors.to_dict()
        return d


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
        s.duration,
        s.harmonics,
        s.base_frequency,
        s.criterion,
        s.starts,
        s.rate,
    )
    margin, velocity_scale, acceleration_scale, bias, seed = (
        s.margin,
        s.velocity_scale,
        s.acceleration_scale,
        s.bias,
        s.seed,
    )
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
    if not 1 <= starts <= MAX_STARTS:
        raise ExcitationError(f"starts must be in 1..{MAX_STARTS:,}, got {starts}", reason="settings")
    bounds = design_bounds(model, margin, velocity_scale, acceleration_scale)
    limits = SafetyLimits(s.floor, None if s.workspace is None else tuple(float(v) for v in s.workspace))
    if limits.active:
        check_limits(model, limits)
    sigma = design_noise(noise, settings.channels, model)
    design_points = design_points or DEFAULT_CHUNK * math.ceil(32 * harmonics / DEFAULT_CHUNK)
    constraint_points = constraint_points or 32 * harmonics
    base = design_base(model, bias, settings.channels)
    samples = n_rate + 1
    if base.n_axes * samples < base.rank:
        raise ExcitationError(
            f"{samples} samples give {base.n_axes * samples} equations for {base.rank} base parameters; "
            "lengthen --duration "
            "or raise --rate",
            reason="duration",
        )
    problem = _Problem(model, base, sigma, criterion, bounds, f0, harmonics, design_points, constraint_points)
    safety = None
    pairs = CollisionPairs(model, bounds.qd_max) if s.self_collision else None
    if limits.active or (pairs is not None and pairs.n):
        safety = SafetyConstraints(
            model,
            limits,
            bounds.qd_max,
            bounds.qdd_max,
            f0,
            harmonics,
            problem.rest,
            problem.mid,
            problem.half,
            problem.v_scale,
            pairs,
        )
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 12]))
    x0s = [problem.random_start(rng) for _ in range(starts)]
    t_compile = time.perf_counter()
    problem.gradient(x0s[0])  # the first call of the compiled regressor and its derivatives
    compile_seconds = time.perf_counter() - t_compile
    if s.sensors is not None:  # the state errors' noise, once, on the first start: IPOPT's objective stays as is
        weights = state_errors(
            model, s.sensors, problem.trajectory(x0s[0], duration, model.joint_names), rate, sigma, base.channels, seed
        )
        problem.reweigh(weights.sigma)

    solver, _keep, bnds = _ipopt_solver(problem, max_iter, tol, safety)
    records: list[StartRecord] = []
    best_x, best_f = None, math.inf
    unsafe: tuple[float, str] | None = None  # the smallest grid slack of a rejected start, and its constraint
    log.info("IPOPT: %d start%s of %d variables", starts, "" if starts == 1 else "s", len(x0s[0]))
    for k, x0 in enumerate(x0s):
        t0 = time.perf_counter()
        f_start = problem.value(x0)
        if not math.isfinite(f_start):
            records.append(StartRecord(f_start, f_start, "rank_deficient_start", 0, time.perf_counter() - t0))
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
                    if unsafe is None or slack[worst] > unsafe[0]:
                        unsafe = (float(slack[worst]), safety.labels()[worst])
                    status = f"unsafe ({status})"
                x = safe
            f = problem.value(x) if x is not None else math.inf
            records.append(StartRecord(f_start, f, status, int(stats.get("iter_count", 0)), time.perf_counter() - t0))
            if x is not None and f < best_f:
                best_x, best_f = x, f
        if progress is not None:
            progress(k + 1, starts)
    if best_x is None and unsafe is not None:
        raise ExcitationError(
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
    if best_x is None:
        raise ExcitationError(
            f"every random start leaves base parameters undetermined (the information matrix of the "
            f"{base.rank} base parameters is singular); widen the bounds (--margin), add --harmonics or lengthen "
            "--duration",
            reason="rank_deficient",
        )
    names = model.joint_names
    traj = problem.trajectory(best_x, duration, names)
    start_values = np.array([r.start_value for r in records])
    median_start = int(np.argsort(start_values)[(len(start_values) - 1) // 2])
    random_traj = problem.trajectory(x0s[median_start], duration, names)
    sig_opt = sig_rnd = sigma
    states = None
    if s.sensors is not None:  # each trajectory's own state errors
        st_opt, st_rnd = (
            state_errors(model, s.sensors, tr, rate, sigma, base.channels, seed) for tr in (traj, random_traj)
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
    safety_record = None if pairs is None else dict(limits.to_dict(), self_collision=pairs.describe())
    if safety is not None:
        # check the written samples themselves, and a grid ten times denser, against the bounds (no margins)
        safety_record = dict(
            safety.describe(),
            samples=verify(safety, q),
            dense=verify(safety, traj.evaluate(np.linspace(0.0, 1.0 / f0, 10 * n_rate // periods + 1))[0]),
        )
        if min(safety_record["samples"]["min_clearance"], safety_record["dense"]["min_clearance"]) < 0:
            raise ExcitationError(  # the guarantee of excite_safety failed: never write such a design
                f"the design breaks {safety_record['dense']['constraint']}; please report this; meanwhile "
                "give the bound more room",
                reason="infeasible_workspace",
            )
    record = dict(
        s.to_dict(),
        base_frequency=f0,
        design_points=design_points,
        constraint_points=constraint_points,
        unknown_links=list(model.unknown_links),
        robot=model.name,
    )
    return ExcitationResult(
        trajectory=traj,
        criterion=criterion,
        value=best_f,
        optimized=optimized,
        random=random,
        random_trajectory=random_traj,
        base=base,
        sigma=sigma,
        bounds=bounds,
        rate=float(rate),
        starts=records,
        seconds=time.perf_counter() - t_start,
        compile_seconds=compile_seconds,
        settings=record,
        safety=safety_record,
        states=states,
    )
