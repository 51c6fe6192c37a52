"""FloBaRoID's two steps: the links from the wrench alone, then the joint torques' extra parameters.

``ineid solve --two-step`` (``SolveSettings(two_step=True)``) with a wrench and a joint-torque
channel, and an actuation model (friction, armature, torque offsets):

1. the links' parameters ``theta_u`` from the wrench channels alone, by the chosen method
   (:func:`ineid.identify.solve.solve_dataset` with the torques left out): the base wrench
   sees no joint friction, so no friction model can bias them;
2. the joint torques' extra parameters ``x`` from their residual with ``theta`` fixed,

       tau_k - T Phi(s_k) theta_hat = E(s_k) x + b + e_k,

   by weighted least squares over the base parameters of ``E`` alone (``linear`` and
   ``nonlinear``: the extras are linear, so the two agree), or by IPOPT with the dissipative
   ones bounded below by 0 (``consistent``, :mod:`ineid.identify.extras`); offsets ``b`` by
   centring when ``bias="estimate"``.

With ``--torque-constant-unknown`` (``SolveSettings.torque_constant_unknown``) a motor-current
channel's torque constants are identified in step 2 too. With ``k_j = k0_j (1 + d_j)`` (``k0``
the channel's nominal ``torque_constant``) the currents read ``i_j (1 + d_j) = T_j (Y_j theta + E_j x)``,
so the residual ``i_j - T_j Y_j theta_hat = -i_j d_j + T_j E_j x`` is linear in ``d_j``: one more
column per joint, ``-i_j`` (the measured current, row ``j``), appended to ``E`` (its base parameters
over generic frames take the currents predicted at the CAD parameters in its stead). They are
reported last, after the other extra parameters, as ``<joint>.k = k0_j (1 + d_j)`` with std
``|k0_j| std(d_j)`` (prior ``k0_j``; ``base_hat`` holds ``d_j``). The residuals use the identified
constants: the prediction ``(T (Y theta + E x) + b) / (1 + d)``, and the offsets reported are
``b / (1 + d)``, in A.

The results hold ``[theta_u, x]`` as a one-step solve does, with block-diagonal base
parameters (those of step 1, then those of ``E``). The standard deviations of ``x`` are
conditional on ``theta_hat`` (its uncertainty is not propagated into step 2); the residual
RMS runs over every channel's axes at the combined estimate. On a filtered recording both steps take the
covariance of frames correlated in time and the filter's own error (step 1 as every solve does, step 2 by
:mod:`ineid.identify.step_two_covariance`).

References:
    Bethge, Malzahn, Tsagarakis, Caldwell (2017), FloBaRoID -- a software package for the
    identification of robotic floating-base dynamics.
"""

from __future__ import annotations

import time

import numpy as np

from ineid.channels import ChannelSet
from ineid.identify.choose import solve_channels, torque_noise_levels, two_step_channels
from ineid.identify.fused import residual_sums
from ineid.identify.identifiability import (
    BaseParameters,
    base_parameters_from_regressor,
    centred_regressor,
    generic_frames,
    offset_mask,
    regressor_unknown,
    unknown_scales,
)
from ineid.identify.least_squares import concat_fits, subtract_offset_dof
from ineid.identify.linear import Estimate, fit_base, linear_estimate
from ineid.identify.nlp import NlpSolver, nlp_estimate
from ineid.identify.settings import SolveSettings
from ineid.identify.solve_results import SolveResults, dataset_results
from ineid.identify.step_two_covariance import StepTwoFrames, step_two_covariance
from ineid.identify.steps import bias_estimate
from ineid.identify.systems import Offsets, predict_wrench, remove_offsets
from ineid.identify.time_correlation import filtered_frames

CHUNK_ROWS = 20_000_000
"""Numbers of ``E`` (rows x columns) stacked at a time in step 2 (160 MB)."""


