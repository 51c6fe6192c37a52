"""Triangular factors of each axis's rows, accumulated over chunks of frames: the exact linear fit.

For configuration ``c`` and measured axis ``a`` (:mod:`ineid.identify.fused` for the notation) the
rows ``X_a = [W_b[:, a] | y_a]`` (F x (r + 1)) have the QR factorization ``X_a = Q_a Rt_a`` with

    Rt_a = [[R_a, z_a],          R_a^T R_a = G_a,   R_a^T z_a = h_a,   |z_a|^2 + rho_a^2 = e_a
            [0,   rho_a]]

and a factor of stacked rows is the factor of the stacked factors (``qr([X1; X2]) = qr([Rt1; Rt2])``
up to signs). So chunks of frames, recordings, and the axes with row weights ``d_a`` combine without
the rows: the factor of ``[d_1 Rt_1; ...; d_A Rt_A]`` is ``[[R, z], [0, rho]]``, and

    beta_hat = R^-1 z,     rss = rho^2,     rss_a(beta) = |Rt_a [beta; -1]|^2

are the weighted least squares of every row (:func:`ineid.identify.least_squares.fit_base`'s QR, to
round-off), for any weights: each reweighting round of ``weights="estimate"`` is one QR of ``A (r + 1)``
rows, never of the frames. Unlike the normal equations (:func:`ineid.identify.least_squares.fit_base_blocks`)
nothing is squared: ill-conditioned frames lose ``eps * cond``, and the residuals need no second pass over
the frames (``e - 2 beta.h + beta^T G beta`` cancels; ``|Rt_a [beta; -1]|`` does not).

One compiled kernel (:func:`factor_blocks`) forms each chunk's rows (:func:`ineid.identify.rows.chunk_rows`)
and factors them (``jax.numpy.linalg.qr``, LAPACK's ``geqrf`` on the CPU); the chunks' factors are
stacked and factored again on the host. With constant offsets the rows get a column of ones first,
``[1 | W_b | y]``: the trailing block of that factor is the factor of the frames centred per axis
(Frisch-Waugh-Lovell, :class:`ineid.identify.systems.Offsets`), the first row gives the means, and an
axis without an offset keeps the factor of the other columns. The frame sums of every unknown column come
too, for the offsets ``b = ybar - Wbar theta`` of standard parameters.

References:
    Golub & Van Loan (2013), Matrix Computations, 5.2 and 5.3 (QR, updating, least squares).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ineid.channels import ChannelSet
from ineid.identify.blocks import InformationBlocks
from ineid.identify.chunks import map_chunks
from ineid.identify.fused import chunk_shape
from ineid.identify.identifiability import BaseParameters, numerical_rank
from ineid.identify.least_squares import (
    ESTIMATE_ROUNDS,
    BaseFit,
    axis_frames,
    axis_weights,
    estimated_axis_weights,
    r_inverse,
    triangular_fit,
)
from ineid.identify.rows import RowLayout, chunk_rows, layout_of, transforms
from ineid.identify.systems import Offsets

FACTOR_WORKERS = 1
"""Threads dispatching the factor kernel: one. Two executions of a compiled ``jax.numpy.linalg.qr`` at once
deadlock XLA:CPU (measured with jax 0.10.2: both threads wait on their results for ever)."""


def qr_r(a: np.ndarray) -> np.ndarray:
    """The triangular factor of each matrix of ``a`` (..., m, n), square (n, n): zero rows pad ``m < n``."""
    m, n = a.shape[-2:]
    if m < n:
        a = np.concatenate([a, np.zeros(a.shape[:-2] + (n - m, n))], axis=-2)
    return np.linalg.qr(a, mode="r")[..., :n, :]


@dataclass
class FactorBlocks:
    """Per-axis triangular factors of a batch of configurations' rows (see module doc).

    Attributes:
        R: (C, A, p, p) the factor of each axis's rows ``[1 | W_b | y]`` (``ones``) or ``[W_b | y]``;
            ``p = r + 2`` or ``r + 1``.
        n_frames: frames per configuration.
        ones: a leading column of ones (for offsets: :meth:`centred`, :meth:`axis_rss` with a bias).
        s: (C, A, 10 n_u + n_extra) the frame sums of every unknown column, with ``ones``; else None.
        t: (C, A) the frame sums of ``y``, with ``ones``; else None.
    """

    R: np.ndarray
    n_frames: int
    ones: bool = False
    s: np.ndarray | None = None
    t: np.ndarray | None = None

    def joined(self, other: FactorBlocks) -> FactorBlocks:
        """The factors of both batches' frames together (the same configurations, the same columns)."""
        if self.ones != other.ones:
            raise ValueError("join factors of the same columns (both with or both without the column of ones)")
        s = None if self.s is None or other.s is None else self.s + other.s
        t = None if self.t is None or other.t is None else self.t + other.t
        r = qr_r(np.concatenate([self.R, other.R], axis=-2))
        return FactorBlocks(r, self.n_frames + other.n_frames, self.ones, s, t)

    def uncentred(self) -> FactorBlocks:
        """The factors of ``[W_b | y]`` alone (the column of ones left out)."""
        if not self.ones:
            return self
        return FactorBlocks(qr_r(self.R[..., :, 1:]), self.n_frames)

    def centred(self, mask: np.ndarray | None = None) -> tuple[FactorBlocks, Offsets]:
        """``(factors, offsets)``: the factors of the frames centred per axis on ``mask``'s axes (None: every
        axis; the others keep theirs), and the means (:class:`ineid.identify.systems.Offsets`)."""
        if not self.ones or self.s is None or self.t is None:
            raise ValueError("these factors carry no column of ones; compute them with offsets=True")
        mask = None if mask is None or np.all(mask) else np.asarray(mask, dtype=bool)
        r = self.R[..., 1:, 1:].copy()  # the trailing block: the centred frames' factor
        if mask is not None:
            r[:, ~mask] = qr_r(self.R[:, ~mask][..., :, 1:])
        f = self.n_frames
        return FactorBlocks(r, f), Offsets(self.s / f, self.t / f, f, mask)

    def information(self) -> InformationBlocks:
        """The normal-equation blocks ``G_a = R_a^T R_a``, ``h_a = R_a^T z_a``, ``e_a`` (:class:`InformationBlocks`)."""
        rt = self.uncentred().R
        r = rt.shape[-1] - 1
        top = rt[..., :r, :r]
        z = rt[..., :r, r]
        g = np.swapaxes(top, -1, -2) @ top
        h = np.einsum("cask,cas->cak", top, z)
        return InformationBlocks(g, h, np.sum(rt[..., :, r] ** 2, axis=-1), self.n_frames)

    def axis_rss(self, beta: np.ndarray, bias: np.ndarray | None = None) -> np.ndarray:
        """(C, A) unweighted residual sum of squares per axis of ``beta`` (C, r), ``|Rt_a [-b_a; beta; -1]|^2``.

        ``bias`` (C, A): offsets ``b`` subtracted from every frame (needs ``ones``); None: none."""
        c, n_axes, p, _ = self.R.shape
        v = np.concatenate([-np.asarray(beta, dtype=np.float64), np.ones((c, 1))], axis=1)  # y - W b = -[W y] v
        v = np.broadcast_to(v[:, None, :], (c, n_axes, v.shape[1]))
        if self.ones:
            b = np.zeros((c, n_axes)) if bias is None else np.asarray(bias, dtype=np.float64)
            v = np.concatenate([-b[..., None], v], axis=-1)
        elif bias is not None:
            raise ValueError("a bias needs factors with the column of ones (offsets=True)")
        res = np.einsum("caij,caj->cai", self.R, v)
        return np.sum(res**2, axis=-1)

    def select(self, rows) -> FactorBlocks:
        def pick(a):
            return None if a is None else a[rows]

        return FactorBlocks(self.R[rows], self.n_frames, self.ones, pick(self.s), pick(self.t))


