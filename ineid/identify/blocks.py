"""Per-axis normal-equation blocks of a batch of configurations (:func:`ineid.identify.fused.information_blocks`).

See :mod:`ineid.identify.fused` for the equations: ``G_a, h_a, e_a`` per axis, their weighted sums,
the residual per axis of any ``beta``, and the centring that fits constant offsets jointly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class InformationBlocks:
    """Per-axis normal-equation blocks of a batch of configurations (see module doc).

    ``A`` is the number of stacked axes of the channels (six for the base wrench).

    Attributes:
        G: (C, A, r, r) ``sum_k W_b[k, a]^T W_b[k, a]`` per axis ``a``.
        h: (C, A, r) ``sum_k W_b[k, a]^T y[k, a]``.
        e: (C, A) ``sum_k y[k, a]^2``.
        n_frames: frames per configuration ``F`` (rows ``AF``).
        s: (C, A, 10 n_u + n_extra) ``sum_k (W_u[k, a] - w_ref_a)`` (every unknown column: the unknown
            links', then the channels' extra kept columns), or None.
        t: (C, A) ``sum_k (y[k, a] - y_ref_a)``, or None.
        w_ref, y_ref: (C, A, 10 n_u + n_extra), (C, A) the rows subtracted from every frame before
            ``G, h, e, s, t`` were summed (the first frame's), or None (nothing subtracted).
        axis_w: None for per-axis blocks; else (C, A) row weights ``d_a`` the blocks were
            summed with in the kernel: ``G`` (C, r, r) ``= sum_a d_a^2 G_a``, ``h`` (C, r)
            ``= sum_a d_a^2 h_a`` (``e`` stays per axis). ``A`` times less memory, for fits
            whose weights are known before the frames are read (none, noise).
    """

    G: np.ndarray
    h: np.ndarray
    e: np.ndarray
    n_frames: int
    s: np.ndarray | None = None
    t: np.ndarray | None = None
    w_ref: np.ndarray | None = None
    y_ref: np.ndarray | None = None
    axis_w: np.ndarray | None = None

    def _per_axis(self, what: str) -> None:
        if self.axis_w is not None:
            raise ValueError(f"{what} needs per-axis blocks; these were summed with fixed weights (axis_weights=...)")

    def centred(self, base, mask: np.ndarray | None = None):
        """``(blocks, offsets)``: the blocks of the frames centred per axis, and their means.

        With ``sb_a = s_a[base columns]``: ``G_a - sb_a sb_a^T / F``, ``h_a - sb_a t_a / F``,
        ``e_a - t_a^2 / F`` (``sum_k (x_k - xbar)(z_k - zbar) = sum_k x_k z_k - F xbar zbar``);
        ``offsets`` holds ``Wbar = s / F + w_ref`` and ``ybar = t / F + y_ref``
        (:class:`ineid.identify.systems.Offsets`). The shift by ``w_ref, y_ref`` leaves the
        centred blocks as they are and keeps them from cancelling. ``mask`` (A,) bool: only
        those axes have offsets and are centred (:meth:`ineid.channels.ChannelSet.offset_mask`);
        None: every axis.
        """
        from ineid.identify.systems import Offsets

        self._per_axis("centring")
        if self.s is None or self.t is None:
            raise ValueError("these blocks carry no frame sums; compute them with sums=True")
        f = self.n_frames
        mask = None if mask is None or np.all(mask) else np.asarray(mask, dtype=bool)
        s, t = (self.s, self.t) if mask is None else (self.s * mask[:, None], self.t * mask)
        sb = s[..., base.base_index]
        g = self.G - np.einsum("car,cas->cars", sb, sb) / f
        h = self.h - sb * (t / f)[..., None]
        e = self.e - t**2 / f
        w_ref = 0.0 if self.w_ref is None else self.w_ref
        y_ref = 0.0 if self.y_ref is None else self.y_ref
        return InformationBlocks(g, h, e, f), Offsets(self.s / f + w_ref, self.t / f + y_ref, f, mask)

    def weighted(self, axis_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(W_b^T D^2 W_b, W_b^T D^2 y, y^T D^2 y)`` for row weights ``axis_w`` (C, A)."""
        if self.axis_w is not None:
            if not np.array_equal(np.broadcast_to(axis_w, self.axis_w.shape), self.axis_w):
                raise ValueError("these blocks were summed with other row weights; compute them again")
            return self.G, self.h, np.sum(self.axis_w**2 * self.e, axis=1)
        d2 = (np.asarray(axis_w, dtype=np.float64) ** 2)[:, None, :]  # (C, 1, A)
        c, n_axes, r, _ = self.G.shape
        a = np.matmul(d2, self.G.reshape(c, n_axes, r * r)).reshape(c, r, r)
        b = np.matmul(d2, self.h)[:, 0]
        return a, b, np.matmul(d2, self.e[:, :, None])[:, 0, 0]

    def axis_rss(self, beta: np.ndarray) -> np.ndarray:
        """(C, A) unweighted residual sum of squares per axis, ``e_a - 2 beta.h_a + beta^T G_a beta``."""
        self._per_axis("the residual per axis")
        gb = np.matmul(self.G, beta[:, None, :, None])[..., 0]  # (C, A, r)
        quad = np.matmul(gb, beta[:, :, None])[..., 0]
        lin = np.matmul(self.h, beta[:, :, None])[..., 0]
        return np.maximum(self.e - 2.0 * lin + quad, 0.0)

    def select(self, rows) -> InformationBlocks:
        def pick(a):
            return None if a is None else a[rows]

        return InformationBlocks(
            self.G[rows],
            self.h[rows],
            self.e[rows],
            self.n_frames,
            pick(self.s),
            pick(self.t),
            pick(self.w_ref),
            pick(self.y_ref),
            pick(self.axis_w),
        )
