"""Eager evaluation of a robot's jitted kernels over chunks of frames, NumPy in and NumPy out.

Every public evaluator of :class:`ineid.robots.model.RobotModel` (the base-wrench and
joint-torque regressors, the wrenches and torques, the cut wrench at a link) and of the
measurement channels runs here: the frames are flattened, cut into chunks of
:data:`CHUNK_FRAMES` (a second, small compiled shape of :data:`SMALL_FRAMES` serves short
calls and remainders), each chunk padded to its compiled size and dispatched before the
previous result is copied out, so XLA computes while NumPy copies and memory beyond the
result stays about one chunk's.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from ineid.cache import enable_compilation_cache

CHUNK_FRAMES = 2048
"""Frames per compiled call of the public evaluators. XLA:CPU keeps a chunk's temporaries
in cache up to a few thousand frames; throughput falls beyond (benchmarks/regressor.py)."""
SMALL_JOB_FRAMES = 10_000
"""Jobs of at most this many frames that a compiled kernel would serve once (a small dataset's
generation, its solver's refits and residuals) evaluate through CasADi instead: its virtual
machine needs no compilation and takes about 10 us a frame for a 7-joint arm, where XLA
compiles each kernel for seconds (3 s of CPU for a 7-joint arm, ``benchmarks/compile.py``)
before its first call."""
SMALL_FRAMES = 64
"""Calls of at most this many frames, and remainders this short, use a second, small
compiled shape instead of a padded full chunk."""


def host_array(label: str, x) -> np.ndarray:
    """``x`` as a float64 NumPy array (a JAX array is copied from its device if needed).

    Raises:
        TypeError: ``x`` is a tracer (called inside ``jax.jit``, ``grad`` or ``vmap``), naming the pure functions
        to use.
    """
    try:
        return np.asarray(x, dtype=np.float64)
    except TypeError as e:  # a tracer: called inside jax.jit / grad / vmap
        raise TypeError(
            f"{label} is a traced JAX value: the RobotModel evaluators (regressor, regressor_split, base_wrench, "
            "joint_torque_regressor, joint_torques, link_wrench_regressor) evaluate eagerly into NumPy; inside "
            "jax.jit, grad or vmap use model.jax_regressor, model.jax_base_wrench, model.jax_joint_torque_regressor "
            "or model.jax_joint_torques with model.gravity"
        ) from e


def nonzero_flat(nonzero: tuple[tuple[int, ...], ...], n_cols: int) -> np.ndarray:
    """Flat (row-major) indices of the structurally nonzero entries of a regressor with ``n_cols`` columns."""
    return np.array([r * n_cols + c for r, cols in enumerate(nonzero) for c in cols], dtype=np.int64)


@functools.cache
def _entries_kernel_cached(entries_fn: Callable, entries: tuple[int, ...]):
    import jax
    import jax.numpy as jnp

    def kernel(q, qd, qdd, gravity):
        values = entries_fn(q, qd, qdd, gravity)
        batch = q.shape[:-1]
        return jnp.stack([jnp.broadcast_to(values[i], batch).astype(q.dtype) for i in entries], axis=0)

    return jax.jit(kernel)


def entries_kernel(entries_fn: Callable, entries: np.ndarray):
    """Jitted ``(q, qd, qdd, gravity) -> (len(entries), N)``: chosen entries of a flat regressor
    (``entries_fn(q, qd, qdd, gravity)`` returns them all, row-major), frames last (XLA:CPU's
    fastest layout: each entry one contiguous row). One compilation per entries function (one
    per generated module and regressor) and choice of entries, shared by every model of the robot."""
    return _entries_kernel_cached(entries_fn, tuple(int(i) for i in entries))


@functools.cache
def theta_kernel(fn: Callable):
    """Jitted ``(q, qd, qdd, theta, gravity) -> fn(q, qd, qdd, gravity, theta)``: theta (N, p) per
    frame or (p,) for all (a composed wrench or torque that never forms the regressor)."""
    import jax

    def kernel(q, qd, qdd, theta, gravity):
        return fn(q, qd, qdd, gravity, theta)

    return jax.jit(kernel)


def chunks(n: int):
    """``(start, stop, compiled size)`` covering frames ``[0, n)``."""
    if n <= SMALL_FRAMES:
        if n:
            yield 0, n, SMALL_FRAMES
        return
    for start in range(0, n, CHUNK_FRAMES):
        stop = min(start + CHUNK_FRAMES, n)
        yield start, stop, CHUNK_FRAMES if stop - start > SMALL_FRAMES else SMALL_FRAMES


def run_chunked(kernel, batched: list[np.ndarray], consts: tuple, write) -> None:
    """``write(start, stop, kernel(*chunk_of(batched), *consts))`` over frame chunks.

    Each chunk is padded with zeros to its compiled size; the next chunk is dispatched
    before the previous result is written, so XLA computes while NumPy copies.
    """
    enable_compilation_cache()
    pending = None
    for start, stop, size in chunks(len(batched[0])):
        args = []
        for a in batched:
            part = a[start:stop]
            if stop - start < size:
                part = np.concatenate([part, np.zeros((size - (stop - start),) + a.shape[1:])])
            args.append(part)
        result = kernel(*args, *consts)
        if pending is not None:
            write(pending[0], pending[1], np.asarray(pending[2]))
        pending = (start, stop, result)
    if pending is not None:
        write(pending[0], pending[1], np.asarray(pending[2]))
