"""Self-collision of an excitation design: bounding capsules of non-adjacent bodies kept apart at every instant.

Bodies are the root (the fixture, index -1) and the moving links, each with the bounding
capsules of its URDF collision geometry (:func:`ineid.robots.collision.body_capsules`).
A pair of capsules is checked when their bodies are not adjacent: not the same body, and neither the
other's parent in the tree (for a serial chain, chain indices two or more apart; in a tree, two
branches' links are checked against each other, siblings included). Pairs whose capsules are never
apart in a sample of the joint space (a link two joints on, fingers on a palm: the shapes are too
coarse to tell a collision from a joint's neighbourhood) are left out by
:func:`ineid.excite.feasibility.always_touching` through :meth:`CollisionPairs.without`, one line
each in the notes.

**Between samples.** With ``D(t) = min |P1 - P2|^2`` over the points ``P1, P2`` of the two segments,
the pair is clear when ``D >= (r1 + r2)^2``. ``D`` is the minimum of a family of smooth functions of
``t`` (one per pair of segment parameters), so at its smallest instant ``t*`` the member that
attains it has zero slope too, and between ``t*`` and the nearest grid point (within ``dt / 2``) it
grows by at most ``A_D dt^2 / 8`` with ``A_D = 2 V^2 + 2 (r1 + r2 + V dt / 2) A`` (its second
derivative ``2 |v|^2 + 2 p . a``, with ``|p| < r1 + r2 + V dt / 2`` wherever a violation could
hide): ``V`` bounds the relative speed of the two points (``V1 + V2``, ``V = sum_j w_j l_j`` with
``w_j`` the velocity bound of joint ``j`` that moves the body (before it; an ancestor in a tree) and
``l_j`` the reach from joint ``j`` to the body's origin plus the segment's farthest end, 1 for a
prismatic joint) and ``A`` their relative acceleration
(:func:`ineid.excite.safety.acceleration_bounds` at the same reach). So a grid clearance of
``sqrt((r1 + r2)^2 + A_D dt^2 / 8) - (r1 + r2)`` at every grid point
(:meth:`CollisionPairs.margins`) keeps the capsules apart at every instant: a second-order bound, a
few millimetres on a grid of about a thousand points per period.
"""

from __future__ import annotations

import copy
from itertools import product

import numpy as np

FAR = 0.1
"""m: pairs whose bounding spheres are this far apart at a grid point take that distance there (a lower bound of
their gap: cheaper, and far from where the aggregate of the grid values is decided)."""


