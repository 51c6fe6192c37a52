"""The ``nonlinear`` and ``consistent`` methods: an IPOPT solve per configuration, from the shared base fit.

Each configuration's problem (:class:`ineid.identify.nlp.NlpSolver`, compiled once for the base
parameters and the prior) is solved from a start, the prior or the linear estimate made physical
(:func:`physical_start`); from :data:`PARALLEL_MIN_CONFIGS` configurations on, and with
``SolveSettings.workers`` above one, in spawned worker processes, blocks of configurations each
(:func:`run_nlp`). :func:`nlp_method` is the methods' entry of
:data:`ineid.identify.solve.ESTIMATORS`.
"""

from __future__ import annotations

import logging
import signal
import time

import numpy as np

from ineid.identify.identifiability import BaseParameters
from ineid.identify.linear import BaseFit, Estimate, MethodEstimate, SharedFit
from ineid.identify.nlp import MAX_ITER, NlpSolver, estimate_from_solves, nlp_estimate, scaled_pseudo_inertia
from ineid.identify.settings import SolveSettings
from ineid.progress import Progress

log = logging.getLogger(__name__)

PARALLEL_MIN_CONFIGS = 256
"""Fewer configurations are solved in this process: starting workers costs about a second."""
BIAS_MAX_ITER = MAX_ITER
"""IPOPT iterations with offsets estimated: the cap of every IPOPT solve (:data:`ineid.identify.nlp.MAX_ITER`)."""


def physical_start(theta_lin: np.ndarray, prior: np.ndarray, scales: np.ndarray, n_extra: int = 0) -> np.ndarray:
    """Linear estimates as IPOPT starts, moved towards the prior until they are rigid bodies.

    Per configuration, ``prior + t (theta_lin - prior)`` with the largest ``t`` in
    ``1, 1/2, ..., 1/64`` whose links all have a positive definite pseudo-inertia, in each
    link's mass and length units (smallest eigenvalue at least 1e-4 of the largest);
    the prior where none does (it must be physical). The last ``n_extra`` entries (the
    channels' extra parameters) start at the linear estimate (the solver clips them to their bounds).
    """
    if n_extra:
        n = np.shape(theta_lin)[-1] - n_extra
        links = physical_start(np.asarray(theta_lin)[..., :n], np.asarray(prior)[..., :n], np.asarray(scales)[:n])
        extra = np.where(np.isfinite(theta_lin[..., n:]), theta_lin[..., n:], np.asarray(prior)[..., n:])
        return np.concatenate([links, extra], axis=-1)
    lin = np.where(np.isfinite(theta_lin), theta_lin, prior)
    c = len(lin)
    start = np.broadcast_to(prior, lin.shape).copy()
    pending = np.ones(c, dtype=bool)
    for t in 0.5 ** np.arange(7):
        cand = prior + t * (lin - prior)
        good = pending.copy()
        for i in np.flatnonzero(pending):
            w = np.linalg.eigvalsh(scaled_pseudo_inertia(cand[i], scales))
            good[i] = bool(np.all(w[:, 0] >= 1e-4 * w[:, -1]))
        start[good] = cand[good]
        pending &= ~good
    return start


def nlp_method(shared: SharedFit, settings: SolveSettings, progress: Progress | None = None) -> MethodEstimate:
    """``nonlinear`` or ``consistent`` (``settings.method``) on the shared base fit, from ``settings.start``:
    the prior, or the linear estimate made physical (:func:`physical_start`)."""
    base = shared.base
    if settings.start == "prior":
        start = shared.prior
    else:
        start = physical_start(shared.theta_lin, shared.prior, base.scales, base.n_extra)
    est, seconds = run_nlp(shared.fit, base, shared.prior, shared.data_rms, start, settings, progress)
    return MethodEstimate(est, seconds)


def run_nlp(
    fit: BaseFit,
    base: BaseParameters,
    prior: np.ndarray,
    data_rms: np.ndarray,
    start: np.ndarray,
    settings: SolveSettings,
    progress: Progress | None = None,
) -> tuple[Estimate, np.ndarray]:
    """The IPOPT estimates of every configuration of ``fit`` (:func:`ineid.identify.nlp.nlp_estimate`) and the
    seconds each took (C,): in this process, or in ``settings.workers`` processes from
    :data:`PARALLEL_MIN_CONFIGS` configurations on.

    Args:
        fit: the base least-squares fit; base, prior: the problem's base parameters and prior (n,).
        data_rms: (C,) RMS of the weighted data (the noise floor of the variance).
        start: (n,) or (C, n) the starts, as standard parameters.
        settings: ``method``, ``pull``, ``entropic``, ``workers``; ``bias`` (:data:`BIAS_MAX_ITER`) and
            ``backend`` (``casadi-c``: the problem compiled).
    """
    c = fit.beta.shape[0]
    start = np.broadcast_to(start, (c, base.n_params))
    build = (
        settings.method,
        base,
        prior,
        settings.pull,
        settings.entropic,
        {"max_iter": BIAS_MAX_ITER} if settings.estimates_offsets else None,
        settings.backend == "casadi-c",
    )
    workers = settings.workers or 1
    if workers <= 1 or c < PARALLEL_MIN_CONFIGS:
        return _run_here(fit, data_rms, start, build, progress)
    return _run_in_workers(fit, data_rms, start, build, workers, progress)


