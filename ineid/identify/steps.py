"""Steps 1 and 2 of a solve, shared by every method: the base least-squares fit of every configuration.

:func:`fit_dataset` fits the base parameters of every configuration: from fused normal-equation
blocks (:func:`fused_fit`) or through CasADi one configuration at a time (:func:`casadi_fits`), with
the sensor offsets taken out by centring when they are identified (their estimates:
:func:`bias_estimate`); then the residuals of that fit exactly, at the linear estimate
(:func:`estimate_residual_sums`, which also gives the reported residuals of any estimate;
:func:`predicted_wrench` is what an estimate predicts the sensors read). Every method of
:data:`ineid.identify.solve.ESTIMATORS` starts from its result, :attr:`DatasetFit.shared`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from ineid.channels import ChannelSet
from ineid.identify.extras import prior_with_extras, split
from ineid.identify.fused import casadi_predictions, information_blocks, residual_sums
from ineid.identify.identifiability import BaseParameters
from ineid.identify.known import with_known_uncertainty
from ineid.identify.least_squares import (
    BaseFit,
    axis_weights,
    concat_fits,
    fit_base,
    fit_base_blocks,
    with_exact_rss,
)
from ineid.identify.linear import Estimate, SharedFit, linear_theta, prior_map
from ineid.identify.qr_blocks import FactorBlocks, factor_blocks, fit_base_factors
from ineid.identify.settings import SolveSettings
from ineid.identify.systems import Offsets, predict_wrench, remove_offsets, stack, stack_casadi
from ineid.identify.time_correlation import FittedFrames, filtered_frames, recording_covariance
from ineid.progress import Progress
from ineid.robots.model import SMALL_JOB_FRAMES

REFERENCE_ROWS = 200_000
"""Frames per batch when configurations are refitted through the stacked QR (reference)."""
FACTOR_MAX_CONFIGS = 16
"""At most this many configurations of at least :data:`FACTOR_MIN_FRAMES` fitted frames in all (a few long
recordings) are fitted from their triangular factors (:func:`factor_fit`: exact, one pass over the frames, where
their normal equations are often too ill-conditioned and would be refitted through the QR of every row); more,
or fewer frames, from the normal-equation blocks (:func:`fused_fit`)."""
FACTOR_MIN_FRAMES = 4096
"""Fitted frames in all from which a few configurations take the factors (:data:`FACTOR_MAX_CONFIGS`)."""


@dataclass(frozen=True)
class DatasetFit:
    """Steps 1 and 2 of a solve of one dataset: the base fit every method starts from, and what goes with it.

    Attributes:
        shared: the base fit (:class:`ineid.identify.linear.SharedFit`), handed to the method.
        offsets: the means taken out for the sensor offsets (``bias="estimate"``), else None.
        sums: :func:`estimate_residual_sums` at the linear estimate ``shared.theta_lin``.
        seconds: (C,) what the base fit took per configuration.
        factors: the triangular factors of the fitted and held-out frames (:func:`factor_fit`), or None.
    """

    shared: SharedFit
    offsets: Offsets | None
    sums: tuple
    seconds: np.ndarray
    factors: FactorResiduals | None = None

    def residual_sums(self, model, ds, frames: tuple[int, int], theta_unknown, channels: ChannelSet) -> tuple:
        """:func:`estimate_residual_sums` of ``theta_unknown`` (C, n): from the factors where there are, else by a
        pass over ``frames = (fitted, held out)`` of ``ds``."""
        if self.factors is not None:
            return self.factors.sums(theta_unknown)
        return estimate_residual_sums(model, ds, *frames, theta_unknown, channels, self.offsets)


@dataclass(frozen=True)
class FactorResiduals:
    """The triangular factors of a solve's fitted frames (centred where offsets are fitted) and of its held-out
    ones (:mod:`ineid.identify.qr_blocks`): the residual sums of any estimate without a pass over the frames,
    ``W theta = W_b B theta`` on every frame (with offsets, the base parameters are the centred frames':
    ``W theta - W_b B theta`` is then a constant per axis, which the offsets ``ybar - Wbar_b beta`` take).

    Attributes:
        fitted: the fitted frames' factors; held: the held-out frames' (with the column of ones with offsets),
            or None; ss_held: (C,) the held-out measured values' sum of squares; base: the base parameters;
            offsets: the means taken out of the fitted frames, or None.
    """

    fitted: FactorBlocks
    held: FactorBlocks | None
    ss_held: np.ndarray
    base: BaseParameters
    offsets: Offsets | None

    def sums(self, theta_unknown: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ssr_fit (C, A), ssr_held (C, A), ss_held (C,))`` as :func:`estimate_residual_sums` gives them."""
        theta = np.asarray(theta_unknown, dtype=np.float64)[:, : self.base.n_params]
        beta = np.nan_to_num(theta) @ self.base.B.T
        ssr_fit = self.fitted.axis_rss(beta)
        if self.held is None:
            return ssr_fit, np.zeros_like(ssr_fit), self.ss_held
        bias = None
        if self.offsets is not None:  # b = ybar - Wbar theta; W theta and W_b beta differ by a constant per axis
            off = self.offsets
            bias = off.y_mean - np.einsum("car,cr->ca", off.w_mean[..., self.base.base_index], beta)
            bias = bias if off.mask is None else bias * off.mask
        return ssr_fit, self.held.axis_rss(beta, bias), self.ss_held


