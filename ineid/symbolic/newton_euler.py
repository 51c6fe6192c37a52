"""Newton-Euler base-wrench regressor of a serial chain, derived with SymPy.

For each moving link ``i`` the forward pass propagates, in the link frame, the angular
velocity ``w_i``, angular acceleration ``wd_i`` and the acceleration of the link origin
``a_i`` with gravity folded in (the base moves with ``a_0 = -g``, so weight appears as an
inertial force), plus the placement ``base_R_i``, ``base_p_i``. Newton and Euler about the
link origin give the net wrench on the link, in its frame, linear in its parameters
``theta_i = [m, h, vech(I_O)]`` (``h = m c``, ``I_O`` about the origin)::

    f_i = m a_i + wd_i x h + w_i x (w_i x h)
    n_i = I_O wd_i + w_i x (I_O w_i) + h x a_i

The fixture supplies the sum of these over the moving links (joint forces are internal),
so the wrench the robot exerts on its fixture, in the base frame about its origin, is::

    F = -sum_i base_R_i f_i
    M = -sum_i (base_R_i n_i + base_p_i x base_R_i f_i)

and ``[F; M] = Psi(q, qd, qdd; g) @ theta`` with ``theta`` the links' parameters stacked
in chain order. At rest ``F = m_total * g``: the arm's weight loads the fixture.

References:
    Featherstone (2008), Rigid Body Dynamics Algorithms, ch. 5 (RNEA).
    Atkeson, An, Hollerbach (1986): linearity of the Newton-Euler equations in theta.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import sympy as sp

from ineid.errors import CodegenError
from ineid.robots.urdf import Chain

log = logging.getLogger(__name__)

MAX_DERIVED_JOINTS = 16
"""Most moving joints a chain may have to be derived (see ``docs/regressor.md`` for the
measured times: the common-subexpression elimination grows steeply with the chain)."""

SLOW_DERIVATION_JOINTS = 8
"""Chains with more moving joints than this get a warning before they are derived (minutes to hours)."""

STEPS_AFTER_JOINTS = 4
"""Logged steps of a derivation after its per-joint ones: the elimination, the two printers
and the end (``done == total``)."""


def derivation_step(done: int, total: int, message: str, *args: object) -> None:
    """Log one step of a derivation at INFO, with ``record.derivation_step = (done, total)`` and
    ``record.derivation_text``, the step's own words (``message % args``)."""
    text = message % args
    log.info("regressor derivation, step %d of %d: %s", done, total, text,
             extra={"derivation_step": (done, total), "derivation_text": text})


_LOCK = "lock the joints you do not identify with --lock JOINT=POSITION (locked_joints in Python)"


def _refuse_long(chain: Chain) -> None:
    if chain.n_dof > MAX_DERIVED_JOINTS:
        raise CodegenError(
            f"{chain.name!r} has {chain.n_dof} moving joints; ineid derives chains of at most {MAX_DERIVED_JOINTS} "
            f"(the derivation time grows steeply with the chain, see docs/regressor.md); {_LOCK}"
        )


def check_derivable(chain: Chain) -> None:
    """Refuse a chain too long to derive in reasonable time (:data:`MAX_DERIVED_JOINTS`); warn
    (a WARNING log line) about one longer than :data:`SLOW_DERIVATION_JOINTS`.

    Raises:
        CodegenError: naming the count and the fix (lock joints).
    """
    _refuse_long(chain)
    if chain.n_dof > SLOW_DERIVATION_JOINTS:
        log.warning("%r has %d moving joints: deriving its regressor takes minutes to hours (see docs/regressor.md); "
                    "to shorten it, %s", chain.name, chain.n_dof, _LOCK)


Vec = list  # three sympy expressions
Mat = list  # 3x3 nested list of sympy expressions

_SNAP = 1e-14


def _num(x: float) -> sp.Expr:
    """A URDF constant as a SymPy number; values within 1e-14 of 0 or +-1 become exact.

    Quarter-turn ``rpy`` values give cos(pi/2) = 6e-17 in floating point; treating it as
    0 removes terms from the generated code and changes results by ~1e-16 relative.
    """
    x = float(x)
    for exact in (0, 1, -1):
        if abs(x - exact) < _SNAP:
            return sp.Integer(exact)
    return sp.Float(x)


def _const_mat(m: np.ndarray) -> Mat:
    return [[_num(m[r, c]) for c in range(3)] for r in range(3)]