def stacked_bases(a: BaseParameters, b: BaseParameters) -> BaseParameters:
    """The base parameters of ``[theta_a, theta_b]`` fitted separately: block-diagonal (``b``'s after ``a``'s)."""
    n_a = a.n_params

    def block(x, y):
        out = np.zeros((x.shape[0] + y.shape[0], x.shape[1] + y.shape[1]))
        out[: x.shape[0], : x.shape[1]], out[x.shape[0] :, x.shape[1] :] = x, y
        return out

    return BaseParameters(
        param_names=(*a.param_names, *b.param_names),
        base_index=np.concatenate([a.base_index, n_a + b.base_index]),
        dependent_index=np.concatenate([a.dependent_index, n_a + b.dependent_index]),
        K=block(a.K, b.K),
        B=block(a.B, b.B),
        null_basis=block(a.null_basis, b.null_basis),
        identifiable=np.concatenate([a.identifiable, b.identifiable]),
        names=(*a.names, *b.names),
        scales=np.concatenate([a.scales, b.scales]),
        n_extra=a.n_extra + b.n_extra,
    )


def _k_channels(torque: ChannelSet, model) -> list:
    """``(axis block, k0)`` of each motor-current channel of ``torque`` whose torque constants are identified."""
    return [
        (b, np.asarray(b.channel.torque_constant))
        for b in torque.blocks(model)
        if getattr(b.channel, "identify_k", False)
    ]


def k_columns(values: np.ndarray, blocks: list, n_axes: int) -> np.ndarray:
    """The columns ``-i_j`` of the relative torque-constant corrections ``d``: (..., n_axes, n_k) from the stacked
    currents ``values`` (..., n_axes), row ``j`` of each channel's block holding its joint's."""
    n_k = sum(len(k0) for _, k0 in blocks)
    out = np.zeros(values.shape[:-1] + (n_axes, n_k))
    col = 0
    for b, k0 in blocks:
        for j in range(len(k0)):
            out[..., b.start + j, col + j] = -values[..., b.start + j]
        col += len(k0)
    return out


def extra_base_parameters(model, torque: ChannelSet, bias: bool) -> BaseParameters:
    """The base parameters of the extra kept columns ``E`` of ``torque`` alone (the links known), over generic
    frames, with the scales of :mod:`ineid.identify.extras`; centred per axis with ``bias``. The columns of the
    identified torque constants (module doc) come last, with scale 1 (``d`` is relative)."""
    q, qd, qdd = generic_frames(model)
    w = regressor_unknown(model, q, qd, qdd, torque)
    scales = unknown_scales(model, w, torque)
    n_e, n_axes = torque.n_extra(model), torque.n_axes(model)
    e, names, scales = w[:, w.shape[1] - n_e :], torque.extra_names(model), scales[len(scales) - n_e :]
    blocks = _k_channels(torque, model)
    if blocks:  # the currents predicted at the CAD parameters stand in for the measured ones
        predicted = predict_wrench(model, q[None], qd[None], qdd[None], model.theta_cad[None], torque)[0]
        k = k_columns(predicted, blocks, n_axes).reshape(len(q) * n_axes, -1)
        e = np.concatenate([e, k], axis=1)
        names = (*names, *(n for b, _ in blocks for n in b.channel.k_names(model)))
        scales = np.concatenate([scales, np.ones(k.shape[1])])
    if bias:
        e = centred_regressor(e, n_axes, offset_mask(torque, model, True))
    return base_parameters_from_regressor(e, names, scales, n_extra=len(names))


def _stack_order(channels: ChannelSet, wrench: ChannelSet, torque: ChannelSet, model) -> np.ndarray:
    """Indices taking ``[wrench axes, torque axes]`` into ``channels``' stacked order."""
    where, start = {}, 0
    for part in (wrench, torque):
        for b in part.blocks(model):
            where[b.channel.key] = np.arange(start + b.start, start + b.stop)
        start += part.n_axes(model)
    return np.concatenate([where[k] for k in channels.keys])


