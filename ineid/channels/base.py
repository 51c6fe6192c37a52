"""What a measurement channel is: rows of a regressor linear in the parameters, and what rides along.

A channel is one sensor's stream of ``n_a`` numbers per frame (six for an F/T sensor,
``n_dof`` for joint torques), modelled as

    y_k = T Phi(q_k, qd_k, qdd_k; g) theta + E(q_k, qd_k, qdd_k) x + b + e_k,
    e_k ~ N(0, diag(sigma^2))

* ``Phi`` (n_a x 10 n_links) is a regressor the generated code provides, in the frame the
  model computes it in (the base frame for the base wrench), linear in every link's
  parameters ``theta`` (:mod:`ineid.params`);
* ``T`` (n_a x n_a) a constant map into the sensor's own axes (the wrench transform of a
  sensor mounted under the base, :func:`ineid.channels.pose.wrench_transform`), or the
  identity (:meth:`Channel.transform` returns None);
* ``E x`` the channel's *extra kept columns*: nuisance parameters ``x`` that are linear in
  their own regressor columns and reported with the links' parameters (joint friction
  ``<joint>.fv`` against ``qd``, ...). None today: :meth:`Channel.extra_names` is empty
  and :meth:`Channel.extra_rows_function` None; the stacking code carries zero columns;
* ``b`` (n_a,) constant offsets, identified by centring the frames per axis when the
  channel is set up with ``offsets=True`` (an untared sensor; ``ineid solve --bias
  estimate``); they are not columns, so they never enter the base-parameter analysis;
* ``sigma`` (n_a,) the noise per axis: recorded with the data (the dataset's ``noise``
  record under the channel's :attr:`Channel.key`) or estimated from the residuals.

Every layer above asks channels, never a particular sensor, for what it needs (see
``docs/architecture.md``, "Measurement channels"): datasets store each channel's values
under its :attr:`Channel.key`; identification stacks the rows of a
:class:`ineid.channels.channelset.ChannelSet` (fused normal-equation blocks from
:meth:`Channel.entries_function`, the QR reference from :meth:`Channel.rows_split`, the
identifiability analysis from :meth:`Channel.casadi_function`); excitation design and the
networks' physics loss evaluate :meth:`Channel.jax_rows_function`. A new sensor is a new
subclass registered with :func:`register`.
"""

from __future__ import annotations

import functools
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import ClassVar, NamedTuple

import numpy as np

from ineid.errors import DatasetError

_KINDS: dict[str, type[Channel]] = {}

KEY_PATTERN = re.compile(r"[a-z][a-z0-9_]{0,31}")
RESERVED_KEYS = frozenset({"q", "qd", "qdd", "time", "theta_known", "theta_unknown", "link_set_index", "config_index"})
"""Dataset names a channel's values cannot take (the frames, the truth, the indices)."""


def register(cls: type[Channel]) -> type[Channel]:
    """Class decorator: make a channel kind readable from its :meth:`Channel.to_dict` (datasets, results)."""
    if not cls.kind:
        raise TypeError(f"{cls.__name__} must set the class attribute kind")
    if _KINDS.get(cls.kind, cls) is not cls:
        raise TypeError(f"channel kind {cls.kind!r} is registered twice ({_KINDS[cls.kind].__name__}, {cls.__name__})")
    _KINDS[cls.kind] = cls
    return cls


def channel_kinds() -> tuple[str, ...]:
    """The registered channel kinds (``"wrench"``, ...)."""
    return tuple(_KINDS)


def channel_from_dict(d: Mapping, where: str = "channel") -> Channel:
    """Inverse of :meth:`Channel.to_dict`.

    Raises:
        DatasetError: not a record, an unknown kind, or a malformed field (one line naming ``where``).
    """
    if not isinstance(d, Mapping):
        raise DatasetError(f"{where}: a measurement channel must be a record with a kind, got {d!r}")
    kind = d.get("kind")
    if kind not in _KINDS:
        raise DatasetError(
            f"{where}: unknown measurement channel kind {kind!r} (this ineid reads "
            f"{', '.join(sorted(_KINDS))}); a newer ineid wrote it: upgrade ineid"
        )
    return _KINDS[kind].from_dict(d, where)


