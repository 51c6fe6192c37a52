"""Loading robots (:mod:`ineid.robots`): the built-in arm, any serial URDF, and clear errors for bad models."""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid import RobotModelError
from ineid.errors import InputFileError
from ineid.reference import pinocchio_model, pinocchio_theta
from ineid.robots import load_chain
from ineid.robots.urdf import parse_chain

from .conftest import FIXTURES

LINK = (
    '<link name="{name}"><inertial><origin xyz="0 0 0.1" rpy="0 0 0"/><mass value="{m}"/>'
    '<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial></link>'
)


def urdf(*, joint_type="revolute", axis="0 0 1", m1="1", inertia=("0.01", "0.01", "0.01"), extra=""):
    ixx, iyy, izz = inertia
    return f"""<robot name="t">
      <link name="base"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" velocity="2" effort="1"/></joint>
      {LINK.format(name="a", m=m1, ixx=ixx, iyy=iyy, izz=izz)}
      <joint name="j2" type="{joint_type}"><parent link="a"/><child link="b"/><origin xyz="0 0 0.2"/>
        <axis xyz="{axis}"/><limit lower="-1" upper="1" velocity="2" effort="1"/></joint>
      {LINK.format(name="b", m="1", ixx="0.01", iyy="0.01", izz="0.01")}
      {extra}
    </robot>"""


def test_builtin_arm():
    m = ineid.load_robot("sweaty-arm")
    assert m.name == "sweaty-arm"
    assert m.joint_names == ("shoulder_pitch", "shoulder_roll", "upper_arm_yaw", "elbow")
    assert m.link_names == ("shoulder_pitch_link", "shoulder_roll_link", "upper_arm", "forearm")
    assert m.unknown_links == ("upper_arm", "forearm") and m.known_links == (
        "shoulder_pitch_link",
        "shoulder_roll_link",
    )
    assert len(m.unknown_index) == 20
    assert m.theta_cad.shape == (40,)
    assert m.urdf_path.is_file() and "REPRESENTATIVE" in m.urdf_path.read_text()
    assert np.all(m.q_lower < m.q_upper) and np.all(m.qd_max > 0) and np.all(m.qdd_max == [30, 30, 40, 40])
    ineid.check_physical(m.theta_cad, m.link_names)
    assert m.param_names[20:22] == ["upper_arm.m", "upper_arm.mx"]


def test_unknown_links_choice():
    m = ineid.load_robot("sweaty-arm", unknown_links=["forearm"])
    assert m.unknown_links == ("forearm",) and len(m.known_links) == 3
    # chain order, whatever order given
    m = ineid.load_robot("sweaty-arm", unknown_links=["forearm", "upper_arm"])
    assert m.unknown_links == ("upper_arm", "forearm")
    with pytest.raises(RobotModelError, match="'palm' is not a moving link of sweaty-arm; choose from .*: hand$"):
        ineid.load_robot("sweaty-arm", unknown_links=["palm"])
    m = ineid.load_robot("sweaty-arm", unknown_links=["hand"])  # welded to the forearm: a payload
    assert m.link_names[-2:] == ("forearm", "hand") and m.unknown_links == ("hand",)


def test_urdf_default_unknown_is_every_moving_link():
    m = ineid.load_robot(FIXTURES / "mixed_chain.urdf")
    assert m.unknown_links == m.link_names == ("l1", "l2", "l3")
    assert m.joint_types == ("continuous", "prismatic", "revolute")


def test_fixed_joints_fold_like_pinocchio():
    """Links welded mid-chain and at the tip fold into their parent body; root welds are tared."""
    path = FIXTURES / "mixed_chain.urdf"
    chain = load_chain(path)
    assert chain.root_link == "world"
    assert chain.merged_links["world"] == ("world", "base")
    assert chain.merged_links["l2"] == ("l2", "bracket")
    assert chain.merged_links["l3"] == ("l3", "tool", "tcp")
    assert np.allclose(
        np.concatenate([j.theta for j in chain.joints]), pinocchio_theta(pinocchio_model(path)), atol=1e-14
    )


