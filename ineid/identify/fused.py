"""Fused kernels of the linear identification: what a batch of configurations needs, never the stacks.

For configuration ``c`` with frames ``k = 1..F`` the base least squares (see
:mod:`ineid.identify.linear`) uses ``W_b`` (AF x r, the unknown links' base columns of the
measurement channels' stacked rows ``T Phi``, :class:`ineid.channels.ChannelSet`; ``A``
axes a frame, six for the base wrench) and ``y`` (AF, the measured values minus the known
links' share) only through

    G_a = sum_k W_b[k, a]^T W_b[k, a]        (r x r)   per axis a (fx..mz for the base wrench)
    h_a = sum_k W_b[k, a]^T y[k, a]           (r,)
    e_a = sum_k y[k, a]^2

so that, with row weights ``d_a`` per axis (``D`` in :mod:`ineid.identify.linear`),

    W_b^T D^2 W_b = sum_a d_a^2 G_a,   W_b^T D^2 y = sum_a d_a^2 h_a,   y^T D^2 y = sum_a d_a^2 e_a

and the per-axis residual sum of squares of any ``beta`` is ``e_a - 2 beta.h_a + beta^T G_a beta``.
:func:`information_blocks` computes ``G, h, e`` in one jitted function per chunk of
configurations: each channel's generated entries (:meth:`ineid.channels.Channel.entries_function`)
of the base columns and the known links' contraction are formed and reduced inside it, so the
``(C, AF, n)`` stacks never exist (the memory is the blocks', ``A r^2`` numbers per
configuration). :func:`residual_sums` is the same for the residual of given parameters (each
channel's ``Phi theta``, for the base wrench the generated ``base_wrench``, which never forms
``Psi``), over fitted and held-out frames in one pass.

A channel with a transform ``T`` (a base wrench in an F/T sensor's frame: the 6x6 wrench
transform ``X``) is fitted in its own axes: the kernel applies ``T`` to the regressor rows and
to the known links' share before reducing (``W_b[k] -> T W_b[k]``); ``T``'s values are
arguments, so a new sensor pose does not recompile. For constant offsets (the bias) the
kernel also returns the sums over the frames ``s_a = sum_k Psi_u[k, a]`` (all unknown
columns) and ``t_a = sum_k y[k, a]``, and :meth:`InformationBlocks.centred` turns the blocks
into those of the frames centred per axis (``G_a - s_a s_a^T / F``, ...), which is the joint
fit of the parameters and the offsets (:class:`ineid.identify.systems.Offsets`).

Channels with extra kept columns ``E x`` (joint friction, ..., :mod:`ineid.identify.extras`):
the kernel appends each channel's ``E`` (block-diagonal, in its own axes, ``T`` not applied) to
the rows, ``W_b`` is the base columns of ``[T Phi_u | E]`` over ``[theta_u, x]``, and the
residual kernel predicts ``T Phi theta + E x``.

One compiled shape serves every chunk: configurations are padded to a fixed count and long
recordings are split into frame chunks (masked). Compiled once per robot, link split, base
structure, channels' structure (:meth:`ineid.channels.ChannelSet.structure`) and frame count
(see :func:`ineid.cache.enable_compilation_cache`); one base wrench compiles what it
compiled before channels existed.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable

import numpy as np

from ineid.channels import BASE_WRENCH, ChannelSet
from ineid.identify.blocks import InformationBlocks  # defined here before: still importable from here
from ineid.identify.chunks import map_chunks
from ineid.identify.extras import unknown_rows
from ineid.identify.rows import RowLayout, chunk_rows, layout_of, transforms
from ineid.robots.model import SMALL_JOB_FRAMES

TARGET_FRAMES = 2048
"""Frames (configurations x frames) per compiled call: the chunk the regressor runs fastest on."""
RESIDUAL_TARGET_FRAMES = 8192
"""Frames per call of the residual kernel (``base_wrench`` only: cheaper per frame)."""
MAX_FRAME_CHUNK = 2048
"""Longer configurations (recordings) are reduced over chunks of this many frames."""
WORKERS = min(os.cpu_count() or 1, 4)
"""Threads dispatching chunks: XLA:CPU runs each call in its caller's thread, so calls from
two threads run on two cores (measured 1.3x on two cores over one dispatching thread)."""


def chunk_shape(n_configs: int, n_frames: int, target: int | None = None) -> tuple[int, int]:
    """``(configurations, frames)`` per compiled call of about ``target`` frames (default :data:`TARGET_FRAMES`)."""
    frames = min(n_frames, MAX_FRAME_CHUNK)
    return max(1, (target or TARGET_FRAMES) // frames), frames


def _map_chunks(kernel, frame_arrays, config_arrays, consts, progress=None, target: int | None = None) -> list:
    """:func:`ineid.identify.chunks.map_chunks` in calls of about ``target`` frames (:func:`chunk_shape`) from
    :data:`WORKERS` threads."""
    n_configs, n_frames = frame_arrays[0].shape[:2]
    shape = chunk_shape(n_configs, n_frames, target)
    return map_chunks(kernel, frame_arrays, config_arrays, consts, shape, WORKERS, progress)


@functools.cache
def _blocks_kernel(layout: RowLayout, summed: bool = False):
    """Jitted ``(q, qd, qdd, values, mask, [w_ref, y_ref,] gravity, theta_known, xs) -> (G, h, e[, s, t])``.

    The rows are ``layout``'s (:func:`ineid.identify.rows.chunk_rows`: the channels' rows stacked in order, in
    their own axes, ``xs`` their transforms ``T``, the extra kept columns ``E`` after the links').
    ``summed``: ``(q, qd, qdd, values, mask, d, gravity, theta_known, xs)`` with row weights
    ``d`` (Cc, A), and ``G, h`` summed over the axes with weights ``d_a^2`` (see
    :class:`InformationBlocks`): one (AFc x r) product per configuration instead of A.
    ``layout.sums`` (every unknown column, base columns among them): the blocks are of the
    frames minus a reference row per configuration and axis (``w_ref`` (Cc, A, p), ``y_ref``
    (Cc, A): the first frame's), and the frame sums ``s`` of those columns and ``t`` of ``y``
    come too. Centring is invariant to the shift, and the shift takes the large constant part
    (offsets, the weight of the links) out of the sums before they cancel.
    """
    import jax

    if layout.sums:
        return jax.jit(
            lambda q, qd, qdd, wrench, mask, w_ref, y_ref, gravity, theta_known, xs: _blocks_core(
                layout, q, qd, qdd, wrench, mask, w_ref, y_ref, gravity, theta_known, xs, None
            )
        )
    if summed:
        return jax.jit(
            lambda q, qd, qdd, wrench, mask, d, gravity, theta_known, xs: _blocks_core(
                layout, q, qd, qdd, wrench, mask, None, None, gravity, theta_known, xs, d
            )
        )
    return jax.jit(
        lambda q, qd, qdd, wrench, mask, gravity, theta_known, xs: _blocks_core(
            layout, q, qd, qdd, wrench, mask, None, None, gravity, theta_known, xs, None
        )
    )


def _blocks_core(layout: RowLayout, q, qd, qdd, wrench, mask, w_ref, y_ref, gravity, theta_known, xs, d):
    """The blocks of one chunk (traced; :func:`_blocks_kernel`): ``(G, h, e[, s, t])``."""
    import jax.numpy as jnp

    w_b, y = chunk_rows(layout, q, qd, qdd, wrench, mask, gravity, theta_known, xs)
    if layout.sums:
        w_all = w_b - jnp.moveaxis(w_ref, 1, 0)[..., None] * mask[None, :, None, :]
        y = y - jnp.moveaxis(y_ref, 1, 0)[..., None] * mask[None]
        w_b = w_all[:, :, layout.base_pos, :]
    e = jnp.einsum("acf,acf->ca", y, y)
    if d is not None:  # rows weighted, axes and frames contracted together
        w_d = w_b * jnp.moveaxis(d, 1, 0)[:, :, None, None]
        y_d = y * jnp.moveaxis(d, 1, 0)[:, :, None]
        return jnp.einsum("acrf,acsf->crs", w_d, w_d), jnp.einsum("acrf,acf->cr", w_d, y_d), e
    g = jnp.einsum("acrf,acsf->cars", w_b, w_b)
    h = jnp.einsum("acrf,acf->car", w_b, y)
    if not layout.sums:
        return g, h, e
    return g, h, e, jnp.einsum("acpf->cap", w_all), jnp.einsum("acf->ca", y)


def _no_blocks(n_axes: int, base, n_frames: int, sums: bool, summed: bool) -> InformationBlocks:
    """The (empty) blocks of no configuration, shaped as :func:`information_blocks` makes them."""
    r, p = base.rank, base.n_params
    if summed:
        return InformationBlocks(
            np.zeros((0, r, r)), np.zeros((0, r)), np.zeros((0, n_axes)), n_frames, axis_w=np.zeros((0, n_axes))
        )
    return InformationBlocks(
        np.zeros((0, n_axes, r, r)),
        np.zeros((0, n_axes, r)),
        np.zeros((0, n_axes)),
        n_frames,
        np.zeros((0, n_axes, p)) if sums else None,
        np.zeros((0, n_axes)) if sums else None,
    )


def information_blocks(
    model,
    base,
    q,
    qd,
    qdd,
    wrench,
    theta_known,
    progress: Callable[[int, int], None] | None = None,
    sums: bool = False,
    axis_weights: np.ndarray | None = None,
    channels: ChannelSet | None = None,
) -> InformationBlocks:
    """Per-axis blocks ``G, h, e`` of every configuration (see module doc).

    Args:
        model: the :class:`ineid.RobotModel` (unknown links, gravity, generated code).
        base: the :class:`~ineid.identify.identifiability.BaseParameters` of its unknown links.
        q, qd, qdd: (C, F, n_dof) frames; wrench: (C, F, A) the channels' measured values, stacked.
        theta_known: (10 n_known,) the known links' parameters.
        progress: ``progress(done, total)`` over configurations.
        sums: also the frame sums ``s, t`` (for :meth:`InformationBlocks.centred`); the
            blocks are then of the frames minus each configuration's first frame (``w_ref,
            y_ref``), which only :meth:`InformationBlocks.centred` should use.
        axis_weights: (C, A) or (A,) row weights ``d_a`` known in advance: ``G, h`` come
            summed over the axes with them (``InformationBlocks.axis_w``); not with ``sums``.
        channels: the :class:`ineid.channels.ChannelSet` measured (rows, transforms); None:
            the base wrench in the base frame.
    """
    channels = BASE_WRENCH if channels is None else channels
    n_axes = channels.n_axes(model)
    n_extra = channels.n_extra(model)
    if base.n_extra != n_extra:
        raise ValueError(f"the base parameters have {base.n_extra} extra columns, the channels {n_extra}")
    arrays = [np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench)]
    n_configs, n_frames = arrays[0].shape[:2]
    if arrays[3].shape[-1] != n_axes:
        raise ValueError(f"the measured values have {arrays[3].shape[-1]} axes, the channels {n_axes}")
    if n_configs == 0:
        return _no_blocks(n_axes, base, n_frames, sums, axis_weights is not None)
    if sums and axis_weights is not None:
        raise ValueError("centred blocks (sums=True) are per axis; leave axis_weights out")
    kernel = _blocks_kernel(layout_of(model, base, channels, sums), axis_weights is not None)
    theta_known = np.asarray(theta_known, dtype=np.float64)
    consts = (model.gravity, theta_known, transforms(channels, model))
    if axis_weights is not None:
        d = np.ascontiguousarray(np.broadcast_to(np.asarray(axis_weights, dtype=np.float64), (n_configs, n_axes)))
        return InformationBlocks(*_map_chunks(kernel, arrays, [d], consts, progress), n_frames, axis_w=d)
    if not sums:
        return InformationBlocks(*_map_chunks(kernel, arrays, [], consts, progress), n_frames)
    rows_u, rows_k = unknown_rows(model, *(a[:, :1] for a in arrays[:3]), channels)  # the first frames: (C, 1, A, .)
    w_ref = np.asarray(rows_u)[:, 0]
    y_ref = arrays[3][:, 0] - np.asarray(rows_k)[:, 0] @ theta_known
    out = _map_chunks(kernel, arrays, [w_ref, y_ref], consts, progress)
    return InformationBlocks(*out[:3], n_frames, out[3], out[4], w_ref, y_ref)


@functools.cache
def _residual_kernel(structure: tuple):
    """Jitted ``(q, qd, qdd, values, fit, mask, theta, bias, gravity, xs) -> (ssr_fit, ssr_held, ss_held)``.

    With extra kept columns (``n_e`` over the channels) ``theta`` is ``[theta, x]`` (Cc, 10 n + n_e)
    and the prediction ``T Phi theta + E x`` (each channel's ``E_i x_i`` on its own axes).
    """
    import jax
    import jax.numpy as jnp

    n_extra = sum(channel.n_extra for channel in structure)

    def kernel(q, qd, qdd, wrench, fit, mask, theta, bias, gravity, xs):
        # fit: (Cc, Fc, 1) 1 on fitted frames, 0 on held-out ones; theta: (Cc, 10 n); bias: (Cc, A)
        if n_extra:
            theta, extra = theta[:, : theta.shape[1] - n_extra], theta[:, theta.shape[1] - n_extra :]
        parts = []
        e0 = 0
        for channel, x in zip(structure, xs, strict=True):
            predicted = channel.phi_theta(q, qd, qdd, gravity, theta[:, None, :])
            predicted = predicted @ x.T if channel.transformed else predicted
            if channel.n_extra:
                e = channel.extra_rows(q, qd, qdd)  # (Cc, Fc, n_a, n_e_i)
                predicted = predicted + jnp.einsum("cfae,ce->cfa", e, extra[:, e0 : e0 + channel.n_extra])
                e0 += channel.n_extra
            parts.append(predicted)
        predicted = parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=-1)
        predicted = predicted + bias[:, None, :]
        r2 = (wrench - predicted) ** 2 * mask[..., None]
        held = (1.0 - fit) * mask[..., None]
        return (jnp.sum(r2 * fit, axis=1), jnp.sum(r2 * held, axis=1), jnp.sum(wrench**2 * held, axis=(1, 2)))

    return jax.jit(kernel)


def residual_sums(
    model,
    q,
    qd,
    qdd,
    wrench,
    theta,
    n_fit: int,
    bias: np.ndarray | None = None,
    channels: ChannelSet | None = None,
    extra: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums of squares of ``values - (T Phi theta + E x + b)`` per configuration: fitted and held-out frames.

    Args:
        model: the :class:`ineid.RobotModel`.
        q, qd, qdd: (C, F, n_dof); wrench: (C, F, A) the channels' measured values, stacked.
        theta: (C, 10 n_links) every link's parameters, per configuration.
        n_fit: the first ``n_fit`` frames are the fitted ones, the rest held out.
        bias: (C, A) offsets ``b`` (None: zero).
        channels: the :class:`ineid.channels.ChannelSet` (None: the base wrench in the base frame).
        extra: (C, n_e) the channels' extra parameters ``x`` (:meth:`ineid.channels.ChannelSet.extra_names`);
            None: zero (none without extra columns).

    Returns:
        ``(ssr_fit (C, A), ssr_held (C, A), ss_held (C,))``: per axis, the sum over the
        fitted and over the held-out frames of the squared residual, and the sum of the
        squared measured values over the held-out frames (all axes).

    A job of at most :data:`ineid.robots.model.SMALL_JOB_FRAMES` frames is evaluated through CasADi (the same
    sums to round-off), a larger one by a compiled kernel.
    """
    channels = BASE_WRENCH if channels is None else channels
    n_axes = channels.n_axes(model)
    arrays = [np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench)]
    n_configs, n_frames = arrays[0].shape[:2]
    if n_configs == 0:
        return np.zeros((0, n_axes)), np.zeros((0, n_axes)), np.zeros(0)
    fit = (np.arange(n_frames) < n_fit).astype(np.float64)
    fit = np.broadcast_to(fit[None, :, None], (n_configs, n_frames, 1))
    theta = np.asarray(theta, dtype=np.float64)
    n_extra = channels.n_extra(model)
    if n_extra:  # [theta, x]: the kernels split it
        extra = np.zeros((n_configs, n_extra)) if extra is None else np.asarray(extra, dtype=np.float64)
        theta = np.concatenate([theta, extra.reshape(n_configs, n_extra)], axis=1)
    bias = np.zeros((n_configs, n_axes)) if bias is None else np.asarray(bias, dtype=np.float64)
    if n_configs * n_frames <= SMALL_JOB_FRAMES:
        return _residual_sums_casadi(model, channels, arrays, theta, bias, n_fit)
    kernel = _residual_kernel(channels.structure(model))
    ssr_fit, ssr_held, ss_held = _map_chunks(
        kernel,
        [*arrays, fit],
        [theta, bias],
        (model.gravity, transforms(channels, model)),
        target=RESIDUAL_TARGET_FRAMES,
    )
    return ssr_fit, ssr_held, ss_held


