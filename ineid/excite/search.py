"""The search of an excitation design: random feasible candidates, then IPOPT from the best of them.

**Candidates.** ``N`` random trajectories that keep every bound (the joints' and the floor, box
and self-collision's): each joint's coefficients uniform, its mean pose a feasible pose of the
sample (:mod:`ineid.excite.feasibility`; without a floor, box or self-collision, uniform where
the swing fits), the amplitudes scaled to the tightest joint bound on the grid, then about the
mean pose until the floor, box and capsule pairs hold on their grid (bisection; the mean pose
itself keeps them). Their criteria are evaluated in one batch (:meth:`DesignProblem.values`):
about a millisecond each for a 7-joint arm.

**Starts.** IPOPT from the best ``K`` candidates (:func:`ineid.excite.trajectory.ipopt_solver`).
With a floor, box or self-collision the search stays feasible: each constraint's smooth lower
bound ``g_c(x) > 0`` (the Kreisselmeier-Steinhauser aggregate of its grid values, which is
below their minimum, :mod:`ineid.excite.safety`) enters the objective as a barrier
``f(x) - mu sum_c log g_c(x)`` (``mu`` = :data:`BARRIER`), and a step that leaves the feasible set
is an evaluation error IPOPT backs off from. Every iterate keeps every bound, so a start that
stops at the iteration cap still ends on a safe design; and the barrier's pull away from a bound
is ``mu / |df/dg|``, far below a millimetre for these criteria.

**The answer.** The best safe design over the starts, unless the best candidate is at least as
good: a design that does not beat the best random candidate is not returned (the candidate is,
and the result says so).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ineid.excite.safety import make_safe
from ineid.excite.settings import StartRecord

log = logging.getLogger(__name__)

BARRIER = 1e-2
"""``mu`` of the floor, box and self-collision barrier (criterion units: ``-log det`` or ``log cond``)."""
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
"""IPOPT's statuses of a start that converged."""
SETTLED = 0.05
"""A start stopped by the iteration cap has settled when its best criterion improved by less than this over its
last quarter of evaluations (criterion units, natural logarithms: 5 % of ``det M``, or of the condition number)."""

WAIT_SECONDS = 1.0
"""How often the status line is renewed while only worker processes solve starts."""

Status = Callable[[str], None]
"""``status(line)``: what the search is doing, called often (the caller decides how often to show it)."""


@dataclass
class Candidates:
    """The random feasible candidates: ``xs`` (N, n_dof (2H - 1)) and their criteria ``values`` (N,), best first;
    ``drawn``: how many were drawn to find them (the rest could not be made to keep the bounds)."""

    xs: np.ndarray
    values: np.ndarray
    drawn: int
    seconds: float


def random_candidates(problem, safety, poses, n: int, rng: np.random.Generator, status: Status | None = None):
    """``n`` random feasible candidates (module doc), sorted by criterion; ``poses`` (K, n_dof) the feasible
    mean poses to draw from (None: uniform where the swing fits)."""
    t0 = time.perf_counter()
    xs, drawn, last = [], 0, t0
    while len(xs) < n and drawn < 4 * n:
        drawn += 1
        pose = None if poses is None else poses[rng.integers(len(poses))]
        x = problem.random_start(rng, pose)
        if safety is not None:
            x = make_safe(safety, x)
        if x is not None:
            xs.append(x)
        if status is not None and time.perf_counter() - last > 0.5:
            status(f"random feasible candidates: {len(xs)} of {n}")
            last = time.perf_counter()
    xs = np.array(xs).reshape(len(xs), -1)
    values = problem.values(xs) if len(xs) else np.zeros(0)
    order = np.argsort(values, kind="stable")
    return Candidates(xs[order], values[order], drawn, time.perf_counter() - t0)


@dataclass
class StartOutcome:
    """One start's result: its record, its safe design ``x`` (None: it ended unsafe) and criterion ``f``, and
    for an unsafe end ``(slack, label)`` of its worst constraint."""

    record: StartRecord
    x: np.ndarray | None
    f: float
    unsafe: tuple[float, str] | None = None


