"""Where an excitation design may move the arm: a floor and a workspace box, at every instant.

**What is kept.** Every moving link frame's origin and every frame welded to a moving
link (the tool flange, a hand: :func:`ineid.robots.kinematics.welded_frames`), the
"points" ``p_P(t)`` in the base frame, stay at ``z >= floor`` and inside the box
``[xmin, xmax] x [ymin, ymax] x [zmin, zmax]`` for every ``t``, not only at samples.

**Between samples.** Each bound is a half-space ``g(t) = s (p_P,a(t) - b) >= 0`` (axis
``a``, sign ``s``). At the instant ``t*`` where ``g`` is smallest, ``g'(t*) = 0`` (the
trajectory is periodic, so every instant is interior), and the nearest point of a grid of
``N`` points per period is within ``dt / 2``, so ``g(t_k) <= g(t*) + A_P dt^2 / 8`` with
``A_P`` a bound of the point's acceleration ``|p_P''|``; the grid constraint
``g(t_k) >= A_P dt^2 / 8`` therefore implies ``g(t) >= 0`` everywhere. ``A_P`` comes from
the joint bounds the design keeps at every instant (``|qd_j| <= w_j``, ``|qdd_j| <= a_j``)
and the reach ``L_Pj`` (:func:`ineid.robots.kinematics.reach`: an upper bound of the
distance from joint ``j`` to the point in every configuration). Differentiating
``p' = sum_j J_j qd_j`` (``J_j = s_j x (p - o_j)`` revolute, ``s_j`` prismatic):

    |p''| <= sum_j a_j l_Pj + sum_j w_j D_Pj,
    D_Pj = 2 W_{j-1} L_Pj + sum_{k >= j} w_k l_Pk     (revolute j; W_{j-1}: sum of w over the
    D_Pj = W_{j-1}                                     revolute joints before j, a bound of
                                                       the angular speed of the axis)

with ``l_Pj = L_Pj`` (revolute) or 1 (prismatic), the sums over the joints that move the point
(in a tree, its link's ancestors: "before j" is j's ancestors). ``N`` is chosen so that the largest
``A_P dt^2 / 8`` is at most :data:`STEP_TOLERANCE` (at most :data:`MAX_GRID` points).

**In IPOPT.** The grid values of each (point, half-space) pair are aggregated into one
smooth constraint, the Kreisselmeier-Steinhauser lower bound of their minimum,
``KS = -(1/rho) log sum_k exp(-rho g_k) <= min_k g_k`` (within ``log(N) / rho`` =
:data:`KS_SLACK` of it), with its exact gradient (the softmax weights times the point
Jacobians, :func:`ineid.robots.kinematics.point_jacobians`, through the linear map from
the design variables to ``q``), on the whole grid: what IPOPT keeps is what the design is
checked against. The capsule pairs of self-collision are kept the same way, with a second-order
margin of their own (:mod:`ineid.excite.collision`). After IPOPT, the values on the grid are
checked; a design that misses them (IPOPT's tolerance) has its amplitudes scaled towards its
mean pose until they hold (or the start is rejected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.errors import ExcitationError
from ineid.excite.callbacks import numpy_function

STEP_TOLERANCE = 0.005
"""m: the largest clearance kept between grid points (sets the grid of the floor and the box)."""
KS_SLACK = 0.001
"""m: how much the smooth aggregate may undershoot the smallest grid clearance."""
COLLISION_TOLERANCE = 0.005
"""m: the largest gap kept between capsules between grid points."""
MAX_GRID = 2048
"""Grid points per period of the floor, workspace and self-collision constraints, at most (beyond it the margins
grow past the tolerances: still kept, only more conservative)."""
_AXES = "xyz"


@dataclass(frozen=True)
class SafetyLimits:
    """A floor and a workspace box in the base frame (m); None: not bounded.

    Attributes:
        floor: every point at ``z >= floor``.
        workspace: ``(xmin, xmax, ymin, ymax, zmin, zmax)``.
    """

    floor: float | None = None
    workspace: tuple[float, float, float, float, float, float] | None = None

    @property
    def active(self) -> bool:
        return self.floor is not None or self.workspace is not None

    def half_spaces(self) -> list[tuple[int, float, float, str]]:
        """``(axis, sign, bound, label)``: ``sign * (p[axis] - bound) >= 0`` each."""
        out = []
        if self.floor is not None:
            out.append((2, 1.0, float(self.floor), f"--floor {self.floor:g}"))
        if self.workspace is not None:
            for a in range(3):
                lo, hi = self.workspace[2 * a], self.workspace[2 * a + 1]
                out.append((a, 1.0, float(lo), f"workspace {_AXES[a]} >= {lo:g}"))
                out.append((a, -1.0, float(hi), f"workspace {_AXES[a]} <= {hi:g}"))
        return out

    def to_dict(self) -> dict:
        return {"floor": self.floor, "workspace": None if self.workspace is None else list(self.workspace)}


def check_limits(model, limits: SafetyLimits) -> None:
    """Refuse limits no motion can keep, before any design (one line each, with the fix).

    Raises:
        ExcitationError: a box whose minimum is not below its maximum, a non-finite number,
            or a floor or box that excludes where a point must be: the origin of a link on the
            root when its joint is revolute (it never moves), or every place a point can reach
            (a ball about the origin of the joint on the root that carries it, of radius its reach).
    """
    from ineid.robots.kinematics import reach, welded_frames

    if limits.floor is not None and not math.isfinite(limits.floor):
        raise ExcitationError(f"--floor must be a finite height in m, got {limits.floor!r}", reason="workspace")
    if limits.workspace is not None:
        box = limits.workspace
        if len(box) != 6 or not all(math.isfinite(v) for v in box):
            raise ExcitationError(
                "--workspace takes six finite numbers XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX (m, base frame)", reason="workspace"
            )
        for a in range(3):
            if not box[2 * a] < box[2 * a + 1]:
                c = _AXES[a].upper()
                raise ExcitationError(
                    f"--workspace: {c}MIN {box[2 * a]:g} is not below {c}MAX {box[2 * a + 1]:g}; give "
                    "XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX with each minimum below its maximum",
                    reason="workspace",
                )
    chain = model.chain
    welded = welded_frames(model.urdf_text, chain, model.locked_joints)
    names = [*model.link_names, *welded.names]
    # per point, the joint on the root that carries it (joint 0 for a serial chain): its origin never moves
    top = np.array([chain.ancestors(int(i))[0] for i in [*range(chain.n_dof), *welded.link]])
    radius = reach(chain, welded)[np.arange(len(top)), top]
    origin = np.array([chain.joints[j].parent_p_joint for j in top])
    for axis, sign, bound, label in limits.half_spaces():
        for first in (chain.joints[j] for j in chain.children(-1)):
            o1 = first.parent_p_joint
            if first.type == "revolute" and sign * (o1[axis] - bound) < 0:
                raise ExcitationError(
                    f"{label} excludes the origin of link {first.link!r}, fixed at {_AXES[axis]} = {o1[axis]:.4g} m "
                    f"by joint {first.name!r} (the mount; base frame, origin at the base link): "
                    f"{'lower --floor' if label.startswith('--floor') else 'widen the --workspace box'} to include it",
                    reason="workspace",
                )
        reach_max = sign * (origin[:, axis] - bound) + radius
        worst = int(np.argmin(reach_max))
        if reach_max[worst] < 0:
            first = chain.joints[top[worst]]
            raise ExcitationError(
                f"{label} excludes everywhere link frame {names[worst]!r} can reach ({_AXES[axis]} within "
                f"{origin[worst, axis]:.4g} +- {radius[worst]:.4g} m of joint {first.name!r}'s origin, base frame); "
                f"{'lower --floor' if label.startswith('--floor') else 'widen the --workspace box'}",
                reason="workspace",
            )


class SafetyConstraints:
    """The floor, box and self-collision constraints of one design problem (module doc): values, Jacobian, clearances.

    Rows: every (point, half-space) pair of the floor and box, then every capsule pair of
    ``pairs`` (:mod:`ineid.excite.collision`).

    Args:
        model: the robot.
        limits: the floor and box.
        qd_max, qdd_max: (n_dof,) the bounds the design keeps at every instant.
        f0, harmonics: the trajectory's base frequency and harmonics.
        rest: (2H, 2H - 2) the rest basis; ``mid, half, v_scale`` the map of
            :class:`ineid.excite.trajectory.DesignProblem`.
        pairs: the capsule pairs kept apart, or None.
    """

    def __init__(
        self,
        model,
        limits: SafetyLimits,
        qd_max,
        qdd_max,
        f0: float,
        harmonics: int,
        rest,
        mid,
        half,
        v_scale,
        pairs=None,
    ) -> None:
        from ineid.data.synthesis.trajectory import state_matrices
        from ineid.robots.kinematics import reach, welded_frames

        self.model, self.limits, self.chain = model, limits, model.chain
        self.pairs = pairs if pairs is not None and pairs.n else None
        self._asked = pairs  # None: --no-self-collision
        self.welded = welded_frames(model.urdf_text, self.chain, model.locked_joints)
        n = self.chain.n_dof
        self.spaces = limits.half_spaces()
        self.names = (*model.link_names, *self.welded.names) if self.spaces else ()
        self.point_link = np.r_[np.arange(n), self.welded.link].astype(int)[: len(self.names)]
        self.accel = acceleration_bounds(
            self.chain, reach(self.chain, self.welded)[: len(self.names)], self.point_link, qd_max, qdd_max
        )
        period = 1.0 / f0
        grid = math.ceil(period * math.sqrt(max(self.accel.max(initial=0.0), 0.0) / (8.0 * STEP_TOLERANCE)))
        grid = int(min(max(grid, 32 * harmonics), MAX_GRID))
        pair_accel = self.pairs.accelerations(qd_max, qdd_max) if self.pairs is not None else np.zeros(0)
        while self.pairs is not None and grid < MAX_GRID:
            if self.pairs.margins(period / grid, pair_accel).max() <= COLLISION_TOLERANCE:
                break
            grid = min(math.ceil(grid * 1.25), MAX_GRID)
        self.grid = grid
        dt = period / self.grid
        self.margin = self.accel * dt * dt / 8.0  # (P,) m
        self.pair_margin = self.pairs.margins(dt, pair_accel) if self.pairs is not None else np.zeros(0)
        self.rho = math.log(self.grid) / KS_SLACK
        self.n, self.nz = n, 2 * harmonics - 1
        self.mid, self.half, self.v_scale = mid, half, v_scale
        self.pq = state_matrices(np.arange(self.grid) * dt, f0, harmonics)[0] @ rest  # (N, 2H-2)
        n_pairs = self.pairs.n if self.pairs is not None else 0
        self._moves = np.r_[np.repeat(~self._static_points(), len(self.spaces)), np.ones(n_pairs, dtype=bool)]
        self._last: tuple[bytes, tuple] | None = None

    def _static_points(self, samples: int = 16) -> np.ndarray:
        """(P,) True for a point no joint moves (it lies on the axis of every joint before it, as the first links'
        origins often do): its rows' Jacobian is zero, so :meth:`jacobian` skips them. Found on ``samples``
        random configurations within the joint limits (the same every time)."""
        from ineid.robots.kinematics import frame_points

        if not self.spaces:
            return np.zeros(0, dtype=bool)
        lo = np.clip([j.q_lower for j in self.chain.joints], -math.pi, None)  # continuous joints: one turn
        hi = np.clip([j.q_upper for j in self.chain.joints], None, math.pi)
        q = lo + (hi - lo) * np.random.default_rng(0).random((samples, self.n))
        pts = frame_points(self.chain, q, self.welded)[:, : len(self.names)]
        return np.ptp(pts, axis=0).max(axis=1) <= 1e-12 * max(1.0, float(np.abs(pts).max()))

    @property
    def n_constraints(self) -> int:
        return len(self.names) * len(self.spaces) + (self.pairs.n if self.pairs is not None else 0)

    def labels(self) -> list[str]:
        """One per constraint row: ``"<point> <half-space>"``, then ``"<body> and <body> self-collision"``."""
        out = [f"{p!r} {s[3]}" for p in self.names for s in self.spaces]
        return out + ([f"{p} self-collision" for p in self.pairs.labels()] if self.pairs is not None else [])

    def grid_q(self, x: np.ndarray) -> np.ndarray:
        z = np.asarray(x, dtype=np.float64).reshape(self.n, self.nz)
        return self.mid + self.half * z[:, 0] + self.pq @ (z[:, 1:].T * self.v_scale)

    def clearances(self, q: np.ndarray) -> np.ndarray:
        """(T, C) every row's clearance at ``q`` (T, n_dof), m, no margins: ``sign * (p[axis] - bound)``
        of each point and half-space, then each capsule pair's gap."""
        return self._measured(np.atleast_2d(q))[0]

    def _measured(self, q: np.ndarray, broad: bool = False):
        """``(clearances (T, C), points (T, P, 3) or None, pair points (c1, c2) or None, poses)``: the clearances,
        the points they were measured at (the frames' origins; each pair's two points) and the links' poses at
        ``q``; with ``broad`` a capsule pair far apart throughout takes its bounding spheres' distance, a lower
        bound (what the optimizer keeps)."""
        from ineid.robots.kinematics import link_poses

        poses = link_poses(self.chain, q)  # shared by the points and the capsules
        parts, pts, pair_points = [], None, None
        if self.spaces:
            r, p = poses
            w = self.welded
            pts = p
            if len(w.names):
                pts = np.concatenate([p, p[:, w.link] + np.einsum("tkij,kj->tki", r[:, w.link], w.offset)], axis=1)
            parts.append(np.stack([s * (pts[..., a] - b) for a, s, b, _ in self.spaces], axis=-1).reshape(len(q), -1))
        if self.pairs is not None:
            gap, c1, c2 = self.pairs.closest(q, poses, broad)
            parts.append(gap)
            pair_points = (c1, c2)
        return np.concatenate(parts, axis=1), pts, pair_points, poses

    def margins(self) -> np.ndarray:
        """(C,) the clearance each row keeps on the grid (module doc), m."""
        return np.r_[np.repeat(self.margin, len(self.spaces)), self.pair_margin]

    def _evaluate(self, x: np.ndarray):
        key = np.asarray(x, dtype=np.float64).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        q = self.grid_q(x)
        clear, pts, pair_points, poses = self._measured(q, broad=True)
        g = clear - self.margins()  # (N, C)
        gmin = g.min(axis=0)
        e = np.exp(-self.rho * (g - gmin))
        total = e.sum(axis=0)
        ks = gmin - np.log(total) / self.rho
        self._last = (key, (q, g, ks, e / total, pts, pair_points, poses))
        return self._last[1]

    def breaks(self, x: np.ndarray, every: int = 8) -> bool:
        """True when a grid clearance of ``x`` is already below its margin on every ``every``-th grid point: then
        :meth:`values` is negative too (it is below every grid value), found at a fraction of the cost."""
        if self._last is not None and self._last[0] == np.asarray(x, dtype=np.float64).tobytes():
            return bool(np.any(self._last[1][2] <= 0))
        z = np.asarray(x, dtype=np.float64).reshape(self.n, self.nz)
        q = self.mid + self.half * z[:, 0] + self.pq[::every] @ (z[:, 1:].T * self.v_scale)
        return bool(np.any(self._measured(q, broad=True)[0] - self.margins() < 0))

    def values(self, x: np.ndarray) -> np.ndarray:
        """(C,) the smooth lower bounds of the smallest clearance less margin on the grid (what IPOPT keeps >= 0;
        positive implies :meth:`grid_slack` positive)."""
        return self._evaluate(x)[2]

    def grid_slack(self, x: np.ndarray) -> np.ndarray:
        """(C,) the smallest grid clearance less margin of each constraint (>= 0: kept at every instant)."""
        return self._evaluate(x)[1].min(axis=0)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """(C, n_dof (2H - 1)) the exact derivative of :meth:`values` (where the closest points are unique).

        Only the (grid point, row) pairs whose softmax weight exceeds ``1e-10`` are differentiated: the others
        change the derivative by less than that fraction of a grid point's.
        """
        from ineid.robots.kinematics import entry_jacobians

        q, _, _, w, pts, pair_points, (r, p) = self._evaluate(x)
        t, c = np.nonzero((w > 1e-10) & self._moves)  # (E,) entries: grid point, row (a row no joint moves: zero)
        dq = np.zeros((len(t), self.n))
        n_points = len(self.names) * len(self.spaces)
        on_point = c < n_points
        if on_point.any():
            tp, cp = t[on_point], c[on_point]
            point, space = np.divmod(cp, len(self.spaces))
            axes = np.array([a for a, _, _, _ in self.spaces])[space]
            signs = np.array([s for _, s, _, _ in self.spaces])[space]
            jac = entry_jacobians(self.chain, q[tp], self.point_link[point], pts[tp, point], (r[tp], p[tp]))
            dq[on_point] = signs[:, None] * jac[np.arange(len(tp)), axes]
        if (~on_point).any():
            tc, pair = t[~on_point], c[~on_point] - n_points
            c1, c2 = pair_points
            dq[~on_point] = self.pairs.entry_gradient(q[tc], pair, c1[tc, pair], c2[tc, pair], (r[tc], p[tc]))
        dq *= w[t, c][:, None]  # d ks_c / d q(t_k), weighted
        du = np.zeros((self.n_constraints, self.n))
        np.add.at(du, c, self.half * dq)
        dalpha = np.zeros((self.n_constraints, self.n, self.nz - 1))
        np.add.at(dalpha, c, dq[:, :, None] * self.pq[t][:, None, :] * self.v_scale[None, :, None])
        return np.concatenate([du[..., None], dalpha], axis=-1).reshape(self.n_constraints, self.n * self.nz)

    def describe(self) -> dict:
        """The settings and guarantees, JSON-able (recorded in the design)."""
        out = dict(
            self.limits.to_dict(),
            points=list(self.names),
            grid_points_per_period=self.grid,
            margin_between_samples=self.margin.tolist(),
            acceleration_bound=self.accel.tolist(),
        )
        out["self_collision"] = (
            None
            if self._asked is None
            else dict(self._asked.describe(), margin_between_samples=self.pair_margin.tolist())
        )
        return out


