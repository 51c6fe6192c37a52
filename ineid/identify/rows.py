"""The measurement channels' rows of a chunk of frames, inside a compiled kernel.

Every kernel of the linear identification (:mod:`ineid.identify.fused`: the normal-equation
blocks; :mod:`ineid.identify.qr_blocks`: the triangular factors) starts from the same traced
rows: each channel's generated regressor entries (:meth:`ineid.channels.Channel.entries_function`)
at the chosen unknown columns, the channel's transform ``T`` applied, its extra kept columns ``E``
appended, and the measured values less the known links' share. :class:`RowLayout` says which
columns (what a kernel is compiled for); :func:`chunk_rows` forms them, frames last (each entry one
contiguous run: XLA:CPU's fast layout), and never leaves the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.channels import ChannelSet


@dataclass(frozen=True)
class RowLayout:
    """What a kernel's rows are (resolved from the model, the base parameters and the channels).

    Attributes:
        structure: :meth:`ineid.channels.ChannelSet.structure` of the channels, whose rows are stacked in order.
        n_cols: the regressor's columns (``10 n_links``).
        columns: the unknown columns taken (the base ones, or every unknown one when ``sums``).
        known_columns: the known links' columns (their share is subtracted from the values).
        extra_columns: the channels' extra kept columns taken (indices into their ``n_extra``).
        n_extra: the channels' extra kept columns in all.
        sums: every unknown column is taken (for frame sums); the base ones sit at ``base_pos``.
        base_pos: with ``sums``, the positions of the base columns among those taken.
    """

    structure: tuple
    n_cols: int
    columns: tuple[int, ...]
    known_columns: tuple[int, ...]
    extra_columns: tuple[int, ...]
    n_extra: int
    sums: bool
    base_pos: tuple[int, ...]


def layout_of(model, base, channels: ChannelSet, sums: bool) -> RowLayout:
    """The :class:`RowLayout` of ``base``'s columns of ``channels``' rows (``sums``: every unknown column, the
    base ones among them)."""
    n_link, n_extra = base.n_link_params, channels.n_extra(model)
    link_base = base.base_index[base.base_index < n_link]
    base_columns = tuple(int(c) for c in np.asarray(model.unknown_index)[link_base])
    base_extra = tuple(int(j) - n_link for j in base.base_index[base.base_index >= n_link]) if n_extra else ()
    if not sums:
        return RowLayout(
            channels.structure(model),
            10 * model.n_links,
            base_columns,
            tuple(int(c) for c in model.known_index),
            base_extra,
            n_extra,
            False,
            (),
        )
    sum_columns = tuple(int(c) for c in model.unknown_index)
    sum_extra = tuple(range(n_extra))
    base_pos = tuple(sum_columns.index(c) for c in base_columns) + tuple(
        len(sum_columns) + sum_extra.index(j) for j in base_extra
    )
    return RowLayout(
        channels.structure(model),
        10 * model.n_links,
        sum_columns,
        tuple(int(c) for c in model.known_index),
        sum_extra,
        n_extra,
        True,
        base_pos,
    )


def transforms(channels: ChannelSet, model) -> tuple[np.ndarray, ...]:
    """Each channel's ``T`` as a kernel argument (the identity where it has none: not read)."""
    return tuple(
        np.eye(c.n_axes(model)) if t is None else np.asarray(t, dtype=np.float64)
        for c, t in zip(channels, channels.transforms(), strict=True)
    )


def extra_rows(layout: RowLayout, q, qd, qdd, mask):
    """(A, Cc, len(extra_columns), Fc): the block-diagonal ``E`` of the channels at ``layout.extra_columns``
    (traced)."""
    import jax.numpy as jnp

    batch = q.shape[:-1]
    n_axes = sum(channel.n_axes for channel in layout.structure)
    e = jnp.zeros(batch + (n_axes, layout.n_extra), dtype=q.dtype)
    a0 = e0 = 0
    for channel in layout.structure:
        if channel.n_extra:
            e = e.at[..., a0 : a0 + channel.n_axes, e0 : e0 + channel.n_extra].set(channel.extra_rows(q, qd, qdd))
        a0, e0 = a0 + channel.n_axes, e0 + channel.n_extra
    e = e[..., jnp.asarray(layout.extra_columns, dtype=jnp.int32)]  # (Cc, Fc, A, k)
    return jnp.transpose(e, (2, 0, 3, 1)) * mask[None, :, None, :]


