"""Eager evaluation of a robot's jitted kernels over chunks of frames, NumPy in and NumPy out.

Every public evaluator of :class:`ineid.robots.model.RobotModel` (the base-wrench and
joint-torque regressors, the wrenches and torques, the cut wrench at a link) and of the
measurement channels runs here when given NumPy arrays: the frames are flattened, cut into
chunks (:func:`chunk_frames`: :data:`CHUNK_FRAMES` on a CPU, :data:`DEVICE_CHUNK_FRAMES` on an
accelerator; a second, small compiled shape of :data:`SMALL_FRAMES` serves short calls and
remainders), each chunk padded to its compiled size. The chunks are shared among a few threads
(:func:`stream_workers`), each dispatching its next chunk before it copies the previous result
out, so XLA computes on every core while NumPy copies, and memory beyond the result stays
about one chunk's per thread. JAX arrays stay where they are (:mod:`ineid.robots.device`).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable

import numpy as np

from ineid._threads import run_blocks
from ineid.cache import enable_compilation_cache

CHUNK_FRAMES = 2048
"""Frames per compiled call of the public evaluators on a CPU. XLA:CPU keeps a chunk's temporaries
in cache up to a few thousand frames; throughput falls beyond (benchmarks/regressor.py)."""
DEVICE_CHUNK_FRAMES = 1 << 18
"""Frames per compiled call on an accelerator (a GPU keeps its cores busy only with many frames
per kernel; the regressor of a 7-joint arm on this many frames takes about 1 GB)."""
SMALL_JOB_FRAMES = 10_000
"""Jobs of at most this many frames that a compiled kernel would serve once (a small dataset's
generation, its solver's refits and residuals) evaluate through CasADi instead: its virtual
machine needs no compilation and takes about 10 us a frame for a 7-joint arm, where XLA
compiles each kernel for seconds (3 s of CPU for a 7-joint arm, ``benchmarks/compile.py``)
before its first call."""
SMALL_FRAMES = 64
"""Calls of at most this many frames, and remainders this short, use a second, small
compiled shape instead of a padded full chunk."""
MAX_STREAM_WORKERS = 16
"""Most threads one evaluation streams its chunks from (see :func:`stream_workers`)."""


def host_array(label: str, x) -> np.ndarray:
    """``x`` as a float64 NumPy array (a JAX array is copied from its device if needed).

    Raises:
        TypeError: ``x`` is a tracer (called inside ``jax.jit``, ``grad`` or ``vmap`` with some of the
        states not traced), naming what to do instead.
    """
    try:
        return np.asarray(x, dtype=np.float64)
    except TypeError as e:  # a tracer among NumPy arrays: called inside jax.jit / grad / vmap
        raise TypeError(
            f"{label} is a traced JAX value while other states are NumPy arrays: the RobotModel evaluators "
            "(regressor, regressor_split, base_wrench, joint_torque_regressor, joint_torques, "
            "link_wrench_regressor, link_wrench) trace into a caller's jax.jit, grad or vmap when q, qd and qdd "
            "are all JAX values; inside jax.jit, grad or vmap use model.jax_regressor, model.jax_base_wrench, "
            "model.jax_joint_torque_regressor or model.jax_joint_torques with model.gravity, or pass every state "
            "as a JAX array"
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


def _platform(device) -> str:
    import jax

    return device.platform if device is not None else jax.default_backend()


def chunk_frames(device=None) -> int:
    """Frames per compiled call on ``device`` (default: JAX's default device): :data:`CHUNK_FRAMES`
    on a CPU, :data:`DEVICE_CHUNK_FRAMES` on an accelerator."""
    return CHUNK_FRAMES if _platform(device) == "cpu" else DEVICE_CHUNK_FRAMES


def compiled_size(count: int, chunk: int = CHUNK_FRAMES) -> int:
    """The compiled size that serves ``count`` frames (at most ``chunk``): :data:`SMALL_FRAMES` for a
    short piece; for a CPU's chunk the chunk itself, for an accelerator's the next power of two
    (a few shapes, each compiled once, and never more than twice the work)."""
    if count <= SMALL_FRAMES:
        return SMALL_FRAMES
    if chunk <= CHUNK_FRAMES:
        return chunk
    return min(chunk, 1 << (count - 1).bit_length())


def chunks(n: int, chunk: int = CHUNK_FRAMES):
    """``(start, stop, compiled size)`` covering frames ``[0, n)`` in pieces of at most ``chunk``."""
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        yield start, stop, compiled_size(stop - start, chunk)


def stream_workers(n_chunks: int) -> int:
    """Threads for ``n_chunks`` chunks: one per core this process may use (XLA runs each call
    on one core), at most :data:`MAX_STREAM_WORKERS` and one per chunk; ``INEID_EVAL_THREADS``
    overrides the core count (1: no threads)."""
    try:
        cores = int(os.environ.get("INEID_EVAL_THREADS", "0")) or len(os.sched_getaffinity(0))
    except (ValueError, AttributeError):
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_STREAM_WORKERS, n_chunks))


def _piece(a: np.ndarray, start: int, stop: int, size: int) -> np.ndarray:
    part = a[start:stop]
    if stop - start == size:
        return part
    out = np.zeros((size,) + a.shape[1:])
    out[: stop - start] = part
    return out


def run_chunked(kernel, batched: list[np.ndarray], consts: tuple, write, device=None) -> None:
    """``write(start, stop, kernel(*chunk_of(batched), *consts))`` over frame chunks.

    Each chunk is padded with zeros to its compiled size (:func:`chunks`, sized for ``device``,
    default JAX's default device, where the kernel runs). The first chunk runs on the calling
    thread (it compiles the kernel); the rest are shared among :func:`stream_workers` threads in
    contiguous blocks, each dispatching its next chunk before it writes the previous result, so
    XLA computes while NumPy copies. ``write`` is called from several threads, for disjoint
    frame ranges, with NumPy rows. An error or Ctrl-C on any thread stops the others at their
    next chunk and is raised here.
    """
    enable_compilation_cache()
    import jax

    pieces = list(chunks(len(batched[0]), chunk_frames(device)))
    consts = tuple(jax.device_put(c, device) for c in consts)  # once, not with every chunk
    stop_event = threading.Event()

    def dispatch(start, stop, size):
        args = [_piece(a, start, stop, size) for a in batched]
        if device is not None:
            args = [jax.device_put(x, device) for x in args]
        return kernel(*args, *consts)

    def work(block):
        pending = None
        for start, stop, size in block:
            if stop_event.is_set():
                return
            result = dispatch(start, stop, size)
            if pending is not None:
                write(pending[0], pending[1], np.asarray(pending[2]))
            pending = (start, stop, result)
        if pending is not None:
            write(pending[0], pending[1], np.asarray(pending[2]))

    if not pieces:
        return
    work(pieces[:1])
    rest = pieces[1:]
    n_workers = stream_workers(len(rest))
    if n_workers <= 1:
        work(rest)
        return
    blocks = [[rest[i] for i in b] for b in np.array_split(np.arange(len(rest)), n_workers)]
    run_blocks(work, blocks, stop_event)  # an error or a signal: the other threads stop at their next chunk
