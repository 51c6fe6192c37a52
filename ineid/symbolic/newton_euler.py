"""The Newton-Euler recursion of a chain (a tree on a fixed base) as a straight-line program, derived with SymPy.

For each moving link ``i`` the forward pass propagates from its parent link's motion (the parent
joint's, :attr:`Chain.parents`; the root body's for a joint on it), in the link frame, the angular
velocity ``w_i``, angular acceleration ``wd_i`` and the acceleration of the link origin
``a_i`` with gravity folded in (the base moves with ``a_0 = -g``, so weight appears as an
inertial force), plus the placement ``base_R_i``, ``base_p_i``. Newton and Euler about the
link origin give the net wrench on the link, in its frame, linear in its parameters
``theta_i = [m, h, vech(I_O)]`` (``h = m c``, ``I_O`` about the origin)::

    f_i = m a_i + wd_i x h + w_i x (w_i x h)
    n_i = I_O wd_i + w_i x (I_O w_i) + h x a_i

Rotated into the base frame, moment about the base origin, its 10 columns are
``Yn_i`` (6 x 10, rows ``[F; M]``): ``[F; M]_i = Yn_i theta_i``. The fixture supplies the sum
over the moving links of every branch (joint forces are internal), so the wrench the robot exerts on its
fixture, base frame, about its origin, is ``[F; M] = Psi theta`` with ``Psi = -[Yn_1 ... Yn_n]``.

The program mirrors the recursion: per joint, the joint transform and the link's ``w, wd, a,
base_R, base_p``; per link, ``Yn_i``; per joint, its axis in base Pluecker coordinates
``(z_j, p_j x z_j)``. SymPy only simplifies each step's expressions of the previous steps'
*named* results, folding the URDF's constants (exact 0 and +-1 after snapping, zero terms
dropped), and each non-trivial result is bound to a fresh name: the program grows linearly
with the chain, and no global common-subexpression elimination is needed (it took hours at
12 joints). See ``docs/regressor.md``.

References:
    Featherstone (2008), Rigid Body Dynamics Algorithms, ch. 5 (RNEA).
    Atkeson, An, Hollerbach (1986): linearity of the Newton-Euler equations in theta.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ineid.chain import Chain
from ineid.errors import CodegenError
from ineid.symbolic.prune import prune, vanishing

log = logging.getLogger(__name__)

MAX_DERIVED_JOINTS = 32
"""Most moving joints a chain may have to be derived. The derivation itself is linear in the
chain (about 5 s at 24 joints, 10 s at 48; ``benchmarks/compile.py``); the limit guards what
follows it: XLA's compile time of the kernels grows faster (24 joints: about a minute per
kernel on a busy 2-core machine, see ``docs/regressor.md``)."""

SLOW_DERIVATION_JOINTS = 16
"""Chains with more moving joints than this get a warning before they are derived (compiling
their kernels takes a minute or more)."""

STEPS_AFTER_JOINTS = 3
"""Logged steps of a derivation after its per-joint ones: the two printers and the end
(``done == total``)."""


def derivation_step(done: int, total: int, message: str, *args: object) -> None:
    """Log one step of a derivation at INFO, with ``record.derivation_step = (done, total)`` and
    ``record.derivation_text``, the step's own words (``message % args``)."""
    text = message % args
    log.info(
        "regressor derivation, step %d of %d: %s",
        done,
        total,
        text,
        extra={"derivation_step": (done, total), "derivation_text": text},
    )


_LOCK = "lock the joints you do not identify with --lock JOINT=POSITION (locked_joints in Python)"


def _refuse_long(chain: Chain) -> None:
    if chain.n_dof > MAX_DERIVED_JOINTS:
        raise CodegenError(
            f"{chain.name!r} has {chain.n_dof} moving joints; ineid derives chains of at most {MAX_DERIVED_JOINTS} "
            f"(compiling the kernels of a longer chain takes too long and too much memory, see docs/regressor.md); "
            f"{_LOCK}"
        )


