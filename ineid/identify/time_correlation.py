"""The covariance of a least-squares fit on a filtered recording: residuals correlated in time, the filter's error.

An imported recording's frames are low-passed (:mod:`ineid.data.recordings.frames`: one zero-phase Butterworth at
the cut-off ``f_c`` on every channel, the angles differentiated after it). Its residuals are then far from
independent: white noise at ``f_s`` Hz low-passed at ``f_c`` keeps its correlation over about ``f_s / (2 f_c)``
frames, and ``sigma^2 (W^T D^2 W)^-1``, which counts every frame as a new draw, is that many times too small in
variance (RMS z 8.4 at 1 kHz and 10 Hz, 3.2 at 200 Hz; ``docs/identification.md``).

:func:`recording_covariance` counts each axis's residual variance ``kappa_a`` times,

    cov(beta_hat) = sigma^2 A^-1 (sum_a kappa_a d_a^2 G_a) A^-1,     A = sum_a d_a^2 G_a,

``kappa_a`` the variance of a mean of the axis's residuals over that of a mean of independent frames, taken from
the residuals' power density where the motion and the parameters are, ``[0, f_c / 4]``, with the fit's leverage
taken out of that band (:func:`band_long_run`); and adds ``delta delta^T``, ``delta`` what the filter and the
differentiation themselves move the estimate by, estimated from the data (:func:`filter_error`). The Newey-West
sandwich over the per-frame scores ``A^-1 (sum_l w_l Gamma_l) A^-1`` (:func:`moving_sum_covariance`) and the
filter's own gain (:func:`filter_gain`) are the alternatives measured: the first is biased low (the residuals lack
exactly the noise at the regressor's frequencies, which the fit absorbed), the second counts a differentiated
angle noise, which has no power at low frequencies, as white.

References:
    Newey & West (1987), Econometrica 55(3); Andrews (1991), Econometrica 59(3); MacKinnon & White (1985).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ineid.identify.least_squares import BaseFit, axis_leverage, r_inverse
from ineid.identify.systems import Offsets, predict_wrench, stack

LAG_PERIODS = 2.0
"""The Newey-West bandwidth in the filter's cut-off periods: ``L = LAG_PERIODS f_s / f_c`` lags."""
NYQUIST_SHARE = 0.45
"""The highest cut-off, as a share of the frames' rate, that :class:`ineid.data.recordings.signals.LowPass` takes."""
CHUNK_FRAMES = 4096
"""Frames per stacked chunk of the pass over the frames (one compiled regressor kernel: the last chunk padded)."""


@dataclass(frozen=True)
class FilteredFrames:
    """What makes a dataset's frames correlated in time: the low-pass its recording was imported with.

    Attributes:
        cutoff: Hz, the low-pass cut-off.
        rate: Hz, the frames' rate.
    """

    cutoff: float
    rate: float

    @property
    def lags(self) -> int:
        """The Newey-West bandwidth ``L`` (:func:`bandwidth`)."""
        return bandwidth(self.cutoff, self.rate)


def bandwidth(cutoff: float, rate: float) -> int:
    """``L = ceil(LAG_PERIODS rate / cutoff)`` lags, at least 1."""
    return max(1, math.ceil(LAG_PERIODS * rate / cutoff))


def filtered_frames(ds) -> FilteredFrames | None:
    """The low-pass of an imported recording (its origin's ``import`` record: cut-off and rate), or None for frames
    that are independent draws (a synthetic dataset, a recording imported without a filter). The frames' rate is
    their time stamps' where the dataset has them (a selection of every k-th frame is at ``rate / k``); a cut-off at
    or above :data:`NYQUIST_SHARE` of it leaves successive frames as good as independent (None)."""
    record = (ds.meta.origin or {}).get("import") or {}
    cutoff, rate = record.get("cutoff"), record.get("rate")
    if not cutoff or not rate:
        return None
    time = getattr(ds, "time", None)
    if time is not None and time.shape[-1] > 1:
        step = float(np.median(np.diff(np.asarray(time[0], dtype=np.float64))))
        rate = 1.0 / step if step > 0 else rate
    if cutoff >= NYQUIST_SHARE * rate:
        return None
    return FilteredFrames(float(cutoff), float(rate))


