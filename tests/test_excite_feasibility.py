"""Feasibility up front: the sampled joint space against the floor, the box and the capsule pairs, before IPOPT."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import ineid
from ineid.errors import ExcitationError
from ineid.excite.collision import CollisionPairs
from ineid.excite.feasibility import APART, always_touching, check_feasibility, sample_poses
from ineid.excite.safety import SafetyConstraints, SafetyLimits, check_limits
from ineid.excite.trajectory import design_bounds
from ineid.robots.kinematics import frame_points, welded_frames

from .conftest import example_robot_data_dir
from .test_excite_safety import collision_arm  # noqa: F401  (the fixture: the sweaty arm with collision shapes)


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


def _sample(model, seed: int = 0):
    b = design_bounds(model)
    return sample_poses(model, b.q_lower, b.q_upper, np.random.default_rng(seed))


def _constraints(model, limits: SafetyLimits, pairs=None, harmonics: int = 3, f0: float = 0.2) -> SafetyConstraints:
    """The floor, box and pairs of a design of ``harmonics`` at ``f0`` (the trajectory's map is not needed here)."""
    b = design_bounds(model)
    h = harmonics
    mid, half = 0.5 * (b.q_lower + b.q_upper), 0.5 * (b.q_upper - b.q_lower)
    return SafetyConstraints(
        model, limits, b.qd_max, b.qdd_max, f0, h, np.zeros((2 * h, 2 * h - 2)), mid, half, b.qd_max, pairs
    )


def _zoo(name: str, locked: dict | None):
    path = example_robot_data_dir() / name
    if not path.exists():
        pytest.skip(f"example-robot-data is not installed ({path})")
    return ineid.load_robot(path, locked_joints=locked)


def test_a_floor_no_pose_keeps_is_refused_at_once_with_one_line(arm):
    limits = SafetyLimits(floor=0.4)  # at the mount's height: check_limits lets it pass, no motion keeps it
    check_limits(arm, limits)
    t0 = time.perf_counter()
    sample = _sample(arm)
    with pytest.raises(ExcitationError) as err:
        check_feasibility(sample, _constraints(arm, limits))
    seconds = time.perf_counter() - t0
    line = str(err.value)
    assert err.value.reason == "infeasible_workspace" and "\n" not in line
    assert line.startswith("--floor 0.4: 'shoulder_roll_link' is below it in every one of the 2,050 sampled poses")
    assert line.endswith("lower --floor") and seconds < 1.0, (line, seconds)
    # true: the shoulder roll link's origin never rises above the mount (z at most 0.4 m, the margin above it)
    q = _sample(arm, seed=1).poses
    z = frame_points(arm.chain, q, welded_frames(arm.urdf_text, arm.chain))[:, 1, 2]
    assert z.max() <= 0.4 + 1e-12
    assert "z at most 0.4 m" in line


def test_no_pose_keeping_the_box_and_the_others_names_the_bound_that_fails(arm):
    limits = SafetyLimits(workspace=(-0.1, 0.1, -0.37, 0.43, 0.28, 0.59))
    check_limits(arm, limits)
    sample = _sample(arm)
    safety = _constraints(arm, limits)
    with pytest.raises(ExcitationError) as err:
        check_feasibility(sample, safety)
    line = str(err.value)
    assert line.startswith("no sampled pose keeps every bound: 'hand' is outside workspace y <= 0.43 in every one ")
    assert "that keeps every other point in the box (10 of the 2,050); widen the --workspace box" in line
    # what the line says, from the points themselves: the 8 poses that keep every other bound put the hand beyond
    pts = frame_points(arm.chain, sample.poses, safety.welded)  # (T, P, 3)
    box = np.array(limits.workspace).reshape(3, 2)
    margin = safety.margin[:, None]
    inside = (pts >= box[:, 0] + margin) & (pts <= box[:, 1] - margin)  # (T, P, 3)
    hand = safety.names.index("hand")
    others = np.delete(inside, hand, axis=1).all(axis=(1, 2)) & inside[:, hand, [0, 2]].all(axis=1)
    assert others.sum() == 10 and np.all(pts[others, hand, 1] > 0.43 - safety.margin[hand])
    # no pose keeps the others either: the bounds failing most, with their counts
    limits = SafetyLimits(workspace=(-0.08, 0.03, -0.25, 0.2, 0.01, 0.52))
    with pytest.raises(ExcitationError) as err:
        check_feasibility(sample, _constraints(arm, limits))
    counts = (pts[..., 1] > 0.2 - safety.margin).sum(axis=0)
    named = ", ".join(
        f"{p!r} is outside workspace y <= 0.2 in {counts[safety.names.index(p)]:,}"
        for p in ("forearm", "upper_arm", "hand")
    )
    assert (
        str(err.value)
        == f"no one of the 2,050 sampled poses keeps every bound at once: {named}; widen the --workspace box"
    )
    assert counts[safety.names.index("forearm")] == 1934


def test_the_rest_pose_is_reported_with_what_it_breaks(arm):
    sample = _sample(arm)
    assert sample.clipped == ("elbow",)  # the elbow's range excludes zero: the rest pose has it at the nearest bound
    safety = _constraints(arm, SafetyLimits(floor=0.3))
    feas = check_feasibility(sample, safety)
    rest = sample.poses[0]
    b = design_bounds(arm)
    np.testing.assert_array_equal(rest, np.clip(np.zeros(arm.n_dof), b.q_lower, b.q_upper))
    z = frame_points(arm.chain, rest[None], safety.welded)[0, :, 2] - safety.margin
    below = tuple(f"{name!r} --floor 0.3" for name, h in zip(safety.names, z, strict=True) if h < 0.3)
    assert feas.rest_violations == below == ("'forearm' --floor 0.3", "'hand' --floor 0.3")
    assert feas.rest_clipped == ("elbow",) and feas.n_sampled == 2050
    record = json.loads(json.dumps(feas.to_dict()))
    assert record["rest_violations"] == list(below) and record["feasible"] == len(feas.poses)
    assert 0.4 < feas.share < 0.8 and feas.seconds < 1.0
    # the rest pose and the middle of the ranges come first when they are feasible
    low = check_feasibility(sample, _constraints(arm, SafetyLimits(floor=-0.5)))
    assert low.rest_violations == () and len(low.poses) == 2050
    np.testing.assert_array_equal(low.poses[:2], sample.poses[:2])


def test_feasible_poses_keep_every_constraint_by_hpp_fcl_and_pinocchio():
    """Panda (fingers locked), --floor 0 and every kept capsule pair: the capsules' distances by hpp-fcl, the
    frames by Pinocchio, in the feasible poses."""
    fcl = pytest.importorskip("hppfcl")
    pin = pytest.importorskip("pinocchio")
    from ineid.reference import pinocchio_model

    locked = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    model = _zoo("panda_description/urdf/panda.urdf", locked)
    sample = _sample(model)
    full = CollisionPairs(model, model.qd_max)
    pairs = always_touching(full, sample)
    safety = _constraints(model, SafetyLimits(floor=0.0), pairs)
    feas = check_feasibility(sample, safety, pairs)
    assert 0.2 < feas.share < 0.6 and feas.seconds < 2.0
    pmodel = pinocchio_model(example_robot_data_dir() / "panda_description/urdf/panda.urdf", locked_joints=locked)
    data = pmodel.createData()
    order = [pmodel.joints[pmodel.getJointId(j)].idx_q for j in model.joint_names]
    frames = [
        pmodel.getFrameId("panda_link0" if c.link < 0 else model.chain.joints[c.link].link) for c in pairs.capsules
    ]

    def fcl_capsule(cap, placement):
        a, b = placement.act(cap.a), placement.act(cap.b)
        axis = b - a
        length = float(np.linalg.norm(axis))
        z = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
        rot = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), z).matrix()
        return fcl.Capsule(cap.radius, length), fcl.Transform3f(rot, 0.5 * (a + b))

    margins = safety.margins()
    per_point = len(safety.names) * len(safety.spaces)
    picks = feas.poses[:: max(1, len(feas.poses) // 40)]
    for q in picks:
        qp = np.zeros(pmodel.nq)
        qp[order] = q
        pin.framesForwardKinematics(pmodel, data, qp)
        for r, name in enumerate(safety.names):  # every point above the floor by its margin
            assert data.oMf[pmodel.getFrameId(name)].translation[2] >= margins[r] - 1e-12, name
        for c, (i, k) in enumerate(pairs.pairs):
            s1, t1 = fcl_capsule(pairs.capsules[i], data.oMf[frames[i]])
            s2, t2 = fcl_capsule(pairs.capsules[k], data.oMf[frames[k]])
            result = fcl.DistanceResult()
            fcl.distance(s1, t1, s2, t2, fcl.DistanceRequest(), result)
            assert result.min_distance >= margins[per_point + c] - 1e-9, pairs.labels()[c]
            assert abs(result.min_distance - pairs.clearances(q)[0, c]) < 1e-6


def test_so101_pairs_touching_at_every_angle_are_left_out_and_named_once():
    model = _zoo("so_arm_description/urdf/so101.urdf", {"gripper": 0.0})
    sample = _sample(model)
    full = CollisionPairs(model, model.qd_max)
    t0 = time.perf_counter()
    pairs = always_touching(full, sample)
    assert time.perf_counter() - t0 < 1.0
    # the pair IPOPT could not keep: two of its six capsule pairs never 2 cm apart, one overlapping in every pose
    line = (
        "'lower_arm_link' and 'gripper_link' (2 of their 6 capsule pairs): overlap in every one of the 2,050 "
        "sampled poses"
    )
    assert [x for x in pairs.excluded if "'gripper_link'" in x] == [
        f"{line} (bounding shapes too coarse to tell): not checked"
    ]
    assert pairs.labels().count("'lower_arm_link' and 'gripper_link'") == 4
    assert len(pairs.excluded) == len({x.split(":")[0] for x in pairs.excluded}) == 2  # each pair of bodies once
    assert all(x in pairs.notes for x in pairs.excluded)
    clear = full.clearances(sample.poses)
    kept = {tuple(p) for p in pairs.pairs}
    left = np.array([tuple(p) not in kept for p in full.pairs])
    assert np.all(clear[:, left].max(axis=0) < APART) and np.all(clear[:, ~left].max(axis=0) >= APART)
    assert pairs.n == full.n - left.sum() == 78
    feas = check_feasibility(sample, _constraints(model, SafetyLimits(floor=0.0), pairs), pairs)
    assert feas.rest_violations == () and feas.share > 0.3 and feas.excluded == tuple(pairs.excluded)
    # kept, that pair is refused in a second, where IPOPT took half an hour to give up
    t0 = time.perf_counter()
    with pytest.raises(ExcitationError, match="^'lower_arm_link' and 'gripper_link' self-collision: the bounding "):
        check_feasibility(sample, _constraints(model, SafetyLimits(), full), full)
    assert time.perf_counter() - t0 < 1.0


def test_a_pair_overlapping_at_the_middle_of_the_ranges_but_apart_elsewhere_is_kept():
    model = _zoo("panda_description/urdf/panda.urdf", {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    sample = _sample(model)
    full = CollisionPairs(model, model.qd_max)
    pairs = always_touching(full, sample)
    label = "'panda_link0' and 'panda_link2'"
    c = full.labels().index(label)
    clear = full.clearances(sample.poses)[:, c]
    assert clear[1] < 0 and clear.max() > APART  # overlapping at the middle of the ranges, 4 cm apart elsewhere
    assert label in pairs.labels() and not any(label in x for x in pairs.excluded)
    safety = _constraints(model, SafetyLimits(), pairs)
    feas = check_feasibility(sample, safety, pairs)
    assert np.all(pairs.clearances(feas.poses)[:, pairs.labels().index(label)] > 0)  # the feasible poses avoid it
    assert label + " self-collision" in feas.rest_violations


def test_without_self_collision_or_bounds_every_pose_is_feasible(arm, collision_arm):  # noqa: F811
    sample = _sample(arm)
    feas = check_feasibility(sample, None)
    assert len(feas.poses) == 2050 and feas.rest_violations == () and feas.excluded == ()
    pairs = always_touching(CollisionPairs(collision_arm, collision_arm.qd_max), sample)
    assert pairs.n == 6 and pairs.excluded == []  # the sweaty arm's shapes are apart somewhere, every pair


def test_the_design_at_rest_in_a_feasible_pose_keeps_every_bound_on_its_grid(collision_arm):  # noqa: F811
    """What the starts rely on: the trajectory at rest in a feasible pose keeps the floor and every pair on the
    design's dense grid, so a start about it is made safe by scaling its amplitudes (and in no infeasible one)."""
    from ineid.excite.design import design_base, design_noise
    from ineid.excite.safety import make_safe
    from ineid.excite.trajectory import DesignProblem

    b = design_bounds(collision_arm)
    prob = DesignProblem(collision_arm, design_base(collision_arm), design_noise(None), "d-opt", b, 0.2, 3, 96, 96)
    sample = sample_poses(collision_arm, prob.q_lo, prob.q_hi, np.random.default_rng(0))
    pairs = always_touching(CollisionPairs(collision_arm, b.qd_max), sample)
    args = (b.qd_max, b.qdd_max, 0.2, 3, prob.rest, prob.mid, prob.half, prob.v_scale, pairs)
    safety = SafetyConstraints(collision_arm, SafetyLimits(floor=0.25), *args)
    feas = check_feasibility(sample, safety, pairs)
    rng = np.random.default_rng(1)
    feasible = {p.tobytes() for p in feas.poses}
    moved = 0
    for q in sample.poses[:20]:
        at_rest = np.concatenate([((q - prob.mid) / prob.half)[:, None], np.zeros((prob.n, prob.nz - 1))], 1).ravel()
        assert (safety.grid_slack(at_rest).min() >= 0) == (q.tobytes() in feasible)
        if q.tobytes() in feasible and moved < 3:
            moved += 1
            moving = at_rest.reshape(prob.n, prob.nz).copy()
            moving[:, 1:] = prob.random_start(rng).reshape(prob.n, prob.nz)[:, 1:]
            safe = make_safe(safety, moving.ravel())
            assert safe is not None and safety.grid_slack(safe).min() >= 0
