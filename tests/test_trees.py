"""Kinematic trees on a fixed base, against Pinocchio: a torso with two arms the test writes, Baxter, an Allegro hand.

For each tree, on random states: the base-wrench regressor and the base wrench (the load of every branch
on the fixture), the joint-torque regressor and the torques (each joint carries its subtree), and the
wrench at each cut (what the links below a link exert on it) equal Pinocchio's ``jointBodyRegressor``,
``rnea``, ``computeJointTorqueRegressor`` and ``data.f`` to 1e-10 (the written tree to 1e-12). The big
trees are evaluated through CasADi (no compilation); the written tree through the JAX kernels too.
ineid orders the moving joints depth first (every parent before its children), Pinocchio by its own
walk: the comparison maps them by joint name. Forward kinematics, point Jacobians and the reach bound of
the excitation follow the tree too; a serial chain keeps its fingerprint; a loop and two roots are
refused in one line.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import ineid
from ineid.errors import RobotModelError
from ineid.reference import (
    pinocchio_base_regressor,
    pinocchio_base_wrench,
    pinocchio_joint_torque_regressor,
    pinocchio_joint_torques,
    pinocchio_link_wrench,
    pinocchio_model,
    pinocchio_q,
)
from ineid.robots.urdf import parse_chain

from .conftest import example_robot_data_dir, random_states, rel_err
from .test_cli import one_line_error

GRAVITY = (0.3, -0.4, -9.81)
N_STATES = 6

_INERTIAL = (
    '<link name="{n}"><inertial><origin xyz="{c}" rpy="0.1 -0.2 0.3"/><mass value="{m}"/>'
    '<inertia ixx="{i}" ixy="{o}" ixz="{o}" iyy="{i}" iyz="{o}" izz="{i}"/></inertial>'
    '<collision><origin xyz="{c}"/><geometry><sphere radius="0.03"/></geometry></collision></link>'
)


def _link(name: str, com: str, mass: str, inertia: float) -> str:
    return _INERTIAL.format(n=name, c=com, m=mass, i=inertia, o=round(0.07 * inertia, 6))


def _joint(name, kind, parent, child, xyz, rpy, axis="0 0 1", limit=(-1.5, 1.5)) -> str:
    moving = "" if kind == "fixed" else f'<axis xyz="{axis}"/><limit lower="{limit[0]}" upper="{limit[1]}" '
    moving += "" if kind == "fixed" else 'velocity="2" effort="10"/>'
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/>{moving}</joint>'
    )


def torso_urdf(extra: str = "") -> str:
    """A waist carrying a torso with two 2-joint arms (one revolute-prismatic with a welded hand, one with a
    welded shoulder frame and a tilted axis), on a fixed mount welded to the world."""
    return "".join(
        [
            '<robot name="two_arm_torso"><link name="world"/><link name="mount"/><link name="r_shoulder_frame"/>',
            _link("torso", "0.01 0.02 0.2", "5", 0.2),
            _link("l_upper", "0.1 0 0.01", "1.5", 0.02),
            _link("l_fore", "0.05 0.01 0", "1.0", 0.01),
            _link("l_hand", "0.02 0 0.03", "0.4", 0.003),
            _link("r_upper", "0.1 0 -0.02", "1.4", 0.02),
            _link("r_fore", "0.06 0.01 0", "0.9", 0.01),
            _joint("mount_fix", "fixed", "world", "mount", "0 0 0.1", "0 0 0.4"),
            _joint("waist", "revolute", "mount", "torso", "0 0.05 0.2", "0 0.1 0"),
            _joint("l_shoulder", "revolute", "torso", "l_upper", "0 0.2 0.4", "1.5707963267948966 0 0", "0 1 0"),
            _joint("l_slide", "prismatic", "l_upper", "l_fore", "0.25 0 0", "0 0 0.3", "1 0 0", (-0.1, 0.1)),
            _joint("l_wrist_fix", "fixed", "l_fore", "l_hand", "0.15 0 0", "0.2 0 0"),
            _joint("r_frame_fix", "fixed", "torso", "r_shoulder_frame", "0 -0.2 0.4", "-0.3 0 0.1"),
            _joint("r_shoulder", "revolute", "r_shoulder_frame", "r_upper", "0.01 0 0", "0 0 0", "0.6 0 0.8"),
            _joint("r_elbow", "revolute", "r_upper", "r_fore", "0.25 0 0", "0 0.2 0"),
            extra,
            "</robot>",
        ]
    )


@dataclasses.dataclass
class Tree:
    model: object
    pin: object
    states: tuple
    perm: list  # ineid joint i is Pinocchio's joint perm[i] + 1
    tol: float
    gen: object = None  # the generated code's folder

    def pin_states(self):
        inv = np.argsort(self.perm)
        return tuple(x[:, inv] for x in self.states)

    @property
    def cols(self):
        return np.concatenate([np.arange(10 * k, 10 * k + 10) for k in self.perm])


def _tree(path, tol, locked=None, codegen_dir=None, seed=0) -> Tree:
    model = ineid.load_robot(path, gravity=GRAVITY, locked_joints=locked, codegen_dir=codegen_dir)
    pin = pinocchio_model(path, gravity=GRAVITY, locked_joints=locked)
    names = list(pin.names)[1:]
    perm = [names.index(n) for n in model.joint_names]
    states = random_states(model, N_STATES, np.random.default_rng(seed))
    return Tree(model, pin, states, perm, tol)


@pytest.fixture(scope="module")
def torso(tmp_path_factory):
    folder = tmp_path_factory.mktemp("torso")
    path = folder / "torso.urdf"
    path.write_text(torso_urdf())
    tree = _tree(path, 1e-12, codegen_dir=folder / "gen")
    tree.gen = folder / "gen"
    return tree


ERD = {
    # Baxter's grippers are mimic pairs: locked; its head and both 7-joint arms stay (15 joints)
    "baxter": (
        "baxter_description/urdf/baxter.urdf",
        {f"{s}_gripper_{f}_finger_joint": 0.0 for s in "lr" for f in "lr"},
    ),
    "allegro": ("allegro_hand_description/urdf/allegro_right_hand.urdf", None),  # 4 fingers of 4 joints
    # a humanoid on a fixed base (its waist): two 6-joint legs, a 2-joint torso carrying the head and two arms
    "talos": ("talos_data/robots/talos_reduced.urdf", None),  # 32 joints: derived in about 2 s
}


def _isotropic(text: str) -> str:
    """The URDF with every ``<inertia>`` made isotropic with its largest moment (a rigid body; the kinematics
    unchanged): the Allegro hand's CAD inertias break the triangle inequality, which ineid refuses."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(text)
    for el in root.iter("inertia"):
        big = max(float(el.get(k)) for k in ("ixx", "iyy", "izz"))
        el.attrib.update({k: repr(big) for k in ("ixx", "iyy", "izz")} | {k: "0" for k in ("ixy", "ixz", "iyz")})
    return ET.tostring(root, encoding="unicode")


