"""URDFs as CAD tools write them (:mod:`ineid.robots.urdf`, :mod:`ineid.robots.cad_rounding`): rounded
angles, frames, point masses, massless links, mimic joints.

Numbers are compared with Pinocchio, which loads the same files its own way.
"""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid import RobotModelError
from ineid.identify.identifiability import base_parameters, base_parameters_from_regressor, numerical_rank
from ineid.identify.systems import parameter_scales
from ineid.reference import pinocchio_base_regressor, pinocchio_model, pinocchio_theta
from ineid.robots.urdf import parse_chain

from .conftest import example_robot_data_dir, random_states, real_robot, rel_err

# -- rank decisions: one tolerance for the SVD and the column scan ---------------------------


def test_kinova_rounded_pi_column_scan_agrees_with_the_svd():
    """Kinova's rpy="0 3.14159265359 0" leaves a column at 1e-12 of the rest in Pinocchio's regressor
    (which takes the angle literally): the base parameters come out at Pinocchio's own SVD rank."""
    path, _ = real_robot("kinova")
    pin = pinocchio_model(path)
    q = np.random.default_rng(7).uniform(-2, 2, (100, pin.nv))
    qd, qdd = np.random.default_rng(8).uniform(-1, 1, (2, 100, pin.nv))
    w = pinocchio_base_regressor(pin, q, qd, qdd).reshape(-1, 10 * pin.nv)
    scales = parameter_scales(pinocchio_theta(pin))
    tiny = np.linalg.norm(w * scales, axis=0)
    assert 0 < tiny[np.argsort(tiny)[3]] < 1e-10  # the rounded-pi column: round-off, not exactly zero
    rank = numerical_rank(np.linalg.svd(w * scales, compute_uv=False))
    base = base_parameters_from_regressor(w, [f"p{i}" for i in range(w.shape[1])], scales)
    assert base.rank == rank == 41
    assert np.argsort(tiny)[3] not in base.base_index


def test_rounded_quarter_turns_are_snapped_at_parse():
    path, _ = real_robot("kinova")
    chain = parse_chain(path.read_bytes(), source=str(path))
    assert any("CAD rounding" in n and "j2s6s200_joint_1" in n for n in chain.notes)
    r = chain.joints[0].parent_R_joint
    assert set(np.unique(np.abs(r))) <= {0.0, 1.0}  # exact signed permutation, not 1 - 1e-26 and 2e-13


def test_identifiability_rank_of_kinova_equals_pinocchios():
    """The model (snapped angles) has the rank Pinocchio's regressor (literal angles) has."""
    path, _ = real_robot("kinova")
    model = ineid.load_robot(path)
    pin = pinocchio_model(path)
    q, qd, qdd = random_states(model, 60, np.random.default_rng(3))
    w = pinocchio_base_regressor(pin, q, qd, qdd).reshape(-1, 10 * model.n_links)
    pin_rank = numerical_rank(np.linalg.svd(w * parameter_scales(model.theta_cad), compute_uv=False))
    assert base_parameters(model).rank == pin_rank == 41


# -- inertials as exporters write them --------------------------------------------------------

LINK = (
    '<link name="{n}"><inertial><origin xyz="0 0 0.1"/><mass value="{m}"/>'
    '<inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial></link>'
)
JOINT = (
    '<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="0 0 0.2"/>'
    '<axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="2" effort="1"/></joint>'
)


def arm(links: dict[str, str], joints: list[tuple[str, str, str, str]]) -> str:
    return (
        "<robot name='cad'><link name='base'/>"
        + "".join(links.values())
        + "".join(JOINT.format(n=n, t=t, p=p, c=c) for n, t, p, c in joints)
        + "</robot>"
    )