def check_derivable(chain: Chain) -> None:
    """Refuse a chain too long to derive and compile (:data:`MAX_DERIVED_JOINTS`); warn (a
    WARNING log line) about one longer than :data:`SLOW_DERIVATION_JOINTS`.

    Raises:
        CodegenError: naming the count and the fix (lock joints).
    """
    _refuse_long(chain)
    if chain.n_dof > SLOW_DERIVATION_JOINTS:
        log.warning(
            "%r has %d moving joints: compiling its regressor's kernels takes a minute or more "
            "(see docs/regressor.md); "
            "to shorten it, %s",
            chain.name,
            chain.n_dof,
            _LOCK,
        )


Vec = list  # three sympy expressions
Mat = list  # 3x3 nested list of sympy expressions
ZERO = sp.Integer(0)
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


def _eye() -> Mat:
    return [[sp.Integer(int(r == c)) for c in range(3)] for r in range(3)]


def _matmul(a: Mat, b: Mat) -> Mat:
    return [[sum((a[r][k] * b[k][c] for k in range(3)), ZERO) for c in range(3)] for r in range(3)]


def _matvec(a: Mat, v: Vec) -> Vec:
    return [sum((a[r][k] * v[k] for k in range(3)), ZERO) for r in range(3)]


def _tmatvec(a: Mat, v: Vec) -> Vec:
    """``a^T v``."""
    return [sum((a[k][r] * v[k] for k in range(3)), ZERO) for r in range(3)]


def _cross(u: Vec, v: Vec) -> Vec:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def _add(*vs: Vec) -> Vec:
    return [sum((v[k] for v in vs), ZERO) for k in range(3)]


def _scale(v: Vec, s: sp.Expr) -> Vec:
    return [s * x for x in v]


def _skew(v: Vec) -> Mat:
    return [[ZERO, -v[2], v[1]], [v[2], ZERO, -v[0]], [-v[1], v[0], ZERO]]


def _axis_rotation(axis: Vec, c: sp.Expr, s: sp.Expr) -> Mat:
    """Rodrigues: ``R = 1 + s K + (1 - c) K^2`` for a unit axis ``k``, ``K = S(k)``, expanded
    (sparse for an axis along a frame axis)."""
    k = _skew(axis)
    k2 = _matmul(k, k)
    eye = _eye()
    return [[sp.expand(eye[r][col] + s * k[r][col] + (1 - c) * k2[r][col]) for col in range(3)] for r in range(3)]


def _inertia_map(v: Vec) -> list[list[sp.Expr]]:
    """``L(v)`` with ``I_O v = L(v) @ [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (Pinocchio order)."""
    return [
        [v[0], v[1], ZERO, v[2], ZERO, ZERO],
        [ZERO, v[0], v[1], ZERO, v[2], ZERO],
        [ZERO, ZERO, ZERO, v[0], v[1], v[2]],
    ]


def _is_identity(m: Mat) -> bool:
    return all(m[r][c] == (1 if r == c else 0) for r in range(3) for c in range(3))


@dataclass
class _Builder:
    """Collects the program: each non-trivial expression bound to a fresh name."""

    lines: list = field(default_factory=list)
    barriers: list = field(default_factory=list)
    named: set = field(default_factory=set)  # the names of lines other than the trigonometric ones
    known: dict = field(default_factory=dict)  # expression -> its name, so that none is computed twice

    def let(self, expr: sp.Expr, prefix: str = "t") -> sp.Expr:
        """``expr`` expanded, bound to a new name unless it is a number, a name or minus a name,
        or already named (itself or its negative: ``qd0**2`` and ``-qd0**2`` share one line)."""
        expr = sp.expand(expr)
        if (
            expr.is_Number
            or expr.is_Symbol
            or (expr.is_Mul and len(expr.args) == 2 and expr.args[0] == -1 and expr.args[1].is_Symbol)
        ):
            return expr
        if expr in self.known:
            return self.known[expr]
        negated = -expr
        if negated in self.known:
            return -self.known[negated]
        name = sp.Symbol(f"{prefix}{len(self.lines)}", real=True)
        self.lines.append((name, expr))
        self.named.add(name)
        self.known[expr] = name
        return name

    def vec(self, v: Vec, prefix: str = "t") -> Vec:
        return [self.let(x, prefix) for x in v]

    def mat(self, m: Mat, prefix: str = "t") -> Mat:
        return [[self.let(x, prefix) for x in row] for row in m]

    def trig_pair(self, i: int, angle: sp.Symbol) -> tuple[sp.Symbol, sp.Symbol]:
        c, s = sp.Symbol(f"c{i}", real=True), sp.Symbol(f"s{i}", real=True)
        self.lines += [(c, sp.cos(angle)), (s, sp.sin(angle))]
        return c, s

    def barrier(self, values) -> None:
        """Mark the named values among ``values`` (a name or minus a name) to be materialised here."""
        names = []
        for v in values:
            sym = v if v.is_Symbol else (-v if (-v).is_Symbol else None)
            if sym is not None and sym in self.named and sym not in names:
                names.append(sym)
        if names:
            self.barriers.append((len(self.lines), tuple(names)))