def _matmul(a: Mat, b: Mat) -> Mat:
    return [[sum((a[r][k] * b[k][c] for k in range(3)), sp.Integer(0)) for c in range(3)] for r in range(3)]


def _matvec(a: Mat, v: Vec) -> Vec:
    return [sum((a[r][k] * v[k] for k in range(3)), sp.Integer(0)) for r in range(3)]


def _transpose(a: Mat) -> Mat:
    return [[a[c][r] for c in range(3)] for r in range(3)]


def _cross(u: Vec, v: Vec) -> Vec:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def _add(*vs: Vec) -> Vec:
    return [sum((v[k] for v in vs), sp.Integer(0)) for k in range(3)]


def _scale(v: Vec, s: sp.Expr) -> Vec:
    return [s * x for x in v]


def _skew(v: Vec) -> Mat:
    z = sp.Integer(0)
    return [[z, -v[2], v[1]], [v[2], z, -v[0]], [-v[1], v[0], z]]


def _axis_rotation(axis: Vec, c: sp.Expr, s: sp.Expr) -> Mat:
    """Rodrigues: ``R = 1 + s K + (1 - c) K^2`` for a unit axis ``k``, ``K = S(k)``."""
    k = _skew(axis)
    k2 = _matmul(k, k)
    eye = [[sp.Integer(int(r == col)) for col in range(3)] for r in range(3)]
    return [[sp.expand(eye[r][col] + s * k[r][col] + (1 - c) * k2[r][col]) for col in range(3)] for r in range(3)]


def _inertia_map(v: Vec) -> list[list[sp.Expr]]:
    """``L(v)`` with ``I_O v = L(v) @ [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (Pinocchio order)."""
    z = sp.Integer(0)
    return [
        [v[0], v[1], z, v[2], z, z],
        [z, v[0], v[1], z, v[2], z],
        [z, z, z, v[0], v[1], v[2]],
    ]


@dataclass(frozen=True)
class SymbolicRegressor:
    """``Psi(q, qd, qdd; g)`` as SymPy expressions, with the symbols it depends on.

    ``Y[r][c]`` is row ``r`` of ``[Fx, Fy, Fz, Mx, My, Mz]`` (load on the fixture, base
    frame, moment about the base origin) and column ``c = 10 * link + param``.
    """

    chain: Chain
    q: tuple[sp.Symbol, ...]
    qd: tuple[sp.Symbol, ...]
    qdd: tuple[sp.Symbol, ...]
    gravity: tuple[sp.Symbol, sp.Symbol, sp.Symbol]
    Y: tuple[tuple[sp.Expr, ...], ...]
    seconds: float

    @property
    def n_dof(self) -> int:
        return len(self.q)

    @property
    def shape(self) -> tuple[int, int]:
        return (6, 10 * self.n_dof)

    def split(self, unknown_links: Sequence[int]) -> tuple[sp.Matrix, sp.Matrix]:
        """``(Psi_unknown, Psi_known)``: the columns of the chosen links and of the rest."""
        unknown = sorted(set(unknown_links))
        known = [i for i in range(self.n_dof) if i not in unknown]

        def cols(links: list[int]) -> sp.Matrix:
            idx = [10 * i + k for i in links for k in range(10)]
            return sp.Matrix(6, len(idx), lambda r, c: self.Y[r][idx[c]])

        return cols(unknown), cols(known)

    def numpy_function(self, cse: bool = True):
        """SymPy's own evaluation, through ``lambdify`` with NumPy (SymPy's printer, not ours).

        Args:
            cse: let lambdify eliminate common subexpressions (much faster to build for
                large arms; without it, each entry is evaluated as one expanded tree).

        Returns:
            ``f(q, qd, qdd, gravity) -> (..., 6, 10 * n_dof)`` for ``q`` of shape (..., n_dof).
        """
        flat = [e for row in self.Y for e in row]
        fn = sp.lambdify((self.q, self.qd, self.qdd, self.gravity), flat, modules="numpy", cse=cse)

        def f(q, qd, qdd, gravity):
            q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
            batch = q.shape[:-1]
            args = [tuple(np.moveaxis(x, -1, 0)) for x in (q, qd, qdd)]
            out = fn(*args, tuple(np.asarray(gravity, dtype=np.float64)))
            return np.stack([np.broadcast_to(np.asarray(v, dtype=np.float64), batch) for v in out], axis=-1).reshape(
                batch + self.shape
            )

        return f


