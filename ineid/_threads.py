"""Blocks of work shared among threads, the calling thread among them, stopped together on any error."""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor


def run_blocks(work: Callable[[Sequence], None], blocks: Sequence[Sequence], stop_event: threading.Event) -> None:
    """``work(block)`` for every block: the first on the calling thread, the others on a pool of their own.

    ``work`` should return early once ``stop_event`` is set: it is set when any block raises (Ctrl-C, SIGTERM,
    an error), so that the other threads stop at their next step, and the exception propagates.
    """
    if len(blocks) <= 1:
        for block in blocks:
            work(block)
        return
    with ThreadPoolExecutor(max_workers=len(blocks) - 1) as pool:
        jobs = [pool.submit(work, block) for block in blocks[1:]]
        try:
            work(blocks[0])
            for job in jobs:
                job.result()
        except BaseException:
            stop_event.set()
            raise
