"""A compiled kernel run over a batch in chunks of configurations and frames, on a few threads.

The fused kernels (:mod:`ineid.identify.fused`) are compiled for one shape: :func:`map_chunks` pads the
configurations to a fixed count and splits long recordings into frame chunks (masked), sums the
kernel's outputs over the frame chunks and concatenates them over the configurations, dispatching the
chunks from a few threads (the shape and the threads are the caller's choice).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ineid.cache import enable_compilation_cache


def map_chunks(
    kernel: Callable,
    frame_arrays: list[np.ndarray],
    config_arrays: list[np.ndarray],
    consts: tuple,
    shape: tuple[int, int],
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> list[np.ndarray]:
    """Sum ``kernel(*frame_chunks, mask, *config_chunks, *consts)`` over frame chunks, per configuration chunk.

    ``frame_arrays`` are (C, F, .) and ``config_arrays`` (C, .); each call gets (Cc, Fc, .)
    and (Cc, .) zero-padded pieces, ``shape = (Cc, Fc)``, and the (Cc, Fc) mask of real frames. The kernel
    returns a tuple of (Cc, ...) arrays, summed over frame chunks and concatenated over
    configurations. The configurations are split among ``workers`` threads (the calling one among them);
    each dispatches its calls one ahead so XLA computes while NumPy collects.
    """
    enable_compilation_cache()  # JAX is imported by now: registers the cache-hit log too
    n_configs, n_frames = frame_arrays[0].shape[:2]
    per, frames = shape
    starts = list(range(0, n_configs, per))
    n_workers = max(1, min(workers, len(starts)))
    results: list = [None] * len(starts)
    done = [0]
    lock = threading.Lock()
    stop_event = threading.Event()

    def pad(piece, shape):
        if piece.shape[: len(shape)] == shape:
            return piece
        out = np.zeros(shape + piece.shape[len(shape) :])
        out[tuple(slice(0, k) for k in piece.shape[: len(shape)])] = piece
        return out

    def collect(k, outs):
        start = starts[k]
        stop = min(start + per, n_configs)
        results[k] = [np.asarray(o)[: stop - start] for o in outs]
        if progress is not None:
            with lock:
                done[0] += stop - start
                progress(done[0], n_configs)

    def work(chunk_ids):
        pending = []
        for k in chunk_ids:
            if stop_event.is_set():
                return
            start = starts[k]
            stop = min(start + per, n_configs)
            per_config = [pad(a[start:stop], (per,)) for a in config_arrays]
            total = None
            for f0 in range(0, n_frames, frames):
                f1 = min(f0 + frames, n_frames)
                parts = [pad(a[start:stop, f0:f1], (per, frames)) for a in frame_arrays]
                mask = np.zeros((per, frames))
                mask[: stop - start, : f1 - f0] = 1.0
                outs = kernel(*parts, mask, *per_config, *consts)
                total = outs if total is None else tuple(t + o for t, o in zip(total, outs, strict=True))
            pending.append((k, total))
            if len(pending) > 1:
                collect(*pending.pop(0))
        for item in pending:
            collect(*item)

    # contiguous blocks of chunks per thread; the main thread works too
    blocks = [list(b) for b in np.array_split(np.arange(len(starts)), n_workers)]
    if n_workers == 1:
        work(blocks[0])
    else:
        with ThreadPoolExecutor(max_workers=n_workers - 1) as pool:
            jobs = [pool.submit(work, b) for b in blocks[1:]]
            try:
                work(blocks[0])
                for job in jobs:
                    job.result()
            except BaseException:  # Ctrl-C, SIGTERM, an error: the other threads stop at their next chunk
                stop_event.set()
                raise
    return [np.concatenate([r[i] for r in results]) for i in range(len(results[0]))]