def fit_dataset(
    ds,
    model,
    settings: SolveSettings,
    channels: ChannelSet,
    base: BaseParameters,
    frames: tuple[int, int],
    axis_sigma: np.ndarray | None,
    progress: Progress | None = None,
) -> DatasetFit:
    """Steps 1 and 2 of :func:`ineid.identify.solve.solve_dataset` (module doc): the base fit of ``channels``
    over the first of ``frames = (fitted, held out)`` of every configuration of ``ds``, and its residuals at the
    linear estimate, on every frame.

    Args:
        ds, model: the dataset and its robot.
        settings: ``backend`` (the route), ``weights`` (with ``axis_sigma``, the noise per axis of ``"noise"``),
            ``bias`` (offsets), ``known_uncertainty``; ``method``: only ``linear`` reports ``progress`` here.
        channels, base: the channels fitted and the base parameters of their unknowns.
    """
    n_fit, n_val = frames
    with_bias = settings.estimates_offsets
    prior = prior_with_extras(model, channels)  # [theta_cad_u, 0 for each extra parameter]
    fit_sl = slice(0, n_fit)

    # 1. base least squares, batched (or per configuration through CasADi)
    if settings.backend == "jax" and ds.n_configs <= FACTOR_MAX_CONFIGS and ds.n_configs * n_fit >= FACTOR_MIN_FRAMES:
        t0 = time.perf_counter()
        fit_progress = progress if settings.method == "linear" else None
        fit, rms, factors = factor_fit(model, ds, frames, base, settings, axis_sigma, channels, fit_progress)
        seconds = np.full(ds.n_configs, (time.perf_counter() - t0) / max(ds.n_configs, 1))
        theta_lin = linear_theta(fit, base, prior)  # 2. the residuals from the factors: exact, no pass
        fit = _time_correlated(model, ds, fit_sl, base, fit, channels, factors.offsets, theta_lin)
        if settings.known_uncertainty:
            fit = with_known_uncertainty(fit, model, base, ds, fit_sl, channels, settings.known_uncertainty, with_bias)
        shared = SharedFit(base, prior, fit, theta_lin, rms)
        return DatasetFit(shared, factors.offsets, factors.sums(theta_lin), seconds, factors)
    if settings.backend == "casadi":
        fit, rms, seconds, offsets = casadi_fits(
            model, ds, fit_sl, base, settings.weights, axis_sigma, with_bias, progress, channels
        )
    else:
        t0 = time.perf_counter()
        blocks_fn = information_blocks
        if settings.backend == "casadi-c":
            from ineid.identify.casadi_c import information_blocks_c as blocks_fn
        fit_progress = progress if settings.method == "linear" else None  # the other methods report their solves
        fit, rms, offsets = fused_fit(
            model, ds, fit_sl, base, settings.weights, axis_sigma, with_bias, fit_progress, blocks_fn, channels
        )
        seconds = np.full(ds.n_configs, (time.perf_counter() - t0) / max(ds.n_configs, 1))

    # 2. the residuals of the least-squares fit itself, exactly (one fused pass over every
    # frame at the linear estimate): the normal equations give the rss only up to
    # cancellation (eps * ||y||^2), the covariance and the IPOPT noise level need it exact
    theta_lin = linear_theta(fit, base, prior)
    sums = estimate_residual_sums(model, ds, n_fit, n_val, theta_lin, channels, offsets)
    fit = with_exact_rss(fit, sums[0])
    fit = _time_correlated(model, ds, fit_sl, base, fit, channels, offsets, theta_lin)
    if settings.known_uncertainty:  # the known links' CAD uncertainty (ineid.identify.known)
        fit = with_known_uncertainty(fit, model, base, ds, fit_sl, channels, settings.known_uncertainty, with_bias)
    return DatasetFit(SharedFit(base, prior, fit, theta_lin, rms), offsets, sums, seconds)