def _run_here(fit: BaseFit, data_rms, start, build: tuple, progress: Progress | None) -> tuple[Estimate, np.ndarray]:
    """:func:`run_nlp` in this process: one compiled solver (``build``: :meth:`NlpSolver.build`'s arguments)."""
    method, base, prior, pull, entropic, options, compiled = build
    solver = NlpSolver.build(method, base, prior, pull, entropic, options, compiled=compiled)
    c = fit.beta.shape[0]
    seconds = np.zeros(c)
    t = [time.perf_counter()]

    def timed(done, total):
        now = time.perf_counter()
        seconds[done - 1] = now - t[0]
        t[0] = now
        if progress is not None:
            progress(done, total)

    log.info("IPOPT: %s solves of %d configurations", method, c)
    return nlp_estimate(fit, solver, data_rms, start, progress=timed), seconds


def _worker_init(build: tuple, stop=None) -> None:
    """A worker process's one compiled solver (``build``: :meth:`NlpSolver.build`'s arguments)."""
    global _WORKER_SOLVER, _WORKER_STOP  # one compiled solver per worker process
    # Ctrl-C and SIGTERM are the main process's to handle: it sets ``stop`` and drops the queued blocks
    # (a worker interrupted on its own would print a traceback, or die and break the pool)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    method, base, prior, pull, entropic, options, compiled = build
    _WORKER_STOP = stop
    _WORKER_SOLVER = NlpSolver.build(method, base, prior, pull, entropic, options, compiled=compiled)


def _worker(args):
    """One block of configurations in a worker: ``(theta or None, success, status, seconds)`` each."""
    r, beta, sigma2, rms, start, full_rank = args
    out = []
    for i in range(len(r)):
        if _WORKER_STOP is not None and _WORKER_STOP.is_set():
            break  # the main process was interrupted: it reads nothing more
        t0 = time.perf_counter()
        if not full_rank[i]:
            out.append((None, False, None, time.perf_counter() - t0))
            continue
        th, ok, status, _ = _WORKER_SOLVER.solve_one(r[i], beta[i], sigma2[i], rms[i], start[i])
        out.append((th, ok, status, time.perf_counter() - t0))
    return out


def _run_in_workers(
    fit: BaseFit, data_rms, start, build: tuple, workers: int, progress: Progress | None
) -> tuple[Estimate, np.ndarray]:
    """:func:`run_nlp` in ``workers`` spawned processes, blocks of configurations each; an interruption or an
    error stops the pool at once (the queued blocks dropped)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    base = build[1]
    c = fit.beta.shape[0]
    block = max(8, min(256, c // (4 * workers)))
    jobs = [
        (
            fit.R[i : i + block],
            fit.beta[i : i + block],
            fit.sigma2[i : i + block],
            data_rms[i : i + block],
            start[i : i + block],
            fit.full_rank[i : i + block],
        )
        for i in range(0, c, block)
    ]
    theta = np.full((c, base.n_params), np.nan)
    success = np.zeros(c, dtype=bool)
    status = np.empty(c, dtype=object)
    seconds = np.zeros(c)
    ctx = mp.get_context("spawn")  # JAX's threads and fork do not mix
    log.info("IPOPT: %s solves of %d configurations in %d worker processes", build[0], c, workers)
    stop = ctx.Event()
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init, initargs=(build, stop)) as pool:
        try:
            done = 0
            for j, out in enumerate(pool.map(_worker, jobs)):
                for k, (th, ok, st, sec) in enumerate(out):
                    i = j * block + k
                    seconds[i] = sec
                    if th is None:
                        status[i] = f"rank_deficient ({fit.rank[i]} of {base.rank})"
                        continue
                    success[i] = ok
                    status[i] = "ok" if ok else st
                    if ok:
                        theta[i] = th
                done += len(out)
                if progress is not None:
                    progress(done, c)
        except BaseException:  # Ctrl-C, SIGTERM, an error: stop now, not once every queued block is solved
            stop.set()
            pool.shutdown(cancel_futures=True)
            raise
    method, _, prior, pull, entropic, options = build[:6]
    solver = NlpSolver.build(method, base, prior, pull, entropic, options)  # the problem's derivatives, for the std
    return estimate_from_solves(theta, success, status, fit, base, solver, data_rms), seconds