@functools.cache
def _factor_kernel(layout: RowLayout):
    """Jitted ``(q, qd, qdd, values, mask, gravity, theta_known, xs) -> (Rt[, s, t])``: per configuration and axis
    the triangular factor of the chunk's rows ``[W_b | y]`` ((Cc, A, r + 1, r + 1)); ``layout.sums``: of
    ``[1 | W_b | y]`` (r + 2), and the frame sums of every unknown column ``s`` (Cc, A, p) and of ``y`` (Cc, A)."""
    import jax
    import jax.numpy as jnp

    def kernel(q, qd, qdd, values, mask, gravity, theta_known, xs):
        w, y = chunk_rows(layout, q, qd, qdd, values, mask, gravity, theta_known, xs)  # (A, Cc, k, Fc), (A, Cc, Fc)
        w_b = w[:, :, jnp.asarray(layout.base_pos, dtype=jnp.int32), :] if layout.sums else w
        cols = [w_b, y[:, :, None, :]]
        if layout.sums:
            cols.insert(0, jnp.broadcast_to(mask[None, :, None, :], y[:, :, None, :].shape))
        x = jnp.transpose(jnp.concatenate(cols, axis=2), (1, 0, 3, 2))  # (Cc, A, Fc, p)
        p = x.shape[-1]
        if x.shape[-2] < p:  # fewer frames than columns: zero rows make the factor square
            x = jnp.concatenate([x, jnp.zeros(x.shape[:-2] + (p - x.shape[-2], p), x.dtype)], axis=-2)
        r = jnp.linalg.qr(x, mode="r")[..., :p, :]
        if not layout.sums:
            return (r,)
        return r, jnp.einsum("acpf->cap", w), jnp.einsum("acf->ca", y)

    return jax.jit(kernel)


def _merge(parts: list[tuple]) -> tuple:
    """The frame chunks' outputs of one configuration chunk merged: factors stacked and factored, sums added."""
    if len(parts) == 1:
        return parts[0]
    r = qr_r(np.concatenate([p[0] for p in parts], axis=-2))
    return (r, *(sum(p[i] for p in parts) for i in range(1, len(parts[0]))))