def _time_correlated(model, ds, fit_sl: slice, base, fit: BaseFit, channels, offsets, theta) -> BaseFit:
    """``fit`` with the covariance of residuals correlated in time when ``ds`` is a filtered recording
    (:mod:`ineid.identify.time_correlation`); as it is for independent frames."""
    parts = [FittedFrames(ds, fit_sl, offsets, filtered_frames(ds))]
    return recording_covariance(model, parts, base, fit, channels, theta)


def factor_fit(
    model,
    ds,
    frames: tuple[int, int],
    base: BaseParameters,
    settings: SolveSettings,
    axis_sigma: np.ndarray | None,
    channels: ChannelSet,
    progress: Progress | None = None,
) -> tuple[BaseFit, np.ndarray, FactorResiduals]:
    """The base fit of every configuration from the triangular factors of its rows (the QR of every stacked row,
    to round-off; :mod:`ineid.identify.qr_blocks`), the RMS of the weighted data (C,), and the factors of the
    fitted and held-out ``frames = (fitted, held out)`` for the residual sums of any estimate."""
    n_fit, n_val = frames
    with_bias = settings.estimates_offsets
    mask = channels.offset_mask(model)
    values = ds.measured(channels)

    def factors(sl: slice, progress=None) -> FactorBlocks:
        arrays = (ds.q[:, sl], ds.qd[:, sl], ds.qdd[:, sl], values[:, sl])
        return factor_blocks(model, base, *arrays, ds.theta_known, channels, with_bias, progress, n_fit)

    fitted, offsets = factors(slice(0, n_fit), progress), None
    if with_bias:
        fitted, offsets = fitted.centred(mask)
    lost = mask.astype(np.float64) if with_bias else None  # a residual degree of freedom per offset
    fit = fit_base_factors(fitted, base, settings.weights, axis_sigma, lost)
    held = factors(slice(n_fit, n_fit + n_val)) if n_val else None
    ss_held = np.sum(values[:, n_fit : n_fit + n_val] ** 2, axis=(1, 2))
    e = fitted.information().e
    rms = np.sqrt(np.einsum("ca,ca->c", fit.axis_weights**2, e) / (channels.n_axes(model) * n_fit))
    return fit, rms, FactorResiduals(fitted, held, ss_held, base, offsets)