@dataclass(frozen=True)
class SymbolicRegressor:
    """The structured program of a chain: named lines and the outputs, expressions of its names.

    Every output entry is a SymPy number (exact 0, +-1 or a float), an input or line name,
    or minus a name. Frames: ``w, wd, a`` of link ``i`` in its own frame, the rest in the
    base frame (moments about the base origin). Links and joints in chain order.

    Attributes:
        lines: ``(name, expression)`` in dependency order (trigonometric lines
            ``c_i = cos(q_i)``, ``s_i = sin(q_i)`` among them).
        barriers: ``(line count, names)``: after that many lines, these values are complete
            (a link's pose, then its motion): where the JAX printer materialises them.
        R: per link ``base_R_i`` (3x3, row-major); p: ``base_p_i`` (3).
        w, wd, a: per link, link frame (a: origin acceleration minus gravity).
        axis, moment: per joint, ``z_j`` and ``p_j x z_j`` (its Pluecker coordinates).
        Yn: per link the 6 x 10 columns of its net wrench, rows ``[F; M]``.
    """

    chain: Chain
    q: tuple[sp.Symbol, ...]
    qd: tuple[sp.Symbol, ...]
    qdd: tuple[sp.Symbol, ...]
    gravity: tuple[sp.Symbol, sp.Symbol, sp.Symbol]
    lines: tuple[tuple[sp.Symbol, sp.Expr], ...]
    barriers: tuple[tuple[int, tuple[sp.Symbol, ...]], ...]
    R: tuple
    p: tuple
    w: tuple
    wd: tuple
    a: tuple
    axis: tuple
    moment: tuple
    Yn: tuple
    seconds: float

    @property
    def n_dof(self) -> int:
        return len(self.q)

    @property
    def shape(self) -> tuple[int, int]:
        return (6, 10 * self.n_dof)

    @property
    def Y(self) -> tuple[tuple[sp.Expr, ...], ...]:
        """``Psi`` (6 x 10 n) as expressions of the program's names: ``Psi[r][10 i + k] = -Yn[i][r][k]``."""
        return tuple(tuple(-self.Yn[c // 10][r][c % 10] for c in range(10 * self.n_dof)) for r in range(6))

    @property
    def nonzero(self) -> tuple[tuple[int, ...], ...]:
        """Per row of ``Psi``, the columns that are not identically zero."""
        return tuple(tuple(c for c, e in enumerate(row) if e != 0) for row in self.Y)

    @functools.cached_property
    def op_count(self) -> int:
        """Arithmetic operations of the program's lines: ``k - 1`` per sum or product of ``k``
        terms, one per negation, power, sine or cosine (SymPy's ``count_ops`` counts alike, 20x slower)."""
        return sum(_ops(rhs) for _, rhs in self.lines)

    def numpy_function(self):
        """SymPy's own evaluation of ``Psi``, through ``lambdify`` with NumPy (SymPy's printer, not ours),
        the program's lines given to it as its common subexpressions.

        Returns:
            ``f(q, qd, qdd, gravity) -> (..., 6, 10 * n_dof)`` for ``q`` of shape (..., n_dof).
        """
        flat = [e for row in self.Y for e in row]
        lines = list(self.lines)
        fn = sp.lambdify(
            (self.q, self.qd, self.qdd, self.gravity), flat, modules="numpy", cse=lambda exprs: (lines, list(exprs))
        )

        def f(q, qd, qdd, gravity):
            q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
            batch = q.shape[:-1]
            args = [tuple(np.moveaxis(x, -1, 0)) for x in (q, qd, qdd)]
            out = fn(*args, tuple(np.asarray(gravity, dtype=np.float64)))
            return np.stack([np.broadcast_to(np.asarray(v, dtype=np.float64), batch) for v in out], axis=-1).reshape(
                batch + self.shape
            )

        return f


def _ops(expr: sp.Expr) -> int:
    """Arithmetic operations of one expression (see :attr:`SymbolicRegressor.op_count`)."""
    if expr.is_Atom:
        return 0
    args = expr.args
    if expr.is_Mul and args[0] == -1:  # a negation, then the product of the rest
        return 1 + (len(args) - 2) + sum(_ops(a) for a in args[1:])
    own = len(args) - 1 if (expr.is_Add or expr.is_Mul) else 1
    return own + sum(_ops(a) for a in args)


def _net_wrench_columns(b: _Builder, R: Mat, p: Vec, w: Vec, wd: Vec, a: Vec) -> tuple:
    """``Yn`` of one link (6 x 10 rows ``[F; M]``): its net wrench's columns in the base frame,
    moment about the base origin, from its motion in its own frame."""
    sw = _skew(w)
    h_map = b.mat(
        [[_skew(wd)[r][c] + sum((sw[r][m] * sw[m][c] for m in range(3)), ZERO) for c in range(3)] for r in range(3)]
    )  # f = h_map h: wd x h + w x (w x h)
    l_w, l_wd = _inertia_map(w), _inertia_map(wd)
    l_map = b.mat(
        [[l_wd[r][c] + sum((sw[r][m] * l_w[m][c] for m in range(3)), ZERO) for c in range(6)] for r in range(3)]
    )  # n = l_map vech(I): I wd + w x (I w)
    f_m = b.vec(_matvec(R, a), "f")  # the mass column: f = m a, n = 0
    cols = [(f_m, b.vec(_cross(p, f_m), "n"))]
    f_h = b.mat(_matmul(R, h_map), "f")
    n_h = b.mat(_matmul(R, [[-x for x in row] for row in _skew(a)]))  # n = h x a = -S(a) h
    for c in range(3):
        f = [f_h[r][c] for r in range(3)]
        cols.append((f, b.vec(_add([n_h[r][c] for r in range(3)], _cross(p, f)), "n")))
    r_l = [[b.let(sum((R[r][m] * l_map[m][c] for m in range(3)), ZERO), "n") for c in range(6)] for r in range(3)]
    cols += [([ZERO] * 3, [r_l[r][c] for r in range(3)]) for c in range(6)]
    return tuple(tuple((cols[c][0] + cols[c][1])[r] for c in range(10)) for r in range(6))


def derive_base_wrench_regressor(chain: Chain) -> SymbolicRegressor:
    """Derive the structured program of a chain, see the module docstring for the equations.

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
    b = _Builder()
    root = _LinkMotion(_eye(), [ZERO] * 3, [ZERO] * 3, [ZERO] * 3, [-g[0], -g[1], -g[2]])
    motions: list[_LinkMotion] = []
    out: dict[str, list] = {k: [] for k in ("R", "p", "w", "wd", "a", "axis", "moment", "Yn")}
    for i, joint in enumerate(chain.joints):
        derivation_step(i + 1, total, "Newton-Euler terms of joint %d of %d, %s", i + 1, n, ascii(joint.name))
        parent = chain.parents[i]
        link = _next_link(b, joint, i, q[i], qd[i], qdd[i], root if parent < 0 else motions[parent])
        motions.append(link)
        R, p, w, wd, a = link.R, link.p, link.w, link.wd, link.a
        # the joint axis (constant in the link frame), base frame
        z = b.vec(_matvec(R, [_num(x) for x in joint.axis]), "z")
        out["axis"].append(tuple(z))
        out["moment"].append(tuple(b.vec(_cross(p, z), "m")))
        for key, value in (
            ("R", tuple(tuple(row) for row in R)),
            ("p", tuple(p)),
            ("w", tuple(w)),
            ("wd", tuple(wd)),
            ("a", tuple(a)),
        ):
            out[key].append(value)
        out["Yn"].append(_net_wrench_columns(b, R, p, w, wd, a))
    # columns that vanish identically become exact zeros (structure the solvers and NONZERO rely on)
    flat = [e for yn in out["Yn"] for row in yn for e in row]
    zero = iter(vanishing((*q, *qd, *qdd, *g), b.lines, flat))
    out["Yn"] = [tuple(tuple(ZERO if next(zero) else e for e in row) for row in yn) for yn in out["Yn"]]
    every = [e for key in out for e in _flatten(out[key])]
    lines, barriers = prune(b.lines, b.barriers, [e for e in every if isinstance(e, sp.Basic)])
    return SymbolicRegressor(
        chain,
        q,
        qd,
        qdd,
        g,
        tuple(lines),
        tuple(barriers),
        **{k: tuple(v) for k, v in out.items()},
        seconds=time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class _LinkMotion:
    """A link's pose in the base frame and its motion in its own frame, as the builder's names.

    Attributes:
        R: base_R_link (3x3). p: base_p_link (3,), the link origin.
        w, wd: the link's angular velocity and acceleration, link frame.
        a: its origin's acceleration less gravity, link frame.
    """

    R: Mat
    p: Vec
    w: Vec
    wd: Vec
    a: Vec


def _next_link(b: _Builder, joint, i: int, q_i: sp.Symbol, qd_i: sp.Symbol, qdd_i: sp.Symbol, parent: _LinkMotion):
    """The motion of joint ``i``'s child link from its parent link's (the forward Newton-Euler recursion), each
    stage bound to a name in ``b`` and the pose and the motion marked as barriers."""
    w, wd, a, R, p = parent.w, parent.wd, parent.a, parent.R, parent.p
    P = [[_num(joint.parent_R_joint[r, c]) for c in range(3)] for r in range(3)]
    r_ = [_num(x) for x in joint.parent_p_joint]
    k = [_num(x) for x in joint.axis]
    revolute = joint.type == "revolute"
    if revolute:
        rq = _axis_rotation(k, *b.trig_pair(i, q_i))
        offset = r_
    else:  # prismatic: translation along the axis, no rotation
        rq = _eye()
        offset = b.vec(_add(r_, _scale(_matvec(P, k), q_i)))
    # the pose: base_p_i at the joint origin, base_R_i = base_R_parent P Rq
    p_new = b.vec(_add(p, _matvec(R, offset)), "p")
    ident = _is_identity(P)
    r_p = R if ident else b.mat(_matmul(R, P))
    R_new = b.mat(_matmul(r_p, rq), "R")
    b.barrier([*p_new, *(x for row in R_new for x in row)])

    def to_link(v: Vec) -> Vec:
        """``(P Rq)^T v``, each stage named."""
        if all(x == 0 for x in v):
            return [ZERO] * 3
        v1 = v if ident else b.vec(_tmatvec(P, v))
        return b.vec(_tmatvec(rq, v1))

    # origin acceleration in the parent frame, then everything rotated into link i
    w_r = b.vec(_cross(w, offset))
    a_new = to_link(b.vec(_add(a, _cross(wd, offset), _cross(w, w_r))))
    w_rot, wd_rot = to_link(w), to_link(wd)
    if revolute:
        w_new = b.vec(_add(w_rot, _scale(k, qd_i)))
        wd_new = b.vec(_add(wd_rot, _scale(k, qdd_i), _cross(w_rot, _scale(k, qd_i))))
    else:
        w_new, wd_new = w_rot, wd_rot
        a_new = b.vec(_add(a_new, _scale(_cross(w_new, k), 2 * qd_i), _scale(k, qdd_i)))
    b.barrier([*w_new, *wd_new, *a_new])
    return _LinkMotion(R_new, p_new, w_new, wd_new, a_new)


def _flatten(x):
    if isinstance(x, (tuple, list)):
        for v in x:
            yield from _flatten(v)
    else:
        yield x