def factor_blocks(
    model,
    base: BaseParameters,
    q,
    qd,
    qdd,
    values,
    theta_known,
    channels: ChannelSet,
    offsets: bool = False,
    progress: Callable[[int, int], None] | None = None,
    n_frames_max: int | None = None,
) -> FactorBlocks:
    """Per-axis triangular factors of every configuration's rows (see module doc), one compiled kernel.

    Args:
        model: the :class:`ineid.RobotModel`; base: the base parameters of its unknown links and ``channels``' extras.
        q, qd, qdd: (C, F, n_dof) frames; values: (C, F, A) the channels' measured values, stacked.
        theta_known: (10 n_known,) the known links' parameters.
        channels: the :class:`ineid.channels.ChannelSet` measured.
        offsets: the column of ones and the frame sums too (:meth:`FactorBlocks.centred`).
        progress: ``progress(done, total)`` over configurations.
        n_frames_max: the frame count the kernel's shape is chosen for (default ``F``): pass the longest of
            several recordings, and one compiled shape serves them all (the shorter ones padded).
    """
    arrays = [np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, values)]
    n_configs, n_frames = arrays[0].shape[:2]
    n_axes = channels.n_axes(model)
    p = base.rank + (2 if offsets else 1)
    if n_configs == 0:
        sums = (np.zeros((0, n_axes, base.n_params)), np.zeros((0, n_axes))) if offsets else (None, None)
        return FactorBlocks(np.zeros((0, n_axes, p, p)), n_frames, offsets, *sums)
    kernel = _factor_kernel(layout_of(model, base, channels, offsets))
    consts = (model.gravity, np.asarray(theta_known, dtype=np.float64), transforms(channels, model))
    shape = chunk_shape(n_configs, max(n_frames, n_frames_max or 0))
    out = map_chunks(kernel, arrays, [], consts, shape, FACTOR_WORKERS, progress, combine=_merge)
    return FactorBlocks(out[0], n_frames, offsets, *(out[1:] if offsets else (None, None)))


def _factor_fit(rt: np.ndarray, axis_w: np.ndarray, scales_b: np.ndarray):
    """One weighted fit from the factors ``rt`` (C, A, r + 1, r + 1) with row weights ``axis_w`` (C, A):
    ``(beta, R, rss, rank, cond)`` as the QR of every row gives them (the rank scale-aware: the singular values
    of ``R`` with its columns scaled by ``scales_b``); rows not of full rank: NaN estimates, ``R`` the identity,
    ``rss`` of ``beta = 0``."""
    c, n_axes, p, _ = rt.shape
    r = p - 1
    top = qr_r((rt * axis_w[:, :, None, None]).reshape(c, n_axes * p, p))
    rr, z, rho = top[:, :r, :r], top[:, :r, r], top[:, r, r]
    sv = np.linalg.svd(rr * scales_b[None, None, :], compute_uv=False)
    rank = np.array([numerical_rank(s) for s in sv], dtype=np.int64)
    ok = rank == r
    safe_r = np.where(ok[:, None, None], rr, np.eye(r)[None])
    beta = np.linalg.solve(safe_r, np.where(ok[:, None], z, 0.0)[..., None])[..., 0]
    beta[~ok] = np.nan
    rss = np.where(ok, rho**2, np.sum(z**2, axis=1) + rho**2)
    cond = np.where(ok, sv[:, 0] / np.maximum(sv[:, -1], 1e-300), np.inf)
    return beta, safe_r, rss, rank, cond


def fit_base_factors(
    blocks: FactorBlocks,
    base: BaseParameters,
    weights: str = "estimate",
    axis_sigma: np.ndarray | None = None,
    axis_offsets: np.ndarray | None = None,
) -> BaseFit:
    """:func:`ineid.identify.least_squares.fit_base` from per-axis factors (:class:`FactorBlocks`, without the
    column of ones: centre them first): the same estimates, residuals, weights, covariance and rank decisions
    as the QR of every stacked row, to round-off, and the residual sum of squares exact.

    Args:
        blocks: the factors of C configurations; base, weights, axis_sigma, axis_offsets: as in ``fit_base``.
    """
    if blocks.ones:
        raise ValueError("fit centred or uncentred factors (FactorBlocks.centred, .uncentred), not the raw ones")
    rt = blocks.R
    c, n_axes = rt.shape[:2]
    axis_w = axis_weights(weights, axis_sigma, c, n_axes)
    r = base.rank
    scales_b = base.scales[base.base_index]
    beta, rr, rss, rank, cond = _factor_fit(rt, axis_w, scales_b)
    dof = n_axes * blocks.n_frames - r
    frames = axis_frames(blocks.n_frames, n_axes, axis_offsets)
    g = None
    if weights == "estimate" and dof > 0:  # feasible weighted least squares (ineid.identify.least_squares)
        info = blocks.information()
        g = info.G
        for _ in range(ESTIMATE_ROUNDS):
            axis_rss = blocks.axis_rss(np.nan_to_num(beta))
            axis_w = estimated_axis_weights(axis_rss, g, axis_w, r_inverse(rr), frames, info.e)
            beta, rr, rss, rank, cond = _factor_fit(rt, axis_w, scales_b)
    return triangular_fit(beta, rr, rss, dof, rank, cond, axis_w, g, frames)