def acceleration_bounds(chain, reach_m: np.ndarray, point_link: np.ndarray, qd_max, qdd_max) -> np.ndarray:
    """(P,) bounds of ``|p_P''|`` (m/s^2) over every motion within ``|qd| <= qd_max``, ``|qdd| <= qdd_max`` (module
    doc)."""
    w, a = np.asarray(qd_max, float), np.asarray(qdd_max, float)
    revolute = np.array([j.type == "revolute" for j in chain.joints])
    moves = chain.moved_by()  # [i, j]: joint j moves link i (an ancestor in a tree, j <= i in a serial chain)
    spin = np.where(revolute, w, 0.0)
    omega_before = np.array([spin[moves[j]].sum() - spin[j] for j in range(chain.n_dof)])  # over j's ancestors
    out = np.zeros(len(point_link))
    for k, i in enumerate(point_link):
        moved = moves[int(i)] if i >= 0 else np.zeros(chain.n_dof, dtype=bool)
        ell = np.where(revolute, reach_m[k], 1.0) * moved
        total = float(a @ ell)
        for j in np.flatnonzero(moved):
            if revolute[j]:
                d = 2.0 * omega_before[j] * reach_m[k, j] + float(w[j:] @ ell[j:])
            else:
                d = omega_before[j]
            total += w[j] * d
        out[k] = total
    return out