@pytest.fixture(scope="module", params=sorted(ERD))
def erd_tree(request, tmp_path_factory):
    rel, locked = ERD[request.param]
    folder = tmp_path_factory.mktemp(request.param)
    path = example_robot_data_dir() / rel
    if request.param == "allegro":
        # its thumb's yaw -1.5707963259 is CAD rounding of -pi/2, which ineid snaps (9e-10 rad): Pinocchio reads
        # the snapped angle too, so that the comparison holds at 1e-10
        text = path.read_text()
        assert text.count("-1.5707963259") == 1
        path = folder / "allegro.urdf"
        path.write_text(_isotropic(text.replace("-1.5707963259", repr(-np.pi / 2))))
    return _tree(path, 1e-10, locked, folder / "gen", seed=1)


def _casadi_frames(fn, states, *extra):
    return np.stack([np.asarray(fn(q, qd, qdd, *extra)).reshape(-1) for q, qd, qdd in zip(*states, strict=True)])


def _check_casadi(tree: Tree, links) -> None:
    """Every quantity, through CasADi, against Pinocchio."""
    model, pin, states, tol = tree.model, tree.pin, tree.states, tree.tol
    ps = tree.pin_states()
    theta = model.theta_cad
    y = _casadi_frames(model.casadi_regressor, states).reshape(N_STATES, 6, -1)
    assert rel_err(y, pinocchio_base_regressor(pin, *ps)[:, :, tree.cols]) < tol
    assert rel_err(_casadi_frames(model.casadi_base_wrench, states, theta), pinocchio_base_wrench(pin, *ps)) < tol
    y_tau = _casadi_frames(model.casadi_joint_torque_regressor, states).reshape(N_STATES, model.n_dof, -1)
    assert rel_err(y_tau, pinocchio_joint_torque_regressor(pin, *ps)[:, tree.perm][:, :, tree.cols]) < tol
    tau = _casadi_frames(model.casadi_joint_torques, states, theta)
    assert rel_err(tau, pinocchio_joint_torques(pin, *ps)[:, tree.perm]) < tol
    for link in links:
        i = model.link_names.index(link)
        y_cut = _casadi_frames(model.casadi_link_wrench_regressor(link), states).reshape(N_STATES, 6, -1)
        assert rel_err(y_cut @ theta, pinocchio_link_wrench(pin, *ps, tree.perm[i] + 1)) < tol, link


