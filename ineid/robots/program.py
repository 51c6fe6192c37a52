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

The backward pass of the recursion composes from the same outputs: the wrench a joint
transmits to everything beyond it is the sum of the net wrenches of the links it moves, its
subtree (``sum_{i in sub(j)} Yn_i theta_i``, base frame, about the base origin; ``sub(j)`` is
``j`` and its descendants in the module's ``PARENTS``, ``i >= j`` for a serial chain), so

- :func:`joint_torque_entries`: the joint-torque regressor ``tau = Y_tau theta``,
  ``Y_tau[j, 10 i + k] = z_j . M_ik + (p_j x z_j) . F_ik`` for links ``i`` beyond joint ``j``
  (prismatic: ``z_j . F_ik``), ``[F; M]_ik = Yn_i[:, k]``; :func:`joint_torques` the same
  torques without forming ``Y_tau`` (inverse dynamics, O(n));
- :func:`link_wrench_entries`: the wrench the links beyond link ``L`` exert on it, in ``L``'s
  frame, moment about ``L``'s origin: ``-X_L sum_{i > L} Yn_i`` with ``X_L`` the wrench transform
  of ``L``'s placement (:func:`link_wrench` without forming the regressor), the sum over the
  links below ``L`` in the tree. With ``L`` the root (no link) it is the base wrench.

A parameter block ``i`` belongs to the moving body ``body_of[i]`` (a payload welded to a body
is a block of its own after it, :mod:`ineid.robots.payload`); a block is beyond joint ``j`` when
its body is in ``sub(j)``, beyond link ``L`` when its body is in ``sub(L)`` but not ``L``, or it
is a payload welded to ``L``. ``parents``: per joint its parent joint (-1: the root), the
module's ``PARENTS`` (:func:`parents_of`); None is a serial chain.

:func:`jax_functions` and :func:`casadi_functions` wrap these for one generated module,
once per module (the same function objects on every call, so they can key compile caches).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from types import ModuleType
from typing import NamedTuple

from ineid.chain import serial_parents, subtree

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
    return (
        add(mul(u[1], v[2]), neg(mul(u[2], v[1]))),
        add(mul(u[2], v[0]), neg(mul(u[0], v[2]))),
        add(mul(u[0], v[1]), neg(mul(u[1], v[0]))),
    )


def matvec(m: Sequence, v: Sequence) -> tuple:
    """``m v`` for a 3 x 3 row-major nested ``m``."""
    return tuple(dot(row, v) for row in m)


def base_entries(out: dict) -> tuple:
    """The ``6 x 10 n`` entries of ``Psi`` (load on the fixture), row-major: ``Psi[r, 10 i + k] = -Yn_i[r, k]``."""
    yn = out["Yn"]
    n = len(yn)
    return tuple(
        neg(yn[c // 10][r][c % 10]) if not _zero(yn[c // 10][r][c % 10]) else 0 for r in range(6) for c in range(10 * n)
    )


def _zero(x) -> bool:
    return _number(x) and x == 0


def _block_wrench(out: dict, i: int, theta_i: Sequence) -> tuple[tuple, tuple]:
    """``(F, M)`` of block ``i``'s net wrench ``Yn_i theta_i`` (base frame, moment about the base origin),
    formed in the link's own frame from its 10 parameters, then rotated (never forming ``Yn_i``)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = theta_i
    w, wd, a, R, p = (out[k][i] for k in ("w", "wd", "a", "R", "p"))
    h = (hx, hy, hz)
    inertia = ((ixx, ixy, ixz), (ixy, iyy, iyz), (ixz, iyz, izz))
    f = tuple(add(mul(m, a[r]), x, y) for r, x, y in zip(range(3), cross(wd, h), cross(w, cross(w, h)), strict=True))
    n = tuple(
        add(x, y, z) for x, y, z in zip(matvec(inertia, wd), cross(w, matvec(inertia, w)), cross(h, a), strict=True)
    )
    force = matvec(R, f)
    return force, tuple(add(x, y) for x, y in zip(matvec(R, n), cross(p, force), strict=True))


def _sum_wrenches(wrenches) -> tuple[tuple, tuple]:
    wrenches = list(wrenches)
    return (
        tuple(add(*(f[r] for f, _ in wrenches)) for r in range(3)),
        tuple(add(*(m[r] for _, m in wrenches)) for r in range(3)),
    )


def base_wrench(out: dict, theta: Sequence) -> tuple:
    """``Psi theta``: the 6 entries ``[F; M]`` of the wrench on the fixture for the parameters ``theta``
    (``10 n`` scalars, links in chain order), never forming ``Psi``.

    Per link, with ``theta_i = [m, h, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``, in its own frame:
    ``f = m a + wd x h + w x (w x h)``, ``n = I wd + w x (I w) + h x a``; then
    ``F = -sum_i R_i f_i``, ``M = -sum_i (R_i n_i + p_i x R_i f_i)``.
    """
    force, moment = _sum_wrenches(_block_wrench(out, i, theta[10 * i : 10 * i + 10]) for i in range(len(out["R"])))
    return tuple(neg(x) for x in force) + tuple(neg(x) for x in moment)


def _project(kind: str, axis: Sequence, moment: Sequence, force: Sequence, torque: Sequence):
    """A joint's generalized force from a wrench ``[F; M]`` (base frame, about the base origin) it
    transmits: revolute ``z . M + (p x z) . F`` (the moment about the joint's axis), prismatic ``z . F``."""
    if kind == "prismatic":
        return dot(axis, force)
    return add(dot(axis, torque), dot(moment, force))


def _subtrees(parents: Sequence[int] | None, n: int) -> list[set[int]]:
    """Per joint, the set of bodies it moves (its subtree)."""
    parents = serial_parents(n) if parents is None else parents
    return [set(subtree(parents, j)) for j in range(n)]


def joint_torque_entries(
    out: dict, joint_types: Sequence[str], body_of: Sequence[int], parents: Sequence[int] | None = None
) -> tuple:
    """The ``n_dof x 10 n`` entries of the joint-torque regressor ``Y_tau``, row-major: ``tau = Y_tau theta``.

    ``tau_j`` is what joint ``j``'s actuator applies (Pinocchio's ``rnea``): the projection on its
    axis of the wrench it transmits to the blocks beyond it, ``sum_{body_of[i] in sub(j)} Yn_i theta_i``
    (gravity folded into the accelerations, so the weight is in it). Entries of blocks the joint
    does not move are the number 0.
    """
    yn = out["Yn"]
    moves = _subtrees(parents, len(joint_types))
    entries = []
    for j, kind in enumerate(joint_types):
        z, m = out["axis"][j], out["moment"][j]
        for i, block in enumerate(yn):
            for k in range(10):
                if body_of[i] not in moves[j]:
                    entries.append(0)
                    continue
                entries.append(
                    _project(kind, z, m, [block[r][k] for r in range(3)], [block[r][k] for r in range(3, 6)])
                )
    return tuple(entries)


def joint_torques(
    out: dict,
    theta: Sequence,
    joint_types: Sequence[str],
    body_of: Sequence[int],
    parents: Sequence[int] | None = None,
) -> tuple:
    """``Y_tau theta`` without forming ``Y_tau``: each block's wrench once, summed over each joint's
    subtree (the backward pass of inverse dynamics), projected on each joint's axis."""
    wrenches = [_block_wrench(out, i, theta[10 * i : 10 * i + 10]) for i in range(len(out["R"]))]
    moves = _subtrees(parents, len(joint_types))
    taus = []
    for j, kind in enumerate(joint_types):
        force, torque = _sum_wrenches(w for w, body in zip(wrenches, body_of, strict=True) if body in moves[j])
        taus.append(_project(kind, out["axis"][j], out["moment"][j], force, torque))
    return tuple(taus)


def beyond_link(body_of: Sequence[int], link_block: int, parents: Sequence[int] | None = None) -> tuple[int, ...]:
    """The blocks beyond an F/T sensor on block ``link_block``'s body: the bodies below it in the tree
    (after it, for a serial chain) and the payloads welded to it (the blocks after it with the same body)."""
    body = body_of[link_block]
    below = set(subtree(serial_parents(max(body_of) + 1) if parents is None else parents, body)) - {body}
    return tuple(i for i, b in enumerate(body_of) if b in below or (b == body and i > link_block))


def _to_link(out: dict, link_block: int, force: Sequence, torque: Sequence) -> tuple:
    """``-[R^T F; R^T (M - p x F)]``: a wrench the blocks beyond receive, as the one they exert on the
    link, in the link's frame (``R, p`` its placement), moment about its origin."""
    R, p = out["R"][link_block], out["p"][link_block]
    rt = tuple(tuple(R[r][c] for r in range(3)) for c in range(3))
    about = tuple(add(x, neg(y)) for x, y in zip(torque, cross(p, force), strict=True))
    return tuple(neg(x) for x in matvec(rt, force)) + tuple(neg(x) for x in matvec(rt, about))


def link_wrench_entries(
    out: dict, link_block: int, body_of: Sequence[int], parents: Sequence[int] | None = None
) -> tuple:
    """The ``6 x 10 n`` entries, row-major, of the regressor of the wrench that the blocks beyond
    link ``link_block`` (:func:`beyond_link`) exert on it, in its frame, moment about its origin.
    The columns of the other blocks are the number 0."""
    beyond = set(beyond_link(body_of, link_block, parents))
    cols = []
    for i, block in enumerate(out["Yn"]):
        for k in range(10):
            if i in beyond:
                cols.append(
                    _to_link(out, link_block, [block[r][k] for r in range(3)], [block[r][k] for r in range(3, 6)])
                )
            else:
                cols.append((0,) * 6)
    return tuple(col[r] for r in range(6) for col in cols)


def link_wrench(
    out: dict, theta: Sequence, link_block: int, body_of: Sequence[int], parents: Sequence[int] | None = None
) -> tuple:
    """The wrench of :func:`link_wrench_entries` for ``theta`` without forming the regressor."""
    force, torque = _sum_wrenches(
        _block_wrench(out, i, theta[10 * i : 10 * i + 10]) for i in beyond_link(body_of, link_block, parents)
    )
    return _to_link(out, link_block, force, torque)


def link_poses(out: dict) -> tuple[tuple, tuple]:
    """``(R, p)``: per link ``base_R_i`` (3 x 3 nested, row-major) and ``base_p_i`` (3), base frame."""
    return out["R"], out["p"]


def body_of(module: ModuleType) -> tuple[int, ...]:
    """Per parameter block of a generated module (or its payload view), the index of its moving body."""
    return tuple(getattr(module, "BODY_OF", range(len(module.LINK_NAMES))))


def parents_of(module: ModuleType) -> tuple[int, ...]:
    """Per joint of a generated module, its parent joint (-1: the root body): its ``PARENTS``, serial without one."""
    return tuple(getattr(module, "PARENTS", serial_parents(module.N_DOF)))


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
        torque_entries: ``(q, qd, qdd, gravity) -> (Y_tau_00, ...)``, ``n_dof x 10 n`` entries, row-major.
        torque_regressor: ``(q, qd, qdd, gravity) -> (..., n_dof, 10 n)``.
        torques: ``(q, qd, qdd, gravity, theta) -> (..., n_dof)``, ``Y_tau theta`` without forming ``Y_tau``.
    """

    program: object
    entries: object
    regressor: object
    wrench: object
    link_poses: object
    torque_entries: object
    torque_regressor: object
    torques: object


def _stack(values, batch, dtype, axis=-1):
    import jax.numpy as jnp

    return jnp.stack([jnp.broadcast_to(jnp.asarray(v, dtype=dtype), batch) for v in values], axis=axis)


def _jax_rows(entries, n_rows: int, n_cols: int):
    """``(q, qd, qdd, gravity) -> (..., n_rows, n_cols)`` from an entries function."""

    def rows(q, qd, qdd, gravity):
        import jax.numpy as jnp

        q, qd, qdd, gravity = (jnp.asarray(x) for x in (q, qd, qdd, gravity))
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        return _stack(entries(q, qd, qdd, gravity), batch, q.dtype).reshape(batch + (n_rows, n_cols))

    return rows


def _jax_contracted(program, compose, n_cols: int):
    """``(q, qd, qdd, gravity, theta) -> (..., k)``: ``compose(out, theta_entries)`` stacked."""

    def contracted(q, qd, qdd, gravity, theta):
        import jax.numpy as jnp

        q, qd, qdd, gravity, theta = (jnp.asarray(x) for x in (q, qd, qdd, gravity, theta))
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1], theta.shape[:-1])
        out = program(q, qd, qdd, gravity)
        return _stack(compose(out, [theta[..., c] for c in range(n_cols)]), batch, q.dtype)

    return contracted


@functools.cache
def jax_functions(module: ModuleType) -> JaxFunctions:
    """The compositions of one generated JAX module (the same objects on every call)."""
    import jax.numpy as jnp

    program = module.program
    n = len(module.LINK_NAMES)  # parameter blocks (payload views add links after their body)
    types, owners, parents = tuple(module.JOINT_TYPES), body_of(module), parents_of(module)

    def entries(q, qd, qdd, gravity):
        return base_entries(program(q, qd, qdd, gravity))

    def torque_entries(q, qd, qdd, gravity):
        return joint_torque_entries(program(q, qd, qdd, gravity), types, owners, parents)

    def poses(q):
        q = jnp.asarray(q)
        zero = jnp.zeros_like(q)
        rot, pos = link_poses(program(q, zero, zero, jnp.zeros(3, q.dtype)))
        batch = q.shape[:-1]
        r = _stack([x for link in rot for row in link for x in row], batch, q.dtype)
        return r.reshape(batch + (n, 3, 3)), _stack([x for link in pos for x in link], batch, q.dtype).reshape(
            batch + (n, 3)
        )

    return JaxFunctions(
        program,
        entries,
        _jax_rows(entries, 6, 10 * n),
        _jax_contracted(program, base_wrench, 10 * n),
        poses,
        torque_entries,
        _jax_rows(torque_entries, len(types), 10 * n),
        _jax_contracted(program, lambda out, th: joint_torques(out, th, types, owners, parents), 10 * n),
    )


class LinkWrenchFunctions(NamedTuple):
    """The cut wrench at one link (:func:`link_wrench_entries`) as JAX or CasADi functions.

    Attributes:
        entries: JAX ``(q, qd, qdd, gravity) -> 6 x 10 n`` entries, row-major (None for CasADi).
        regressor: ``(q, qd, qdd, gravity) -> (..., 6, 10 n)`` (CasADi: ``Y`` 6 x 10 n).
        wrench: ``(q, qd, qdd, gravity, theta) -> (..., 6)`` (CasADi: ``w`` 6 x 1).
    """

    entries: object
    regressor: object
    wrench: object


@functools.cache
def jax_link_wrench_functions(module: ModuleType, link_block: int) -> LinkWrenchFunctions:
    """The cut wrench at parameter block ``link_block``'s link, for one generated JAX module (cached)."""
    program, owners, parents = module.program, body_of(module), parents_of(module)
    n = len(module.LINK_NAMES)

    def entries(q, qd, qdd, gravity):
        return link_wrench_entries(program(q, qd, qdd, gravity), link_block, owners, parents)

    return LinkWrenchFunctions(
        entries,
        _jax_rows(entries, 6, 10 * n),
        _jax_contracted(program, lambda out, th: link_wrench(out, th, link_block, owners, parents), 10 * n),
    )


# -- CasADi ------------------------------------------------------------------------------------------
class CasadiFunctions(NamedTuple):
    """A generated module's compositions as ``casadi.Function`` objects (one frame each).

    Attributes:
        regressor: ``base_wrench_regressor(q, qd, qdd, gravity) -> Y`` (n x 1, n x 1, n x 1, 3 x 1 -> 6 x 10 n).
        wrench: ``base_wrench(q, qd, qdd, gravity, theta) -> w`` (theta 10 n x 1 -> 6 x 1).
    """

    regressor: object
    wrench: object


class CasadiTorqueFunctions(NamedTuple):
    """A generated module's joint-torque compositions as ``casadi.Function`` objects (one frame each).

    Attributes:
        regressor: ``joint_torque_regressor(q, qd, qdd, gravity) -> Y`` (n_dof x 10 n).
        torques: ``joint_torques(q, qd, qdd, gravity, theta) -> tau`` (n_dof x 1).
    """

    regressor: object
    torques: object


def _casadi_matrix(ca, entries, n_rows: int, n_cols: int):
    y = ca.SX.zeros(n_rows, n_cols)
    for k, e in enumerate(entries):
        if not _zero(e):
            y[k // n_cols, k % n_cols] = e
    return y


def _casadi_vector(ca, values):
    return ca.vertcat(*(ca.SX(e) if _number(e) else e for e in values))


def _casadi_symbols(module: ModuleType):
    import casadi as ca

    n = len(module.LINK_NAMES)
    q, qd, qdd = (ca.SX.sym(s, module.N_DOF) for s in ("q", "qd", "qdd"))
    gravity = ca.SX.sym("gravity", 3)
    theta = ca.SX.sym("theta", 10 * n)
    return [q, qd, qdd, gravity], ["q", "qd", "qdd", "gravity"], theta, [theta[c] for c in range(10 * n)]


@functools.cache
def casadi_functions(module: ModuleType) -> CasadiFunctions:
    """The compositions of one generated CasADi module, built once per module (an ``SX`` graph of the program)."""
    import casadi as ca

    n = len(module.LINK_NAMES)  # parameter blocks (payload views add links after their body)
    args, names, theta, th = _casadi_symbols(module)
    out = module.program(*args)
    regressor = ca.Function(
        "base_wrench_regressor", args, [_casadi_matrix(ca, base_entries(out), 6, 10 * n)], names, ["Y"]
    )
    wrench = ca.Function(
        "base_wrench", [*args, theta], [_casadi_vector(ca, base_wrench(out, th))], [*names, "theta"], ["w"]
    )
    return CasadiFunctions(regressor, wrench)


@functools.cache
def casadi_torque_functions(module: ModuleType) -> CasadiTorqueFunctions:
    """The joint-torque compositions of one generated CasADi module (built on first use, then cached)."""
    import casadi as ca

    n = len(module.LINK_NAMES)
    types, owners, parents = tuple(module.JOINT_TYPES), body_of(module), parents_of(module)
    args, names, theta, th = _casadi_symbols(module)
    out = module.program(*args)
    y_tau = _casadi_matrix(ca, joint_torque_entries(out, types, owners, parents), len(types), 10 * n)
    torque_regressor = ca.Function("joint_torque_regressor", args, [y_tau], names, ["Y"])
    torques = ca.Function(
        "joint_torques",
        [*args, theta],
        [_casadi_vector(ca, joint_torques(out, th, types, owners, parents))],
        [*names, "theta"],
        ["tau"],
    )
    return CasadiTorqueFunctions(torque_regressor, torques)


@functools.cache
def casadi_link_wrench_functions(module: ModuleType, link_block: int) -> LinkWrenchFunctions:
    """The cut wrench at parameter block ``link_block``'s link as ``casadi.Function`` objects (cached)."""
    import casadi as ca

    n, owners, parents = len(module.LINK_NAMES), body_of(module), parents_of(module)
    args, names, theta, th = _casadi_symbols(module)
    out = module.program(*args)
    y = _casadi_matrix(ca, link_wrench_entries(out, link_block, owners, parents), 6, 10 * n)
    w = _casadi_vector(ca, link_wrench(out, th, link_block, owners, parents))
    return LinkWrenchFunctions(
        None,
        ca.Function("link_wrench_regressor", args, [y], names, ["Y"]),
        ca.Function("link_wrench", [*args, theta], [w], [*names, "theta"], ["w"]),
    )