@dataclass
class Starts:
    """What the starts gave: one record each, the best design ``best_x`` (None: none safe) and its criterion."""

    records: list[StartRecord] = field(default_factory=list)
    best_x: np.ndarray | None = None
    best_f: float = math.inf
    unsafe: tuple[float, str] | None = None


def start_solver(problem, safety, max_iter: int, tol: float, watch: _Watch | None = None):
    """``solve(k, x0) -> StartOutcome``: IPOPT from ``x0`` (start ``k``), the best design it found kept.

    IPOPT's iterates need not improve monotonically nor stay feasible on the way, so each start keeps the best
    feasible point it evaluated (the linear bounds to round-off, the floor, box and self-collision's smooth lower
    bounds positive) beside where IPOPT stopped; both are projected onto the grid bounds, made safe, and the
    better one is the start's design. ``watch``: the status lines (None: none).
    """
    from ineid.excite.trajectory import ipopt_solver

    watch = watch if watch is not None else _Watch(None, 1, problem, safety)
    solver, _, bnds = ipopt_solver(problem, max_iter, tol, safety, barrier=BARRIER, on_value=watch)

    def solve(k: int, x0: np.ndarray) -> StartOutcome:
        t0 = time.perf_counter()
        f_start = problem.value(x0)
        watch.begin(k, f_start, x0)
        sol = solver(x0=x0, **bnds)
        stats = solver.stats()
        status_text = str(stats.get("return_status"))
        tried = [_finished(problem, safety, np.asarray(sol["x"]).ravel()), _finished(problem, safety, watch.best_x)]
        f, x = min(tried, key=lambda t: t[0])
        unsafe = None
        if x is None and safety is not None:
            slack = safety.grid_slack(problem.project(np.asarray(sol["x"]).ravel()))
            worst = int(np.argmin(slack))
            unsafe = (float(slack[worst]), safety.labels()[worst])
            status_text = f"unsafe ({status_text})"
        iterations = int(stats.get("iter_count", 0))
        converged = x is not None and status_text in CONVERGED
        settled = x is not None and not converged and watch.settled()
        if settled:
            status_text += " (settled)"
        record = StartRecord(f_start, f, status_text, iterations, time.perf_counter() - t0, converged, settled)
        return StartOutcome(record, x, f, unsafe)

    return solve


def solve_starts(
    problem, safety, x0s, max_iter: int, tol: float, progress=None, status: Status | None = None, lanes=None
) -> Starts:
    """IPOPT from each start of ``x0s`` (:func:`start_solver`); the best design kept (the first of the lowest
    criterion, in start order). With ``lanes`` (:class:`ineid.excite.lanes.Lanes`), idle lanes take starts
    while more than one is left and this process solves the others: the same starts, the same outcomes."""
    n = len(x0s)
    log.info(
        "IPOPT: %d starts of the excitation design%s",
        n,
        f" ({len(lanes)} worker process{'es' if len(lanes) > 1 else ''} beside this one)" if lanes else "",
    )
    watch = _Watch(status, n, problem, safety)
    solve = start_solver(problem, safety, max_iter, tol, watch)
    outcomes: list = [None] * n
    queue = list(range(n))
    done = 0

    def finished(k: int, outcome) -> None:
        nonlocal done
        outcomes[k] = outcome
        if math.isfinite(outcome.f):
            watch.best = min(watch.best, outcome.f)
        done += 1
        if progress is not None:
            progress(done, n)

    while queue:
        if lanes is not None:
            for k, outcome in lanes.collect(timeout=0.0):
                finished(k, outcome)
            while lanes.idle() and len(queue) > 1:
                k = queue.pop(0)
                lanes.submit(k, x0s[k], problem.sigma)
        k = queue.pop(0)
        watch.elsewhere = lanes.busy() if lanes is not None else 0
        finished(k, solve(k, x0s[k]))
    t_wait = time.perf_counter()
    while lanes is not None and lanes.busy():
        if status is not None:
            status(
                f"waiting for {lanes.busy()} start{'s' if lanes.busy() > 1 else ''} in a worker process, "
                f"{time.perf_counter() - t_wait:.0f} s"
            )
        for k, outcome in lanes.collect(timeout=WAIT_SECONDS):
            finished(k, outcome)
    best_x, best_f, unsafe = best_of(outcomes)
    return Starts([o.record for o in outcomes], best_x, best_f, unsafe)