def test_written_tree_is_walked_depth_first(torso):
    chain = torso.model.chain
    assert torso.model.joint_names == ("waist", "l_shoulder", "l_slide", "r_shoulder", "r_elbow")
    assert chain.parents == (-1, 0, 1, 0, 3) and not chain.is_serial
    assert chain.children(0) == (1, 3) and chain.subtree(0) == (0, 1, 2, 3, 4) and chain.subtree(3) == (3, 4)
    assert chain.ancestors(4) == (0, 3, 4) and chain.ancestors(2) == (0, 1, 2)
    assert chain.merged_links["l_fore"] == ("l_fore", "l_hand") and "r_shoulder_frame" in chain.merged_links["torso"]
    (module,) = torso.gen.glob("*_jax.py")
    assert "\nPARENTS = (-1, 0, 1, 0, 3)\n" in module.read_text()


def test_written_tree_equals_pinocchio_through_casadi(torso):
    _check_casadi(torso, ["torso", "l_upper", "r_upper"])


def test_written_tree_equals_pinocchio_through_jax(torso):
    """The JAX kernels (compiled once each): the base regressor and the joint torques."""
    model, pin, tol = torso.model, torso.pin, torso.tol
    ps = torso.pin_states()
    q, qd, qdd = torso.states
    assert rel_err(model.regressor(q, qd, qdd), pinocchio_base_regressor(pin, *ps)[:, :, torso.cols]) < tol
    assert rel_err(model.joint_torques(q, qd, qdd), pinocchio_joint_torques(pin, *ps)[:, torso.perm]) < tol


def test_example_robot_data_trees_equal_pinocchio(erd_tree):
    model = erd_tree.model
    assert not model.chain.is_serial
    roots_children = [model.link_names[j] for j in model.chain.children(-1)]
    # the cut below each branch's first link, and below a link that carries two branches where there is one
    forks = [model.link_names[j] for j in range(model.n_dof) if len(model.chain.children(j)) > 1]
    _check_casadi(erd_tree, [*roots_children[:2], *forks[:1]])