def bias_estimate(off: Offsets, est: Estimate, base: BaseParameters) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``b = ybar - Wbar theta_hat`` (C, A) and their standard deviations (NaN on axes without offsets).

    ``ybar``'s noise is independent of ``beta_hat`` (fitted on the centred frames), so
    ``var(b_a) = s^2 / (d_a^2 F) + (Wbar T cov(beta) T^T Wbar^T)_aa`` with ``d_a`` the axis
    weight and ``T`` the null-space rule's map (:func:`ineid.identify.linear.prior_map`;
    the linearization for the IPOPT methods). Where a solve failed: NaN.
    """
    bias = off.bias(est.theta)
    g = np.einsum("cap,pr->car", off.w_mean, prior_map(base))
    var = np.einsum("car,crs,cas->ca", g, np.nan_to_num(est.fit.cov_beta), g)
    long_run = 1.0 if est.fit.axis_long_run is None else est.fit.axis_long_run  # frames correlated in time
    var += long_run * est.fit.sigma2[:, None] / (est.fit.axis_weights**2 * off.n_frames)
    std = np.sqrt(np.maximum(var, 0.0))
    bad = ~est.success
    bias[bad], std[bad] = np.nan, np.nan
    if off.mask is not None:
        bias[:, ~off.mask], std[:, ~off.mask] = np.nan, np.nan
    return bias, std


def _refit_stack(model, q, qd, qdd, wrench, theta_known, channels):
    """:func:`stack` of a few configurations, through CasADi when they are few frames
    (:data:`ineid.robots.model.SMALL_JOB_FRAMES`: no regressor kernel compiled for them)."""
    if q.shape[0] * q.shape[1] > SMALL_JOB_FRAMES:
        return stack(model, q, qd, qdd, wrench, theta_known, channels)
    pairs = [stack_casadi(model, q[c], qd[c], qdd[c], wrench[c], theta_known, channels) for c in range(q.shape[0])]
    return np.stack([w for w, _ in pairs]), np.stack([y for _, y in pairs])


def fused_fit(
    model,
    ds,
    fit_sl: slice,
    base: BaseParameters,
    weights: str,
    axis_sigma: np.ndarray | None,
    with_bias: bool,
    progress: Progress | None,
    blocks_fn=information_blocks,
    channels: ChannelSet | None = None,
) -> tuple[BaseFit, np.ndarray, Offsets | None]:
    """The base fit of every configuration from fused normal-equation blocks (``blocks_fn``) of ``channels``
    (default: the dataset's), ill-conditioned ones refitted through QR of their stacks; the RMS of the
    weighted data, (C,); ``with_bias`` (offsets identified): the fit of the frames centred per axis, and
    the means taken out."""
    channels = ds.meta.channels if channels is None else channels
    n_axes = channels.n_axes(model)
    mask = channels.offset_mask(model)
    q, qd, qdd = (a[:, fit_sl] for a in (ds.q, ds.qd, ds.qdd))
    wrench = ds.measured(channels)[:, fit_sl]
    # casadi-c fits one base wrench in the base frame, without offsets (refused otherwise: solve_channels)
    extra: dict = {"channels": channels, "sums": with_bias} if blocks_fn is information_blocks else {}
    if blocks_fn is information_blocks and not with_bias and weights != "estimate":
        # the row weights are known before the frames are read: blocks summed over the axes
        extra["axis_weights"] = axis_weights(weights, axis_sigma, ds.n_configs, n_axes)
    blocks = blocks_fn(model, base, q, qd, qdd, wrench, ds.theta_known, progress=progress, **extra)
    offsets = None
    lost = mask.astype(np.float64) if with_bias else None  # a residual degree of freedom per offset
    if with_bias:
        blocks, offsets = blocks.centred(base, mask)
    fit, refit = fit_base_blocks(blocks, base, weights, axis_sigma, lost)
    rows = np.flatnonzero(refit)
    per = max(1, REFERENCE_ROWS // max(blocks.n_frames, 1))
    for start in range(0, len(rows), per):
        idx = rows[start : start + per]
        w, y = _refit_stack(model, q[idx], qd[idx], qdd[idx], wrench[idx], ds.theta_known, channels)
        if with_bias:
            w, y, _ = remove_offsets(w, y, n_axes, mask)
        ref = fit_base(w, y, base, weights, axis_sigma, n_axes, lost)
        for f in dataclasses.fields(BaseFit):
            if f.name != "dof" and getattr(fit, f.name) is not None:
                getattr(fit, f.name)[idx] = getattr(ref, f.name)
    _, _, yy = blocks.weighted(fit.axis_weights)
    return fit, np.sqrt(yy / (n_axes * blocks.n_frames)), offsets


def casadi_fits(
    model,
    ds,
    fit_sl: slice,
    base: BaseParameters,
    weights: str,
    axis_sigma: np.ndarray | None,
    with_bias: bool,
    progress: Progress | None,
    channels: ChannelSet | None = None,
) -> tuple[BaseFit, np.ndarray, np.ndarray, Offsets | None]:
    """The linear fit through CasADi, one configuration at a time (an independent route): the fit, the RMS of
    the weighted data (C,), the seconds each configuration took (C,) and, ``with_bias``, the means taken out."""
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
        if with_bias:
            mask = channels.offset_mask(model)
            wc, yc, off = remove_offsets(w[None], y[None], n_axes, mask)
            w, y, lost = wc[0], yc[0], np.asarray(mask, dtype=np.float64)
            offsets.append(off)
        f = fit_base(w[None], y[None], base, weights, axis_sigma, n_axes, lost)
        beta = fit_base_casadi(w, y, base, f.axis_weights[0])
        if f.full_rank[0]:
            f.beta[0] = beta
        fits.append(f)
        rows = np.tile(f.axis_weights[0], y.shape[0] // n_axes)
        rms[i] = np.sqrt(np.mean((y * rows) ** 2))
        seconds[i] = time.perf_counter() - t0
        if progress is not None:
            progress(i + 1, ds.n_configs)
    return concat_fits(fits), rms, seconds, Offsets.concat(offsets) if with_bias else None


def fit_base_casadi(w: np.ndarray, y: np.ndarray, base: BaseParameters, axis_w: np.ndarray | None = None):
    """One configuration's base fit through CasADi's QR (an independent route); (r,) beta.

    ``w`` (AF, 10 n_u) and ``y`` (AF,); ``axis_w`` (A,) optional row weights (default: none, six axes).
    """
    import casadi as ca

    n = w.shape[0]
    axis_w = np.ones(6) if axis_w is None else np.asarray(axis_w, dtype=np.float64)
    rows = np.tile(axis_w, n // len(axis_w))
    a = ca.DM(w[:, base.base_index] * rows[:, None])
    b = ca.DM(y * rows)
    q, r = ca.qr(a)
    beta = ca.solve(r, ca.mtimes(q.T, b))
    return np.array(beta).ravel()


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
    q, qd, qdd = (np.asarray(a[:, frames], dtype=np.float64) for a in (ds.q, ds.qd, ds.qdd))
    if q.shape[0] * q.shape[1] <= SMALL_JOB_FRAMES:  # a few frames: CasADi's rows, no kernel compiled for them
        n_configs = q.shape[0]
        links = np.broadcast_to(np.asarray(theta, dtype=np.float64), (n_configs, theta.shape[-1]))
        both = np.concatenate([links, np.asarray(extra, dtype=np.float64).reshape(n_configs, -1)], axis=1)
        w = casadi_predictions(model, channels, (q, qd, qdd), both)
    else:
        w = predict_wrench(model, q, qd, qdd, theta, channels, extra if extra.shape[-1] else None)
    gain = _torque_constant_gain(model, theta_u, channels)
    if gain is not None:
        w = w * gain[:, None, :]
    return w if bias is None else w + np.nan_to_num(bias)[:, None, :]