def moving_sum_covariance(scores: np.ndarray, lags: int) -> np.ndarray:
    """(r, r) Newey-West ``sum_{|l| <= L} (1 - |l| / (L + 1)) Gamma_l`` of scores (F, r), as the moving sums'
    second moment ``(1 / (L + 1)) sum_t S_t S_t^T`` (``S_t = s_{t-L} + ... + s_t``, zero beyond the ends)."""
    f, r = scores.shape
    cum = np.concatenate([np.zeros((1, r)), np.cumsum(scores, axis=0)])  # cum[k] = s_0 + ... + s_{k-1}
    t = np.arange(f + lags)
    total = cum[np.minimum(t + 1, f)] - cum[np.maximum(t - lags, 0)]
    return total.T @ total / (lags + 1)


def stacked_chunks(model, arrays, theta_known, channels, base_index):
    """``(start, stop, W_b, y)`` over chunks of :data:`CHUNK_FRAMES` frames of ``arrays = (q, qd, qdd, values)``
    (F, .) of one configuration: the base columns ``W_b`` (f, A, r) and the values less the known links' share
    (f, A); every chunk stacked at one shape (the last one padded), so one regressor kernel serves them all."""
    n_frames, n_axes = arrays[3].shape
    size = min(CHUNK_FRAMES, n_frames)
    for start in range(0, n_frames, size):
        stop = min(start + size, n_frames)
        take = np.minimum(np.arange(start, start + size), n_frames - 1)
        w, y = stack(model, *(a[None, take] for a in arrays), theta_known, channels)
        yield (
            start,
            stop,
            w[0][:, base_index].reshape(size, n_axes, -1)[: stop - start],
            y[0].reshape(size, n_axes)[: stop - start],
        )


def _predicted(model, states, theta, channels, extra) -> np.ndarray:
    """(F, A) :func:`ineid.identify.systems.predict_wrench` of one configuration's ``states = (q, qd, qdd)``, in
    chunks of :data:`CHUNK_FRAMES` frames at one shape (the last one padded)."""
    n_frames = len(states[0])
    size = min(CHUNK_FRAMES, n_frames)
    parts = []
    for start in range(0, n_frames, size):
        take = np.minimum(np.arange(start, start + size), n_frames - 1)
        parts.append(predict_wrench(model, *(a[None, take] for a in states), theta, channels, extra)[0])
    return np.concatenate(parts)[:n_frames]


