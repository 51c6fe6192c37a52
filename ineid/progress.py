"""The progress callbacks long-running library functions accept (the CLI passes a progress bar)."""

from __future__ import annotations

from collections.abc import Callable

Progress = Callable[[int, int], None]
"""``progress(done, total)``: called as work completes (configurations, solves, runs)."""

EpochProgress = Callable[[int, int, dict], None]
"""``progress(epoch, epochs, record)``: called after each training epoch with its metrics record."""
