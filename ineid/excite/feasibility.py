"""Whether an excitation design's floor, box and self-collision can be kept at all: a sample of the joint space
checked before any optimisation (a fraction of a second, no IPOPT).

**The sample** (:func:`sample_poses`). The rest pose (the URDF's zero configuration, each
joint clipped into the design's tightened position bounds), the middle of those bounds,
and ``n`` (default :data:`SAMPLES`) poses drawn uniformly within them, seeded.

**Pairs always touching** (:func:`always_touching`). A capsule pair whose capsules are less
than :data:`APART` apart in every sampled pose (a link two joints on, fingers on a palm) is
one the bounding shapes cannot tell from a joint's neighbourhood: each grid point keeps a
margin of up to :data:`ineid.excite.safety.COLLISION_TOLERANCE` between the capsules (a
little more where the grid is capped), so such a pair would leave the design a sliver of
the joint space to move in, or none, while the links themselves need not touch at all.
Such pairs are left out, one line per pair of bodies. A pair that is that far apart
somewhere is kept wherever the middle of the ranges puts it: the design can avoid it.
Measured with the default design (10 s, 5 harmonics, ``--floor 0``): on xArm7 two pairs
are never 1.7 cm apart; keeping them leaves about 1 % of the sampled poses feasible,
leaving them out 28 %; on SO-101 (gripper locked) a capsule pair of ``lower_arm_link`` and
``gripper_link`` is never 1.2 mm apart, and kept, it leaves no pose feasible.

**Feasible poses** (:func:`check_feasibility`). A pose is feasible when every kept row of
:class:`ineid.excite.safety.SafetyConstraints` holds with the margin its grid keeps
(``clearances(q) - margins() >= 0``). The trajectory at rest in a feasible pose keeps every
bound at every instant, so a design exists as soon as one pose is feasible; the feasible
poses are returned (the design's mean poses are drawn from them) and an ask that none
keeps is refused at once, naming the bound that fails most and what to change.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ineid.errors import ExcitationError

SAMPLES = 2048
"""Uniform poses of the sample (the rest pose and the middle of the ranges come on top)."""
APART = 0.02
"""m: a capsule pair never this far apart in the sample is left out (module doc; four times
:data:`ineid.excite.safety.COLLISION_TOLERANCE`, the most a grid point keeps between capsules)."""


@dataclass(frozen=True)
class PoseSample:
    """The sampled poses (T, n_dof): the rest pose, the middle of the bounds, then the uniform ones.

    Attributes:
        clipped: the joints whose zero lies outside the bounds (the rest pose has them at the nearest bound).
        started: ``time.perf_counter()`` when the sample was drawn (:attr:`Feasibility.seconds` counts from it).
    """

    poses: np.ndarray
    clipped: tuple[str, ...]
    started: float

    @property
    def rest_pose(self) -> np.ndarray:
        return self.poses[0]


def sample_poses(model, q_lo, q_hi, rng: np.random.Generator, n: int = SAMPLES) -> PoseSample:
    """The rest pose, the middle of ``[q_lo, q_hi]`` (n_dof,) each, and ``n`` uniform poses within (module doc)."""
    started = time.perf_counter()
    lo, hi = np.asarray(q_lo, dtype=np.float64), np.asarray(q_hi, dtype=np.float64)
    rest = np.clip(np.zeros_like(lo), lo, hi)
    clipped = tuple(name for name, q in zip(model.joint_names, rest, strict=True) if q != 0.0)
    poses = np.concatenate([rest[None], 0.5 * (lo + hi)[None], rng.uniform(lo, hi, (int(n), len(lo)))])
    return PoseSample(poses, clipped, started)


def always_touching(pairs, sample: PoseSample):
    """``pairs`` (:class:`ineid.excite.collision.CollisionPairs`) less those whose capsules are less than
    :data:`APART` apart in every sampled pose, with one line per pair of bodies left out (module doc)."""
    if not pairs.n:
        return pairs
    clear = pairs.clearances(sample.poses)  # (T, C)
    drop = clear.max(axis=0) < APART
    t = len(sample.poses)
    labels = pairs.labels()
    groups: dict[str, list[int]] = {}
    for c in np.flatnonzero(drop):
        groups.setdefault(labels[c], []).append(int(c))
    lines = []
    for bodies, members in groups.items():
        overlap = int((clear[:, members] < 0).any(axis=1).sum())  # the bodies' shapes overlap
        of = labels.count(bodies)
        count = f" ({len(members)} of their {of} capsule pairs)" if len(members) < of else ""
        count = count or (f" ({of} capsule pairs)" if of > 1 else "")
        where = (
            f"overlap in every one of the {t:,} sampled poses"
            if overlap == t
            else f"overlap in {overlap:,} of the {t:,} sampled poses and are never {APART * 100:g} cm apart"
        )
        lines.append(f"{bodies}{count}: {where} (bounding shapes too coarse to tell): not checked")
    return pairs.without(drop, lines)


@dataclass(frozen=True)
class Feasibility:
    """What the sample says of one design problem (module doc).

    Attributes:
        poses: (K, n_dof) the feasible sampled poses (K >= 1): the rest pose first and the middle of the
            bounds next when they are feasible.
        n_sampled: poses checked.
        rest_pose: (n_dof,) the rest pose; ``rest_violations`` the constraints (their labels) it breaks,
            grid margin included; ``rest_clipped`` the joints whose zero lies outside the bounds.
        excluded: one line per pair of bodies left out of the self-collision check.
        seconds: from drawing the sample to the end of the check.
    """

    poses: np.ndarray
    n_sampled: int
    rest_pose: np.ndarray
    rest_violations: tuple[str, ...]
    rest_clipped: tuple[str, ...]
    excluded: tuple[str, ...]
    seconds: float

    @property
    def share(self) -> float:
        return len(self.poses) / self.n_sampled

    def to_dict(self) -> dict:
        return {
            "sampled": self.n_sampled,
            "feasible": len(self.poses),
            "rest_pose": self.rest_pose.tolist(),
            "rest_violations": list(self.rest_violations),
            "rest_clipped": list(self.rest_clipped),
            "excluded": list(self.excluded),
            "seconds": self.seconds,
        }


def check_feasibility(sample: PoseSample, safety, pairs=None) -> Feasibility:
    """The feasible poses of ``sample`` under ``safety`` (:class:`ineid.excite.safety.SafetyConstraints`;
    None: nothing bounds the poses), and the rest pose's violations (module doc).

    Args:
        sample: from :func:`sample_poses`.
        safety: the floor, box and self-collision constraints of the design.
        pairs: the capsule pairs after :func:`always_touching` (their lines of pairs left out), or None.

    Raises:
        ExcitationError: (``infeasible_workspace``) no sampled pose keeps every constraint; one line naming
            the constraint that fails most and what to change.
    """
    excluded = tuple(pairs.excluded) if pairs is not None else ()
    poses = sample.poses
    if safety is None or not safety.n_constraints:
        ok = np.ones(len(poses), dtype=bool)
        rest_violations: tuple[str, ...] = ()
    else:
        raw = safety.clearances(poses)
        slack = raw - safety.margins()
        good = slack >= 0  # (T, C)
        ok = good.all(axis=1)
        if not ok.any():
            raise ExcitationError(_refusal(safety, raw, slack), reason="infeasible_workspace")
        labels = safety.labels()
        rest_violations = tuple(dict.fromkeys(labels[c] for c in np.flatnonzero(~good[0])))
    return Feasibility(
        poses[ok],
        len(poses),
        sample.rest_pose.copy(),
        rest_violations,
        sample.clipped,
        excluded,
        time.perf_counter() - sample.started,
    )


# -- the one line of a refusal --------------------------------------------------------------

_FIX = {"floor": "lower --floor", "box": "widen the --workspace box", "pair": "pass --no-self-collision"}
_KEEPS = {  # what the other rows keep: of another kind, of the same kind
    "floor": ("the floor", "every other point above the floor"),
    "box": ("the workspace box", "every other point in the box"),
    "pair": ("the capsules apart", "the other capsule pairs apart"),
}


def _row(safety, r: int) -> tuple[str, str, tuple]:
    """Row ``r``'s kind (``floor``, ``box``, ``pair``), what failing it says, and its point, axis, sign, bound
    (a pair: its label)."""
    per_point = len(safety.names) * len(safety.spaces)
    if r >= per_point:
        label = safety.pairs.labels()[r - per_point]
        return "pair", f"{label} overlap (self-collision)", (label,)
    name = safety.names[r // len(safety.spaces)]
    axis, sign, bound, label = safety.spaces[r % len(safety.spaces)]
    if label.startswith("--floor"):
        return "floor", f"{name!r} is below {label}", (name, axis, sign, bound, label)
    return "box", f"{name!r} is outside {label}", (name, axis, sign, bound, label)


def _everywhere(safety, r: int, raw: np.ndarray, n: int) -> str:
    """The line of row ``r`` failing in every pose (``raw`` (T,) its clearances without margin)."""
    kind, _, what = _row(safety, r)
    best = float(raw.max())
    margin = float(safety.margins()[r])
    within = f", and the grid keeps {margin:.2g} m from it" if best >= 0 else ""
    if kind == "pair":
        fix = "pass --no-self-collision if those shapes are too coarse"
        if best < 0:
            return (
                f"{what[0]} self-collision: the bounding capsules overlap (by {-best:.2g} m or more) in every one of "
                f"the {n:,} sampled poses; {fix}"
            )
        return (
            f"{what[0]} self-collision: the bounding capsules are never {margin:.2g} m apart (the margin kept between "
            f"grid points) in any of the {n:,} sampled poses (at most {best:.2g} m); {fix}"
        )
    name, axis, sign, bound, label = what
    extreme = f"{'xyz'[axis]} at {'most' if sign > 0 else 'least'} {bound + sign * best:.3g} m"
    side = "below" if kind == "floor" else "outside"
    return f"{label}: {name!r} is {side} it in every one of the {n:,} sampled poses ({extreme}{within}); {_FIX[kind]}"


def _refusal(safety, raw: np.ndarray, slack: np.ndarray) -> str:
    """The one line of an ask no sampled pose keeps: the row failing everywhere that misses most, else the row
    failing most, in every pose that keeps the others (or with the next rows failing most)."""
    n = len(slack)
    fails = (slack < 0).sum(axis=0)
    everywhere = np.flatnonzero(fails == n)
    if everywhere.size:
        r = int(everywhere[np.argmin(slack[:, everywhere].max(axis=0))])
        return _everywhere(safety, r, raw[:, r], n)
    order = np.argsort(-fails, kind="stable")
    r = int(order[0])
    kind, says, _ = _row(safety, r)
    kinds = {_row(safety, c)[0] for c in range(slack.shape[1]) if c != r}
    fixes = " or ".join(dict.fromkeys(_FIX[k] for k in (kind, *sorted(kinds))))
    others = np.delete(slack >= 0, r, axis=1).all(axis=1)
    if others.any():
        keeps = " and ".join(_KEEPS[k][k == kind] for k in sorted(kinds))
        return (
            f"no sampled pose keeps every bound: {says} in every one that keeps {keeps} ({int(others.sum()):,} of "
            f"the {n:,}); {fixes}"
        )
    named = ", ".join(f"{_row(safety, int(c))[1]} in {int(fails[c]):,}" for c in order[:3])
    return f"no one of the {n:,} sampled poses keeps every bound at once: {named}; {fixes}"