def test_tree_kinematics_equal_pinocchio(torso):
    """Link poses, point Jacobians (each joint moves its subtree only) and the reach bound of the excitation."""
    import pinocchio as pin

    from ineid.robots.kinematics import link_poses, point_jacobians, reach

    chain, pm = torso.model.chain, torso.pin
    data = pm.createData()
    q = torso.states[0]
    inv = np.argsort(torso.perm)
    r, p = link_poses(chain, q)
    points = p + 0.1  # a point fixed in each link at its origin + 0.1 (base frame at q), per sample
    link = np.arange(chain.n_dof)
    jac = point_jacobians(chain, q, link, points[:, :, :])
    bound = reach(chain)
    for t in range(len(q)):
        pin.forwardKinematics(pm, data, pinocchio_q(pm, q[t][inv]))
        pin.computeJointJacobians(pm, data)
        for i in range(chain.n_dof):
            placement = data.oMi[torso.perm[i] + 1]
            assert np.allclose(r[t, i], placement.rotation, atol=1e-12)
            assert np.allclose(p[t, i], placement.translation, atol=1e-12)
            full = pin.getJointJacobian(pm, data, torso.perm[i] + 1, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            lin = full[:3] - np.cross(points[t, i] - p[t, i], full[3:].T).T  # moved from the origin to the point
            assert np.allclose(jac[t, i], lin[:, torso.perm], atol=1e-12)
            for j in chain.ancestors(i):  # the bound holds where the joint moves the link; zero elsewhere
                assert np.linalg.norm(p[t, i] - p[t, j]) <= bound[i, j] + 1e-12
    assert bound[4, 1] == 0 and bound[2, 3] == 0 and bound[4, 0] > 0


def test_serial_chain_keeps_its_fingerprint_and_a_topology_changes_it(torso):
    arm = ineid.load_robot("sweaty-arm")
    from ineid.generated import load_builtin

    assert arm.chain.is_serial and arm.chain.parents == (-1, 0, 1, 2)
    assert arm.chain.kinematic_fingerprint() == load_builtin("sweaty-arm")[0].KINEMATIC_FINGERPRINT
    chain = torso.model.chain
    serial = dataclasses.replace(chain, parents=())
    assert serial.is_serial and serial.kinematic_fingerprint() != chain.kinematic_fingerprint()
    with pytest.raises(ValueError, match="joint 1's parent 1 is not a joint before it"):
        dataclasses.replace(chain, parents=(-1, 1, 1, 0, 3))


def test_a_loop_and_two_roots_are_one_line(run, tmp_path):
    loop = tmp_path / "loop.urdf"
    loop.write_text(torso_urdf(_joint("closing", "revolute", "l_fore", "r_fore", "0 0 0", "0 0 0")))
    line = one_line_error(run("robot", "show", loop))
    assert line.endswith(
        "link 'r_fore' is the child of two joints ('r_elbow', 'closing'): a closed loop; ineid models kinematic "
        "trees: remove one of the two joints"
    )
    roots = tmp_path / "roots.urdf"
    roots.write_text(torso_urdf('<link name="table"/>'))
    line = one_line_error(run("robot", "show", roots))
    assert "exactly one root link, found 2: ['world', 'table']; join them with fixed joints" in line


def test_mjcf_body_tree_loads_as_a_tree(tmp_path):
    """A MuJoCo body with two jointed children: the URDF written from it is a tree Pinocchio agrees with."""
    pytest.importorskip("mujoco")
    from .test_mjcf import MENAGERIE

    old = '<body name="tool" pos="0.2 0 0" euler="0 90 0">'
    path = tmp_path / "branch.xml"
    path.write_text(MENAGERIE.replace(old, old + '<joint name="jt" axis="0 0 1"/>'))
    model = ineid.load_robot(path, gravity=GRAVITY, codegen_dir=tmp_path / "gen")
    assert not model.chain.is_serial and "jt" in model.joint_names
    urdf = tmp_path / "branch.urdf"
    urdf.write_text(model.urdf_text)
    tree = Tree(model, pinocchio_model(urdf, gravity=GRAVITY), (), [], 1e-12)
    names = list(tree.pin.names)[1:]
    tree.perm = [names.index(n) for n in model.joint_names]
    tree.states = random_states(model, N_STATES, np.random.default_rng(2))
    _check_casadi(tree, [model.link_names[0]])


def test_parse_of_a_tree_is_cached_with_its_parents(tmp_path, monkeypatch):
    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "cache"))
    text = torso_urdf()
    first = parse_chain(text)
    again = parse_chain(text)  # read back from the cache folder
    assert again is not first and again.parents == first.parents == (-1, 0, 1, 0, 3)


def test_a_loop_closed_by_a_fixed_joint_is_refused_too():
    with pytest.raises(RobotModelError, match="closed loop"):
        parse_chain(torso_urdf(_joint("closing", "fixed", "l_fore", "r_fore", "0 0 0", "0 0 0")))