def _finished(problem, safety, x: np.ndarray) -> tuple[float, np.ndarray | None]:
    """``(criterion, design)`` of ``x`` projected onto the grid bounds and made safe (``(inf, None)``: it cannot be)."""
    x = problem.project(x)
    if safety is not None:
        x = make_safe(safety, x)
    return (problem.value(x), x) if x is not None else (math.inf, None)


class _Watch:
    """The objective's evaluations: the status line (start, evaluations, the criterion and the best so far) and the
    best feasible point of the current start (:func:`solve_starts`)."""

    def __init__(self, status: Status | None, starts: int, problem, safety) -> None:
        self.status, self.starts, self.problem, self.safety = status, starts, problem, safety
        self.linear = problem.linear_constraints()
        self.k, self.evals, self.best, self.t0 = 0, 0, math.inf, time.perf_counter()
        self.best_x, self.best_f = None, math.inf
        self.elsewhere = 0  # starts solved in worker processes meanwhile (the status line says so)

    def begin(self, k: int, f_start: float, x0: np.ndarray) -> None:
        self.k, self.evals, self.t0 = k, 0, time.perf_counter()
        self.best_x, self.best_f = np.asarray(x0, dtype=np.float64).copy(), f_start
        self.history = [(0, f_start)]  # (evaluation, best feasible criterion) at each improvement
        if self.status is not None:
            self.status(f"{self._start()}: criterion {f_start:.5g} at the start")

    def _start(self) -> str:
        others = f" ({self.elsewhere} more in a worker process)" if self.elsewhere else ""
        return f"start {self.k + 1} of {self.starts}{others}"

    def __call__(self, f: float, x: np.ndarray) -> None:
        self.evals += 1
        if f < self.best_f and self._feasible(x):
            self.best_x, self.best_f = np.asarray(x, dtype=np.float64).copy(), f
            self.history.append((self.evals, f))
        if self.status is not None and math.isfinite(self.best_f):
            self.status(
                f"{self._start()}: {self.evals} evaluations, criterion {self.best_f:.5g}"
                + (f" (best start so far {self.best:.5g})" if math.isfinite(self.best) else "")
                + f", {time.perf_counter() - self.t0:.0f} s"
            )

    def settled(self) -> bool:
        """The best criterion improved by less than :data:`SETTLED` over the last quarter of the evaluations."""
        cut = 0.75 * self.evals
        before = [f for e, f in self.history if e <= cut]
        return bool(before) and before[-1] - self.best_f < SETTLED

    def _feasible(self, x: np.ndarray) -> bool:
        a, lo, hi = self.linear
        ax = a @ x
        scale = 1e-9 * np.maximum(1.0, np.abs(lo) + np.abs(hi))
        if np.any(ax < lo - scale) or np.any(ax > hi + scale):
            return False
        return self.safety is None or bool(np.all(self.safety.values(x) > 0))


def best_of(outcomes: list[StartOutcome]) -> tuple[np.ndarray | None, float, tuple[float, str] | None]:
    """``(best_x, best_f, unsafe)`` over the outcomes in start order: the first of the lowest criterion among the
    safe ones (None, inf: none), and the least violated constraint among the unsafe ends."""
    best_x, best_f, unsafe = None, math.inf, None
    for o in outcomes:
        if o.x is not None and o.f < best_f:
            best_x, best_f = o.x, o.f
        if o.unsafe is not None and (unsafe is None or o.unsafe[0] > unsafe[0]):
            unsafe = o.unsafe
    return best_x, best_f, unsafe