def test_locked_joints_cut_a_tree_to_a_chain():
    from .conftest import real_robot

    path, locked = real_robot("panda")
    with pytest.raises(RobotModelError, match="'panda_finger_joint2' mimics 'panda_finger_joint1'.*--lock"):
        load_chain(path)  # the two fingers branch off the hand, one mimicking the other
    tree = load_chain(path, locked_joints={"panda_finger_joint2": 0.0})  # one finger left: a chain again
    assert tree.n_dof == 8 and tree.parents == (-1, 0, 1, 2, 3, 4, 5, 6) and tree.is_serial
    chain = load_chain(path, locked_joints=locked)
    assert chain.n_dof == 7 and chain.is_serial
    with pytest.raises(RobotModelError, match="locked joint 'nope' is not in the URDF"):
        load_chain(path, locked_joints={"nope": 0.0})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("<robot name='t'><link name='a'>", "malformed XML"),
        ("<robt name='t'/>", "top-level element is <robt>, a URDF needs <robot>"),
        (urdf(joint_type="planar"), "joint 'j2' has type 'planar'; ineid supports revolute, continuous, prismatic"),
        (urdf(axis="0 0 0"), "joint 'j2' has an axis of zero length"),
        (urdf(m1="-1"), "link 'a': mass -1 kg is negative"),
        (urdf(m1="0"), "link 'a': zero mass with a non-zero inertia"),
        (
            urdf(inertia=("0.01", "-0.01", "0.01")),
            "link 'a': non-physical <inertial>: inertia about the centre of mass has a negative principal moment",
        ),
        (
            urdf(inertia=("0.01", "0.01", "0.05")),
            "link 'a': non-physical <inertial>: principal moments .* violate the triangle inequality",
        ),
        (
            urdf(m1="0", inertia=("0", "0", "0")).replace(
                LINK.format(name="b", m="1", ixx="0.01", iyy="0.01", izz="0.01"), '<link name="b"/>'
            ),
            "no moving link carries mass \\(a, b\\).* give the moving links <inertial> elements",
        ),
        (
            urdf(
                extra='<joint name="j3" type="revolute"><parent link="a"/><child link="b"/>'
                '<axis xyz="1 0 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>'
            ),
            "link 'b' is the child of two joints \\('j2', 'j3'\\): a closed loop; ineid models kinematic trees: "
            "remove one of the two joints$",
        ),
        (
            urdf(extra='<joint name="j9" type="fixed"><parent link="b"/><child link="ghost"/></joint>'),
            "joint 'j9' refers to link 'ghost', which is not defined",
        ),
        (urdf(extra='<link name="island"/>'), "exactly one root link, found 2"),
        (urdf(joint_type="fixed"), ""),  # legal: one moving joint left
        (urdf().replace('xyz="0 0 0.2"', 'xyz="0 nan 0.2"'), "joint 'j2': <origin xyz='0 nan 0.2'> holds a non-finite"),
        (urdf().replace('xyz="0 0 0.2"', 'xyz="0 0 0.2" rpy="inf 0 0"'), "joint 'j2': <origin rpy='inf 0 0'> holds"),
        (urdf().replace('xyz="0 0 0.2"', 'xyz="-inf 0 0.2"'), "joint 'j2': <origin xyz='-inf 0 0.2'> holds"),
        (urdf(axis="0 nan 1"), "joint 'j2': <axis xyz='0 nan 1'> holds a non-finite value"),
        (urdf(axis="0 0 inf"), "joint 'j2': <axis xyz='0 0 inf'> holds a non-finite value"),
        (
            urdf(
                extra='<joint name="j9" type="fixed"><parent link="b"/><child link="c"/><origin rpy="0 nan 0"/></joint>'
                '<link name="c"/>'
            ),
            "joint 'j9': <origin",
        ),
        (
            urdf().replace('<origin xyz="0 0 0.1" rpy="0 0 0"/>', '<origin xyz="0 0 nan" rpy="0 0 0"/>', 1),
            "link 'a': <inertial><origin xyz='0 0 nan'> holds a non-finite value",
        ),
        (urdf().replace('name="j2"', 'name="j1"'), "two <joint> elements are named 'j1'; give every joint its own"),
        (
            urdf(extra=LINK.format(name="b", m="2", ixx="0.01", iyy="0.01", izz="0.01")),
            "two <link> elements are named 'b'; give every link its own name",
        ),
        ("<robot name='t'><link name='a'/></robot>", "no moving joint"),
        # every number ineid reads: finite, limits not negative (0 is URDF writers' "not given")
        (urdf().replace('velocity="2"', 'velocity="nan"', 1), "joint 'j1': <limit velocity='nan'> holds a non-finite"),
        (
            urdf().replace('velocity="2"', 'velocity="-3"', 1),
            "joint 'j1': <limit velocity='-3'> is negative; give the joint's speed limit \\(a positive number\\), or "
            "leave the attribute out for ineid's default$",
        ),
        (urdf().replace('effort="1"', 'effort="-1"', 1), "joint 'j1': <limit effort='-1'> is negative"),
        (urdf().replace('lower="-1"', 'lower="-inf"', 1), "joint 'j1': <limit lower='-inf'> holds a non-finite"),
        (
            urdf().replace('upper="1"', 'upper="fast"', 1),
            "joint 'j1': <limit upper='fast'> is not a number; give a number",
        ),
        (urdf().replace('lower="-1"', 'lower="2"', 1), "joint 'j1': lower limit 2.0 is not below upper limit 1.0"),
        (urdf(axis="0 1"), "joint 'j2': <axis xyz='0 1'> holds 2 numbers; give 3"),
        (urdf(m1="nan"), "link 'a': <inertial><mass value='nan'> holds a non-finite value"),
        (urdf(inertia=("0.01", "inf", "0.01")), "link 'a': <inertial><inertia iyy='inf'> holds a non-finite value"),
        (
            urdf(
                extra='<joint name="j9" type="fixed"><parent link="b"/><child link="c"/><mimic joint="j1" '
                'multiplier="nan"/></joint><link name="c"/>'
            ),
            "joint 'j9': <mimic multiplier='nan'> holds",
        ),
        (
            urdf(
                extra='<link name="c"><collision><geometry><sphere radius="nan"/></geometry></collision></link>'
                '<joint name="j9" type="fixed"><parent link="b"/><child link="c"/></joint>'
            ),
            "link 'c': <collision><geometry><sphere radius='nan'> holds a non-finite value",
        ),
    ],
)
def test_bad_models_raise_robot_model_error(text, message):
    """One line naming the element, the attribute, its value and the fix; each case fails without its check."""
    if not message:
        assert parse_chain(text).n_dof == 1
        return
    with pytest.raises(RobotModelError, match=message):
        parse_chain(text)


