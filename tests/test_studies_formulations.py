"""MuJoCo's joint torques against ineid's (:mod:`ineid.studies.mujoco_sim`), and ``ineid study formulations``
(:mod:`ineid.studies.formulations`).

MuJoCo (its own dynamics, independent of ineid's generated code) simulates the arms with joint
friction and armature; what its actuators apply must be ineid's joint torques plus exactly the
friction and armature torques MuJoCo applied, while the base wrench stays ineid's, untouched by
the joints' friction. The study's quick run goes through the command line.
"""

from __future__ import annotations

import csv
import subprocess
import sys

import numpy as np
import pytest

import ineid

from .conftest import FIXTURES, rel_err

pytest.importorskip("mujoco")

ROOT = np.array([1.0, 0.01, -0.02, 0.03, 0.01, 0, 0.012, 0, 0, 0.011])
"""Any root body: the sensor reads its weight as a constant."""


@pytest.fixture(scope="module", params=["sweaty-arm", "mixed-chain"])
def arm(request):
    return ineid.load_robot("sweaty-arm" if request.param == "sweaty-arm" else FIXTURES / "mixed_chain.urdf")


def _theta(model, seed):
    from ineid.data.synthesis.sampling import sample_link_parameters

    rng, theta = np.random.default_rng(seed), model.theta_cad.copy()
    for link in model.unknown_links:
        i = model.link_names.index(link)
        theta[10 * i : 10 * i + 10] = sample_link_parameters(theta[10 * i : 10 * i + 10], 1, rng)[0]
    return theta


def _simulate(model, friction, seed=3, duration=1.5):
    from ineid.studies.mujoco_sim import simulate

    theta = _theta(model, seed)
    return theta, simulate(
        model, theta, None, duration, rate=200.0, steps_per_sample=5, friction=friction, seed=seed, root_theta=ROOT
    )


def test_mujoco_joint_torques_are_ineids_without_friction(arm):
    from ineid.studies.mujoco_sim import NO_FRICTION, root_wrench

    theta, sim = _simulate(arm, NO_FRICTION)
    tau = arm.joint_torques(sim.q, sim.qd, sim.qdd, theta)
    assert rel_err(tau, sim.tau) < 1e-9
    assert np.abs(sim.friction).max() == 0.0
    wrench = sim.wrench_sensor - root_wrench(ROOT, arm.gravity)
    assert rel_err(arm.base_wrench(sim.q, sim.qd, sim.qdd, theta), wrench) < 1e-9


def test_mujoco_joint_torques_with_friction_are_ineids_plus_the_drive(arm):
    """tau = Y_tau theta + Ia qdd + f (f: MuJoCo's damping, frictionloss and Stribeck torques), and f is
    viscous + Coulomb + Stribeck away from rest; the base wrench does not see the joints' friction."""
    from ineid.studies.mujoco_sim import JointFriction, root_wrench

    n = arm.n_dof
    drive = JointFriction(
        viscous=np.linspace(0.1, 0.3, n),
        coulomb=np.linspace(0.2, 0.1, n),
        armature=np.linspace(0.02, 0.01, n),
        stribeck=0.1,
        stribeck_velocity=0.05,
    )
    theta, sim = _simulate(arm, drive)
    ia = drive.per_joint(n)["armature"]
    tau = arm.joint_torques(sim.q, sim.qd, sim.qdd, theta) + ia * sim.qdd + sim.friction
    assert rel_err(tau, sim.tau) < 1e-9
    # frictionloss is a soft constraint: fc sign(qd) once the velocity is well away from rest (MuJoCo's
    # reference acceleration, -qd / 0.01 s by default, beyond what the arm does)
    moving = np.abs(sim.qd) > 0.3
    model = drive.model_torque(sim.qd) + drive.stribeck_torque(sim.qd)
    assert moving.mean() > 0.2 and np.abs(model - sim.friction)[moving].max() < 1e-3
    wrench = sim.wrench_sensor - root_wrench(ROOT, arm.gravity)
    assert rel_err(arm.base_wrench(sim.q, sim.qd, sim.qdd, theta), wrench) < 1e-9