def check_key(key, where: str = "channel") -> str:
    """``key`` if it can name a channel's values in a dataset, else :class:`DatasetError`."""
    if not isinstance(key, str) or not KEY_PATTERN.fullmatch(key) or key in RESERVED_KEYS or key.endswith("_clean"):
        raise DatasetError(
            f"{where}: channel key {key!r} cannot name a dataset entry; use lower-case letters, digits and "
            f"'_' (at most 32, a letter first), not ending in '_clean' nor one of {', '.join(sorted(RESERVED_KEYS))}"
        )
    return key


class ChannelStructure(NamedTuple):
    """What compiled kernels of a channel depend on (:meth:`Channel.structure`); ``T``'s values are arguments.

    Attributes:
        entries: :meth:`Channel.entries_function` (the fused normal-equation kernels).
        phi_theta: :meth:`Channel.phi_theta_function` (the residual kernels).
        n_axes: ``n_a``.
        transformed: ``T`` is not the identity (the kernels apply the ``T`` they are given).
        extra_rows: :meth:`Channel.extra_rows_function`, or None.
        n_extra: the number of extra kept columns.
    """

    entries: Callable
    phi_theta: Callable
    n_axes: int
    transformed: bool
    extra_rows: Callable | None
    n_extra: int


@dataclass(frozen=True, kw_only=True)
class Channel(ABC):
    """One sensor's measurement model (see the module docstring). Immutable, hashable, equal by value.

    Subclasses are frozen keyword-only dataclasses that set :attr:`kind` (and usually a
    default :attr:`key`), list their own record fields in :attr:`RECORD_FIELDS`, and
    implement the abstract methods; everything else (the eager evaluators, the JAX rows,
    the record's common fields) follows. Methods that take ``model`` take the
    :class:`ineid.RobotModel` the channel is evaluated for; :meth:`axes`, :meth:`units` and
    :meth:`n_axes` use only its ``n_dof``, ``joint_names`` and ``link_names``, so a
    dataset's metadata (:class:`ineid.data.DatasetMeta`) serves there before any model is built.

    Attributes:
        key: the name of the channel's values in a dataset file (``"wrench"``) and of its
            noise in the dataset's noise record; unique within a :class:`ChannelSet`.
        offsets: constant per-axis offsets ``b`` are identified with the parameters.
    """

    key: str
    offsets: bool = False

    kind: ClassVar[str] = ""
    """Registry name, stored in the record (``"wrench"``)."""
    RECORD_FIELDS: ClassVar[tuple[str, ...]] = ()
    """The subclass's own fields in :meth:`to_dict` (besides ``kind``, ``key``, ``offsets``)."""

    def __post_init__(self) -> None:
        check_key(self.key)
        if not isinstance(self.offsets, bool):
            raise DatasetError(f"channel {self.key!r}: offsets must be true or false, got {self.offsets!r}")

    # -- what it measures ------------------------------------------------------------------
    @abstractmethod
    def axes(self, model) -> tuple[str, ...]:
        """Names of the ``n_a`` measured numbers per frame (``"fx"``, ..., or one per joint)."""

    @abstractmethod
    def units(self, model) -> tuple[str, ...]:
        """SI unit of each axis (``"N"``, ``"N*m"``)."""

    @abstractmethod
    def describe(self) -> str:
        """One line for people (``"base wrench (sensor frame xyz=(...) m, rpy=(...) rad)"``)."""

    def n_axes(self, model) -> int:
        return len(self.axes(model))

    # -- the model: abstract primitives ------------------------------------------------------
    @abstractmethod
    def entries_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity) -> (Phi_00, Phi_01, ..., Phi_(n_a-1)(p-1))``, ``p = 10 n_links``.

        The entries of ``Phi`` in row-major order, in the model's frame (before
        :meth:`transform`), each of the batch shape or the number 0 where identically zero;
        pure JAX, jit-safe, and the same object on every call for the same model (it keys
        compiled kernels). The fused normal-equation kernels pick the entries they need.
        """

    @abstractmethod
    def casadi_function(self, model):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (n_dof x 1 each -> n_a x p): ``Phi`` with the model's
        gravity, in the model's frame (before :meth:`transform`): the QR reference and identifiability."""

    # -- the model: defaults a subclass may override ----------------------------------------
    def transform(self) -> np.ndarray | None:
        """``T`` (n_a, n_a) into the sensor's axes, invertible, or None for the identity (the default).

        Invertible: a sensor that reads fewer numbers is a channel with fewer axes, not a
        singular ``T``; so ranks, base parameters and null spaces are those of ``Phi``.
        """
        return None

    def nonzero(self, model) -> tuple[tuple[int, ...], ...]:
        """Per row of ``Phi`` (before ``T``) the columns that are not identically zero (default: all)."""
        return (tuple(range(10 * model.n_links)),) * self.n_axes(model)

    def phi_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity) -> (..., n_a, p)``: ``Phi`` in the model's frame (before ``T``), pure and
        jit-safe; the same object on every call. Default: stacked from :meth:`entries_function`."""
        return _rows_from_entries(self.entries_function(model), self.n_axes(model), 10 * model.n_links, None)

    def phi_theta_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity, theta) -> (..., n_a)``: ``Phi theta`` in the model's frame (before ``T``),
        jit-safe; ``theta`` (p,) or (..., p) broadcasting with the frames; the same object on every call.
        Default: :meth:`phi_function` contracted with ``theta``; a channel whose generated code
        contracts inside its loops (never forming ``Phi``, several times faster) overrides it."""
        return _predict_from_rows(self.phi_function(model))

    def jax_rows_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity) -> (..., n_a, p)``: ``T Phi``, pure and jit-safe (``T`` a constant in it)."""
        return transformed_rows(self.phi_function(model), _matrix_key(self.transform()))

    def jax_predict_function(self, model) -> Callable:
        """``f(q, qd, qdd, gravity, theta) -> (..., n_a)``: ``T Phi theta``, jit-safe (``T`` a constant in it)."""
        return transformed_predict(self.phi_theta_function(model), _matrix_key(self.transform()))

    # -- extension points: extra kept columns ---------------------------------------------------
    def extra_names(self, model) -> tuple[str, ...]:
        """Names of the channel's extra kept columns ``x`` (``"<joint>.fv"``, ...), reported after the
        links' parameters; unique within a set. Default: none."""
        return ()

    def extra_rows_function(self, model) -> Callable | None:
        """``f(q, qd, qdd) -> (..., n_a, n_e)``: ``E``, in the channel's own axes (the nuisance acts on
        the reading, so ``T`` does not apply), pure and jit-safe; None when there are no extra columns."""
        return None

    def casadi_extra_function(self, model):
        """``casadi.Function`` ``(q, qd, qdd) -> E`` (n_a x n_e), or None when there are no extra columns."""
        return None

    # -- eager evaluation (NumPy in, NumPy out) ------------------------------------------------
    def rows(self, model, q, qd, qdd) -> np.ndarray:
        """``T Phi(q, qd, qdd)`` (..., n_a, p) float64 NumPy, with the model's gravity; leading shapes broadcast."""
        n_a, p = self.n_axes(model), 10 * model.n_links
        return _evaluate(model, _jitted_rows(self.jax_rows_function(model)), (q, qd, qdd), (model.gravity,), (n_a, p))

    def rows_split(self, model, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
        """``(T Phi_u, T Phi_k)``: :meth:`rows` at the unknown and at the known links' columns."""
        rows = self.rows(model, q, qd, qdd)
        return rows[..., model.unknown_index], rows[..., model.known_index]

    def predict(self, model, q, qd, qdd, theta) -> np.ndarray:
        """``T Phi theta`` (..., n_a) float64 NumPy: what the sensor reads without noise, offsets and extras.

        ``theta`` (p,) or (..., p) broadcasting with the frames.
        """
        theta = np.asarray(theta, dtype=np.float64)
        n_a = self.n_axes(model)
        fn = _jitted_predict(self.jax_predict_function(model))
        if theta.ndim <= 1:
            return _evaluate(model, fn, (q, qd, qdd), (model.gravity, theta), (n_a,))
        return _evaluate(model, _per_frame_theta(fn), (q, qd, qdd, theta), (model.gravity,), (n_a,))

    def extra_rows(self, model, q, qd, qdd) -> np.ndarray:
        """``E(q, qd, qdd)`` (..., n_a, n_e) float64 NumPy; n_e = 0 without extra columns."""
        n_e = len(self.extra_names(model))
        fn = self.extra_rows_function(model)
        if fn is None or n_e == 0:
            batch = _batch_shape(model, (q, qd, qdd))
            return np.zeros(batch + (self.n_axes(model), 0))
        return _evaluate(model, _jitted_extra(fn), (q, qd, qdd), (), (self.n_axes(model), n_e))

    # -- nuisances, structure, records ---------------------------------------------------------
    def with_offsets(self, offsets: bool) -> Channel:
        """The same channel with or without identified constant offsets."""
        return replace(self, offsets=bool(offsets))

    def offset_names(self, model) -> tuple[str, ...]:
        """``"<key>.<axis>.offset"`` per axis with offsets identified, else none."""
        return tuple(f"{self.key}.{a}.offset" for a in self.axes(model)) if self.offsets else ()

    def structure(self, model) -> ChannelStructure:
        """What a compiled kernel of this channel depends on (hashable). ``T``'s values are not in it:
        kernels take them as arguments, so a new sensor pose does not recompile."""
        return ChannelStructure(
            self.entries_function(model),
            self.phi_theta_function(model),
            self.n_axes(model),
            self.transform() is not None,
            self.extra_rows_function(model),
            len(self.extra_names(model)),
        )

    def to_dict(self) -> dict:
        """The JSON-able record: ``kind``, ``key``, ``offsets``, :attr:`RECORD_FIELDS` (:func:`channel_from_dict`)."""
        return {"kind": self.kind, "key": self.key, "offsets": self.offsets, **self._record()}

    def _record(self) -> dict:
        """The JSON-able values of :attr:`RECORD_FIELDS`."""
        return {name: getattr(self, name) for name in self.RECORD_FIELDS}

    @classmethod
    def _parse_record(cls, d: Mapping, where: str) -> dict:
        """Constructor arguments from the :attr:`RECORD_FIELDS` present in ``d`` (raise :class:`DatasetError`)."""
        return {name: d[name] for name in cls.RECORD_FIELDS if name in d}

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "channel") -> Channel:
        """Inverse of :meth:`to_dict`.

        Raises:
            DatasetError: another kind, a missing key, a field this ineid does not know, or a
                malformed value (one line naming ``where``).
        """
        if not isinstance(d, Mapping) or d.get("kind") != cls.kind:
            raise DatasetError(f"{where}: expected a {cls.kind!r} channel record, got {d!r}")
        unknown = sorted(set(d) - {"kind", "key", "offsets", *cls.RECORD_FIELDS})
        if unknown:
            raise DatasetError(
                f"{where}: the {cls.kind} channel has fields this ineid does not know "
                f"({', '.join(map(str, unknown))}); a newer ineid wrote it: upgrade ineid"
            )
        if "key" not in d:
            raise DatasetError(f"{where}: the {cls.kind} channel record has no key (the name of its values)")
        kwargs = {"key": check_key(d["key"], where), **cls._parse_record(d, where)}
        offsets = d.get("offsets", False)
        if not isinstance(offsets, bool):
            raise DatasetError(f"{where}: the {cls.kind} channel's offsets must be true or false, got {offsets!r}")
        return cls(offsets=offsets, **kwargs)

    def key_tuple(self) -> tuple:
        """A hashable summary of the record (keys caches that hold this channel's rows)."""
        return _freeze(self.to_dict())