def make_safe(safety: SafetyConstraints, x: np.ndarray, steps: int = 8) -> np.ndarray | None:
    """``x`` if its constraints' smooth lower bounds are positive (:meth:`SafetyConstraints.values`: then every
    grid clearance keeps its margin), else the largest scaling of its amplitudes about its mean pose that makes
    them so (bisection to ``2^-steps``; the joint bounds and rest stay kept), or None when the mean pose fails."""
    z = np.asarray(x, dtype=np.float64).reshape(safety.n, safety.nz)

    def scaled(s: float) -> np.ndarray:
        return np.concatenate([z[:, :1], z[:, 1:] * s], axis=1).ravel()

    def keeps(y: np.ndarray) -> bool:  # a sparse subset of the grid first: most failing scales fail there
        return not safety.breaks(y) and bool(np.all(safety.values(y) > 0))

    if keeps(x):
        return np.asarray(x, dtype=np.float64)
    if not keeps(scaled(0.0)):
        return None
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if keeps(scaled(mid)) else (lo, mid)
    return scaled(lo)


def casadi_constraint(safety: SafetyConstraints):
    """A CasADi function ``x -> (C,)`` of :meth:`SafetyConstraints.values` with its exact Jacobian (callbacks)."""
    return numpy_function(
        "workspace_constraints", safety.n * safety.nz, safety.n_constraints, safety.values, safety.jacobian
    )


