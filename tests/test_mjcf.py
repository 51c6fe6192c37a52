"""MJCF robots (:mod:`ineid.robots.mjcf`) and ``export-mjcf`` (:mod:`ineid.robots.mjcf_write`).

Checked against independent engines: the tests' MuJoCo arm (``arm_mjcf`` of sweaty-arm) gives the
regressor of the URDF's model and of Pinocchio; a Menagerie-style model (default classes, degrees,
quat/euler, tilted axes, full and diagonal inertia with ``quat``, hinges with ``pos`` and ``ref``, a
slide, a welded tool, a base with a geom, actuators, on a turned base) gives MuJoCo's own inverse
dynamics (``mj_inverse`` + ``mj_rnePostConstraint``: the force the base exerts on the first moving body).
"""

from __future__ import annotations

import difflib
import sys
from types import SimpleNamespace

import numpy as np
import pytest

import ineid

from .conftest import random_states, rel_err
from .test_cli import one_line_error

mujoco = pytest.importorskip("mujoco")

MENAGERIE = """<mujoco model="menagerie-style">
  <compiler angle="degree" autolimits="true"/>
  <option timestep="0.002"><flag contact="disable"/></option>
  <default>
    <default class="arm">
      <joint damping="0.5" armature="0.01"/>
      <geom rgba="0.8 0.8 0.8 1"/>
      <default class="pitch"><joint axis="0 1 0" range="-120 120"/></default>
      <default class="tilted"><joint axis="0.3 -0.5 0.8" range="-90 90"/></default>
    </default>
  </default>
  <worldbody>
    <light pos="0 0 2"/>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="base" pos="0.1 -0.2 0.05" euler="8 -5 30" childclass="arm">
      <geom type="cylinder" size="0.06 0.04" mass="3"/>
      <body name="link1" pos="0 0 0.08" quat="0.9 0.1 0 0.3">
        <joint name="j1" axis="0 0 1" range="-170 170"/>
        <inertial pos="0.01 0.02 0.05" mass="1.2" diaginertia="0.01 0.012 0.005" quat="0.9 0.1 0.2 0.3"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.1" size="0.03" mass="0"/>
        <body name="link2" pos="0 0.05 0.1" quat="0.7071 0.7071 0 0">
          <joint name="j2" class="pitch" pos="0 0.01 -0.02" ref="10"/>
          <inertial pos="0.1 0 0.01" mass="0.9" fullinertia="0.004 0.02 0.021 0.0001 -0.0002 0.0003"/>
          <body name="link3" pos="0.25 0 0" euler="10 -20 15">
            <joint name="j3" class="tilted" pos="0.01 -0.02 0.03"/>
            <geom type="box" size="0.1 0.02 0.02" pos="0.1 0 0" mass="0.6"/>
            <body name="tool" pos="0.2 0 0" euler="0 90 0">
              <inertial pos="0 0 0.03" mass="0.25" diaginertia="0.0002 0.0002 0.0001"/>
            </body>
            <body name="slider" pos="0.21 0 0.01">
              <joint name="j4" type="slide" axis="1 0 0" range="-0.05 0.05" ref="0.01"/>
              <inertial pos="0.02 0 0" mass="0.2" diaginertia="0.0001 0.0002 0.0002" quat="0.5 0.5 0.5 0.5"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="j1" gear="100"/>
    <position joint="j2" kp="50"/>
    <motor joint="j3"/>
    <motor joint="j4"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("mjcf")


@pytest.fixture(scope="module")
def arm_xml(folder):
    """The tests' MuJoCo arm: sweaty-arm as :func:`ineid.studies.mujoco_sim.arm_mjcf` writes it."""
    from ineid.studies.mujoco_sim import arm_mjcf, root_link_theta

    model = ineid.load_robot("sweaty-arm")
    path = folder / "arm.xml"
    path.write_text(arm_mjcf(model.chain, model.theta_cad, root_link_theta(model), None, 0.001))
    return path


@pytest.fixture(scope="module")
def menagerie(folder):
    """``(path, ineid model with the base frame's gravity, MuJoCo model)``."""
    path = folder / "menagerie.xml"
    path.write_text(MENAGERIE)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
    g_base = d.xmat[base].reshape(3, 3).T @ m.opt.gravity
    return path, ineid.load_robot(path, gravity=g_base, unknown_links=["link2", "link3"]), m