# -- helpers: functions built once per (function, transform), so they can key jit caches -----------------


def _freeze(x):
    if isinstance(x, Mapping):
        return tuple(sorted((k, _freeze(v)) for k, v in x.items()))
    if isinstance(x, (list, tuple)):
        return tuple(_freeze(v) for v in x)
    return x


def _matrix_key(t: np.ndarray | None) -> tuple | None:
    """A matrix as nested tuples (hashable, exact), or None."""
    return None if t is None else tuple(map(tuple, np.asarray(t, dtype=np.float64).tolist()))


@functools.cache
def _rows_from_entries(entries_fn: Callable, n_axes: int, n_cols: int, transform: tuple | None) -> Callable:
    import jax.numpy as jnp

    def rows(q, qd, qdd, gravity):
        values = entries_fn(q, qd, qdd, gravity)
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        phi = jnp.stack([jnp.broadcast_to(v, batch).astype(q.dtype) for v in values], -1)
        phi = phi.reshape(batch + (n_axes, n_cols))
        return phi if transform is None else jnp.asarray(transform, dtype=phi.dtype) @ phi

    return rows


@functools.cache
def _predict_from_rows(rows_fn: Callable) -> Callable:
    def predict(q, qd, qdd, gravity, theta):
        return (rows_fn(q, qd, qdd, gravity) @ theta[..., None])[..., 0]

    return predict


