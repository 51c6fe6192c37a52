"""What is composed from a generated program's outputs: written once here, for every robot.

A generated module (:mod:`ineid.generated`, printed by :mod:`ineid.symbolic.emit`) holds one
function, ``program(q, qd, qdd, gravity)``, the Newton-Euler recursion of its chain with its
values named: per link its pose ``base_R_i, base_p_i`` and motion ``w_i, wd_i, a_i`` (link
frame), the 6 x 10 columns ``Yn_i`` of its net wrench (base frame, moment about the base
origin), and per joint its axis ``z_j`` and moment ``p_j x z_j`` (its Pluecker coordinates,
base frame); see ``docs/regressor.md``. Every entry is an array (JAX), a scalar expression
(CasADi) or a Python number: structurally 0, +-1, or a constant of the URDF.

The compositions below need only ``+``, ``-`` and ``*``, so the same code serves JAX arrays
and CasADi ``SX`` (the Python numbers are folded here: ``0 * x`` is never formed):

- :func:`base_entries`: the base-wrench regressor ``Psi = -[Yn_1 ... Yn_n]``, flat;
- :func:`base_wrench`: ``Psi theta`` without forming ``Psi`` (each link's wrench formed in its
  own frame from its 10 parameters, then rotated and summed: inverse dynamics, O(n));
- :func:`link_poses`: every link frame's placement.

The joint-torque regressor and the cut wrench at a link (issue 21) compose from the same
outputs: ``Y_tau[j, 10 i + k] = z_j . M_ik + (p_j x z_j) . F_ik`` for ``i >= j`` (prismatic:
``z_j . F_ik``), with ``[F; M]_ik = Yn_i[:, k]``.

:func:`jax_functions` and :func:`casadi_functions` wrap these for one generated module,
once per module (the same function objects on every call, so they can key compile caches).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from types import ModuleType
from typing import NamedTuple

OUTPUTS = ("R", "p", "w", "wd", "a", "axis", "moment", "Yn")
"""The keys of a program's outputs (see the module docstring)."""


def _number(x) -> bool:
    return isinstance(x, (int, float))


def mul(a, b):
    """``a * b`` with exact 0 and 1 folded when either is a Python number."""
    if _number(a):
        if a == 0:
            return 0
        if a == 1:
            return b
        if a == -1:
            return -b
    if _number(b):
        return mul(b, a)
    return a * b


def add(*terms):
    """The sum, Python zeros dropped (0 when nothing is left)."""
    out = 0
    for t in terms:
        if _number(t) and t == 0:
            continue
        out = t if _number(out) and out == 0 else out + t
    return out


def neg(x):
    return -x


def dot(u: Sequence, v: Sequence):
    return add(*(mul(a, b) for a, b in zip(u, v, strict=True)))


def cross(u: Sequence, v: Sequence) -> tuple:
    return (add(mul(u[1], v[2]), neg(mul(u[2], v[1]))),
            add(mul(u[2], v[0]), neg(mul(u[0], v[2]))),
            add(mul(u[0], v[1]), neg(mul(u[1], v[0]))))


def matvec(m: Sequence, v: Sequence) -> tuple:
    """``m v`` for a 3 x 3 row-major nested ``m``."""
    return tuple(dot(row, v) for row in m)


