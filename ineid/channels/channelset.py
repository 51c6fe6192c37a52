"""Channels identified together: their axes stacked, one regressor, one vector of measurements per frame.

For channels ``1..m`` the stacked model of a frame is

    [y_1; ...; y_m] = [T_1 Phi_1; ...; T_m Phi_m] theta + blockdiag(E_1, ..., E_m) [x_1; ...; x_m]
                      + [b_1; ...; b_m] + e

with ``n_axes = n_a1 + ... + n_am`` rows, one parameter vector ``theta`` shared by all,
each channel's extra kept columns ``x_i`` its own, and everything that is per axis (noise,
row weights, residuals, offsets) per stacked axis. One channel stacks to itself: every
function and array of a one-channel set is that channel's own, so the layers above run
the same code (and compiled kernels) for a one-channel set as for the channel alone.
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ineid.channels.base import Channel, channel_from_dict
from ineid.errors import DatasetError


@dataclass(frozen=True)
class AxisBlock:
    """Where one channel's axes sit among a set's stacked axes: ``start:stop``; its extra columns ``extra``."""

    channel: Channel
    start: int
    stop: int
    extra: slice

    @property
    def axes(self) -> slice:
        return slice(self.start, self.stop)


@dataclass(frozen=True)
class ChannelSet:
    """Channels identified together, in order (see the module docstring). Immutable, hashable.

    Raises (on construction):
        DatasetError: no channel, two with one key, or something that is not a :class:`Channel`.
    """

    channels: tuple[Channel, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", tuple(self.channels))
        if not self.channels:
            raise DatasetError("no measurement channel to identify from; a dataset needs at least one (its wrench)")
        for c in self.channels:
            if not isinstance(c, Channel):
                raise TypeError(f"ChannelSet takes Channel objects, got {type(c).__name__}")
        keys = [c.key for c in self.channels]
        if len(set(keys)) != len(keys):
            raise DatasetError(f"measurement channels must have distinct keys, got {', '.join(keys)}")

    @classmethod
    def of(cls, *channels: Channel) -> ChannelSet:
        return cls(tuple(channels))

    def __iter__(self) -> Iterator[Channel]:
        return iter(self.channels)

    def __len__(self) -> int:
        return len(self.channels)

    def __getitem__(self, key: str) -> Channel:
        c = self.get(key)
        if c is None:
            raise KeyError(key)
        return c

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(c.key for c in self.channels)

    def get(self, key: str) -> Channel | None:
        return next((c for c in self.channels if c.key == key), None)

    def select(self, keys: Sequence[str] | None) -> ChannelSet:
        """The channels named in ``keys``, in this set's order; all when ``keys`` is None.

        Raises:
            DatasetError: a key that is not among the channels (naming those there are).
        """
        if keys is None:
            return self
        keys = list(keys)
        missing = [k for k in keys if self.get(k) is None]
        if missing or not keys:
            raise DatasetError(
                f"no {', '.join(missing) or 'channel'} measurements here (the data hold "
                f"{', '.join(self.keys)}); choose among {', '.join(self.keys)}"
            )
        return ChannelSet(tuple(c for c in self.channels if c.key in keys))

    def replace(self, channel: Channel) -> ChannelSet:
        """This set with the channel of ``channel.key`` replaced by ``channel`` (appended when new)."""
        if self.get(channel.key) is None:
            return ChannelSet((*self.channels, channel))
        return ChannelSet(tuple(channel if c.key == channel.key else c for c in self.channels))

    def with_offsets(self, offsets: bool) -> ChannelSet:
        """Every channel with (or without) identified constant offsets."""
        return ChannelSet(tuple(c.with_offsets(offsets) for c in self.channels))

    @property
    def has_offsets(self) -> bool:
        return any(c.offsets for c in self.channels)

    def describe(self) -> str:
        return "; ".join(c.describe() for c in self.channels)

    # -- records --------------------------------------------------------------------------
    def to_list(self) -> list[dict]:
        """JSON-able records, one per channel (:meth:`Channel.to_dict`)."""
        return [c.to_dict() for c in self.channels]

    @classmethod
    def from_list(cls, items, where: str = "channels") -> ChannelSet:
        """Inverse of :meth:`to_list` (raises :class:`DatasetError` naming ``where`` and the item)."""
        if not isinstance(items, (list, tuple)):
            raise DatasetError(f"{where}: expected a list of measurement channel records, got {items!r}")
        return cls(tuple(channel_from_dict(d, f"{where}[{i}]") for i, d in enumerate(items)))

    def key_tuple(self) -> tuple:
        return tuple(c.key_tuple() for c in self.channels)

    # -- axes -----------------------------------------------------------------------------
    def blocks(self, model) -> tuple[AxisBlock, ...]:
        """Each channel's rows (and extra columns) among the stacked ones."""
        out, start, e0 = [], 0, 0
        for c in self.channels:
            n, n_e = c.n_axes(model), len(c.extra_names(model))
            out.append(AxisBlock(c, start, start + n, slice(e0, e0 + n_e)))
            start, e0 = start + n, e0 + n_e
        return tuple(out)

    def n_axes(self, model) -> int:
        return sum(c.n_axes(model) for c in self.channels)

    def axes(self, model) -> tuple[str, ...]:
        """Stacked axis names: one channel's are its own (``"fx"``), several ``"<key>.<axis>"``."""
        if len(self.channels) == 1:
            return tuple(self.channels[0].axes(model))
        return tuple(f"{c.key}.{a}" for c in self.channels for a in c.axes(model))

    def units(self, model) -> tuple[str, ...]:
        return tuple(u for c in self.channels for u in c.units(model))

    def offset_mask(self, model) -> np.ndarray:
        """(n_axes,) bool: the axes whose constant offsets are identified."""
        return np.concatenate([np.full(c.n_axes(model), c.offsets) for c in self.channels])

    def offset_names(self, model) -> tuple[str, ...]:
        return tuple(n for c in self.channels for n in c.offset_names(model))

    def transforms(self) -> tuple[np.ndarray | None, ...]:
        """Each channel's ``T`` (None: the identity)."""
        return tuple(c.transform() for c in self.channels)

    def transform(self, model) -> np.ndarray | None:
        """``blockdiag(T_1, ..., T_m)`` (n_axes, n_axes), or None when every ``T`` is the identity."""
        ts = self.transforms()
        if all(t is None for t in ts):
            return None
        n = self.n_axes(model)
        out = np.zeros((n, n))
        for b, t in zip(self.blocks(model), ts, strict=True):
            out[b.axes, b.axes] = np.eye(b.stop - b.start) if t is None else t
        return out

    def nonzero(self, model) -> tuple[tuple[int, ...], ...]:
        """Per stacked row of ``T Phi`` the columns that are not identically zero (``T`` mixes rows)."""
        out = []
        for c in self.channels:
            nz, t = c.nonzero(model), c.transform()
            if t is None:
                out.extend(tuple(r) for r in nz)
                continue
            for a in range(len(nz)):
                cols = set().union(*(nz[b] for b in range(len(nz)) if t[a, b] != 0.0))
                out.append(tuple(sorted(cols)))
        return tuple(out)

    def noise_std(self, noise: Mapping | None, model) -> np.ndarray | None:
        """(n_axes,) recorded noise standard deviations from a dataset's ``noise`` record (each channel's
        under its key: one number or one per axis), or None when a channel has none or a zero one."""
        parts = []
        for c in self.channels:
            std = None if not noise else noise.get(c.key)
            if std is None:
                return None
            try:
                parts.append(np.broadcast_to(np.asarray(std, dtype=np.float64), (c.n_axes(model),)))
            except ValueError:
                raise DatasetError(
                    f"the noise record of channel {c.key!r} holds {np.size(std)} numbers for "
                    f"{c.n_axes(model)} axes; regenerate the file"
                ) from None
        out = np.concatenate(parts)
        return out if np.all(out > 0) and np.all(np.isfinite(out)) else None

    def split(self, values, model, axis: int = -1) -> dict[str, np.ndarray]:
        """Per channel key its part of ``values``, whose ``axis`` runs over the stacked axes."""
        values = np.asarray(values)
        if values.shape[axis] != self.n_axes(model):
            raise ValueError(f"expected {self.n_axes(model)} stacked axes along axis {axis}, got {values.shape}")
        return {b.channel.key: np.take(values, np.arange(b.start, b.stop), axis=axis) for b in self.blocks(model)}

    def values(self, measurements: Mapping[str, np.ndarray], model) -> np.ndarray:
        """The stacked measured values (..., n_axes) from ``measurements[key]`` (..., n_a) per channel.

        Raises:
            DatasetError: a channel whose values are missing or have another number of axes.
        """
        parts = []
        for c in self.channels:
            if c.key not in measurements:
                raise DatasetError(
                    f"no values for measurement channel {c.key!r} (there are "
                    f"{', '.join(map(str, measurements)) or 'none'}); the file is incomplete"
                )
            v = np.asarray(measurements[c.key])
            if v.shape[-1:] != (c.n_axes(model),):
                raise DatasetError(
                    f"measurement channel {c.key!r} has shape {v.shape}; expected "
                    f"{c.n_axes(model)} axes last ({', '.join(c.axes(model))})"
                )
            parts.append(v)
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=-1)

    # -- the stacked model ----------------------------------------------------------------------
    def structure(self, model) -> tuple:
        """Hashable: what compiled kernels of these channels depend on (:meth:`Channel.structure`)."""
        return tuple(c.structure(model) for c in self.channels)

    def jax_rows_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity) -> (..., n_axes, p)``: the stacked ``T Phi``, jit-safe."""
        fns = tuple(c.jax_rows_function(model) for c in self.channels)
        return fns[0] if len(fns) == 1 else _concatenated(fns, -2)

    def jax_predict_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity, theta) -> (..., n_axes)``: the stacked ``T Phi theta``, jit-safe."""
        fns = tuple(c.jax_predict_function(model) for c in self.channels)
        return fns[0] if len(fns) == 1 else _concatenated(fns, -1)

    def rows(self, model, q, qd, qdd) -> np.ndarray:
        """The stacked ``T Phi`` (..., n_axes, p), float64 NumPy (each channel's :meth:`Channel.rows`)."""
        parts = [c.rows(model, q, qd, qdd) for c in self.channels]
        return parts[0] if len(parts) == 1 else _join(parts, -2)

    def rows_split(self, model, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
        """The stacked ``(T Phi_u, T Phi_k)``: (..., n_axes, 10 n_u) and (..., n_axes, 10 n_k)."""
        parts = [c.rows_split(model, q, qd, qdd) for c in self.channels]
        if len(parts) == 1:
            return parts[0]
        return tuple(_join([p[i] for p in parts], -2) for i in range(2))  # type: ignore[return-value]

    def predict(self, model, q, qd, qdd, theta) -> np.ndarray:
        """The stacked ``T Phi theta`` (..., n_axes) (each channel's :meth:`Channel.predict`)."""
        parts = [c.predict(model, q, qd, qdd, theta) for c in self.channels]
        return parts[0] if len(parts) == 1 else _join(parts, -1)

    def casadi_rows(self, model, transformed: bool = True):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (n_axes x p): the stacked ``T Phi``, the model's gravity;
        ``transformed=False``: the stacked ``Phi`` (each ``T`` is invertible, so ranks, base parameters
        and null spaces are those of ``Phi``)."""
        if len(self.channels) == 1 and (self.channels[0].transform() is None or not transformed):
            return self.channels[0].casadi_function(model)
        return _casadi_cached(
            self,
            model,
            "rows" if transformed else "phi",
            functools.partial(_build_casadi_rows, transformed=transformed),
        )

    # -- extra kept columns ------------------------------------------------------------------
    def extra_names(self, model) -> tuple[str, ...]:
        """Every channel's extra kept columns, in order (raises :class:`DatasetError` on a repeated name)."""
        names = tuple(n for c in self.channels for n in c.extra_names(model))
        if len(set(names)) != len(names):
            seen = [n for i, n in enumerate(names) if n in names[:i]]
            raise DatasetError(
                f"two measurement channels name the extra parameter {seen[0]!r}; give them distinct names"
            )
        return names

    def n_extra(self, model) -> int:
        return len(self.extra_names(model))

    def jax_extra_rows_function(self, model) -> Callable | None:
        """``f(q, qd, qdd) -> (..., n_axes, n_extra)``: ``blockdiag(E_1, ..., E_m)``, or None when no
        channel has extra columns."""
        blocks = self.blocks(model)
        if self.n_extra(model) == 0:
            return None
        return _extra_block_function(
            tuple(
                (b.channel.extra_rows_function(model), b.start, b.stop, b.extra.start, b.extra.stop)
                for b in blocks
                if b.extra.stop > b.extra.start
            ),
            self.n_axes(model),
            self.n_extra(model),
        )

    def extra_rows(self, model, q, qd, qdd) -> np.ndarray:
        """``blockdiag(E_1, ..., E_m)`` (..., n_axes, n_extra), float64 NumPy; n_extra may be 0."""
        parts = [c.extra_rows(model, q, qd, qdd) for c in self.channels]
        if len(parts) == 1:
            return parts[0]
        batch = np.broadcast_shapes(*(p.shape[:-2] for p in parts))
        out = np.zeros(batch + (self.n_axes(model), self.n_extra(model)))
        for b, p in zip(self.blocks(model), parts, strict=True):
            out[..., b.axes, b.extra] = p
        return out

    def casadi_extra_rows(self, model):
        """``casadi.Function`` ``(q, qd, qdd) -> E`` (n_axes x n_extra), or None without extra columns."""
        if self.n_extra(model) == 0:
            return None
        return _casadi_cached(self, model, "extra", _build_casadi_extra)


def _join(parts: list, axis: int):
    """The channels' answers stacked in kind: NumPy arrays with NumPy, ``jax.Array``s (on their device, or
    traced inside a caller's ``jit``) with ``jax.numpy``, as the channels' evaluators answered."""
    if all(isinstance(p, np.ndarray) for p in parts):
        return np.concatenate(parts, axis=axis)
    import jax.numpy as jnp

    return jnp.concatenate(parts, axis=axis)


@functools.cache
def _concatenated(fns: tuple, axis: int) -> Callable:
    import jax.numpy as jnp

    def stacked(*args):
        return jnp.concatenate([f(*args) for f in fns], axis=axis)

    return stacked


@functools.cache
def _extra_block_function(parts: tuple, n_axes: int, n_extra: int) -> Callable:
    import jax.numpy as jnp

    def extra(q, qd, qdd):
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        out = jnp.zeros(batch + (n_axes, n_extra), dtype=q.dtype)
        for fn, a0, a1, e0, e1 in parts:
            out = out.at[..., a0:a1, e0:e1].set(fn(q, qd, qdd))
        return out

    return extra


_CASADI: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Per robot model: ``{(what, channels' key_tuple): casadi.Function}`` (dropped with the model)."""


def _casadi_cached(channels: ChannelSet, model, what: str, build: Callable):
    per_model = _CASADI.setdefault(model, {})
    key = (what, channels.key_tuple())
    if key not in per_model:
        per_model[key] = build(channels, model)
    return per_model[key]


def _build_casadi_rows(channels: ChannelSet, model, transformed: bool = True):
    import casadi as ca

    q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
    blocks = []
    for c in channels:
        y = c.casadi_function(model)(q, qd, qdd)
        t = c.transform() if transformed else None
        blocks.append(y if t is None else ca.mtimes(ca.DM(t), y))
    return ca.Function("channel_rows", [q, qd, qdd], [ca.vertcat(*blocks)], ["q", "qd", "qdd"], ["Y"])


def _build_casadi_extra(channels: ChannelSet, model):
    import casadi as ca

    q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
    out = ca.SX.zeros(channels.n_axes(model), channels.n_extra(model))
    for b in channels.blocks(model):
        fn = b.channel.casadi_extra_function(model)
        if fn is not None and b.extra.stop > b.extra.start:
            out[b.start : b.stop, b.extra.start : b.extra.stop] = fn(q, qd, qdd)
    return ca.Function("channel_extra_rows", [q, qd, qdd], [out], ["q", "qd", "qdd"], ["E"])