def test_missing_file_and_unknown_name():
    with pytest.raises(RobotModelError, match="neither a built-in robot"):
        ineid.load_robot("no-such-robot")
    with pytest.raises(InputFileError, match="^the URDF /nonexistent/x.urdf does not exist; check the path$"):
        load_chain("/nonexistent/x.urdf")


def test_sampling_bounds_from_urdf():
    chain = parse_chain(urdf().replace("<limit", '<ineid acceleration="7.5"/><limit', 1))
    assert chain.joints[0].qdd_max == 7.5 and chain.joints[0].qd_max == 2.0
    assert chain.joints[1].qdd_max == 10.0  # the default
    with pytest.raises(RobotModelError, match="joint 'j1': <ineid acceleration='-1'> is negative"):
        parse_chain(urdf().replace("<limit", '<ineid acceleration="-1"/><limit', 1))
    with pytest.raises(RobotModelError, match="acceleration bound 0.0 must be positive"):
        parse_chain(urdf().replace("<limit", '<ineid acceleration="0"/><limit', 1))


def test_a_parsed_urdf_is_remembered_exactly(tmp_path, monkeypatch):
    """The second parse of the same text comes from the cache folder (yourdfpy not needed),
    equal to the first to the last bit; other locked joints or other text parse again."""
    import sys

    from .conftest import real_robot

    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path))
    path, locked = real_robot("panda")
    text = path.read_bytes()
    first = parse_chain(text, source="panda", locked_joints=locked)
    assert len(list((tmp_path / "chains").glob("*.json"))) == 1
    monkeypatch.setitem(sys.modules, "yourdfpy", None)  # any parse now fails with ImportError
    second = parse_chain(text, source="panda", locked_joints=locked)
    assert (second.name, second.root_link, dict(second.merged_links)) == (
        first.name,
        first.root_link,
        dict(first.merged_links),
    )
    for a, b in zip(first.joints, second.joints, strict=True):
        for f in ("name", "type", "continuous", "link", "q_lower", "q_upper", "qd_max", "qdd_max"):
            assert getattr(a, f) == getattr(b, f), f
        for f in ("parent_R_joint", "parent_p_joint", "axis", "theta"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert second.kinematic_fingerprint() == first.kinematic_fingerprint()
    with pytest.raises(ImportError):  # not the same question: parsed, not remembered
        parse_chain(text, source="panda", locked_joints={**locked, "panda_joint7": 0.5})
    monkeypatch.delitem(sys.modules, "yourdfpy")
    (cached,) = (tmp_path / "chains").glob("*.json")
    cached.write_text("{not json")  # a damaged entry is parsed again and replaced
    again = parse_chain(text, source="panda", locked_joints=locked)
    assert np.array_equal(again.joints[-1].theta, first.joints[-1].theta)
    assert cached.read_text().startswith('{"name"')
