"""Safe excitation trajectories: forward kinematics against Pinocchio, a floor and a box kept at every instant."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import ineid
from ineid.errors import ExcitationError
from ineid.excite.design import design_excitation
from ineid.excite.settings import ExcitationSettings
from ineid.robots.kinematics import frame_points, link_poses, point_jacobians, welded_frames

UR5 = "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
# the settings of every design here: short and cheap, one start
FAST = {"duration": 5.0, "harmonics": 3, "starts": 1, "seed": 3, "max_iter": 25}


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


def _dense_points(model, traj):
    q = traj.evaluate(np.linspace(0.0, traj.duration, 50_001))[0]
    return frame_points(model.chain, q, welded_frames(model.urdf_text, model.chain))


@pytest.mark.parametrize("robot", ["sweaty-arm", "ur5"])
def test_kinematics_match_pinocchio(robot):
    pin = pytest.importorskip("pinocchio")
    from pathlib import Path

    from ineid.robots.urdf import load_chain

    if robot == "ur5":
        import sysconfig

        path = Path(sysconfig.get_paths()["purelib"]) / UR5
        if not path.exists():
            pytest.skip(f"example-robot-data is not installed ({path})")
    else:
        path = ineid.robots.BUILTIN_ROBOTS[robot].urdf_path
    text = path.read_text()
    chain = load_chain(path)
    welded = welded_frames(text, chain)
    assert welded.tool  # the hand / tool0 welded to the last link
    pmodel = pin.buildModelFromXML(text)
    data = pmodel.createData()
    q = np.random.default_rng(0).uniform(-2.5, 2.5, (4, chain.n_dof))
    rot, pos = link_poses(chain, q)
    pts = frame_points(chain, q, welded)
    for k in range(len(q)):
        pin.framesForwardKinematics(pmodel, data, q[k])
        for i, j in enumerate(chain.joints):
            placement = data.oMf[pmodel.getFrameId(j.link)]
            np.testing.assert_allclose(pos[k, i], placement.translation, atol=1e-12)
            np.testing.assert_allclose(rot[k, i], placement.rotation, atol=1e-12)
        for i, name in enumerate(welded.names):
            np.testing.assert_allclose(
                pts[k, chain.n_dof + i], data.oMf[pmodel.getFrameId(name)].translation, atol=1e-12
            )
    # the point Jacobians are the derivatives of the points
    link = np.r_[np.arange(chain.n_dof), welded.link]
    jac = point_jacobians(chain, q, link, pts)
    eps = 1e-6
    for j in range(chain.n_dof):
        step = eps * np.eye(chain.n_dof)[j]
        fd = (frame_points(chain, q + step, welded) - frame_points(chain, q - step, welded)) / (2 * eps)
        np.testing.assert_allclose(jac[..., j], fd, atol=1e-8)


def test_kinematics_under_jax_numpy(arm):
    import jax.numpy as jnp

    q = np.random.default_rng(1).uniform(-2, 2, (3, arm.n_dof))
    r_np, p_np = link_poses(arm.chain, q)
    r_j, p_j = link_poses(arm.chain, jnp.asarray(q), jnp)
    np.testing.assert_allclose(np.asarray(p_j), p_np, atol=1e-12)
    np.testing.assert_allclose(np.asarray(r_j), r_np, atol=1e-12)


def test_floor_and_box_hold_at_every_instant_where_the_free_design_breaks_them(arm):
    free = design_excitation(arm, ExcitationSettings(**FAST))
    z_free = _dense_points(arm, free.trajectory)[..., 2]
    floor = 0.25
    assert z_free.min() < floor - 0.05  # the unconstrained design swings the hand below the floor
    kept = design_excitation(arm, ExcitationSettings(**FAST, floor=floor))
    pts = _dense_points(arm, kept.trajectory)
    assert pts[..., 2].min() >= floor
    assert kept.safety["samples"]["min_clearance"] >= 0 and kept.safety["floor"] == floor
    # the box: x stays in [-0.3, 0.3] where the free design leaves it
    box = (-0.3, 0.3, -1.0, 1.0, -1.0, 1.0)
    x_free = _dense_points(arm, free.trajectory)[..., 0]
    assert x_free.min() < box[0] or x_free.max() > box[1]
    boxed = design_excitation(arm, ExcitationSettings(**FAST, workspace=box))
    x = _dense_points(arm, boxed.trajectory)[..., 0]
    assert x.min() >= box[0] and x.max() <= box[1]
    # at rest at the start, in a safe pose: the start is one of the checked instants
    start = _dense_points(arm, boxed.trajectory)[0]
    assert np.all(start[:, 0] >= box[0]) and np.all(start[:, 0] <= box[1])


@pytest.mark.parametrize(
    ("limits", "text"),
    [
        ({"floor": 0.5}, "lower --floor"),
        ({"workspace": (0.0, -1.0, -1, 1, -1, 1)}, "XMIN 0 is not below XMAX -1"),
        ({"workspace": (1.0, 2.0, -1, 1, -1, 1)}, "widen the --workspace box"),
        ({"floor": 1.2}, "lower --floor"),
        ({"floor": 0.4}, "sampled poses"),  # refused before any optimisation (ineid.excite.feasibility)
    ],
)
def test_limits_no_motion_can_keep_are_refused_at_once(arm, limits, text):
    with pytest.raises(ExcitationError, match=text.replace("-", r"\-")):
        design_excitation(arm, ExcitationSettings(**FAST, **limits))


def _run(*args):
    from ineid.cli import main

    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_cli_floor_summary_record_and_one_line_errors(tmp_path):
    out = tmp_path / "t.csv"
    r = _run(
        "excite",
        "sweaty-arm",
        "--duration",
        3,
        "--harmonics",
        2,
        "--starts",
        1,
        "--floor",
        0.25,
        "--acceleration-scale",
        1.2,
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "warning: --acceleration-scale 1.2 goes beyond" in r.output
    for text in (
        "floor: z >= 0.25 m",
        "smallest clearance on the written samples",
        "self-collision: not checked",
        "|qdd| max",
        "URDF",
    ):
        assert text in r.output, text
    record = json.loads(out.with_suffix(".json").read_text())["design"]
    assert record["workspace"]["floor"] == 0.25 and record["settings"]["floor"] == 0.25
    assert record["workspace"]["samples"]["min_clearance"] >= 0
    sampled = ineid.data.synthesis.trajectory.read_trajectory_csv(out)
    arm = ineid.load_robot("sweaty-arm")
    assert frame_points(arm.chain, sampled.q, welded_frames(arm.urdf_text, arm.chain))[..., 2].min() >= 0.25
    for args, text in (
        (("--floor", 0.5), "lower --floor"),
        (("--workspace", "-1,1,-1,1,0.45,1"), "widen the --workspace box"),
    ):
        bad = tmp_path / "bad.csv"
        r = _run("-q", "excite", "sweaty-arm", "--duration", 5, "--harmonics", 3, "--starts", 1, *args, "--out", bad)
        lines = r.output.strip().splitlines()
        assert r.exit_code == 1 and len(lines) == 1 and text in lines[0], r.output
        assert not bad.exists() and not bad.with_suffix(".json").exists()
    r = _run("excite", "sweaty-arm", "--duration", 5, "--workspace", "1,2,3", "--out", tmp_path / "x.csv")
    assert r.exit_code == 2 and "six numbers" in r.output


# the sweaty arm with collision geometry (the same kinematics: its generated code and compilation are reused)
_COLLISION = {
    "base_link": '<origin xyz="0.1 0.15 0.0"/><geometry><sphere radius="0.12"/></geometry>',
    "shoulder_roll_link": '<origin xyz="0 0 -0.03"/><geometry><sphere radius="0.04"/></geometry>',
    "upper_arm": '<origin xyz="0 0 -0.11"/><geometry><cylinder radius="0.035" length="0.22"/></geometry>',
    "forearm": '<origin xyz="0 0 -0.13"/><geometry><cylinder radius="0.03" length="0.26"/></geometry>',
    "hand": '<origin xyz="0 0 -0.05" rpy="0.3 0 0"/><geometry><box size="0.03 0.08 0.1"/></geometry>',
}


@pytest.fixture(scope="module")
def collision_arm(arm):
    from ineid.robots import RobotModel
    from ineid.robots.urdf import parse_chain

    text = arm.urdf_text
    for link, xml in _COLLISION.items():
        text = text.replace(f'<link name="{link}">', f'<link name="{link}">\n    <collision>{xml}</collision>', 1)
    return RobotModel(
        parse_chain(text),
        None,
        "sweaty-arm-collision",
        arm.gravity,
        arm.unknown_links,
        arm._jax,
        arm._casadi,
        urdf_text=text,
    )


def test_bounding_capsules_contain_the_shapes(collision_arm):
    from ineid.robots.collision import body_capsules, segment_distance

    found = body_capsules(collision_arm.urdf_text, collision_arm.chain)
    assert [c.shape for c in found.capsules] == ["sphere", "sphere", "cylinder", "cylinder", "box"]
    assert found.notes == ["link 'shoulder_pitch_link' has no collision geometry"]
    hand = found.capsules[-1]
    assert hand.link == 3  # welded to the forearm, in its frame
    # every corner of the hand's box (rotated, offset by the welded joint) lies inside its capsule
    from ineid.robots.kinematics import rpy_rotation

    corners = np.array([[x, y, z] for x in (-0.015, 0.015) for y in (-0.04, 0.04) for z in (-0.05, 0.05)])
    corners = np.array([0, 0, -0.26]) + np.array([0, 0, -0.05]) + corners @ rpy_rotation((0.3, 0, 0)).T
    d, _, _ = segment_distance(hand.a, hand.b, corners, corners)
    assert np.all(d <= hand.radius + 1e-12) and hand.radius < 0.065


def test_self_collision_kept_at_every_instant_where_the_free_design_collides(collision_arm):
    from ineid.excite.collision import CollisionPairs

    pairs = CollisionPairs(collision_arm, collision_arm.qd_max)
    assert len(pairs.labels()) == 6 and "'base_link' and 'hand'" in pairs.labels()  # non-adjacent bodies only
    free = design_excitation(collision_arm, ExcitationSettings(**FAST, self_collision=False))
    q = free.trajectory.evaluate(np.linspace(0.0, 5.0, 20_001))[0]
    assert pairs.clearances(q).min() < -0.01
    kept = design_excitation(collision_arm, ExcitationSettings(**FAST))
    q = kept.trajectory.evaluate(np.linspace(0.0, 5.0, 50_001))[0]
    assert pairs.clearances(q).min() >= 0
    assert kept.safety["self_collision"]["pairs"] == pairs.labels()
    assert kept.safety["samples"]["min_clearance"] >= 0


def test_mesh_geometry_gives_bounding_capsules():
    import sysconfig
    from pathlib import Path

    from ineid.robots.collision import body_capsules
    from ineid.robots.urdf import load_chain

    path = Path(sysconfig.get_paths()["purelib"]) / UR5
    if not path.exists():
        pytest.skip(f"example-robot-data is not installed ({path})")
    found = body_capsules(path.read_text(), load_chain(path), path)
    assert not found.notes and [c.shape for c in found.capsules].count("mesh") == 7
    assert all(0.03 < c.radius < 0.1 for c in found.capsules if c.shape == "mesh")
    moved = body_capsules(path.read_text().replace("meshes/ur5/collision/", "meshes/nowhere/"), load_chain(path), path)
    assert any("not readable, skipped" in n for n in moved.notes)


def test_constraint_jacobian_matches_finite_differences(collision_arm):
    from ineid.excite.collision import CollisionPairs
    from ineid.excite.design import design_base, design_bounds, design_noise
    from ineid.excite.safety import SafetyConstraints, SafetyLimits
    from ineid.excite.trajectory import DesignProblem

    bounds = design_bounds(collision_arm)
    prob = DesignProblem(
        collision_arm, design_base(collision_arm), design_noise(None), "d-opt", bounds, 0.2, 3, 160, 96
    )
    safety = SafetyConstraints(
        collision_arm,
        SafetyLimits(floor=0.1, workspace=(-0.5, 0.5, -0.5, 0.6, -0.5, 1.0)),
        bounds.qd_max,
        bounds.qdd_max,
        0.2,
        3,
        prob.rest,
        prob.mid,
        prob.half,
        prob.v_scale,
        CollisionPairs(collision_arm, bounds.qd_max),
    )
    assert safety.n_constraints == 5 * 7 + 6
    x = prob.random_start(np.random.default_rng(0))
    eps = 1e-6
    fd = np.stack([(safety.values(x + eps * e) - safety.values(x - eps * e)) / (2 * eps) for e in np.eye(len(x))], 1)
    np.testing.assert_allclose(safety.jacobian(x), fd, atol=1e-7)