def base_entries(out: dict) -> tuple:
    """The ``6 x 10 n`` entries of ``Psi`` (load on the fixture), row-major: ``Psi[r, 10 i + k] = -Yn_i[r, k]``."""
    yn = out["Yn"]
    n = len(yn)
    return tuple(neg(yn[c // 10][r][c % 10]) if not _zero(yn[c // 10][r][c % 10]) else 0
                 for r in range(6) for c in range(10 * n))


def _zero(x) -> bool:
    return _number(x) and x == 0


def base_wrench(out: dict, theta: Sequence) -> tuple:
    """``Psi theta``: the 6 entries ``[F; M]`` of the wrench on the fixture for the parameters ``theta``
    (``10 n`` scalars, links in chain order), never forming ``Psi``.

    Per link, with ``theta_i = [m, h, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``, in its own frame:
    ``f = m a + wd x h + w x (w x h)``, ``n = I wd + w x (I w) + h x a``; then
    ``F = -sum_i R_i f_i``, ``M = -sum_i (R_i n_i + p_i x R_i f_i)``.
    """
    forces, moments = [], []
    for i in range(len(out["R"])):
        m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = theta[10 * i : 10 * i + 10]
        w, wd, a, R, p = (out[k][i] for k in ("w", "wd", "a", "R", "p"))
        h = (hx, hy, hz)
        inertia = ((ixx, ixy, ixz), (ixy, iyy, iyz), (ixz, iyz, izz))
        f = tuple(add(mul(m, a[r]), x, y) for r, x, y in zip(range(3), cross(wd, h), cross(w, cross(w, h)),
                                                               strict=True))
        n = tuple(add(x, y, z) for x, y, z in zip(matvec(inertia, wd), cross(w, matvec(inertia, w)), cross(h, a),
                                                  strict=True))
        force = matvec(R, f)
        forces.append(force)
        moments.append(tuple(add(x, y) for x, y in zip(matvec(R, n), cross(p, force), strict=True)))
    return tuple(neg(add(*(v[r] for v in forces))) for r in range(3)) + tuple(
        neg(add(*(v[r] for v in moments))) for r in range(3))


def link_poses(out: dict) -> tuple[tuple, tuple]:
    """``(R, p)``: per link ``base_R_i`` (3 x 3 nested, row-major) and ``base_p_i`` (3), base frame."""
    return out["R"], out["p"]


# -- JAX ---------------------------------------------------------------------------------------------
class JaxFunctions(NamedTuple):
    """A generated module's compositions as pure, jit-safe JAX functions batched over leading axes.

    Attributes:
        program: the module's ``program(q, qd, qdd, gravity) -> {output: nested tuples}``.
        entries: ``(q, qd, qdd, gravity) -> (Psi_00, Psi_01, ..., Psi_5m)``, each of the batch
            shape or the number 0 where identically zero.
        regressor: ``(q, qd, qdd, gravity) -> (..., 6, 10 n)``.
        wrench: ``(q, qd, qdd, gravity, theta) -> (..., 6)``, ``theta`` (..., 10 n).
        link_poses: ``q -> (base_R (..., n, 3, 3), base_p (..., n, 3))``.
    """

    program: object
    entries: object
    regressor: object
    wrench: object
    link_poses: object


def _stack(values, batch, dtype, axis=-1):
    import jax.numpy as jnp  # noqa: PLC0415

    return jnp.stack([jnp.broadcast_to(jnp.asarray(v, dtype=dtype), batch) for v in values], axis=axis)


@functools.lru_cache(maxsize=None)
def jax_functions(module: ModuleType) -> JaxFunctions:
    """The compositions of one generated JAX module (the same objects on every call)."""
    import jax.numpy as jnp  # noqa: PLC0415

    program = module.program
    n = len(module.LINK_NAMES)  # parameter blocks (payload views add links after their body)

    def entries(q, qd, qdd, gravity):
        return base_entries(program(q, qd, qdd, gravity))

    def regressor(q, qd, qdd, gravity):
        q, qd, qdd, gravity = (jnp.asarray(x) for x in (q, qd, qdd, gravity))
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        return _stack(entries(q, qd, qdd, gravity), batch, q.dtype).reshape(batch + (6, 10 * n))

    def wrench(q, qd, qdd, gravity, theta):
        q, qd, qdd, gravity, theta = (jnp.asarray(x) for x in (q, qd, qdd, gravity, theta))
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1], theta.shape[:-1])
        out = program(q, qd, qdd, gravity)
        return _stack(base_wrench(out, [theta[..., c] for c in range(10 * n)]), batch, q.dtype)

    def poses(q):
        q = jnp.asarray(q)
        zero = jnp.zeros_like(q)
        rot, pos = link_poses(program(q, zero, zero, jnp.zeros(3, q.dtype)))
        batch = q.shape[:-1]
        r = _stack([x for link in rot for row in link for x in row], batch, q.dtype)
        return r.reshape(batch + (n, 3, 3)), _stack([x for link in pos for x in link], batch, q.dtype).reshape(
            batch + (n, 3))

    return JaxFunctions(program, entries, regressor, wrench, poses)


# -- CasADi ------------------------------------------------------------------------------------------
class CasadiFunctions(NamedTuple):
    """A generated module's compositions as ``casadi.Function`` objects (one frame each).

    Attributes:
        regressor: ``base_wrench_regressor(q, qd, qdd, gravity) -> Y`` (n x 1, n x 1, n x 1, 3 x 1 -> 6 x 10 n).
        wrench: ``base_wrench(q, qd, qdd, gravity, theta) -> w`` (theta 10 n x 1 -> 6 x 1).
    """

    regressor: object
    wrench: object


@functools.lru_cache(maxsize=None)
def casadi_functions(module: ModuleType) -> CasadiFunctions:
    """The compositions of one generated CasADi module, built once per module (an ``SX`` graph of the program)."""
    import casadi as ca  # noqa: PLC0415

    n = len(module.LINK_NAMES)  # parameter blocks (payload views add links after their body)
    q, qd, qdd = (ca.SX.sym(s, module.N_DOF) for s in ("q", "qd", "qdd"))
    gravity = ca.SX.sym("gravity", 3)
    theta = ca.SX.sym("theta", 10 * n)
    out = module.program(q, qd, qdd, gravity)
    y = ca.SX.zeros(6, 10 * n)
    for k, e in enumerate(base_entries(out)):
        if not _zero(e):
            y[k // (10 * n), k % (10 * n)] = e
    args, names = [q, qd, qdd, gravity], ["q", "qd", "qdd", "gravity"]
    regressor = ca.Function("base_wrench_regressor", args, [y], names, ["Y"])
    w = ca.vertcat(*(ca.SX(e) if _number(e) else e for e in base_wrench(out, [theta[c] for c in range(10 * n)])))
    wrench = ca.Function("base_wrench", [*args, theta], [w], [*names, "theta"], ["w"])
    return CasadiFunctions(regressor, wrench)
