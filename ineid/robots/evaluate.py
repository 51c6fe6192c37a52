"""The two shapes of every public evaluator of :class:`ineid.robots.model.RobotModel`, written once.

- :func:`evaluate_rows`: regressor entries (a jitted entries kernel, frames last) written into
  one or more results, e.g. ``Psi`` whole, or its unknown and known links' columns;
- :func:`evaluate_contracted`: a wrench or torques for parameters ``theta`` (one set, or one
  per frame), never forming the regressor.

Each takes NumPy or JAX states and answers in kind (:mod:`ineid.robots.device`): NumPy through
the chunked host path (:func:`ineid.robots.chunked.run_chunked`), a ``jax.Array`` on the states'
device, or a traced value inside a caller's ``jax.jit``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from ineid.robots.chunked import entries_kernel, host_array, run_chunked, theta_kernel
from ineid.robots.device import (
    as_device_array,
    check_states,
    device_flat,
    empty_on_device,
    host_output,
    host_views,
    placement,
    run_on_device,
)

_LABELS = ("q", "qd", "qdd")


class RowsOut(NamedTuple):
    """One result of :func:`evaluate_rows`: its per-frame ``shape``, the kernel ``rows`` it takes,
    and ``dest``, the flat (row-major) index in a frame's result of each of those rows."""

    shape: tuple[int, ...]
    rows: slice
    dest: np.ndarray


def _host_states(states: Sequence, n_dof: int, theta=None):
    """The NumPy path's states (and per-frame theta): float64, checked, flattened to (N, .)."""
    arrays = [host_array(label, x) for label, x in zip(_LABELS, states, strict=True)]
    batch = check_states(arrays, n_dof, theta)
    return host_views(arrays + ([] if theta is None else [theta]), batch), batch


def evaluate_rows(model, entries_fn: Callable, order: np.ndarray, outs: Sequence[RowsOut], device_fn: Callable, states):
    """The results ``outs`` of the regressor entries ``order`` (flat indices ``entries_fn`` returns) at ``states``.

    Args:
        model: the :class:`~ineid.robots.model.RobotModel` (``n_dof``, ``gravity``).
        entries_fn: ``(q, qd, qdd, gravity) -> entries``, row-major, numbers where structurally constant.
        order: the entries the kernel computes, in the order ``outs`` take their rows.
        device_fn: pure ``(q, qd, qdd, gravity) -> tuple`` of the results (batch shape first, each
            ``out.shape`` after), for JAX states (the structural zeros included).
        states: ``(q, qd, qdd)``, each (..., n_dof), NumPy or JAX; leading shapes broadcast.

    Returns:
        A tuple of results, each ``batch + out.shape``: float64 NumPy for NumPy states, else a
        ``jax.Array`` on the states' device (traced inside a caller's ``jax.jit``).
    """
    where = placement(states)
    if where.kind == "traced":
        check_states(states, model.n_dof)
        return tuple(device_fn(*states, model.gravity))
    if where.kind == "device" and not where.in_place:
        batch = check_states(states, model.n_dof)
        return _on_device(device_fn, states, (), batch, [o.shape for o in outs], model.gravity, where.device)
    if where.kind == "device":
        batch = check_states(states, model.n_dof)
        flat = host_views(states, batch)
    else:
        flat, batch = _host_states(states, model.n_dof)
    n = len(flat[0])
    on_device = where.kind == "device"
    buffers = [host_output((n, int(np.prod(o.shape))), True, on_device) for o in outs]

    def write(start, stop, rows):
        for buffer, out in zip(buffers, outs, strict=True):
            buffer[start:stop, out.dest] = rows[out.rows, : stop - start].T

    if len(order) and n:
        run_chunked(entries_kernel(entries_fn, order), flat, (model.gravity,), write, where.device)
    results = [b.reshape(batch + o.shape) for b, o in zip(buffers, outs, strict=True)]
    return tuple(as_device_array(r, where.device) for r in results) if on_device else tuple(results)