def frame_scores(
    model, ds, fit_sl: slice, base, fit: BaseFit, channels, offsets: Offsets | None, config: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The per-frame scores ``s_t = sum_a d_a^2 w_ta r_ta`` (F, r) of configuration ``config`` of ``fit``, its
    residuals per axis (F, A) and the per-axis blocks ``G_a = sum_t w_ta w_ta^T`` (A, r, r), from the frames ``fit_sl``
    stacked in chunks of :data:`CHUNK_FRAMES`; with ``offsets`` the centred system's (the offsets' means taken out)."""
    q, qd, qdd = (a[config, fit_sl] for a in (ds.q, ds.qd, ds.qdd))
    values = ds.measured(channels)[config, fit_sl]
    n_frames, n_axes = values.shape
    idx = base.base_index
    beta, d2 = np.nan_to_num(fit.beta[config]), fit.axis_weights[config] ** 2
    if offsets is not None:
        mask = np.ones(n_axes) if offsets.mask is None else np.asarray(offsets.mask, dtype=np.float64)
        w_mean, y_mean = offsets.w_mean[config][:, idx] * mask[:, None], offsets.y_mean[config] * mask
    scores, resid = np.empty((n_frames, len(idx))), np.empty((n_frames, n_axes))
    g = np.zeros((n_axes, len(idx), len(idx)))
    for start, stop, w_b, y in stacked_chunks(model, (q, qd, qdd, values), ds.theta_known, channels, idx):
        if offsets is not None:
            w_b, y = w_b - w_mean[None], y - y_mean[None]
        r = y - w_b @ beta
        resid[start:stop] = r
        scores[start:stop] = np.einsum("fak,fa->fk", w_b, r * d2)
        g += np.einsum("fak,fal->akl", w_b, w_b)
    return scores, resid, g


@dataclass(frozen=True)
class FittedFrames:
    """One dataset's frames in a fit: ``ds``'s frames ``frames``, the offsets taken out of them (or None), and the
    low-pass they were recorded through (None: independent frames)."""

    ds: object
    frames: slice
    offsets: Offsets | None
    filtered: FilteredFrames | None


def filter_gain(filtered: FilteredFrames) -> float:
    """``kappa = 1 / sum_k g_k^2``: the variance of a mean of white noise after the low-pass over that of the mean
    of independent frames, ``g`` the zero-phase filter's impulse response (its DC gain 1): white noise of variance
    ``s^2`` leaves the filter with variance ``s^2 sum g_k^2`` and long-run variance ``s^2``."""
    from ineid.data.recordings.signals import LowPass

    n = 2 * math.ceil(20 * filtered.rate / filtered.cutoff) + 1
    impulse = np.zeros((n, 1))
    impulse[n // 2] = 1.0
    g = LowPass(filtered.cutoff, filtered.rate).apply(impulse)[:, 0]
    return float(1.0 / np.sum(g**2))


BAND = 0.25
"""The band of the residuals' spectrum that stands for the parameters' frequencies: ``[0, BAND f_c]``, where the
zero-phase filter passes 99 % of the power (``(1 + BAND^4)^-2``)."""


MIN_BAND_DOF = 16
"""Fewest degrees of freedom left in the band of :func:`band_long_run`: where ``[0, BAND f_c]`` holds fewer (a
short recording at a low cut-off, many parameters), the band widens up to ``f_c / 2`` until it holds them, and
beyond that the axis takes the filter's rule (:func:`recording_covariance`)."""


def band_long_run(resid: np.ndarray, filtered: FilteredFrames, removed: np.ndarray) -> np.ndarray:
    """(A,) each axis's residual power density in ``[0, BAND f_c]`` over its mean density: the variance of a mean
    over that of the mean of independent frames, the density taken where the motion and the parameters are, and
    below the filter's edge (a white noise's ``kappa``, not a differentiated noise's, which has none there).

    The fit takes ``removed`` (A,) degrees of freedom of each axis out of that band (its leverage ``h_a``, and the
    offset at zero frequency): the band's ``n`` degrees of freedom hold ``n - removed`` of the noise, scaled back;
    the band widens (up to ``f_c / 2``) until ``n - removed`` is at least :data:`MIN_BAND_DOF`.

    Args:
        resid: (F, A) the residuals on a uniform grid at ``filtered.rate``.

    Returns:
        (A,) the ratio; NaN where fewer than :data:`MIN_BAND_DOF` degrees of freedom are left up to ``f_c / 2``.
    """
    n = len(resid)
    power = np.abs(np.fft.rfft(resid, axis=0)) ** 2
    dof = np.full(len(power), 2.0)
    dof[0] = 1.0
    if n % 2 == 0:
        dof[-1] = 1.0
    freq = np.fft.rfftfreq(n, 1.0 / filtered.rate)
    cum_dof, cum_power = np.cumsum(dof), np.cumsum(dof[:, None] * power, axis=0)
    widest = np.searchsorted(freq, 0.5 * filtered.cutoff, side="right") - 1  # the band's widest edge
    ratio = np.full(power.shape[1], np.nan)
    mean = cum_power[-1] / np.maximum(cum_dof[-1] - removed, 1.0)
    for a in range(power.shape[1]):
        edge = max(np.searchsorted(freq, BAND * filtered.cutoff, side="right") - 1, 0)
        short = np.flatnonzero(cum_dof - removed[a] >= MIN_BAND_DOF)
        edge = max(edge, short[0] if len(short) else len(freq))
        if edge <= widest:
            ratio[a] = cum_power[edge, a] / (cum_dof[edge] - removed[a]) / max(mean[a], 1e-300)
    return ratio