@functools.cache
def transformed_predict(predict_fn: Callable, transform: tuple | None) -> Callable:
    """``f(...) @ T^T``: a prediction in the model's frame turned into the sensor's axes (``T`` as nested tuples)."""
    if transform is None:
        return predict_fn

    def predict(q, qd, qdd, gravity, theta):
        import jax.numpy as jnp

        w = predict_fn(q, qd, qdd, gravity, theta)
        return w @ jnp.asarray(transform, dtype=w.dtype).T

    return predict


@functools.cache
def transformed_rows(rows_fn: Callable, transform: tuple | None) -> Callable:
    """``T @ f(...)``: rows in the model's frame turned into the sensor's axes (``T`` as nested tuples)."""
    if transform is None:
        return rows_fn

    def rows(q, qd, qdd, gravity):
        import jax.numpy as jnp

        phi = rows_fn(q, qd, qdd, gravity)
        return jnp.asarray(transform, dtype=phi.dtype) @ phi

    return rows


@functools.cache
def _jitted_rows(fn: Callable) -> Callable:
    """``(q, qd, qdd, gravity) -> (N, n_a * p)`` jitted (the chunked evaluator's row layout)."""
    import jax

    return jax.jit(lambda q, qd, qdd, gravity: fn(q, qd, qdd, gravity).reshape(q.shape[0], -1))