def verify(safety: SafetyConstraints, q: np.ndarray) -> dict:
    """The smallest clearance over samples ``q`` (T, n_dof) (no margins): m, which point and bound.

    Returns:
        ``{"min_clearance": m, "constraint": label}``; negative: a bound is violated.
    """
    c = safety.clearances(q).min(axis=0)  # (C,)
    k = int(np.argmin(c))
    return {"min_clearance": float(c[k]), "constraint": safety.labels()[k]}


def bound_sources(model) -> dict[str, tuple[str, str]]:
    """Per joint name, where its velocity and acceleration bounds come from: ``"URDF"`` or ``"default"``
    (``<limit velocity>`` missing or zero, no ``<ineid acceleration>``: :mod:`ineid.robots.urdf`'s defaults)."""
    import xml.etree.ElementTree as ET

    out = {}
    for j in ET.fromstring(model.urdf_text).findall("joint"):  # not the <joint> of a <transmission>
        limit, acc = j.find("limit"), j.find("ineid")
        try:
            velocity = float(limit.get("velocity", "0")) if limit is not None else 0.0
        except ValueError:
            velocity = 0.0
        out[j.get("name")] = (
            "URDF" if velocity > 0 else "default",
            "URDF" if acc is not None and acc.get("acceleration") else "default",
        )
    return {name: out.get(name, ("default", "default")) for name in model.joint_names}
