"""The public evaluators on JAX arrays: the result stays on the device the states live on.

:class:`ineid.robots.model.RobotModel`'s evaluators (``regressor``, ``regressor_split``,
``base_wrench``, ``joint_torque_regressor``, ``joint_torques``, ``link_wrench_regressor``,
``link_wrench``) look at the states they are given (:func:`placement`):

- NumPy (or lists, or any mix with NumPy): NumPy out, streamed over chunks by
  :func:`ineid.robots.chunked.run_chunked` on JAX's default device, as always;
- ``q``, ``qd`` and ``qdd`` all JAX arrays on one device: a ``jax.Array`` out, committed to that
  device, without a round trip through the host. On an accelerator (:func:`run_on_device`) the
  frames go through the pure kernels in pieces of up to
  :data:`~ineid.robots.chunked.DEVICE_CHUNK_FRAMES` that never leave it; on a CPU device, whose
  memory is the host's, the NumPy path reads the arrays in place and its result becomes the
  ``jax.Array`` without a copy (:func:`host_output`, :func:`as_device_array`);
- traced values (inside a caller's ``jax.jit``, ``grad`` or ``vmap``): the pure function,
  traced into the caller's computation (no chunks: XLA sees the whole batch).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from ineid.robots import chunked
from ineid.robots.chunked import compiled_size

_ALIGN = 64
"""Bytes: a NumPy buffer this aligned becomes a CPU ``jax.Array`` without a copy."""
CPU_IN_PLACE = True
"""JAX arrays on a CPU device go through the NumPy path, read and answered in place (the
fastest there); False sends them through the accelerators' path instead (what the tests use
to run that path without an accelerator)."""


class Placement(NamedTuple):
    """Where an evaluation runs: ``kind`` ``"numpy"``, ``"traced"`` or ``"device"``, and the device
    (``"device"`` only)."""

    kind: str
    device: object = None

    @property
    def in_place(self) -> bool:
        """JAX arrays on a CPU device, evaluated by the NumPy path in place (see :data:`CPU_IN_PLACE`)."""
        return self.kind == "device" and self.device.platform == "cpu" and CPU_IN_PLACE


def _is_jax(x) -> bool:
    import jax

    return isinstance(x, jax.Array)


def _is_traced(x) -> bool:
    import jax

    return isinstance(x, jax.core.Tracer)


def placement(states: Sequence) -> Placement:
    """Where the evaluation of ``states`` (``q, qd, qdd``) runs (see the module docstring).

    Raises:
        ValueError: the states are JAX arrays on different devices, or one array spans several.
    """
    if not all(_is_jax(x) for x in states):
        return Placement("numpy")
    if any(_is_traced(x) for x in states):
        return Placement("traced")
    devices = set()
    for x in states:
        devices |= set(x.devices())
    if len(devices) != 1:
        names = ", ".join(sorted(str(d) for d in devices))
        raise ValueError(f"q, qd and qdd must live on one device to be evaluated there, got {names}")
    return Placement("device", devices.pop())


def check_states(states: Sequence, n_dof: int, theta=None) -> tuple[int, ...]:
    """The broadcast batch shape of ``q, qd, qdd`` (each (..., n_dof)) and ``theta`` when per frame,
    checked on their shapes alone (NumPy or JAX, nothing copied).

    Raises:
        ValueError: a state of the wrong width, or shapes that do not broadcast.
    """
    shapes = []
    for label, x in zip(("q", "qd", "qdd"), states, strict=True):
        shape = tuple(np.shape(x))
        if not shape or shape[-1] != n_dof:
            raise ValueError(f"{label} must have shape (..., {n_dof}), got {shape}")
        shapes.append(shape)
    if theta is not None:
        shapes.append(tuple(np.shape(theta)))
    try:
        return tuple(np.broadcast_shapes(*(s[:-1] for s in shapes)))
    except ValueError:
        names = "q, qd, qdd" + (" and theta" if theta is not None else "")
        raise ValueError(f"{names} must broadcast to one leading shape, got {', '.join(map(str, shapes))}") from None


def device_flat(arrays: Sequence, batch: tuple[int, ...], device) -> list:
    """Each array float64 on ``device``, broadcast to ``batch`` and flattened to (N, width) there."""
    import jax
    import jax.numpy as jnp

    n = int(np.prod(batch, dtype=np.int64))
    out = []
    for x in arrays:
        x = jax.device_put(jnp.asarray(x, dtype=jnp.float64), device)
        out.append(jnp.broadcast_to(x, batch + x.shape[-1:]).reshape(n, x.shape[-1]))
    return out


def host_views(arrays: Sequence, batch: tuple[int, ...]) -> list[np.ndarray]:
    """Each array as float64 NumPy (a CPU ``jax.Array`` read in place), broadcast to ``batch``, (N, width)."""
    n = int(np.prod(batch, dtype=np.int64))
    out = []
    for x in arrays:
        x = np.asarray(x, dtype=np.float64)
        out.append(np.broadcast_to(x, batch + x.shape[-1:]).reshape(n, x.shape[-1]))
    return out


def host_output(shape: tuple[int, ...], zeros: bool, device_result: bool) -> np.ndarray:
    """A float64 NumPy buffer for a result; 64-byte aligned when it is to become a CPU ``jax.Array``
    (:func:`as_device_array` then takes it without a copy)."""
    if not device_result:
        return np.zeros(shape) if zeros else np.empty(shape)
    size = int(np.prod(shape, dtype=np.int64))
    raw = (np.zeros if zeros else np.empty)(size + _ALIGN // 8)
    offset = (-raw.ctypes.data % _ALIGN) // 8
    return raw[offset : offset + size].reshape(shape)


def as_device_array(x: np.ndarray, device):
    """A finished NumPy result as a ``jax.Array`` committed to the CPU ``device`` (aliased, not
    copied, when aligned: the buffer is never written again)."""
    import jax

    return jax.device_put(x, device)


@functools.cache
def _jitted(fn: Callable):
    import jax

    return jax.jit(fn)


@functools.cache
def _window(count: int, size: int):
    """Jitted ``(x, start) -> x[start : start + count]`` zero-padded to ``size`` frames."""
    import jax
    import jax.numpy as jnp

    def window(x, start):
        part = jax.lax.dynamic_slice_in_dim(x, start, count)
        return part if count == size else jnp.pad(part, ((0, size - count),) + ((0, 0),) * (x.ndim - 1))

    return jax.jit(window)


def run_on_device(fn: Callable, per_frame: Sequence, consts: tuple) -> tuple:
    """``fn(*per_frame, *consts)`` over the frames of ``per_frame`` ((N, .) arrays on one device),
    in pieces of up to :data:`~ineid.robots.chunked.DEVICE_CHUNK_FRAMES` frames, each zero-padded to a compiled size
    (:func:`~ineid.robots.chunked.compiled_size`), that never leave the device.

    ``fn`` returns a tuple of arrays with a leading frame axis; so does this, with N frames,
    on the same device.
    """
    import jax
    import jax.numpy as jnp

    from ineid.cache import enable_compilation_cache

    enable_compilation_cache()
    kernel = _jitted(fn)
    n = per_frame[0].shape[0]
    step = chunked.DEVICE_CHUNK_FRAMES
    parts = []
    for start in range(0, n, step):
        count = min(step, n - start)
        size = compiled_size(count, step)
        if start == 0 and count == n == size:
            args = list(per_frame)
        else:
            first = jax.device_put(np.int32(start), per_frame[0].devices().pop())
            args = [_window(count, size)(x, first) for x in per_frame]
        out = kernel(*args, *consts)
        parts.append([y if count == size else jax.lax.slice_in_dim(y, 0, count) for y in out])
    if len(parts) == 1:
        return tuple(parts[0])
    return tuple(jnp.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))


def empty_on_device(shapes: Sequence[tuple[int, ...]], device) -> tuple:
    """Zero-frame results (each of ``shapes``) committed to ``device``."""
    import jax
    import jax.numpy as jnp

    return tuple(jax.device_put(jnp.zeros(s), device) for s in shapes)