def second_step(first: SolveResults, ds, settings: SolveSettings, model, t_start: float) -> SolveResults:
    """Step 2 on the results ``first`` of step 1: the results of both steps together (module doc), their
    ``total_seconds`` since ``t_start`` (``time.perf_counter()`` before step 1)."""
    t0 = time.perf_counter()
    channels = solve_channels(ds, settings, model)
    wrench, torque = two_step_channels(channels)
    axis_sigma = torque_noise_levels(ds, settings, channels, torque, model)
    with_bias = settings.estimates_offsets
    n_e = torque.n_extra(model)
    base_x = extra_base_parameters(model, torque, with_bias)
    k_blocks = _k_channels(torque, model)
    theta = model.full_theta(np.nan_to_num(first.theta_hat), ds.theta_known)
    fit, offsets, rms = _torque_fit(
        ds, model, torque, k_blocks, theta, base_x, settings.weights, axis_sigma, with_bias, first.n_frames_fit
    )
    prior_x = np.zeros(base_x.n_params)  # n_e, then the torque constants' corrections d
    est = linear_estimate(fit, base_x, prior_x)
    if settings.method == "consistent":  # friction and armature >= 0
        solver = NlpSolver.build("consistent", base_x, prior_x, settings.pull, settings.entropic)
        est = nlp_estimate(fit, solver, rms, np.where(np.isfinite(est.theta), est.theta, 0.0))
    gain = np.ones((ds.n_configs, torque.n_axes(model)))  # 1 + d on the axes of identified torque constants
    if k_blocks:
        gain[:, np.concatenate([np.arange(b.start, b.stop) for b, _ in k_blocks])] += np.nan_to_num(est.theta[:, n_e:])
    bias_hat = bias_std = None
    if with_bias:
        b_t, s_t = bias_estimate(offsets, est, base_x)
        parts = {**wrench.split(first.bias_hat, model), **torque.split(b_t / gain, model)}
        stds = {**wrench.split(first.bias_std, model), **torque.split(s_t / np.abs(gain), model)}
        bias_hat = np.concatenate([parts[k] for k in channels.keys], axis=1)
        bias_std = np.concatenate([stds[k] for k in channels.keys], axis=1)
    gain_all = np.concatenate([np.ones((ds.n_configs, wrench.n_axes(model))), gain], axis=1)
    gain_all = gain_all[:, _stack_order(channels, wrench, torque, model)]  # over every channel's axes
    n_fit = first.n_frames_fit
    values = ds.measured(channels)[:, : n_fit + first.n_frames_validation]
    sums = _combined_sums(ds, model, channels, values, gain_all, theta, est.theta[:, :n_e], bias_hat, n_fit)
    if k_blocks:  # (i (1 + d) - prediction)^2 / (1 + d)^2 per axis; the held-out values unscaled
        sums = (sums[0] / gain_all**2, sums[1] / gain_all**2, (values[:, n_fit:] ** 2).sum(axis=(1, 2)))
    theta_x, std_x, prior_x = _with_torque_constants(est, prior_x, k_blocks, n_e)
    status = np.where(first.success, np.asarray(est.status, dtype=object), first.status).astype(object)
    return dataset_results(
        ds,
        settings,
        stacked_bases(first.base, base_x),
        np.concatenate([first.theta_prior, prior_x]),
        sums,
        first.n_frames_fit,
        first.n_frames_validation,
        t_start,
        channels=channels,
        model=model,
        theta_hat=np.concatenate([first.theta_hat, theta_x], axis=1),
        theta_std=np.concatenate([first.theta_std, std_x], axis=1),
        base_hat=np.concatenate([first.base_hat, est.beta], axis=1),
        base_std=np.concatenate([first.base_std, est.beta_std], axis=1),
        success=first.success & est.success,
        status=status,
        seconds=first.seconds + (time.perf_counter() - t0) / max(ds.n_configs, 1),
        bias_hat=bias_hat,
        bias_std=bias_std,
        payload=first.payload,
    )


