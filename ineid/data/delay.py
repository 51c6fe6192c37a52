"""Moved: the delay estimate fits the model, so it lives with its solver in :mod:`ineid.identify.delay`.

This module re-exports its names for one release (``DelayEstimate`` is
:class:`ineid.data.recording.DelayEstimate`); it is removed in ineid 0.3.
"""

from __future__ import annotations

import warnings

from ineid.data.recording import DelayEstimate
from ineid.identify.delay import MAX_DELAY, estimate_delay

warnings.warn(
    "ineid.data.delay moved to ineid.identify.delay (DelayEstimate: ineid.data.recording); "
    "ineid.data.delay is removed in ineid 0.3",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["MAX_DELAY", "DelayEstimate", "estimate_delay"]
