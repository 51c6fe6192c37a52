"""The steps of :func:`ineid.identify.solve.solve_dataset`, method by method.

The base least-squares fit of every configuration, from fused normal-equation blocks
(:func:`_fused_fit`) or through CasADi one configuration at a time (:func:`_casadi_fits`);
the sensor offsets and their standard deviations (:func:`_bias_estimate`); the IPOPT
solves of ``nonlinear`` and ``consistent``, in worker processes when there are many
(:func:`_run_nlp`) from a physical start (:func:`physical_start`); and the residuals of the
estimates on the fitted and held-out frames (:func:`estimate_residual_sums`,
:func:`residual_summary`, :func:`predicted_wrench`). ``settings`` is a
:class:`ineid.identify.solve.SolveSettings`.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import time

import numpy as np

from ineid.channels import ChannelSet
from ineid.identify.extras import split
from ineid.identify.fused import information_blocks, residual_sums
from ineid.identify.identifiability import BaseParameters
from ineid.identify.linear import BaseFit, Estimate, axis_weights, fit_base, fit_base_blocks, fit_base_casadi
from ineid.identify.nlp import NlpSolver, estimate_from_solves, nlp_estimate
from ineid.identify.systems import Offsets, predict_wrench, remove_offsets, stack, stack_casadi
from ineid.robots.model import SMALL_JOB_FRAMES

log = logging.getLogger(__name__)

PARALLEL_MIN_CONFIGS = 256
"""Fewer configurations are solved in this process: starting workers costs about a second."""


def _offset_dof(fit: BaseFit, n_offsets: int = 6) -> None:
    """``n_offsets`` more fitted unknowns (the offsets; six for the base wrench): ``s^2 = rss / (AF - r - n_offsets)``,
    covariance alike."""
    scale = fit.dof / max(fit.dof - n_offsets, 1)
    fit.dof -= n_offsets
    fit.sigma2 *= scale
    fit.cov_beta *= scale


def _bias_estimate(off: Offsets, est: Estimate, base: BaseParameters):
    """Offsets ``b = ybar - Wbar theta_hat`` (C, A) and their standard deviations (NaN on axes without offsets).

    ``ybar``'s noise is independent of ``beta_hat`` (fitted on the centred frames), so
    ``var(b_a) = s^2 / (d_a^2 F) + (Wbar T cov(beta) T^T Wbar^T)_aa`` with ``d_a`` the axis
    weight and ``T`` the null-space rule's map (:func:`ineid.identify.linear.prior_map`;
    the linearization for the IPOPT methods). Where a solve failed: NaN.
    """
    from ineid.identify.linear import prior_map

    bias = off.bias(est.theta)
    g = np.einsum("cap,pr->car", off.w_mean, prior_map(base))
    var = np.einsum("car,crs,cas->ca", g, np.nan_to_num(est.fit.cov_beta), g)
    var += est.fit.sigma2[:, None] / (est.fit.axis_weights**2 * off.n_frames)
    std = np.sqrt(np.maximum(var, 0.0))
    bad = ~est.success
    bias[bad], std[bad] = np.nan, np.nan
    if off.mask is not None:
        bias[:, ~off.mask], std[:, ~off.mask] = np.nan, np.nan
    return bias, std


def _concat_fits(fits: list[BaseFit]) -> BaseFit:
    if len(fits) == 1:
        return fits[0]
    cat = {
        f.name: np.concatenate([getattr(x, f.name) for x in fits])
        for f in dataclasses.fields(BaseFit)
        if f.name != "dof"
    }
    return BaseFit(dof=fits[0].dof, **cat)


def _links_and_extra(model, theta_unknown, channels: ChannelSet) -> tuple[np.ndarray, np.ndarray]:
    """``(theta_u, x)`` of estimates (NaN as zeros): ``[theta_u, x]`` split, or links alone (``x`` empty) when
    they hold no extra parameters (a solver that does not fit them, such as a trained network)."""
    theta = np.nan_to_num(theta_unknown)
    n_extra, n_u = channels.n_extra(model), len(model.unknown_index)
    if theta.shape[-1] > n_u + n_extra:  # identified torque constants after x (ineid.identify.two_step)
        return theta[..., :n_u], theta[..., n_u : n_u + n_extra]
    return split(theta, n_extra if theta.shape[-1] == n_u + n_extra else 0)


def _torque_constant_gain(model, theta_unknown, channels: ChannelSet) -> np.ndarray | None:
    """(C, A) ``k0 / k`` on the axes of motor currents whose torque constants ``[theta_u, x, k]`` holds (the
    prediction ``T (Y theta + E x)`` read through the identified constants), 1 elsewhere; None without them."""
    theta = np.asarray(theta_unknown, dtype=np.float64)
    start = len(model.unknown_index) + channels.n_extra(model)
    if theta.shape[-1] <= start:
        return None
    gain = np.ones((theta.shape[0], channels.n_axes(model)))
    for b in channels.blocks(model):
        if getattr(b.channel, "identify_k", False):
            k0 = np.asarray(b.channel.torque_constant)
            gain[:, b.start : b.stop] = k0 / theta[:, start : start + len(k0)]
            start += len(k0)
    return gain


def estimate_residual_sums(
    model,
    ds,
    n_fit: int,
    n_val: int,
    theta_unknown: np.ndarray,
    channels: ChannelSet | None = None,
    offsets: Offsets | None = None,
):
    """:func:`ineid.identify.fused.residual_sums` of the unknown links' estimates (NaN rows as zeros) on
    ``channels`` (default: the dataset's), in each channel's own axes, with the offsets
    ``b = ybar - Wbar theta`` that go with them. With extra kept columns ``theta_unknown`` is
    ``[theta_u, x]`` (C, 10 n_u + n_extra) and the prediction ``T Phi theta + E x``."""
    channels = ds.meta.channels if channels is None else channels
    links, extra = _links_and_extra(model, theta_unknown, channels)
    theta = model.full_theta(links, ds.theta_known)
    bias = None if offsets is None else np.nan_to_num(offsets.bias(theta_unknown))
    frames = slice(0, n_fit + n_val)
    return residual_sums(
        model,
        ds.q[:, frames],
        ds.qd[:, frames],
        ds.qdd[:, frames],
        ds.measured(channels)[:, frames],
        theta,
        n_fit,
        bias,
        channels,
        extra if extra.shape[-1] else None,
    )


def residual_summary(sums, n_fit: int, n_val: int, theta_unknown: np.ndarray):
    """``(fit_rms (C, A), validation_rms (C, A), validation_rel (C,))`` from :func:`estimate_residual_sums`.

    ``rms_a = sqrt(ssr_a / frames)`` per measured axis; ``rel = ||R - predicted|| / ||R||`` over the
    held-out frames; NaN where ``theta_unknown`` has a non-finite entry (a failed solve) and,
    for the held-out columns, when no frame is held out.
    """
    ssr_fit, ssr_held, ss_held = sums
    failed = ~np.all(np.isfinite(theta_unknown), axis=1)
    fit_rms = np.sqrt(ssr_fit / n_fit)
    fit_rms[failed] = np.nan
    c = len(theta_unknown)
    if not n_val:
        return fit_rms, np.full(ssr_fit.shape, np.nan), np.full(c, np.nan)
    val_rms = np.sqrt(ssr_held / n_val)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero wrench: inf (ineid solve warns)
        val_rel = np.sqrt(ssr_held.sum(axis=1)) / np.sqrt(ss_held)
    val_rms[failed] = np.nan
    val_rel[failed] = np.nan
    return fit_rms, val_rms, val_rel


REFERENCE_ROWS = 200_000
"""Frames per batch when configurations are refitted through the stacked QR (reference)."""


def _refit_stack(model, q, qd, qdd, wrench, theta_known, channels):
    """:func:`stack` of a few configurations, through CasADi when they are few frames
    (:data:`ineid.robots.model.SMALL_JOB_FRAMES`: no regressor kernel compiled for them)."""
    if q.shape[0] * q.shape[1] > SMALL_JOB_FRAMES:
        return stack(model, q, qd, qdd, wrench, theta_known, channels)
    pairs = [stack_casadi(model, q[c], qd[c], qdd[c], wrench[c], theta_known, channels) for c in range(q.shape[0])]
    return np.stack([w for w, _ in pairs]), np.stack([y for _, y in pairs])


def _fused_fit(
    model,
    ds,
    fit_sl,
    base,
    settings,
    axis_sigma,
    progress,
    blocks_fn=information_blocks,
    channels: ChannelSet | None = None,
) -> tuple[BaseFit, np.ndarray, Offsets | None]:
    """The base fit of every configuration from fused normal-equation blocks (``blocks_fn``) of ``channels``
    (default: the dataset's), ill-conditioned ones refitted through QR of their stacks; the RMS of the
    weighted data, (C,); with offsets (``settings.bias == "estimate"``) the fit of the frames centred per
    axis, and the means taken out."""
    channels = ds.meta.channels if channels is None else channels
    n_axes = channels.n_axes(model)
    mask = channels.offset_mask(model)
    q, qd, qdd = (a[:, fit_sl] for a in (ds.q, ds.qd, ds.qdd))
    wrench = ds.measured(channels)[:, fit_sl]
    with_bias = settings.bias == "estimate"
    # casadi-c fits one base wrench in the base frame, without offsets (refused otherwise: solve_channels)
    extra: dict = {"channels": channels, "sums": with_bias} if blocks_fn is information_blocks else {}
    if blocks_fn is information_blocks and not with_bias and settings.weights != "estimate":
        # the row weights are known before the frames are read: blocks summed over the axes
        extra["axis_weights"] = axis_weights(settings.weights, axis_sigma, ds.n_configs, n_axes)
    blocks = blocks_fn(model, base, q, qd, qdd, wrench, ds.theta_known, progress=progress, **extra)
    offsets = None
    lost = mask.astype(np.float64) if with_bias else None  # a residual degree of freedom per offset
    if with_bias:
        blocks, offsets = blocks.centred(base, mask)
    fit, refit = fit_base_blocks(blocks, base, settings.weights, axis_sigma, lost)
    rows = np.flatnonzero(refit)
    per = max(1, REFERENCE_ROWS // max(blocks.n_frames, 1))
    for start in range(0, len(rows), per):
        idx = rows[start : start + per]
        w, y = _refit_stack(model, q[idx], qd[idx], qdd[idx], wrench[idx], ds.theta_known, channels)
        if with_bias:
            w, y, _ = remove_offsets(w, y, n_axes, mask)
        ref = fit_base(w, y, base, settings.weights, axis_sigma, n_axes, lost)
        for f in dataclasses.fields(BaseFit):
            if f.name != "dof":
                getattr(fit, f.name)[idx] = getattr(ref, f.name)
    _, _, yy = blocks.weighted(fit.axis_weights)
    return fit, np.sqrt(yy / (n_axes * blocks.n_frames)), offsets


def _casadi_fits(model, ds, fit_sl, base, settings, axis_sigma, progress, channels: ChannelSet | None = None):
    """The linear fit through CasADi, one configuration at a time (an independent route)."""
    channels = ds.meta.channels if channels is None else channels
    n_axes = channels.n_axes(model)
    values = ds.measured(channels)
    fits, rms, seconds, offsets = [], np.empty(ds.n_configs), np.zeros(ds.n_configs), []
    for i in range(ds.n_configs):
        t0 = time.perf_counter()
        w, y = stack_casadi(
            model, ds.q[i, fit_sl], ds.qd[i, fit_sl], ds.qdd[i, fit_sl], values[i, fit_sl], ds.theta_known, channels
        )
        lost = None
        if settings.bias == "estimate":
            mask = channels.offset_mask(model)
            wc, yc, off = remove_offsets(w[None], y[None], n_axes, mask)
            w, y, lost = wc[0], yc[0], np.asarray(mask, dtype=np.float64)
            offsets.append(off)
        f = fit_base(w[None], y[None], base, settings.weights, axis_sigma, n_axes, lost)
        beta = fit_base_casadi(w, y, base, f.axis_weights[0])
        if f.full_rank[0]:
            f.beta[0] = beta
        fits.append(f)
        rows = np.tile(f.axis_weights[0], y.shape[0] // n_axes)
        rms[i] = np.sqrt(np.mean((y * rows) ** 2))
        seconds[i] = time.perf_counter() - t0
        if progress is not None:
            progress(i + 1, ds.n_configs)
    return fits, rms, seconds, offsets


def physical_start(theta_lin: np.ndarray, prior: np.ndarray, scales: np.ndarray, n_extra: int = 0) -> np.ndarray:
    """Linear estimates as IPOPT starts, moved towards the prior until they are rigid bodies.

    Per configuration, ``prior + t (theta_lin - prior)`` with the largest ``t`` in
    ``1, 1/2, ..., 1/64`` whose links all have a positive definite pseudo-inertia, in each
    link's mass and length units (smallest eigenvalue at least 1e-4 of the largest);
    the prior where none does (it must be physical). The last ``n_extra`` entries (the
    channels' extra parameters) start at the linear estimate (the solver clips them to their bounds).
    """
    from ineid.identify.nlp import scaled_pseudo_inertia

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


BIAS_MAX_ITER = 3000
"""IPOPT iterations with offsets estimated (500 otherwise): centring the frames worsens the scaled
problem's conditioning (``sweaty-arm``: 52 -> 279) and the consistent solver from the CAD start
took 807 iterations on the MuJoCo test recording (a few tenths of a second)."""


def _nlp_options(settings) -> dict | None:
    return {"max_iter": BIAS_MAX_ITER} if settings.bias == "estimate" else None


def _nlp_worker_init(method, base, prior, pull, entropic, compiled, options=None, stop=None):
    global _WORKER_SOLVER, _WORKER_STOP  # one compiled solver per worker process
    # Ctrl-C and SIGTERM are the main process's to handle: it sets ``stop`` and drops the queued blocks
    # (a worker interrupted on its own would print a traceback, or die and break the pool)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _WORKER_STOP = stop
    _WORKER_SOLVER = NlpSolver.build(method, base, prior, pull, entropic, options, compiled=compiled)


def _nlp_worker(args):
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


def _run_nlp(fit, base, settings, prior, rms, start, progress) -> tuple[Estimate, np.ndarray]:
    c = fit.beta.shape[0]
    start = np.broadcast_to(start, (c, base.n_params))
    workers = settings.workers or 1
    seconds = np.zeros(c)
    if workers <= 1 or c < PARALLEL_MIN_CONFIGS:
        solver = NlpSolver.build(
            settings.method,
            base,
            prior,
            settings.pull,
            settings.entropic,
            _nlp_options(settings),
            compiled=settings.backend == "casadi-c",
        )
        t = [time.perf_counter()]

        def timed(done, total):
            now = time.perf_counter()
            seconds[done - 1] = now - t[0]
            t[0] = now
            if progress is not None:
                progress(done, total)

        log.info("IPOPT: %s solves of %d configurations", settings.method, c)
        est = nlp_estimate(fit, solver, rms, start, progress=timed)
        return est, seconds
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    block = max(8, min(256, c // (4 * workers)))
    jobs = [
        (
            fit.R[i : i + block],
            fit.beta[i : i + block],
            fit.sigma2[i : i + block],
            rms[i : i + block],
            start[i : i + block],
            fit.full_rank[i : i + block],
        )
        for i in range(0, c, block)
    ]
    theta = np.full((c, base.n_params), np.nan)
    success = np.zeros(c, dtype=bool)
    status = np.empty(c, dtype=object)
    ctx = mp.get_context("spawn")  # JAX's threads and fork do not mix
    log.info("IPOPT: %s solves of %d configurations in %d worker processes", settings.method, c, workers)
    stop = ctx.Event()
    with ProcessPoolExecutor(
        workers,
        mp_context=ctx,
        initializer=_nlp_worker_init,
        initargs=(
            settings.method,
            base,
            prior,
            settings.pull,
            settings.entropic,
            settings.backend == "casadi-c",
            _nlp_options(settings),
            stop,
        ),
    ) as pool:
        try:
            done = 0
            for j, out in enumerate(pool.map(_nlp_worker, jobs)):
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
    return estimate_from_solves(theta, success, status, fit, base), seconds


def predicted_wrench(
    model, ds, theta_u, frames=slice(None), bias=None, channels: ChannelSet | None = None
) -> np.ndarray:
    """What the estimates predict the sensors read: ``T Phi theta + E x + b`` (C, F, A) on ``frames`` of ``ds``.

    Args:
        theta_u: (C, 10 n_u) the unknown links' estimates (the known links' come from ``ds``); with
            extra kept columns ``[theta_u, x]`` (C, 10 n_u + n_extra).
        bias: (C, A) estimated offsets, or None.
        channels: the channels predicted (default: the dataset's; the base wrench in its sensor's frame).
    """
    channels = ds.meta.channels if channels is None else channels
    links, extra = _links_and_extra(model, theta_u, channels)
    theta = model.full_theta(links, ds.theta_known)
    w = predict_wrench(
        model, ds.q[:, frames], ds.qd[:, frames], ds.qdd[:, frames], theta, channels, extra if extra.shape[-1] else None
    )
    gain = _torque_constant_gain(model, theta_u, channels)
    if gain is not None:
        w = w * gain[:, None, :]
    return w if bias is None else w + np.nan_to_num(bias)[:, None, :]