def _torque_fit(
    ds,
    model,
    torque: ChannelSet,
    k_blocks: list,
    theta: np.ndarray,
    base_x: BaseParameters,
    weights: str,
    axis_sigma,
    with_bias: bool,
    n_fit: int,
):
    """``(fit, offsets, rms)``: the base fit of ``E x`` (and the torque constants' columns, :func:`k_columns`) to
    the joint torques' residual at ``theta`` (C, 10 n) over the first ``n_fit`` frames, a chunk of
    configurations at a time; the offsets taken out ``with_bias`` (else None) and the RMS of the weighted data.
    On a filtered recording the fit's covariance is a recording's (:mod:`ineid.identify.step_two_covariance`)."""
    n_axes, n_e = torque.n_axes(model), torque.n_extra(model)
    mask = torque.offset_mask(model)
    lost = mask.astype(np.float64) if with_bias else None
    c = ds.n_configs
    fits, parts, rms = [], [], np.empty(c)
    per = max(1, CHUNK_ROWS // max(n_fit * n_axes * max(base_x.n_params, 1), 1))
    filtered = filtered_frames(ds)

    def columns(q, qd, qdd, values):  # the stacked columns at other states, for the filter's error
        e = torque.extra_rows(model, q[None], qd[None], qdd[None])[0]
        return np.concatenate([e, k_columns(values, k_blocks, n_axes)], axis=-1) if k_blocks else e

    for start in range(0, c, per):  # the stacks of E of a chunk of configurations at a time
        sl = slice(start, min(start + per, c))
        q, qd, qdd = (a[sl, :n_fit] for a in (ds.q, ds.qd, ds.qdd))
        values = ds.measured(torque)[sl, :n_fit]
        resid = values - predict_wrench(model, q, qd, qdd, theta[sl], torque)
        w = torque.extra_rows(model, q, qd, qdd).reshape(len(q), n_fit * n_axes, n_e)
        if k_blocks:
            w = np.concatenate([w, k_columns(values, k_blocks, n_axes).reshape(len(q), n_fit * n_axes, -1)], axis=2)
        y = resid.reshape(len(q), n_fit * n_axes)
        if with_bias:
            w, y, off = remove_offsets(w, y, n_axes, mask)
            parts.append(off)
        fits.append(fit_base(w, y, base_x, weights, axis_sigma, n_axes, lost))
        if filtered is not None:  # frames correlated in time, the filter's own error
            chunk = StepTwoFrames((q, qd, qdd), w, y, columns, theta[sl], mask if with_bias else np.zeros_like(mask))
            fits[-1] = step_two_covariance(model, torque, base_x, fits[-1], chunk, filtered)
        rms[sl] = np.sqrt(np.mean((y * np.tile(fits[-1].axis_weights, (1, n_fit))) ** 2, axis=1))
    fit = concat_fits(fits)
    if with_bias:
        subtract_offset_dof(fit, int(mask.sum()))
    return fit, Offsets.concat(parts) if with_bias else None, rms


def _combined_sums(ds, model, channels: ChannelSet, values, gain, theta, x, bias_hat, n_fit: int):
    """:func:`ineid.identify.fused.residual_sums` of the combined estimate over every channel's axes on the frames
    of ``values`` (C, F, A; the first ``n_fit`` fitted): the links' ``theta`` and the extra parameters ``x``
    (C, n_e), with the offsets ``bias_hat`` (C, A) or None, the values (and the offsets) multiplied by ``gain``
    (C, A): ``1 + d`` on the axes of identified torque constants, 1 elsewhere."""
    frames = slice(0, values.shape[1])
    return residual_sums(
        model,
        ds.q[:, frames],
        ds.qd[:, frames],
        ds.qdd[:, frames],
        values * gain[:, None],
        theta,
        n_fit,
        None if bias_hat is None else np.nan_to_num(bias_hat) * gain,
        channels,
        np.nan_to_num(x),
    )


def _with_torque_constants(est: Estimate, prior_x: np.ndarray, k_blocks: list, n_e: int):
    """``(theta_x, std_x, prior_x)`` of step 2's estimate as reported: the torque constants' corrections ``d``
    as ``k = k0 (1 + d)``, std ``|k0| std(d)``, prior ``k0`` (module doc); the rest as estimated."""
    theta_x, std_x, prior_x = est.theta.copy(), est.theta_std.copy(), prior_x.copy()
    if k_blocks:  # d -> k = k0 (1 + d)
        k0 = np.concatenate([k for _, k in k_blocks])
        theta_x[:, n_e:] = k0 * (1.0 + est.theta[:, n_e:])
        std_x[:, n_e:] = np.abs(k0) * est.theta_std[:, n_e:]
        prior_x[n_e:] = k0
    return theta_x, std_x, prior_x