ESTIMATORS = ("band", "filter", "newey-west")
"""What :func:`recording_covariance` can take the time correlation from (``docs/identification.md`` measures them)."""


def recording_covariance(
    model, parts: list[FittedFrames], base, fit: BaseFit, channels, theta: np.ndarray, estimator: str = "band"
) -> BaseFit:
    """``fit`` with the covariance of frames correlated in time (module doc), ``parts`` the datasets fitted together
    (independent of each other), plus ``delta delta^T`` for what the filter and the differentiation move the
    estimate by (:func:`filter_error`, at the fit's estimate ``theta`` (C, n)).

    Each axis's residual variance counts ``kappa_a`` times: ``cov = sigma2 A^-1 (sum_a kappa_a d_a^2 G_a) A^-1``,
    ``kappa_a`` by ``estimator`` (:data:`ESTIMATORS`): ``"band"`` (the default) the residuals' own power density
    where the parameters are (:func:`band_long_run`), at least 1, the filter's rule where the band holds too few
    degrees of freedom; ``"filter"`` the larger of the filter's
    (:func:`filter_gain`, exact for white noise before the filter) and the residuals' Bartlett long-run ratio;
    ``"newey-west"`` replaces the whole by the sandwich over the per-frame scores. A part of independent frames
    counts 1. What estimating the weights adds (the fit's ``cov_beta - sigma2 A^-1``) is kept, scaled by the
    square of the variance's growth (fewer effective frames); ``axis_long_run`` is set to the frame-weighted mean
    ``kappa_a`` (the offsets' std takes it). ``fit`` as it is when no part is filtered; rows not full rank stay
    NaN."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    if all(p.filtered is None for p in parts):
        return fit
    c_all, n_axes = fit.axis_weights.shape
    cov, long_run = fit.cov_beta.copy(), np.ones((c_all, n_axes))
    n_frames = [len(range(*p.frames.indices(p.ds.n_frames))) for p in parts]
    hc1 = n_axes * sum(n_frames) / max(fit.dof, 1)
    gains = [1.0 if p.filtered is None else filter_gain(p.filtered) for p in parts]
    for c in range(c_all):
        if not fit.full_rank[c] or not np.all(np.isfinite(fit.cov_beta[c])):
            continue
        a_inv = r_inverse(fit.R[c][None])[0]
        d2 = fit.axis_weights[c] ** 2
        omega, info, moved, lr = 0.0, 0.0, 0.0, 0.0
        for p, n, gain in zip(parts, n_frames, gains, strict=True):
            lags = 0 if p.filtered is None else p.filtered.lags
            scores, resid, g = frame_scores(model, p.ds, p.frames, base, fit, channels, p.offsets, c)
            plain = np.maximum(np.einsum("fa,fa->a", resid, resid), 1e-300)
            kappa = np.maximum(np.diag(moving_sum_covariance(resid, lags)) / plain, gain)  # the filter's rule
            if p.filtered is None:
                kappa = np.ones(n_axes)
            elif estimator == "band":  # never below independent frames' 1
                removed = axis_leverage(g[None], fit.axis_weights[c][None], a_inv[None])[0]
                band = band_long_run(resid, p.filtered, removed + _offset_axes(p.offsets, n_axes))
                kappa = np.where(np.isnan(band), kappa, np.maximum(band, 1.0))
            info = info + np.einsum("a,akl->kl", kappa * d2, g)
            lr = lr + n * kappa
            if estimator == "newey-west":
                omega = omega + moving_sum_covariance(scores, lags)
            if p.filtered is not None:
                args = (p.ds, p.frames, base, fit, channels, p.offsets, theta, p.filtered, c)
                moved = moved + filter_error(model, *args)
        if estimator == "newey-west":
            spread = hc1 * a_inv @ omega @ a_inv
        else:
            spread = fit.sigma2[c] * a_inv @ info @ a_inv
        naive = fit.sigma2[c] * a_inv
        growth = np.mean(np.diag(spread) / np.maximum(np.diag(naive), 1e-300))
        delta = a_inv @ np.broadcast_to(moved, a_inv.shape[:1])  # 0 where every part is too short
        cov[c] = spread + growth**2 * (fit.cov_beta[c] - naive) + np.outer(delta, delta)
        long_run[c] = lr / sum(n_frames)
    return dataclasses.replace(fit, cov_beta=cov, axis_long_run=long_run)


def _offset_axes(offsets: Offsets | None, n_axes: int) -> np.ndarray:
    """(A,) 1 on the axes whose offset was taken out, else 0."""
    if offsets is None:
        return np.zeros(n_axes)
    return np.ones(n_axes) if offsets.mask is None else np.asarray(offsets.mask, dtype=np.float64)


def filter_error(
    model,
    ds,
    fit_sl: slice,
    base,
    fit: BaseFit,
    channels,
    offsets: Offsets | None,
    theta: np.ndarray,
    filtered: FilteredFrames,
    config: int,
) -> np.ndarray | float:
    """(r,) ``W_b^T D^2 e``: what the low-pass and the differentiation do to configuration ``config``'s fit, as a
    score sum (the estimate moves by ``A^-1`` times it), estimated from the data; 0 for too few frames.

    The fit reads ``LP(y(q, qd, qdd))`` against the model at the filtered states ``y(LP q, d/dt LP q, ...)``; the two
    differ where the model is not linear in time (products of rates, the sign of a velocity), by ``e``. With the
    filtered states as a stand-in for the true ones (as :func:`ineid.data.recordings.imus.filter_model_error` does
    for the link IMUs), ``e`` is estimated as ``LP(y(s_f)) - y(LP s_f)`` at the fit's estimate ``theta`` (C, n)
    (``[theta_u, x]``), centred on the axes with offsets, the filter's start-up at each end left out (the sum
    scaled back to every frame).
    """
    from ineid.data.recordings.signals import LowPass, edge_seconds

    low = LowPass(filtered.cutoff, filtered.rate)
    n_u = len(model.unknown_index)
    edge = int(math.ceil(edge_seconds(filtered.cutoff) * filtered.rate))
    s_f = [a[config, fit_sl] for a in (ds.q, ds.qd, ds.qdd)]
    if len(s_f[0]) <= 4 * edge or not np.all(np.isfinite(theta[config])):
        return 0.0
    full = model.full_theta(theta[config, :n_u][None], ds.theta_known)
    x = theta[config, n_u:][None] if theta.shape[1] > n_u else None
    y_f = _predicted(model, s_f, full, channels, x)
    keep = slice(edge, len(s_f[0]) - edge)
    values = low.apply(y_f)[keep]
    s_2 = [low.apply(a)[keep] for a in s_f]
    n_frames, n_axes = values.shape
    mask = np.zeros(n_axes, dtype=bool)
    if offsets is not None:
        mask = np.ones(n_axes, dtype=bool) if offsets.mask is None else np.asarray(offsets.mask, dtype=bool)
    beta = np.nan_to_num(fit.beta[config])
    sum_we, sum_w, sum_e = 0.0, 0.0, 0.0
    for _, _, w_b, y in stacked_chunks(model, (*s_2, values), ds.theta_known, channels, base.base_index):
        e = y - w_b @ beta
        sum_we = sum_we + np.einsum("fak,fa->ak", w_b, e)
        sum_w, sum_e = sum_w + w_b.sum(axis=0), sum_e + e.sum(axis=0)
    centred = sum_we - mask[:, None] * sum_w * (sum_e / n_frames)[:, None]  # sum_t w_t (e_t - mean e) per axis
    total = np.einsum("a,ak->k", fit.axis_weights[config] ** 2, centred)
    return total * (len(s_f[0]) / n_frames)
