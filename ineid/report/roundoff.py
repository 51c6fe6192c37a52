"""Round-off shown as what it is: an estimate far below its resolution is printed ``0 (round-off)``.

A parameter the data pin at zero (a centre of mass on a symmetry axis, clean synthetic data) comes
out of the solvers as ``9.4e-17``: floating-point noise, not a measurement. Its resolution is the larger
of the parameter's scale times :data:`ROUND_OFF` (a relative 1e-12, about 4500 x the float64 epsilon:
what the normal equations and a QR lose) and its std times the same; a value below it is shown
as ``0 (round-off)``, the number stored unchanged. The summary of ``ineid solve`` and the report use it.
"""

from __future__ import annotations

import math

ROUND_OFF = 1e-12
"""Relative resolution: a value below ``ROUND_OFF * max(scale, std)`` is round-off."""

ROUND_OFF_TEXT = "0 (round-off)"


def is_round_off(value: float, scale: float, std: float = math.nan) -> bool:
    """``value`` (finite) is below its resolution: ``|value| <= ROUND_OFF * max(scale, std)`` (a NaN or
    infinite std counts as none)."""
    if value is None or not math.isfinite(value) or value == 0:
        return False
    ref = abs(scale) if math.isfinite(scale) else 0.0
    if std is not None and math.isfinite(std):
        ref = max(ref, abs(std))
    return abs(value) <= ROUND_OFF * ref


def parameter_scale(base, k: int) -> float:
    """The scale of standard parameter ``k`` of :class:`ineid.identify.BaseParameters` ``base`` (NaN: none)."""
    scales = getattr(base, "scales", None)
    return float(scales[k]) if scales is not None and 0 <= k < len(scales) else math.nan


def base_scale(base, k: int) -> float:
    """The scale of base parameter ``k``: its own standard parameter's (the column the base keeps)."""
    return parameter_scale(base, int(base.base_index[k]))


def shown_value(value: float, scale: float, std: float = math.nan, digits: int = 6) -> str:
    """``value`` with ``digits`` significant digits, ``0 (round-off)`` below its resolution, ``-`` when NaN."""
    if value is None or math.isnan(value):
        return "-"
    if is_round_off(value, scale, std):
        return ROUND_OFF_TEXT
    return f"{value:.{digits}g}"
