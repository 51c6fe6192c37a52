"""Gravity in the base frame: ineid's default, standard gravity, and the words every summary states it in.

ineid's default is ``(0, 0, -9.81)`` m/s^2 (:data:`ineid.robots.model.DEFAULT_GRAVITY`, the
paper's); standard gravity (ISO 80000-3) is 9.80665 m/s^2, 0.03 % less: a bias in every mass a fit of
real data makes with the default, as large as the difference. ``--gravity standard`` chooses it.
Imports nothing heavy (the CLI's help reads it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

STANDARD_GRAVITY = 9.80665
"""m/s^2, standard gravity (the CGPM's 1901 value, ISO 80000-3)."""

STANDARD_GRAVITY_VECTOR = (0.0, 0.0, -STANDARD_GRAVITY)
"""m/s^2 in the base frame, z up: ``--gravity standard``."""

GRAVITY_WORDS = {"standard": STANDARD_GRAVITY_VECTOR}
"""The names ``--gravity`` takes instead of three numbers."""


def describe_gravity(gravity: Sequence[float]) -> str:
    """``gravity`` (3,) m/s^2 in words for a summary: the vector, and whether it is ineid's default (then how to
    choose standard gravity) or standard gravity.

    ``"gravity (0, 0, -9.81) m/s^2 (ineid's default; --gravity standard for 9.80665)"``.
    """
    return "gravity " + gravity_words(gravity)


def gravity_words(gravity: Sequence[float]) -> str:
    """:func:`describe_gravity` without the word ``gravity`` in front (for a table's row named so)."""
    from ineid.robots.model import DEFAULT_GRAVITY

    g = tuple(float(x) for x in gravity)
    text = f"({', '.join(f'{x + 0.0:.10g}' for x in g)}) m/s^2"
    if _same(g, DEFAULT_GRAVITY):
        return text + f" (ineid's default; --gravity standard for {STANDARD_GRAVITY:g})"
    if _same(g, STANDARD_GRAVITY_VECTOR):
        return text + " (standard gravity)"
    return text


def _same(a: Sequence[float], b: Sequence[float]) -> bool:
    return len(a) == len(b) and all(math.isclose(x, y, rel_tol=0, abs_tol=1e-12) for x, y in zip(a, b, strict=True))