def casadi_predictions(model, channels: ChannelSet, states, theta: np.ndarray) -> np.ndarray:
    """(C, F, A) ``[T Phi | E] [theta, x]`` of a small job through CasADi's stacked rows (no compilation; the
    kernels' values to round-off).

    Args:
        states: ``(q, qd, qdd)``, each (C, F, n_dof).
        theta: (C, 10 n_links [+ n_extra]) every link's parameters, then the channels' extra parameters ``x``
            where the channels have extra columns.
    """
    n_configs, n_frames = states[0].shape[:2]
    n, n_axes = n_configs * n_frames, channels.n_axes(model)
    flat = [np.asarray(a, dtype=np.float64).reshape(n, -1).T for a in states]
    rows = np.array(channels.casadi_rows(model).map(n)(*flat)).reshape(n_axes, n, -1).transpose(1, 0, 2)
    if channels.n_extra(model):  # [T Phi | E] against [theta, x]
        e = np.array(channels.casadi_extra_rows(model).map(n)(*flat)).reshape(n_axes, n, -1).transpose(1, 0, 2)
        rows = np.concatenate([rows, e], axis=-1)
    return np.einsum("cfap,cp->cfa", rows.reshape(n_configs, n_frames, n_axes, -1), theta)


def _residual_sums_casadi(model, channels: ChannelSet, arrays, theta, bias, n_fit: int):
    """:func:`residual_sums` of a small job through CasADi's stacked rows ``T Phi`` (no compilation)."""
    *states, wrench = arrays
    predicted = casadi_predictions(model, channels, states, theta) + bias[:, None, :]
    r2 = (wrench - predicted) ** 2
    return r2[:, :n_fit].sum(axis=1), r2[:, n_fit:].sum(axis=1), (wrench[:, n_fit:] ** 2).sum(axis=(1, 2))