class CollisionPairs:
    """The checked capsule pairs of a model, their clearances and derivatives (module doc).

    Attributes:
        capsules: every capsule; ``pairs`` (C, 2) indices into it.
        notes: one line per body without geometry, mesh skipped, or pair of bodies left out.
        excluded: of those, the lines of the pairs left out (:meth:`without`).
        speed: (C,) ``V1 + V2`` per pair, m/s.
    """

    def __init__(self, model, qd_max) -> None:
        from ineid.robots.collision import body_capsules
        from ineid.robots.kinematics import reach

        self.chain = model.chain
        found = body_capsules(model.urdf_text, self.chain, model.urdf_path, model.locked_joints)
        self.capsules, self.notes = found.capsules, list(found.notes)
        self.excluded: list[str] = []
        caps = self.capsules
        n = self.chain.n_dof
        parents = (*self.chain.parents, -2)  # parents[-1]: the root body's, none

        def adjacent(a: int, b: int) -> bool:  # the same body, or parent and child in the tree
            return a == b or parents[a] == b or parents[b] == a

        pairs = [
            (i, k) for i, k in product(range(len(caps)), repeat=2) if i < k and not adjacent(caps[i].link, caps[k].link)
        ]
        self.pairs = np.array(pairs, dtype=int).reshape(-1, 2)
        w = np.asarray(qd_max, dtype=np.float64)
        origin_reach = reach(self.chain)  # (n, n)
        revolute = np.array([j.type == "revolute" for j in self.chain.joints])
        moves = self.chain.moved_by()  # [i, j]: joint j moves link i
        speed = np.zeros(len(caps))
        self._reach = np.zeros((len(caps), n))  # m, from each joint to the capsule's farthest point
        for c, cap in enumerate(caps):
            if cap.link < 0:
                continue
            ends = max(np.linalg.norm(cap.a), np.linalg.norm(cap.b))
            moved = moves[cap.link]
            self._reach[c] = (origin_reach[cap.link] + ends) * moved
            ell = np.where(revolute, self._reach[c], 1.0) * moved
            speed[c] = float(w @ ell)
        self.speed = speed[self.pairs].sum(axis=1) if len(self.pairs) else np.zeros(0)
        self.radii = np.array([caps[i].radius + caps[k].radius for i, k in self.pairs]).reshape(-1)
        self._links = np.array([c.link for c in caps], dtype=int)
        # each capsule's segment ends and middle in its link's frame (K, 3 points, 3)
        self._local3 = np.array([[c.a, c.b, (c.a + c.b) / 2.0] for c in caps], dtype=np.float64).reshape(-1, 3, 3)
        self._sphere = np.array([np.linalg.norm(c.b - c.a) / 2.0 + c.radius for c in caps])  # about the middle

    def without(self, drop, lines) -> CollisionPairs:
        """These pairs less those where ``drop`` (C,) is true, with ``lines`` (why) added to the notes and
        to :attr:`excluded`."""
        keep = ~np.asarray(drop, dtype=bool)
        out = copy.copy(self)
        out.pairs, out.speed, out.radii = self.pairs[keep], self.speed[keep], self.radii[keep]
        out.notes, out.excluded = [*self.notes, *lines], [*self.excluded, *lines]
        return out

    @property
    def n(self) -> int:
        return len(self.pairs)

    def accelerations(self, qd_max, qdd_max) -> np.ndarray:
        """(C,) a bound of the relative acceleration of any two points of each pair's segments, m/s^2."""
        from ineid.excite.safety import acceleration_bounds

        links = np.array([c.link for c in self.capsules], dtype=int)
        moving = links >= 0
        acc = np.zeros(len(self.capsules))
        if moving.any():
            acc[moving] = acceleration_bounds(self.chain, self._reach[moving], links[moving], qd_max, qdd_max)
        return acc[self.pairs].sum(axis=1) if len(self.pairs) else np.zeros(0)

    def margins(self, dt: float, accel: np.ndarray) -> np.ndarray:
        """(C,) the clearance each pair keeps on a grid of step ``dt`` s (module doc), m; ``accel`` from
        :meth:`accelerations`."""
        r, v = self.radii, self.speed
        a_d = 2.0 * v * v + 2.0 * (r + v * dt / 2.0) * accel
        return np.sqrt(r * r + a_d * dt * dt / 8.0) - r

    def labels(self) -> list[str]:
        return [f"{self.capsules[i].name!r} and {self.capsules[k].name!r}" for i, k in self.pairs]

    def _ends(self, q: np.ndarray, poses=None):
        """Every capsule's segment ends and middle (T, K, 3) each, base frame, at ``q`` (T, n_dof); ``poses``: the
        links' ``(R, p)`` at ``q`` when already computed (:func:`ineid.robots.kinematics.link_poses`)."""
        from ineid.robots.kinematics import link_poses

        r, p = link_poses(self.chain, q) if poses is None else poses
        link = self._links
        moving = np.flatnonzero(link >= 0)
        local = self._local3[moving]  # (K', 3 points, 3)
        rk = r[:, link[moving]]  # (T, K', 3, 3)
        # R @ local, column by column (three broadcast products beat a batched product of 3 x 3 matrices)
        moved = p[:, link[moving], None, :] + sum(rk[:, :, None, :, j] * local[None, :, :, j, None] for j in range(3))
        if len(moving) == len(link):
            out = moved
        else:  # capsules of the root body stay where they are
            out = np.broadcast_to(self._local3, (len(q), *self._local3.shape)).copy()  # (T, K, 3 points, 3)
            out[:, moving] = moved
        return out[:, :, 0], out[:, :, 1], out[:, :, 2]

    def _clearance(self, q: np.ndarray, pairs: np.ndarray, closest: bool = False, poses=None, broad: bool = False):
        """The gap of each pair at ``q`` (T, C), or with ``broad`` a lower bound of it for a pair far apart at
        every ``q`` (broad phase: the bounding spheres of the two capsules, centre the segment's middle, more than
        :data:`FAR` apart throughout), and with ``closest`` the two points whose distance it is (the closest
        points, or the spheres' centres)."""
        from ineid.robots.collision import closest_on_segments

        a, b, middle = self._ends(q, poses)
        i, k = pairs[:, 0], pairs[:, 1]
        m1, m2 = middle[:, i], middle[:, k]
        diff = m1 - m2
        gap = np.sqrt(np.einsum("tci,tci->tc", diff, diff)) - (self._sphere[i] + self._sphere[k])  # <= the gap
        near = np.flatnonzero((gap < FAR).any(axis=0) | (not broad))  # whole pairs: smooth in the trajectory
        if len(near):
            i, k = i[near], k[near]
            direction = b - a  # (T, K, 3), each capsule once
            d, n1, n2 = closest_on_segments(a[:, i], direction[:, i], a[:, k], direction[:, k])
            gap[:, near] = d - (self.radii if pairs is self.pairs else self.radii_of(pairs))[near]
            if closest:
                m1[:, near], m2[:, near] = n1, n2
        return (gap, m1, m2) if closest else (gap,)

    def radii_of(self, pairs: np.ndarray) -> np.ndarray:
        """(C,) ``r1 + r2`` of each pair of capsule indices ``pairs`` (C, 2)."""
        return np.array([self.capsules[i].radius + self.capsules[k].radius for i, k in pairs]).reshape(-1)

    def clearances(self, q: np.ndarray, poses=None) -> np.ndarray:
        """(T, C) the gap between the two capsules of each pair at ``q`` (T, n_dof), m (negative: they overlap);
        ``poses``: the links' ``(R, p)`` at ``q`` when already computed."""
        return self._clearance(np.atleast_2d(q), self.pairs, poses=poses)[0]

    def entry_gradient(self, q: np.ndarray, pair: np.ndarray, c1: np.ndarray, c2: np.ndarray, poses=None) -> np.ndarray:
        """(E, n_dof) ``d clearance / d q`` of pair ``pair[e]`` at ``q[e]`` (E, n_dof), its two points ``c1[e]``,
        ``c2[e]`` (E, 3) those :meth:`clearances` measured between (the unit vector between them along their
        Jacobians); ``poses``: the links' poses at ``q`` when already computed."""
        from ineid.robots.kinematics import entry_jacobians, link_poses

        diff = c1 - c2
        norm = np.linalg.norm(diff, axis=-1, keepdims=True)
        unit = np.where(norm > 0, diff / np.where(norm > 0, norm, 1.0), 0.0)
        links = self._links[self.pairs[pair]]  # (E, 2)
        if poses is None:
            poses = link_poses(self.chain, q)
        j1 = entry_jacobians(self.chain, q, links[:, 0], c1, poses)  # (E, 3, n); zero for the root body
        j2 = entry_jacobians(self.chain, q, links[:, 1], c2, poses)
        return np.einsum("ei,eij->ej", unit, j1 - j2)

    def closest(self, q: np.ndarray, poses=None, broad: bool = False):
        """``(gap (T, C), c1, c2 (T, C, 3))``: :meth:`clearances` and the two points each gap is measured between;
        with ``broad``, a lower bound of the gap of pairs far apart at every ``q`` (their spheres' distance)."""
        return self._clearance(np.atleast_2d(q), self.pairs, closest=True, poses=poses, broad=broad)

    def describe(self) -> dict:
        return {
            "pairs": self.labels(),
            "capsules": [{"body": c.name, "shape": c.shape, "radius": c.radius} for c in self.capsules],
            "notes": self.notes,
            "excluded": self.excluded,
        }