def test_frames_point_masses_and_massless_moving_links_are_accepted():
    text = arm(
        {
            "a": LINK.format(n="a", m="1", i="0.01"),
            "b": LINK.format(n="b", m="0.3", i="0"),  # b: a point mass
            "dummy": LINK.format(n="dummy", m="1e-9", i="0"),
            "c": "<link name='c'/>",
        },  # a 1e-9 kg frame, a bare one
        [
            ("j1", "revolute", "base", "a"),
            ("j2", "revolute", "a", "b"),
            ("jd", "fixed", "b", "dummy"),
            ("j3", "revolute", "b", "c"),
        ],  # c: a massless moving link (a joint frame)
    )
    chain = parse_chain(text)
    assert [j.link for j in chain.joints] == ["a", "b", "c"]
    assert chain.joints[1].theta[0] == 0.3 and np.all(chain.joints[2].theta == 0)
    assert chain.merged_links["b"] == ("b", "dummy")
    notes = " | ".join(chain.notes)
    assert "'dummy': mass 1e-09 kg" in notes and "is a frame; dropped" in notes
    assert "moving link 'c' has no mass" in notes


@pytest.mark.parametrize(
    ("links", "message"),
    [
        (
            {"b": LINK.format(n="b", m="1e-9", i="0.01")},
            "link 'b': a mass of 1e-09 kg \\(none to speak of\\) with a non-zero inertia is not a rigid body",
        ),
        (
            {"b": LINK.format(n="b", m="1", i="0.01").replace('izz="0.01"', 'izz="0.05"')},
            "link 'b': non-physical <inertial>: principal moments .* violate the triangle inequality",
        ),
        (
            {"a": "<link name='a'/>", "b": "<link name='b'/>"},
            "no moving link carries mass \\(a, b\\).*give the moving links <inertial> elements",
        ),
    ],
)
def test_non_physical_or_massless_chains_are_refused_in_one_line(links, message):
    text = arm(
        {"a": LINK.format(n="a", m="1", i="0.01"), "b": LINK.format(n="b", m="1", i="0.01"), **links},
        [("j1", "revolute", "base", "a"), ("j2", "revolute", "a", "b")],
    )
    with pytest.raises(RobotModelError, match=message) as e:
        parse_chain(text)
    assert "\n" not in str(e.value)


def test_a_chain_without_moving_joints_is_refused():
    text = arm({"a": LINK.format(n="a", m="1", i="0.01")}, [("j1", "fixed", "base", "a")])
    with pytest.raises(RobotModelError, match="has no moving joint .*give a URDF with a moving chain"):
        parse_chain(text)


def test_mimic_followers_are_locked_with_their_leader():
    text = arm(
        {
            "a": LINK.format(n="a", m="1", i="0.01"),
            "b": LINK.format(n="b", m="1", i="0.01"),
            "c": LINK.format(n="c", m="1", i="0.01"),
        },
        [("j1", "revolute", "base", "a"), ("j2", "revolute", "a", "b"), ("j3", "revolute", "a", "c")],
    )
    text = text.replace('<child link="c"/>', '<child link="c"/><mimic joint="j2" multiplier="-1" offset="0.1"/>')
    with pytest.raises(RobotModelError, match="joint 'j3' mimics 'j2'; coupled joints are not supported: lock 'j2'"):
        parse_chain(text)
    chain = parse_chain(text, locked_joints={"j2": 0.5})
    assert [j.name for j in chain.joints] == ["j1"]
    assert any("locked with joint 'j2', which they mimic: j3 at -0.4" in n for n in chain.notes)


def test_so101_loads_and_its_regressor_equals_pinocchios(run):
    """SO-101 (a 1e-9 kg dummy link, CAD-rounded angles), gripper locked to keep the test short."""
    path = example_robot_data_dir() / "so_arm_description/urdf/so101.urdf"
    locked = {"gripper": 0.0}
    model = ineid.load_robot(path, locked_joints=locked)
    pin = pinocchio_model(path, locked_joints=locked)
    assert model.n_dof == pin.nv == 5
    assert np.allclose(model.theta_cad, pinocchio_theta(pin), rtol=0, atol=2e-9)  # the dropped 1e-9 kg frame
    q, qd, qdd = random_states(model, 20, np.random.default_rng(5))
    y = np.array(model.casadi_regressor.map(20)(q.T, qd.T, qdd.T)).reshape(6, 20, -1).transpose(1, 0, 2)
    assert rel_err(y, pinocchio_base_regressor(pin, q, qd, qdd)) < 1e-10
    shown = " ".join(run("robot", "show", path, "--lock", "gripper=0").output.split())
    assert (
        "note: link 'gripper_frame_link': mass 1e-09 kg with inertia of at most 0 kg*m^2 is a frame; dropped" in shown
    )