def test_mujoco_simulation_nests_the_tree(torso):
    """:func:`ineid.studies.mujoco_sim.arm_mjcf` nests the bodies as the tree: MuJoCo's inverse dynamics of it
    (an independent engine) equals ineid's joint torques, its joints in chain order."""
    mujoco = pytest.importorskip("mujoco")
    from ineid.studies.mujoco_sim import arm_mjcf

    model = ineid.load_robot(torso.gen.parent / "torso.urdf", codegen_dir=torso.gen)  # MuJoCo's gravity, -9.81 z
    fixture = np.r_[1.0, 0, 0, 0, 0.1, 0, 0.1, 0, 0, 0.1]  # the root body: welded, not in the joint torques
    m = mujoco.MjModel.from_xml_string(arm_mjcf(model.chain, model.theta_cad, fixture, None, 0.001))
    assert [m.joint(i).name for i in range(m.njnt)] == list(model.joint_names)
    d = mujoco.MjData(m)
    tau = _casadi_frames(model.casadi_joint_torques, torso.states, model.theta_cad)
    for t, (q, qd, qdd) in enumerate(zip(*torso.states, strict=True)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(m, d)
        assert rel_err(d.qfrc_inverse, tau[t]) < 1e-10


def test_a_payload_on_a_branch(torso):
    """The hand welded to the left forearm identified on its own: a block after its body, carried by the left
    branch only (the torques of the right arm do not see it), the torques and cuts still Pinocchio's."""
    model = ineid.load_robot(
        torso.gen.parent / "torso.urdf",
        gravity=GRAVITY,
        codegen_dir=torso.gen,
        unknown_links=["l_upper", "l_hand", "r_upper"],
    )
    assert "l_hand" in model.link_names and model.n_links == 6
    ps = torso.pin_states()
    theta = model.theta_cad
    tau = _casadi_frames(model.casadi_joint_torques, torso.states, theta)
    assert rel_err(tau, pinocchio_joint_torques(torso.pin, *ps)[:, torso.perm]) < torso.tol
    hand = model.link_names.index("l_hand")
    y_tau = _casadi_frames(model.casadi_joint_torque_regressor, torso.states).reshape(N_STATES, model.n_dof, -1)
    right = [model.joint_names.index(n) for n in ("r_shoulder", "r_elbow")]
    assert not np.any(y_tau[:, right, 10 * hand : 10 * hand + 10])
    y_cut = _casadi_frames(model.casadi_link_wrench_regressor("l_upper"), torso.states).reshape(N_STATES, 6, -1)
    shoulder = model.joint_names.index("l_shoulder")  # l_upper's joint; l_fore and its hand lie beyond
    assert rel_err(y_cut @ theta, pinocchio_link_wrench(torso.pin, *ps, torso.perm[shoulder] + 1)) < torso.tol


def test_robot_show_names_each_joints_parent(run, torso):
    r = run("robot", "show", torso.gen.parent / "torso.urdf")
    assert r.exit_code == 0, r.output
    assert "each parent before its children" in r.output
    rows = {line.split("│")[2].strip(): line.split("│")[3].strip() for line in r.output.splitlines() if "│" in line}
    assert rows["waist"] == "(base)" and rows["l_slide"] == "l_shoulder" and rows["r_shoulder"] == "waist"


def test_collision_pairs_follow_the_tree(torso):
    """Bodies are adjacent when one is the other's parent: the two arms' links are checked against each other
    (the two shoulders, siblings on the torso, included), a link against its parent's never."""
    from ineid.excite.collision import CollisionPairs

    model = torso.model
    pairs = CollisionPairs(model, model.qd_max)
    index = {c.name: c.link for c in pairs.capsules}
    assert index == {"torso": 0, "l_upper": 1, "l_fore": 2, "l_hand": 2, "r_upper": 3, "r_fore": 4}
    checked = {tuple(sorted((pairs.capsules[i].link, pairs.capsules[k].link))) for i, k in pairs.pairs}
    assert checked == {(0, 2), (0, 4), (1, 3), (1, 4), (2, 3), (2, 4)}


def test_acceleration_bounds_hold_on_a_tree(torso):
    """The bound of each link origin's acceleration (its ancestors' speeds and accelerations only) holds at random
    states within the joint bounds; the second derivative by central differences along q + qd t + qdd t^2 / 2."""
    from ineid.excite.safety import acceleration_bounds
    from ineid.robots.kinematics import link_poses, reach

    model = torso.model
    chain = model.chain
    bound = acceleration_bounds(chain, reach(chain), np.arange(chain.n_dof), model.qd_max, model.qdd_max)
    rng = np.random.default_rng(5)
    h = 1e-4
    worst = np.zeros(chain.n_dof)
    for _ in range(200):
        q = rng.uniform(model.q_lower, model.q_upper)
        qd = model.qd_max * rng.choice([-1.0, 1.0], chain.n_dof)
        qdd = model.qdd_max * rng.choice([-1.0, 1.0], chain.n_dof)
        p = link_poses(chain, np.stack([q + qd * t + qdd * t * t / 2 for t in (-h, 0.0, h)]))[1]
        worst = np.maximum(worst, np.linalg.norm((p[0] - 2 * p[1] + p[2]) / h**2, axis=-1))
    assert np.all(worst <= bound) and np.all(worst >= 0.2 * bound), (worst, bound)  # the torso's origin: on the axis
    # the right arm's bound is the right arm's own: moving the left arm faster changes nothing there
    faster = acceleration_bounds(chain, reach(chain), np.arange(5), model.qd_max * [1, 9, 9, 1, 1], model.qdd_max)
    assert np.array_equal(faster[[0, 3, 4]], bound[[0, 3, 4]]) and faster[2] > bound[2]


def test_an_excitation_design_on_a_tree_keeps_its_floor_and_branches_apart(torso):
    """``ineid excite`` on the tree: a short design with a floor and self-collision, checked on a dense grid."""
    from ineid.excite.design import design_excitation
    from ineid.excite.settings import ExcitationSettings

    settings = ExcitationSettings(
        duration=5.0, harmonics=3, starts=1, seed=3, max_iter=25, floor=-0.2, self_collision=True
    )
    design = design_excitation(torso.model, settings)
    assert "'l_upper' and 'r_upper'" in design.safety["self_collision"]["pairs"]
    assert design.safety["samples"]["min_clearance"] >= 0 and design.safety["dense"]["min_clearance"] >= 0


def test_export_urdf_of_a_tree_reads_back():
    """``export-urdf`` writes each identified link of any branch; the file reads back as the same tree with them."""
    from ineid.params import theta_from_inertial
    from ineid.robots.urdf_write import urdf_with_inertials

    text = torso_urdf()
    chain = parse_chain(text)
    new = {
        "l_fore": theta_from_inertial(2.0, np.array([0.1, 0.02, 0.0]), np.diag([0.02, 0.03, 0.04])),
        "r_upper": theta_from_inertial(1.1, np.array([0.05, 0.0, 0.01]), np.diag([0.01, 0.01, 0.015])),
    }
    back = parse_chain(urdf_with_inertials(text, new))
    assert back.parents == chain.parents and back.kinematic_fingerprint() == chain.kinematic_fingerprint()
    for i, j in enumerate(back.joints):
        want = new.get(j.link, chain.joints[i].theta)
        assert np.allclose(j.theta, want, rtol=1e-12, atol=1e-15), j.link


def test_a_tree_model_travels_to_a_worker_process(torso):
    """What an excitation worker gets: the pickled tree, its generated code and topology with it."""
    import pickle

    from .conftest import casadi_regressor_frames, regressor_in_another_process

    q = torso.states[0][:2]
    assert np.array_equal(regressor_in_another_process(torso.model, q), casadi_regressor_frames(torso.model, q))
    copy = pickle.loads(pickle.dumps(torso.model))
    assert copy.chain.parents == (-1, 0, 1, 0, 3) and copy.chain.subtree(3) == (3, 4)