def test_joint_torque_channel_fits_mujoco_drives_exactly(model):
    """Least squares on [Y_tau,u | E] (the channel's rows and extra columns) recovers the unknown links'
    torques and the joints' viscous friction and armature from clean MuJoCo torques."""
    from ineid.channels import JointTorque
    from ineid.studies.mujoco_sim import JointFriction

    drive = JointFriction(viscous=[0.3, 0.5, 0.2, 0.1], armature=[0.02, 0.05, 0.01, 0.01])
    theta, sim = _simulate(model, drive, duration=3.0)
    channel = JointTorque(friction=("viscous",), armature=True)
    y = channel.rows(model, sim.q, sim.qd, sim.qdd)  # (F, n_dof, 10 n_links)
    e = channel.extra_rows(model, sim.q, sim.qd, sim.qdd)
    u, k = model.unknown_index, model.known_index
    target = (sim.tau - y[..., k] @ theta[k]).reshape(-1)
    w = np.concatenate([y[..., u], e], axis=-1).reshape(len(target), -1)
    x, *_ = np.linalg.lstsq(w, target, rcond=None)
    assert np.abs(w @ x - target).max() < 1e-8 * np.abs(target).max()
    names = channel.extra_names(model)
    per = drive.per_joint(model.n_dof)
    truth = [
        per["viscous" if n.endswith(".fv") else "armature"][model.joint_names.index(n.rsplit(".", 1)[0])] for n in names
    ]
    # the first joint's armature is collinear with the links' inertia about its axis; the others are seen
    seen = [i for i, n in enumerate(names) if n.endswith(".fv")]
    assert np.allclose(x[len(u) :][seen], np.asarray(truth)[seen], rtol=1e-6)


def test_study_quick_through_the_cli(run, tmp_path):
    """The quick size (2 configurations of 6 s) with three formulations: each compiles its own kernels, and
    ``both`` and ``two-step`` run the same code with other settings (the docs' table has them all)."""
    plot, table = tmp_path / "formulations.png", tmp_path / "formulations.csv"
    r = run(
        "-q",
        "study",
        "formulations",
        "--quick",
        "--formulations",
        "wrench,torque,torque+friction",
        "--plot",
        plot,
        "--csv",
        table,
    )
    assert r.exit_code == 0, r.output
    assert "Formulations study, sweaty-arm" in r.output and "simulated drives per joint" in r.output
    assert plot.stat().st_size > 10_000
    rows = {row["formulation"]: row for row in csv.DictReader(table.open())}
    assert list(rows) == ["wrench", "torque", "torque+friction"]
    f = {name: {k: float(v) for k, v in row.items() if k not in ("robot", "formulation")} for name, row in rows.items()}
    # the base wrench does not see the joints' friction: the same estimate with ideal drives
    assert f["wrench"]["base_error"] == f["wrench"]["base_error_ideal"]
    # joint torques without a friction model pay for it; with the model (Stribeck still missing) far less
    assert f["torque"]["base_error"] > 5 * f["torque"]["base_error_ideal"]
    assert f["torque"]["base_error"] > 5 * f["torque+friction"]["base_error"]
    assert f["torque"]["link_torque_error"] > 3 * f["torque+friction"]["link_torque_error"]
    assert f["torque"]["torque_error"] > 2 * f["torque+friction"]["torque_error"]
    # the wrench alone predicts the links' torques as well as the torques with their friction model do
    assert f["wrench"]["link_torque_error"] < 2 * f["torque+friction"]["link_torque_error"]
    assert f["torque+friction"]["fv_error"] < 0.3 and f["torque+friction"]["fc_error"] < 0.3
    again = run("study", "formulations", "--quick", "--plot", plot)
    assert again.exit_code == 1 and "exists" in again.output


def test_study_without_mujoco_says_how_to_install(run, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco raises ImportError
    plot = tmp_path / "f.png"
    r = run("study", "formulations", "--quick", "--plot", plot)
    assert r.exit_code == 1
    assert r.output.strip() == "Error: ineid study formulations needs MuJoCo: pip install 'ineid[mujoco]'"
    assert not plot.exists()


def test_study_refuses_a_payload_in_one_line(run, tmp_path):
    plot = tmp_path / "f.png"
    r = run("study", "formulations", "--quick", "--unknown-links", "hand", "--plot", plot)
    assert r.exit_code == 1
    assert r.output.strip() == (
        "Error: ineid study formulations simulates moving links, and hand is a payload: "
        "choose --unknown-links among the moving links"
    )
    assert not plot.exists()


def test_the_main_job_never_imports_mujoco():
    code = (
        "import sys, ineid, ineid.data, ineid.identify, ineid.cli, ineid.studies.formulations; "
        "assert 'mujoco' not in sys.modules, 'mujoco imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