def mujoco_base_wrench(m, q, qd, qdd) -> np.ndarray:
    """(n, 6) the wrench the moving links exert on the base body, its frame, moment about its origin (MuJoCo)."""
    d = mujoco.MjData(m)
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
    first = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "link1")
    out = np.empty((len(q), 6))
    for k in range(len(q)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        torque, force = -d.cfrc_int[first][:3], -d.cfrc_int[first][3:]  # at subtree_com of the root body
        moment = torque + np.cross(d.subtree_com[base] - d.xpos[base], force)
        r = d.xmat[base].reshape(3, 3)
        out[k] = np.concatenate([r.T @ force, r.T @ moment])
    return out


def casadi_frames(function, *arrays) -> np.ndarray:
    """``function`` (a model's CasADi regressor or base wrench) frame by frame: (n, ...) NumPy."""
    return np.stack([np.array(function(*(a[k] for a in arrays))) for k in range(len(arrays[0]))])


def test_arm_mjcf_is_the_urdf_robot(arm_xml, model, rng):
    """The tests' MuJoCo arm and sweaty-arm's URDF: the same chain, regressor and parameters; and Pinocchio's.

    (CasADi's evaluation of the generated program: JAX's is checked against it elsewhere, and compiling
    JAX kernels for one more robot costs tens of seconds.)"""
    from ineid.reference import pinocchio_base_regressor, pinocchio_model

    arm = ineid.load_robot(arm_xml, unknown_links=model.unknown_links)
    assert arm.joint_names == model.joint_names and arm.link_names == model.link_names
    assert arm.chain.root_link == model.chain.root_link and arm.model_path == arm_xml.resolve()
    assert arm.chain.kinematic_fingerprint() == model.chain.kinematic_fingerprint()
    assert np.allclose(arm.theta_cad, model.theta_cad, rtol=0, atol=1e-15)
    q, qd, qdd = random_states(model, 20, rng)
    y = casadi_frames(arm.casadi_regressor, q, qd, qdd)
    assert rel_err(y, casadi_frames(model.casadi_regressor, q, qd, qdd)) < 1e-12
    assert rel_err(y, pinocchio_base_regressor(pinocchio_model(model.urdf_path), q, qd, qdd)) < 1e-12


def test_menagerie_style_model_matches_mujoco_inverse_dynamics(menagerie, rng):
    path, model, m = menagerie
    assert model.joint_names == ("j1", "j2", "j3", "j4")
    assert model.link_names == ("link1", "link2", "link3", "slider")
    assert model.chain.merged_links["link3"] == ("link3", "tool")  # the welded tool, folded in
    assert model.chain.root_link == "base" and model.joint_types == ("revolute",) * 3 + ("prismatic",)
    assert np.allclose(model.q_upper, [np.radians(170), np.radians(120), np.radians(90), 0.05], rtol=0, atol=1e-15)
    assert any("gravity in the base frame" in n for n in model.chain.notes)  # the base is turned
    # link2's frame is its body frame moved to the hinge's pos: its centre of mass is the body's minus pos
    j2 = model.link_names.index("link2")
    mass, mc = model.theta_cad[10 * j2], model.theta_cad[10 * j2 + 1 : 10 * j2 + 4]
    assert np.allclose(mc / mass, np.array([0.1, 0.0, 0.01]) - (0, 0.01, -0.02), rtol=0, atol=1e-15)
    # colliding geoms: link1's capsule (a cylinder of its segment) and link3's box, for the excitation's capsules
    assert (
        '<cylinder radius="0.03" length="0.1" />' in model.urdf_text
        and '<box size="0.2 0.04 0.04" />' in model.urdf_text
    )
    from ineid.robots.collision import body_capsules

    capsules = {c.name: c for c in body_capsules(model.urdf_text, model.chain).capsules}
    assert set(capsules) == {"base", "link1", "link3"} and capsules["link1"].radius == 0.03
    assert np.allclose(np.abs(capsules["link1"].b - capsules["link1"].a), [0, 0, 0.1], rtol=0, atol=1e-12)
    q, qd, qdd = random_states(model, 25, rng)
    expected = mujoco_base_wrench(m, q, qd, qdd)
    theta = np.broadcast_to(model.theta_cad, (len(q), model.theta_cad.size))
    assert rel_err(casadi_frames(model.casadi_base_wrench, q, qd, qdd, theta)[..., 0], expected) < 1e-12
    y = casadi_frames(model.casadi_regressor, q, qd, qdd)
    assert rel_err(y @ model.theta_cad, expected) < 1e-12


def fake_results(model, theta_by_link: dict, success=True):
    """What an export reads of :class:`ineid.identify.solve.SolveResults`, for one configuration (7)."""
    links = list(theta_by_link)
    return SimpleNamespace(
        config_index=np.array([7]),
        n=1,
        success=np.array([success]),
        status=np.array(["ok"]),
        theta_links=np.concatenate([theta_by_link[k] for k in links])[None],
        meta={"urdf": model.urdf_text, "unknown_links": links, "locked_joints": {}},
    )


def perturbed(model, link: str, k: int) -> np.ndarray:
    """A rigid body near ``link``'s CAD: heavier, centre of mass moved, inertia scaled and turned."""
    from ineid.params import inertial_from_theta, theta_from_inertial

    i = model.link_names.index(link)
    m, c, ic = inertial_from_theta(model.theta_cad[10 * i : 10 * i + 10])
    rot = np.linalg.qr(np.random.default_rng(k).normal(size=(3, 3)))[0]
    return theta_from_inertial(1.3 * m, c + 0.01 * (k + 1), rot @ (1.2 * ic) @ rot.T)


def changed_lines(before: str, after: str) -> tuple[list[str], list[str]]:
    diff = list(difflib.ndiff(before.splitlines(), after.splitlines()))
    return [d[2:] for d in diff if d.startswith("- ")], [d[2:] for d in diff if d.startswith("+ ")]


def test_export_mjcf_round_trip(menagerie, folder):
    """Identified values read back by MuJoCo (and ineid) to round-off; every other line of the file as it was."""
    from ineid.robots.mjcf_write import export_mjcf

    path, model, _ = menagerie
    theta = {link: perturbed(model, link, k) for k, link in enumerate(("link2", "link3"))}
    out = folder / "identified.xml"
    export_mjcf(fake_results(model, theta), 7, path, out)
    back = ineid.load_robot(out)
    for link, th in theta.items():
        i = back.link_names.index(link)
        assert rel_err(back.theta_cad[10 * i : 10 * i + 10], th) < 1e-12, link
    # link2's inertial replaced; link3's (from its geom) inserted; the tool welded to link3 (its mass is in
    # link3's estimate) made massless; nothing else changed
    removed, added = changed_lines(MENAGERIE, out.read_text())
    assert len(removed) == 2 and len(added) == 3 and all("<inertial " in line for line in removed + added)
    assert '<inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>' in added[-1]
    # a payload: the welded tool identified on its own, in its own frame; link3 and the rest as they were
    payload = ineid.load_robot(path, unknown_links=["link2", "tool"])
    tool = perturbed(payload, "tool", 5)
    out2 = folder / "payload.xml"
    export_mjcf(fake_results(payload, {"tool": tool}), 7, path, out2)
    removed, added = changed_lines(MENAGERIE, out2.read_text())
    assert len(removed) == len(added) == 1 and "<inertial " in added[0]
    back = ineid.load_robot(out2, unknown_links=["tool"])
    i = back.link_names.index("tool")
    assert rel_err(back.theta_cad[10 * i : 10 * i + 10], tool) < 1e-12


def test_export_mjcf_refusals_leave_no_file(menagerie, folder, model):
    from ineid.errors import IdentificationError, RobotModelError
    from ineid.robots.mjcf_write import export_mjcf

    path, mj_model, _ = menagerie
    i = mj_model.link_names.index("link2")
    bad = mj_model.theta_cad[10 * i : 10 * i + 10].copy()
    bad[4] = -1.0  # Ixx < 0
    out = folder / "never.xml"
    with pytest.raises(IdentificationError, match="not a rigid body"):
        export_mjcf(fake_results(mj_model, {"link2": bad}), 7, path, out)
    with pytest.raises(RobotModelError, match="not in the MJCF"):  # results of sweaty-arm, MJCF of another robot
        export_mjcf(fake_results(model, {"forearm": model.theta_cad[-10:]}), 7, path, out)
    geom = folder / "fromgeom.xml"
    geom.write_text(MENAGERIE.replace('angle="degree"', 'angle="degree" inertiafromgeom="true"'))
    with pytest.raises(RobotModelError, match="inertiafromgeom"):  # link3 has a geom: MuJoCo ignores <inertial>
        export_mjcf(fake_results(mj_model, {"link3": perturbed(mj_model, "link3", 1)}), 7, geom, out)
    assert not out.exists() and not list(folder.glob(".never*"))


BAD = {
    "free joint": (
        'childclass="arm">',
        'childclass="arm"><freejoint name="float"/>',
        "free joint 'float' of body 'base'",
    ),
    "ball joint": (
        '<joint name="j1" axis="0 0 1" range="-170 170"/>',
        '<joint name="j1" type="ball"/>',
        "ball joint 'j1' of body 'link1'",
    ),
    "tendon": (
        "<actuator>",
        '<tendon><fixed name="t"><joint joint="j1" coef="1"/><joint joint="j3" coef="1"/></fixed></tendon><actuator>',
        "<tendon> t",
    ),
    "equality": (
        "<actuator>",
        '<equality><joint name="couple" joint1="j1" joint2="j3"/></equality><actuator>',
        "<equality> constraint couple",
    ),
    "two joints": (
        '<joint name="j1" axis="0 0 1" range="-170 170"/>',
        '<joint name="j1" axis="0 0 1" range="-170 170"/><joint name="j1b" axis="1 0 0"/>',
        "body 'link1' has 2 joints",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_unsupported_mjcf_is_one_line(case, run, tmp_path):
    old, new, words = BAD[case]
    assert MENAGERIE.count(old) == 1
    path = tmp_path / "bad.xml"
    path.write_text(MENAGERIE.replace(old, new))
    line = one_line_error(run("robot", "show", path))
    assert line.startswith(f"Error: {path}: ") and words in line, line
    out = tmp_path / "d.h5"
    one_line_error(run("data", "generate", path, "--n-configs", 1, "--n-frames", 2, "--out", out))
    assert not out.exists()


def test_missing_mujoco_is_one_line(run, arm_xml, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` raises ImportError
    assert one_line_error(run("robot", "show", arm_xml)) == "Error: MJCF needs MuJoCo: pip install 'ineid[mujoco]'"
    out = tmp_path / "d.h5"
    one_line_error(run("data", "generate", arm_xml, "--n-configs", 1, "--n-frames", 2, "--out", out))
    assert not out.exists()
    assert run("robot", "show", "sweaty-arm").exit_code == 0  # URDF robots need no MuJoCo


def test_cli_with_an_mjcf_robot(run, menagerie, folder):
    """``robot show``, ``data generate``, ``solve`` and ``export-mjcf`` with the MJCF as ROBOT."""
    path, model, _ = menagerie
    r = run("robot", "show", path, "--unknown-links", "link2,link3")
    assert r.exit_code == 0, r.output
    assert (
        str(path) in r.output
        and "j4" in r.output
        and "prismatic" in r.output
        and "gravity in the base frame" in r.output
    )
    data = folder / "d.h5"
    gravity = [repr(float(g)) for g in model.gravity]
    r = run(
        "data",
        "generate",
        path,
        "--unknown-links",
        "link2,link3",
        "--gravity",
        *gravity,
        "--n-configs",
        2,
        "--n-frames",
        40,
        "--out",
        data,
    )
    assert r.exit_code == 0, r.output
    res = folder / "r.h5"
    r = run("solve", data, "--method", "consistent", "--workers", 1, "--out", res)
    assert r.exit_code == 0 and "2/2 configurations identified" in r.output, r.output
    out = folder / "cli.xml"
    r = run("export-mjcf", res, "--robot", path, "--config", 1, "--out", out)
    assert r.exit_code == 0 and out.is_file(), r.output
    from ineid.identify import load_results

    results = load_results(res)
    back = ineid.load_robot(out, unknown_links=["link2", "link3"])
    assert rel_err(back.theta_cad[back.unknown_index], results.theta_links[1]) < 1e-12
    line = one_line_error(run("export-mjcf", res, "--robot", path, "--config", 1, "--out", out))
    assert line == f"Error: {out} exists; pass --overwrite to replace it"


def test_arm_hinged_on_the_world_with_unnamed_bodies(tmp_path):
    """No fixed base body: the world is the root link; unnamed bodies and joints get names, with a note."""
    from ineid.robots.mjcf import load_mjcf_chain

    path = tmp_path / "bare.mjcf"
    path.write_text(
        '<mujoco><worldbody><geom type="plane" size="1 1 .1"/><body pos="0 0 0.5"><joint axis="0 0 1"/>'
        '<geom type="sphere" size="0.1" pos="0.2 0 0"/><body pos="0.3 0 0"><joint name="b" axis="0 1 0" '
        'pos="0.05 0 0"/><geom type="box" size=".1 .02 .02" pos=".1 0 0"/></body></body></worldbody></mujoco>'
    )
    chain, _ = load_mjcf_chain(path)
    assert chain.root_link == "world" and [j.name for j in chain.joints] == ["joint0", "b"]
    assert [j.link for j in chain.joints] == ["body1", "body2"] and "body1, body2, joint0" in chain.notes[0]
    assert np.allclose(chain.joints[1].parent_p_joint, [0.35, 0, 0], rtol=0, atol=1e-15)  # at the hinge's pos
    assert np.allclose(chain.joints[1].theta[1:4] / chain.joints[1].theta[0], [0.05, 0, 0], rtol=0, atol=1e-15)


def test_export_urdf_results_into_the_mjcf_twin(arm_xml, model, folder):
    """Results identified on sweaty-arm's URDF, written into its MJCF twin (same names and frames)."""
    from ineid.robots.mjcf_write import export_mjcf

    forearm = perturbed(model, "forearm", 3)
    out = folder / "twin.xml"
    export_mjcf(fake_results(model, {"forearm": forearm}), 7, arm_xml, out)
    back = ineid.load_robot(out)
    i = back.link_names.index("forearm")
    assert rel_err(back.theta_cad[10 * i : 10 * i + 10], forearm) < 1e-12
    removed, added = changed_lines(arm_xml.read_text().replace("><", ">\n<"), out.read_text().replace("><", ">\n<"))
    assert len(removed) == len(added) == 1 and "<inertial " in added[0]


def test_export_mjcf_edits_any_spelling_of_inertial(menagerie, folder):
    """``<inertial ...></inertial>``, a comment with ``>`` and quotes before it: only the element is replaced."""
    from ineid.robots.mjcf_write import export_mjcf

    path, model, _ = menagerie
    old = '<inertial pos="0.1 0 0.01" mass="0.9" fullinertia="0.004 0.02 0.021 0.0001 -0.0002 0.0003"/>'
    text = MENAGERIE.replace(old, '<!-- a > b, "it\'s" -->\n          ' + old[:-2] + ">\n          </inertial>")
    spelled = folder / "spelled.xml"
    spelled.write_text(text)
    link2 = perturbed(model, "link2", 9)
    out = folder / "spelled_out.xml"
    export_mjcf(fake_results(model, {"link2": link2}), 7, spelled, out)
    new = out.read_text()
    start, stop = text.index('<inertial pos="0.1'), text.index("</inertial>") + len("</inertial>")
    written = new[start : new.index("/>", start) + 2]
    assert written.startswith('<inertial pos="') and "fullinertia=" in written
    assert new[:start] == text[:start] and new[start + len(written) :] == text[stop:]
    back = ineid.load_robot(out)
    assert rel_err(back.theta_cad[10:20], link2) < 1e-12


def test_export_mjcf_keeps_the_declared_encoding(menagerie, folder):
    """An MJCF declared ISO-8859-1 with accents in a comment (MuJoCo reads it): every byte but the edited
    ``<inertial>`` written back as it was, in that encoding; MuJoCo and ineid read the result."""
    from ineid.robots.mjcf_write import export_mjcf

    path, model, _ = menagerie
    head = '<?xml version="1.0" encoding="ISO-8859-1"?>\n<!-- bras articulé, réglé à 0° -->\n'
    latin = folder / "latin.xml"
    latin.write_bytes((head + MENAGERIE).encode("latin-1"))
    link2 = perturbed(model, "link2", 4)
    out = folder / "latin_out.xml"
    export_mjcf(fake_results(model, {"link2": link2}), 7, latin, out)
    before, after = latin.read_bytes().split(b"\n"), out.read_bytes().split(b"\n")
    changed = [(a, b) for a, b in zip(before, after, strict=True) if a != b]
    assert len(changed) == 1 and all(line.lstrip().startswith(b"<inertial ") for line in changed[0])
    back = ineid.load_robot(out)
    i = back.link_names.index("link2")
    assert rel_err(back.theta_cad[10 * i : 10 * i + 10], link2) < 1e-12