def derive_base_wrench_regressor(chain: Chain) -> SymbolicRegressor:
    """Derive ``Psi`` for a chain, see the module docstring for the equations.

    Each joint is logged as a step (:func:`derivation_step`) of ``n_dof + STEPS_AFTER_JOINTS``.

    Raises:
        CodegenError: the chain has more than :data:`MAX_DERIVED_JOINTS` moving joints.
    """
    _refuse_long(chain)
    t0 = time.perf_counter()
    n = chain.n_dof
    total = n + STEPS_AFTER_JOINTS
    q = sp.symbols(f"q0:{n}", real=True)
    qd = sp.symbols(f"qd0:{n}", real=True)
    qdd = sp.symbols(f"qdd0:{n}", real=True)
    g = sp.symbols("g0:3", real=True)
    zero = sp.Integer(0)

    w: Vec = [zero, zero, zero]
    wd: Vec = [zero, zero, zero]
    a: Vec = [-g[0], -g[1], -g[2]]
    base_R: Mat = [[sp.Integer(int(r == c)) for c in range(3)] for r in range(3)]
    base_p: Vec = [zero, zero, zero]
    columns: list[list[sp.Expr]] = []  # 10 * n columns of 6 entries

    for i, joint in enumerate(chain.joints):
        derivation_step(i + 1, total, "Newton-Euler terms of joint %d of %d, %s", i + 1, n, ascii(joint.name))
        P = _const_mat(joint.parent_R_joint)
        r = [_num(x) for x in joint.parent_p_joint]
        axis = [_num(x) for x in joint.axis]
        if joint.type == "revolute":
            rq = _axis_rotation(axis, sp.cos(q[i]), sp.sin(q[i]))
            parent_R_i = _matmul(P, rq)
            offset = r
        else:  # prismatic: translation along the axis, no rotation
            parent_R_i = P
            offset = _add(r, _scale(_matvec(P, axis), q[i]))
        i_R_parent = _transpose(parent_R_i)
        # Origin acceleration in the parent frame, then rotated into link i.
        a_parent = _add(a, _cross(wd, offset), _cross(w, _cross(w, offset)))
        a_new = _matvec(i_R_parent, a_parent)
        w_rot = _matvec(i_R_parent, w)
        wd_rot = _matvec(i_R_parent, wd)
        if joint.type == "revolute":
            w_new = _add(w_rot, _scale(axis, qd[i]))
            wd_new = _add(wd_rot, _scale(axis, qdd[i]), _cross(w_rot, _scale(axis, qd[i])))
        else:
            w_new, wd_new = w_rot, wd_rot
            a_new = _add(a_new, _scale(_cross(w_new, axis), 2 * qd[i]), _scale(axis, qdd[i]))
        base_p = _add(base_p, _matvec(base_R, offset))
        base_R = _matmul(base_R, parent_R_i)
        w, wd, a = w_new, wd_new, a_new

        # Link-frame regressor blocks: f = A_f theta, n = A_n theta.
        s_wd, s_w = _skew(wd), _skew(w)
        s_w2 = _matmul(s_w, s_w)
        h_map = [[s_wd[r_][c] + s_w2[r_][c] for c in range(3)] for r_ in range(3)]
        l_wd, l_w = _inertia_map(wd), _inertia_map(w)
        s_w_l_w = [[sum((s_w[r_][k] * l_w[k][c] for k in range(3)), zero) for c in range(6)] for r_ in range(3)]
        neg_s_a = [[-x for x in row] for row in _skew(a)]
        for c in range(10):
            if c == 0:
                f_col, n_col = list(a), [zero, zero, zero]
            elif c < 4:
                f_col = [h_map[r_][c - 1] for r_ in range(3)]
                n_col = [neg_s_a[r_][c - 1] for r_ in range(3)]
            else:
                f_col = [zero, zero, zero]
                n_col = [l_wd[r_][c - 4] + s_w_l_w[r_][c - 4] for r_ in range(3)]
            f_base = _matvec(base_R, f_col)
            n_base = _add(_matvec(base_R, n_col), _cross(base_p, f_base))
            columns.append([-x for x in (*f_base, *n_base)])

    Y = tuple(tuple(columns[c][r_] for c in range(10 * n)) for r_ in range(6))
    return SymbolicRegressor(chain, q, qd, qdd, g, Y, time.perf_counter() - t0)
