"""The derivation's program made smaller: entries that vanish identically found by exact evaluation modulo a
prime at random points (:func:`vanishing`), and the lines no output needs dropped (:func:`prune`)."""

from __future__ import annotations

import sympy as sp

PRIME = 2**61 - 1
"""A Mersenne prime: the program evaluated modulo it, exactly (:func:`vanishing`)."""


def mod_value(expr: sp.Expr, env: dict) -> int:
    """``expr`` (numbers, names, ``+``, ``*``, integer powers) evaluated exactly modulo :data:`PRIME`."""
    if expr.is_Symbol:
        return env[expr]
    if expr.is_Rational:
        return expr.p * pow(expr.q, -1, PRIME) % PRIME
    if expr.is_Float:
        num, den = float(expr).as_integer_ratio()  # a URDF constant is a binary fraction, exactly
        return num * pow(den, -1, PRIME) % PRIME
    if expr.is_Add:
        return sum(mod_value(a, env) for a in expr.args) % PRIME
    if expr.is_Mul:
        out = 1
        for a in expr.args:
            out = out * mod_value(a, env) % PRIME
        return out
    if expr.is_Pow and expr.exp.is_Integer:
        return pow(mod_value(expr.base, env), int(expr.exp), PRIME)
    raise ValueError(f"no modular evaluation of {expr.func.__name__}")


def vanishing(sym_inputs, lines, entries, n_points: int = 2) -> list[bool]:
    """Which ``entries`` (expressions of the program's names) vanish identically.

    Named intermediates hide cancellations that expanding everything would show (``c^2 + s^2 =
    1`` among them), so an entry that is zero for every state can come out as round-off.
    Each is evaluated exactly, in the integers modulo a 61-bit prime, at random points with
    ``cos``/``sin`` of each angle parametrized rationally (``c = (1 - t^2)/(1 + t^2)``,
    ``s = 2 t/(1 + t^2)``, so ``c^2 + s^2 = 1`` holds exactly): an entry that is not
    identically zero vanishes at such a point with probability below ``1e-15``. The URDF's
    constants enter as the binary fractions they are (a rotation read from ``rpy`` is not
    exactly orthogonal), as SymPy's expansion saw them. Seeded: the same program, the same answer.
    """
    import random

    rng = random.Random(len(lines))
    zero = [True] * len(entries)
    for _ in range(n_points):
        env = {s: rng.randrange(1, PRIME) for s in sym_inputs}
        angle_t: dict = {}  # one t per angle: its cosine and sine
        for lhs, rhs in lines:
            if isinstance(rhs, (sp.sin, sp.cos)):
                t = angle_t.setdefault(rhs.args[0], rng.randrange(1, PRIME))
                inv = pow(1 + t * t, -1, PRIME)  # never 0: -1 is not a square modulo this prime
                env[lhs] = ((1 - t * t) if isinstance(rhs, sp.cos) else 2 * t) * inv % PRIME
            else:
                env[lhs] = mod_value(rhs, env)
        for k, e in enumerate(entries):
            if zero[k] and mod_value(e, env) != 0:
                zero[k] = False
    return zero


def prune(lines: list, barriers: list, outputs) -> tuple[list, list]:
    """The lines (and barrier names) that the outputs need, in their order."""
    used: set = set()
    for e in outputs:
        used |= e.free_symbols
    kept = []
    for lhs, rhs in reversed(lines):
        if lhs in used:
            kept.append((lhs, rhs))
            used |= rhs.free_symbols
    kept.reverse()
    names = {lhs for lhs, _ in kept}
    position = [0]  # kept lines among the first k
    for lhs, _ in lines:
        position.append(position[-1] + (lhs in names))
    bars = []
    for at, values in barriers:
        values = tuple(v for v in values if v in names)
        if values:
            bars.append((position[at], values))
    return kept, bars
