"""A compiled kernel run over a batch in chunks of configurations and frames, on a few threads.

The fused kernels (:mod:`ineid.identify.fused`) are compiled for one shape: :func:`map_chunks` pads the
configurations to a fixed count and splits long recordings into frame chunks (masked), sums the
kernel's outputs over the frame chunks and concatenates them over the configurations, dispatching the
chunks from a few threads (the shape and the threads are the caller's choice).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from ineid._threads import run_blocks
from ineid.cache import enable_compilation_cache


def map_chunks(
    kernel: Callable,
    frame_arrays: list[np.ndarray],
    config_arrays: list[np.ndarray],
    consts: tuple,
    shape: tuple[int, int],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    combine: Callable[[list[tuple]], tuple] | None = None,
) -> list[np.ndarray]:
    """Sum ``kernel(*frame_chunks, mask, *config_chunks, *consts)`` over frame chunks, per configuration chunk.

    ``frame_arrays`` are (C, F, .) and ``config_arrays`` (C, .); each call gets (Cc, Fc, .)
    and (Cc, .) zero-padded pieces, ``shape = (Cc, Fc)``, and the (Cc, Fc) mask of real frames. The kernel
    returns a tuple of (Cc, ...) arrays, summed over frame chunks (or merged by ``combine(outs)``,
    the outputs of every frame chunk as NumPy arrays) and concatenated over configurations. The calls
    (every configuration chunk's frame chunks: a long recording's too) are split among ``workers`` threads
    (the calling one among them); each dispatches its calls one ahead so XLA computes while NumPy collects.
    """
    enable_compilation_cache()  # JAX is imported by now: registers the cache-hit log too
    n_configs, n_frames = frame_arrays[0].shape[:2]
    per, frames = shape
    starts = list(range(0, n_configs, per))
    frame_starts = range(0, max(n_frames, 1), frames)
    calls = [(k, f0) for k in range(len(starts)) for f0 in frame_starts]  # configuration chunk k's calls in a row
    outputs: list = [None] * len(calls)
    left = [len(frame_starts)] * len(starts)  # calls of each configuration chunk not yet collected
    done = [0]
    lock = threading.Lock()
    stop_event = threading.Event()

    def pad(piece, shape):
        if piece.shape[: len(shape)] == shape:
            return piece
        out = np.zeros(shape + piece.shape[len(shape) :])
        out[tuple(slice(0, k) for k in piece.shape[: len(shape)])] = piece
        return out

    def collect(i, outs):
        outputs[i] = tuple(np.asarray(o) for o in outs)
        k = calls[i][0]
        with lock:
            left[k] -= 1
            if left[k] == 0 and progress is not None:
                done[0] += min(starts[k] + per, n_configs) - starts[k]
                progress(done[0], n_configs)

    def work(call_ids):
        pending = None
        for i in call_ids:
            if stop_event.is_set():
                return
            k, f0 = calls[i]
            start, stop = starts[k], min(starts[k] + per, n_configs)
            f1 = min(f0 + frames, n_frames)
            parts = [pad(a[start:stop, f0:f1], (per, frames)) for a in frame_arrays]
            mask = np.zeros((per, frames))
            mask[: stop - start, : f1 - f0] = 1.0
            outs = kernel(*parts, mask, *(pad(a[start:stop], (per,)) for a in config_arrays), *consts)
            if pending is not None:
                collect(*pending)
            pending = (i, outs)
        if pending is not None:
            collect(*pending)

    # contiguous blocks of calls per thread; the main thread works too
    n_workers = max(1, min(workers, len(calls)))
    blocks = [list(b) for b in np.array_split(np.arange(len(calls)), n_workers)]
    run_blocks(work, blocks, stop_event)  # an error or a signal: the other threads stop at their next chunk
    results = []
    for k, start in enumerate(starts):
        parts = outputs[k * len(frame_starts) : (k + 1) * len(frame_starts)]
        if combine is not None:
            merged = combine(parts)
        elif len(parts) == 1:  # one frame chunk: nothing to add (no copy)
            merged = parts[0]
        else:
            merged = tuple(sum(p[m] for p in parts) for m in range(len(parts[0])))
        results.append([o[: min(start + per, n_configs) - start] for o in merged])
    return [np.concatenate([r[i] for r in results]) for i in range(len(results[0]))]
