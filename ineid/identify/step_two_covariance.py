"""The covariance of the two-step fit's second step on a filtered recording.

Step 2 of :mod:`ineid.identify.two_step` fits the joint torques' extra parameters to their residual at step 1's
links, ``tau - T Phi(s) theta_hat = E(s) x + b + e``, by least squares over the frames. On an imported recording
those frames went through one low-pass (``ineid.identify.time_correlation``), so the residuals are correlated in
time and the filter and the differentiation make an error of their own; :func:`step_two_covariance` gives the fit
the covariance :func:`ineid.identify.time_correlation.recording_covariance` gives a one-step fit,

    cov(beta_hat) = sigma^2 A^-1 (sum_a kappa_a d_a^2 G_a) A^-1 + delta delta^T,

``kappa_a`` each torque axis's residual band density (:func:`ineid.identify.time_correlation.band_long_run`, the
filter's rule where the band is too short), ``delta = A^-1 W_b^T D^2 e`` the move of the filter's error ``e``,
estimated as ``LP(y(s_f)) - y(LP s_f)`` at the combined estimate (step 1's links and step 2's extras) on the
filtered states ``s_f``. The fit's ``axis_long_run`` takes ``kappa`` (the torque offsets' std).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ineid.identify.least_squares import BaseFit, axis_leverage, r_inverse
from ineid.identify.systems import predict_wrench
from ineid.identify.time_correlation import (
    FilteredFrames,
    band_long_run,
    filter_gain,
    moving_sum_covariance,
)


@dataclasses.dataclass(frozen=True)
class StepTwoFrames:
    """A chunk of configurations of step 2 as fitted: their filtered states and the fit's stacks.

    Attributes:
        states: ``(q, qd, qdd)`` each (c, F, n_dof), the frames fitted.
        w: (c, F A, p) the extra columns (and the torque constants'), centred where offsets were taken out.
        y: (c, F A) the torques' residual at step 1's links, centred alike.
        columns: ``f(q, qd, qdd, values) -> (F, A, p)``: the stacked columns at other states (``values`` the
            torques there, for the torque constants' columns).
        theta: (c, 10 n) step 1's links, every link.
        mask: (A,) bool, the axes whose offset was taken out (all False without).
    """

    states: tuple
    w: np.ndarray
    y: np.ndarray
    columns: object
    theta: np.ndarray
    mask: np.ndarray


def step_two_covariance(model, torque, base_x, fit: BaseFit, frames: StepTwoFrames, filtered: FilteredFrames):
    """``fit`` (step 2 of ``frames``' configurations) with the covariance of a filtered recording (module doc)."""
    c_all, n_axes = fit.axis_weights.shape
    cov, long_run = fit.cov_beta.copy(), np.ones((c_all, n_axes))
    gain = filter_gain(filtered)
    idx = base_x.base_index
    for c in range(c_all):
        if not fit.full_rank[c] or not np.all(np.isfinite(fit.cov_beta[c])):
            continue
        a_inv = r_inverse(fit.R[c][None])[0]
        d2 = fit.axis_weights[c] ** 2
        w_b = frames.w[c][:, idx].reshape(-1, n_axes, len(idx))
        resid = frames.y[c].reshape(-1, n_axes) - w_b @ np.nan_to_num(fit.beta[c])
        g = np.einsum("fak,fal->akl", w_b, w_b)
        plain = np.maximum(np.einsum("fa,fa->a", resid, resid), 1e-300)
        rule = np.maximum(np.diag(moving_sum_covariance(resid, filtered.lags)) / plain, gain)
        removed = axis_leverage(g[None], fit.axis_weights[c][None], a_inv[None])[0] + frames.mask
        band = band_long_run(resid, filtered, removed)
        kappa = np.where(np.isnan(band), rule, np.maximum(band, 1.0))
        naive = fit.sigma2[c] * a_inv
        spread = fit.sigma2[c] * a_inv @ np.einsum("a,akl->kl", kappa * d2, g) @ a_inv
        growth = np.mean(np.diag(spread) / np.maximum(np.diag(naive), 1e-300))
        delta = a_inv @ _filter_score(model, torque, base_x, fit, frames, filtered, c)
        cov[c] = spread + growth**2 * (fit.cov_beta[c] - naive) + np.outer(delta, delta)
        long_run[c] = kappa
    return dataclasses.replace(fit, cov_beta=cov, axis_long_run=long_run)


def _filter_score(model, torque, base_x, fit: BaseFit, frames: StepTwoFrames, filtered, c: int) -> np.ndarray:
    """(r,) ``W_b^T D^2 (e - ebar)`` of configuration ``c``: the filter's error ``e`` (module doc) at the combined
    estimate, the filter's start-up at each end left out (the sum scaled back to every frame); 0 for too few
    frames."""
    from ineid.data.recordings.signals import LowPass, edge_seconds

    low = LowPass(filtered.cutoff, filtered.rate)
    s_f = [a[c] for a in frames.states]
    n_frames = len(s_f[0])
    edge = int(math.ceil(edge_seconds(filtered.cutoff) * filtered.rate))
    if n_frames <= 4 * edge or not np.all(np.isfinite(frames.theta[c])):
        return np.zeros(base_x.rank)
    idx, beta = base_x.base_index, np.nan_to_num(fit.beta[c])

    def model_torque(states, values=None):
        links = predict_wrench(model, *(a[None] for a in states), frames.theta[c][None], torque)[0]
        columns = frames.columns(*states, links if values is None else values)[..., idx]
        return links + columns @ beta, columns

    y_f, _ = model_torque(s_f)
    keep = slice(edge, n_frames - edge)
    values = low.apply(y_f)[keep]
    s_2 = [low.apply(a)[keep] for a in s_f]
    y_2, w_b = model_torque(s_2, values)
    e = values - y_2
    e = e - frames.mask * e.mean(axis=0)
    score = np.einsum("a,fak,fa->k", fit.axis_weights[c] ** 2, w_b, e)
    return score * (n_frames / len(values))