def evaluate_contracted(model, fn: Callable, width: int, states, theta):
    """``fn(q, qd, qdd, gravity, theta)`` (..., width) at ``states`` for ``theta`` (default the CAD
    parameters): (10 n_links,) for every frame or (..., 10 n_links) broadcasting with the states.

    NumPy states give float64 NumPy; JAX states a ``jax.Array`` on their device (``theta`` moved
    there), or a traced value inside a caller's ``jax.jit``.

    Raises:
        ValueError: ``theta`` or a state of the wrong width, or shapes that do not broadcast.
    """
    where = placement(states)
    n_par = 10 * model.n_links
    if theta is None:
        theta = model.theta_cad
    if where.kind == "numpy":
        theta = host_array("theta", theta)
    shape = tuple(np.shape(theta))
    if not shape or shape[-1] != n_par:
        raise ValueError(f"theta must have shape (..., {n_par}), got {shape}")
    per_frame = len(shape) > 1
    if where.kind == "traced":
        check_states(states, model.n_dof, theta if per_frame else None)
        return fn(*states, model.gravity, theta)
    if where.kind == "device" and not where.in_place:
        batch = check_states(states, model.n_dof, theta if per_frame else None)
        if per_frame:
            return _on_device(_tupled(fn), (*states, theta), (), batch, [(width,)], model.gravity, where.device)[0]
        return _on_device(_tupled(fn), states, (theta,), batch, [(width,)], model.gravity, where.device)[0]
    if where.kind == "device":
        batch = check_states(states, model.n_dof, theta if per_frame else None)
        flat = host_views([*states, theta] if per_frame else states, batch)
        theta = np.asarray(theta, dtype=np.float64)
    else:
        flat, batch = _host_states(states, model.n_dof, theta if per_frame else None)
    consts = (model.gravity,) if per_frame else (theta, model.gravity)
    out = host_output((len(flat[0]), width), False, where.kind == "device")

    def write(start, stop, rows):
        out[start:stop] = rows[: stop - start]

    run_chunked(theta_kernel(fn), flat, consts, write, where.device)
    out = out.reshape(batch + (width,))
    return as_device_array(out, where.device) if where.kind == "device" else out


def _on_device(fn, per_frame, consts, batch, shapes, gravity, device) -> tuple:
    """``fn`` over the broadcast, flattened ``per_frame`` arrays on ``device``; results reshaped to ``batch``."""
    import jax
    import jax.numpy as jnp

    n = int(np.prod(batch, dtype=np.int64))
    if n == 0:
        return empty_on_device([batch + tuple(s) for s in shapes], device)
    flat = device_flat(per_frame, batch, device)
    consts = tuple(jax.device_put(jnp.asarray(c, dtype=jnp.float64), device) for c in (*consts, gravity))
    results = run_on_device(fn, flat, consts)
    return tuple(r.reshape(batch + tuple(s)) for r, s in zip(results, shapes, strict=True))


@functools.cache
def _tupled(fn):
    """``(q, qd, qdd, theta, gravity) -> (fn(q, qd, qdd, gravity, theta),)``, one object per ``fn`` (it keys
    the compiled kernel); ``theta`` per frame or a constant."""
    return lambda q, qd, qdd, theta, gravity: (fn(q, qd, qdd, gravity, theta),)


@functools.cache
def tupled_rows(fn):
    """``(q, qd, qdd, gravity) -> (fn(q, qd, qdd, gravity),)``: a pure regressor as the one-result
    ``device_fn`` of :func:`evaluate_rows` (one object per ``fn``: it keys the compiled kernel)."""
    return lambda q, qd, qdd, gravity: (fn(q, qd, qdd, gravity),)


@functools.cache
def split_columns(fn, groups: tuple[tuple[int, ...], ...]):
    """``(q, qd, qdd, gravity) -> tuple``: the columns ``groups`` of the pure regressor ``fn``, one result each."""
    import jax.numpy as jnp

    def split(q, qd, qdd, gravity):
        y = fn(q, qd, qdd, gravity)
        return tuple(y[..., jnp.asarray(g, dtype=jnp.int32)] for g in groups)

    return split