@functools.cache
def _jitted_predict(fn: Callable) -> Callable:
    import jax

    return jax.jit(fn)


@functools.cache
def _per_frame_theta(fn: Callable) -> Callable:
    """``(q, qd, qdd, theta, gravity) -> fn(q, qd, qdd, gravity, theta)``: theta one row per frame."""
    import jax

    return jax.jit(lambda q, qd, qdd, theta, gravity: fn(q, qd, qdd, gravity, theta))


@functools.cache
def _jitted_extra(fn: Callable) -> Callable:
    import jax

    return jax.jit(lambda q, qd, qdd: fn(q, qd, qdd).reshape(q.shape[0], -1))


def _batch_shape(model, arrays) -> tuple[int, ...]:
    shapes = []
    for label, x in zip(("q", "qd", "qdd", "theta"), arrays, strict=False):
        x = np.asarray(x, dtype=np.float64)
        width = 10 * model.n_links if label == "theta" else model.n_dof
        if x.ndim == 0 or x.shape[-1] != width:
            raise ValueError(f"{label} must have shape (..., {width}), got {tuple(x.shape)}")
        shapes.append(x.shape[:-1])
    try:
        return tuple(np.broadcast_shapes(*shapes))
    except ValueError:
        raise ValueError(f"q, qd, qdd must broadcast to one leading shape, got {shapes}") from None


def _evaluate(model, kernel: Callable, per_frame: tuple, consts: tuple, shape: tuple[int, ...]) -> np.ndarray:
    """``kernel(*per_frame_rows, *consts)`` over chunks of frames (the robot model's chunked evaluator),
    reshaped to the broadcast batch shape + ``shape``."""
    from ineid.robots.chunked import run_chunked  # one chunked evaluator for every kernel

    batch = _batch_shape(model, per_frame)
    n = int(np.prod(batch, dtype=np.int64))
    flat = [
        np.broadcast_to(np.asarray(x, dtype=np.float64), batch + np.shape(x)[-1:]).reshape(n, np.shape(x)[-1])
        for x in per_frame
    ]
    width = int(np.prod(shape, dtype=np.int64))
    out = np.empty((n, width))

    def write(start, stop, rows):
        out[start:stop] = np.asarray(rows).reshape(-1, width)[: stop - start]

    consts = tuple(np.asarray(c, dtype=np.float64) for c in consts)
    run_chunked(kernel, flat, consts, write)
    return out.reshape(batch + tuple(shape))