def stacked_entries(entries, batch, dtype):
    """(Cc, len(entries) Fc): ``entries`` (each of the batch shape (Cc, Fc) or a Python number) side by side
    along the frames, in one ``concatenate`` (traced): the program stays a few operations whatever the count."""
    import jax.numpy as jnp
    from jax import lax

    zeros = None
    parts = []
    for x in entries:
        if isinstance(x, (int, float)) and x == 0:  # structurally zero: one array shared by all of them
            zeros = jnp.zeros(batch, dtype) if zeros is None else zeros
            x = zeros
        parts.append(jnp.broadcast_to(x, batch).astype(dtype))
    if not parts:
        return jnp.zeros(batch[:-1] + (0,), dtype)
    return lax.concatenate(parts, dimension=len(batch) - 1)


def channel_rows(layout: RowLayout, entries, n_axes: int, batch, mask, theta_known, dtype):
    """``(w, known)``: one channel's rows at ``layout.columns`` (n_a, Cc, r, Fc) and the known links' share
    (n_a, Cc, Fc) from its regressor ``entries`` (traced)."""
    import jax.numpy as jnp

    n_cols = layout.n_cols
    (cc, fc), r = batch, len(layout.columns)
    flat = stacked_entries([entries[a * n_cols + c] for a in range(n_axes) for c in layout.columns], batch, dtype)
    # (n_a, Cc, r, Fc): frames last, each entry one contiguous run (XLA:CPU's fast layout)
    w = jnp.transpose(flat.reshape(cc, n_axes, r, fc), (1, 0, 2, 3)) * mask[None, :, None, :]
    known = jnp.stack(
        [
            sum(
                (entries[a * n_cols + c] * theta_known[k] for k, c in enumerate(layout.known_columns)),
                start=jnp.zeros(batch, dtype),
            )
            for a in range(n_axes)
        ]
    )  # (n_a, Cc, Fc)
    return w, known


def chunk_rows(layout: RowLayout, q, qd, qdd, values, mask, gravity, theta_known, xs):
    """``(w, y)``: the rows ``[T Phi_u | E]`` at the layout's columns (A, Cc, k, Fc) and the values less the
    known links' share (A, Cc, Fc), zero on masked frames (traced).

    Args:
        q, qd, qdd: (Cc, Fc, n_dof); values: (Cc, Fc, A) the channels' measured values, stacked.
        mask: (Cc, Fc) 1 on real frames, 0 on padding.
        gravity: (3,); theta_known: (10 n_k,); xs: each channel's ``T`` (read where it has one).
    """
    import jax.numpy as jnp

    batch = q.shape[:-1]  # (Cc, Fc)
    evaluated: dict = {}  # two channels of one regressor evaluate it once
    w_parts, known_parts = [], []
    for channel, x in zip(layout.structure, xs, strict=True):
        if channel.entries not in evaluated:
            evaluated[channel.entries] = channel.entries(q, qd, qdd, gravity)
        w, known = channel_rows(layout, evaluated[channel.entries], channel.n_axes, batch, mask, theta_known, q.dtype)
        if channel.transformed:  # the channel's axes: T applied to every regressor row and to the known share
            w = jnp.einsum("ab,bcrf->acrf", x, w)
            known = jnp.einsum("ab,bcf->acf", x, known)
        w_parts.append(w)
        known_parts.append(known)
    w = w_parts[0] if len(w_parts) == 1 else jnp.concatenate(w_parts)  # (A, Cc, r, Fc)
    if layout.extra_columns:  # [T Phi_u | E]: the extra kept columns after the links'
        w = jnp.concatenate([w, extra_rows(layout, q, qd, qdd, mask)], axis=2)
    known = known_parts[0] if len(known_parts) == 1 else jnp.concatenate(known_parts)
    y = (jnp.moveaxis(values, -1, 0) - known) * mask  # (A, Cc, Fc)
    return w, y
