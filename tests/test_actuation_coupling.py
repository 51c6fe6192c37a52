"""Coupled transmissions (:mod:`ineid.channels.transmission`): a wrist whose last motor drives two joints,
simulated in MuJoCo with fixed tendons as the motors, its per-motor torques identified against the simulation's
truth; the coupling files (JSON, CSV, URDF ``<transmission>``) and the records."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ineid.channels import ChannelSet, JointTorque, MotorCurrent, channel_from_dict
from ineid.channels.transmission import read_coupling
from ineid.data import Combination, DatasetSpec, generate_dataset
from ineid.errors import DatasetError
from ineid.identify import SolveSettings, solve_dataset

from .conftest import random_states

MOTORS = ("m1", "m2", "m3", "m4")
TENDONS = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0.5], [0, 0, 1.0, -0.5]])
"""Each motor's tendon ``L_m = sum_j A_mj q_j`` (MuJoCo's fixed tendons): ``qd_motor = A qd_joint``, so the
coupling is ``C = A^-1`` (``qd_joint = C qd_motor``); the wrist's last two motors drive two joints each."""
FV = np.array([0.3, 0.25, 0.1, 0.15])
"""The motors' viscous friction (the tendons' damping), N*m*s/rad."""
FC, ZONE = np.array([0.2, 0.1, 0.05, 0.08]), 0.05
"""The motors' smooth Coulomb friction ``fc tanh(qd_motor / zone)`` (applied through ``A^T``), N*m."""
STEP, STEPS = 5e-4, 10
"""MuJoCo's time step (s) and the steps per recorded sample (200 Hz)."""


def _wrist_xml(model, theta) -> str:
    from ineid.studies.mujoco_sim import NO_FRICTION, arm_mjcf, root_link_theta

    xml = arm_mjcf(model.chain, theta, root_link_theta(model), None, STEP, NO_FRICTION)
    tendons = "".join(
        f'<fixed name="{m}" damping="{float(FV[i])!r}">'
        + "".join(
            f'<joint joint="{j}" coef="{float(a)!r}"/>' for j, a in zip(model.joint_names, TENDONS[i], strict=True) if a
        )
        + "</fixed>"
        for i, m in enumerate(MOTORS)
    )
    motors = "".join(f'<motor tendon="{m}" gear="1"/>' for m in MOTORS)
    start, stop = xml.index("<actuator>"), xml.index("</actuator>") + len("</actuator>")
    return xml[:start] + f"<tendon>{tendons}</tendon><actuator>{motors}</actuator>" + xml[stop:]


def _simulate_wrist(model, n: int, seed: int = 0):
    """MuJoCo runs the arm with its motors on tendons (computed torque towards a sum of sines, 2 Hz, mapped to the
    motors): ``(q, qd, qdd, motor torques)`` at 200 Hz, what the motors apply."""
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_string(_wrist_xml(model, model.theta_cad))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    amp, freq, phase = rng.uniform(0.3, 0.8, (3, model.n_dof)) * [[1], [8], [6]]
    coupling_t = np.linalg.inv(TENDONS).T  # C^T: joint torques into motor torques
    out = {k: np.empty((n, model.n_dof)) for k in ("q", "qd", "qdd", "tau")}
    mass, wn = np.empty((model.n_dof, model.n_dof)), 2 * np.pi * 2.0
    for k in range(n):
        for step in range(STEPS):
            t = d.time
            ref, vref = amp * np.sin(freq * t + phase), amp * freq * np.cos(freq * t + phase)
            aref = -amp * freq**2 * np.sin(freq * t + phase)
            mujoco.mj_forward(m, d)
            mujoco.mj_fullM(m, d, mass)
            a = aref + wn**2 * (ref - d.qpos) + 2 * wn * (vref - d.qvel)
            d.ctrl[:] = coupling_t @ (mass @ a + d.qfrc_bias)
            d.qfrc_applied[:] = -TENDONS.T @ (FC * np.tanh(TENDONS @ d.qvel / ZONE))
            mujoco.mj_forward(m, d)
            if step == 0:
                out["q"][k], out["qd"][k], out["qdd"][k] = d.qpos, d.qvel, d.qacc
                out["tau"][k] = d.ctrl  # what the motors apply (the friction on their tendons among it)
            mujoco.mj_step(m, d)
    return out


def _dataset(model, sim, noise: float = 0.0, current: bool = False):
    channel = JointTorque(coupling=tuple(map(tuple, np.linalg.inv(TENDONS))), motors=MOTORS)
    if current:
        channel = MotorCurrent(torque_constant=(0.1,) * 4, gear_ratio=(50.0,) * 4, **_coupled(channel))
    n = len(sim["q"])
    spec = DatasetSpec(Combination("random", n_configs=1), n_frames=n, seed=3, channels=ChannelSet.of(channel))
    ds = generate_dataset(model, spec)
    tau = sim["tau"] / (5.0 if current else 1.0)
    if noise:
        tau = tau + np.random.default_rng(9).normal(0, noise, tau.shape)
    return dataclasses.replace(
        ds,
        q=sim["q"][None],
        qd=sim["qd"][None],
        qdd=sim["qdd"][None],
        channel_values={channel.key: tau[None]},
        clean={},
        theta_unknown=model.theta_cad[model.unknown_index][None],
    )


def _coupled(channel: JointTorque) -> dict:
    return {"coupling": channel.coupling, "motors": channel.motors}


@pytest.fixture(scope="module")
def wrist(model):
    return _simulate_wrist(model, 200)


def test_the_channel_reads_per_motor(model):
    q, qd, qdd = random_states(model, 20, np.random.default_rng(4))
    c = np.linalg.inv(TENDONS)
    ch = JointTorque(coupling=tuple(map(tuple, c)), motors=MOTORS).with_actuation(
        friction=("viscous", "coulomb"), coulomb_zone=ZONE, armature=True
    )
    assert ch.axes(model) == MOTORS and ch.extra_names(model)[:3] == ("m1.fv", "m1.fc", "m1.Ia")
    np.testing.assert_allclose(ch.rows(model, q, qd, qdd), c.T @ model.joint_torque_regressor(q, qd, qdd), atol=1e-12)
    np.testing.assert_allclose(ch.predict(model, q, qd, qdd, model.theta_cad), model.joint_torques(q, qd, qdd) @ c)
    e = ch.extra_rows(model, q, qd, qdd)
    vm, am = qd @ TENDONS.T, qdd @ TENDONS.T  # the motors' velocities and accelerations, A qd
    np.testing.assert_allclose(e[:, 2, 6:9], np.stack([vm[:, 2], np.tanh(vm[:, 2] / ZONE), am[:, 2]], -1), atol=1e-12)
    np.testing.assert_allclose(np.array(ch.casadi_extra_function(model)(q[3], qd[3], qdd[3])), e[3], atol=1e-12)
    assert channel_from_dict(ch.to_dict()) == ch and ch.to_dict()["motors"] == list(MOTORS)
    assert "per motor (m1, m2, m3, m4) through a coupled transmission" in ch.describe()
    cur = MotorCurrent(torque_constant=(0.1,) * 4, gear_ratio=(50.0,) * 4, **_coupled(ch))
    np.testing.assert_allclose(cur.transform(), np.diag([0.2] * 4) @ c.T)
    assert channel_from_dict(cur.to_dict()) == cur


def test_mujoco_wrist_per_motor_torques_identified_exactly(model, wrist):
    """Clean: MuJoCo's motor torques are ``C^T tau_joint + fv qd_m + fc tanh(qd_m / zone)`` to round-off, and the
    fit finds the motors' friction and predicts the held-out torques exactly."""
    ds = _dataset(model, wrist)
    c = np.linalg.inv(TENDONS)
    tau_joint = model.joint_torques(ds.q[0], ds.qd[0], ds.qdd[0])
    vm = ds.qd[0] @ TENDONS.T
    expected = tau_joint @ c + FV * vm + FC * np.tanh(vm / ZONE)
    scale = np.abs(wrist["tau"]).max()
    assert np.abs(expected - wrist["tau"]).max() < 1e-9 * scale  # the convention, checked on MuJoCo's tendons
    settings = SolveSettings(friction=("viscous", "coulomb"), coulomb_zone=ZONE, backend="casadi")
    res = solve_dataset(ds, settings, model=model)
    names = res.param_names[-8:]
    assert names[:2] == ("m1.fv", "m1.fc")
    np.testing.assert_allclose(res.theta_hat[0, -8:], np.stack([FV, FC], -1).ravel(), rtol=1e-6)
    assert np.nanmax(res.validation_rms) < 1e-8 * scale and np.nanmax(res.fit_rms) < 1e-8 * scale
    # without the coupling the same torques read as joint torques fit far worse
    plain = dataclasses.replace(ds, meta=dataclasses.replace(ds.meta, channels=ChannelSet.of(JointTorque())))
    worse = solve_dataset(plain, settings, model=model)
    assert np.nanmax(worse.fit_rms) > 1e3 * np.nanmax(res.fit_rms)


def test_mujoco_wrist_noisy_currents_within_their_std(model, wrist):
    """Motor currents (0.002 A noise, ``i = tau_m / (k G)``) through the coupling, the zone identified too."""
    ds = _dataset(model, wrist, noise=0.002, current=True)
    settings = SolveSettings(friction=("viscous", "coulomb"), coulomb_zone="identify", backend="casadi")
    res = solve_dataset(ds, settings, model=model)
    (record,) = res.meta["channels"]
    assert abs(record["coulomb_zone"] - ZONE) < 4 * record["identified"]["coulomb_zone"], record
    z = (res.theta_hat[0, -8:] - np.stack([FV, FC], -1).ravel()) / res.theta_std[0, -8:]
    assert np.all(np.abs(z) < 4), z
    assert res.param_names[-8:-6] == ("m1.fv", "m1.fc")


def test_coupling_files(model, tmp_path):
    joints = model.joint_names
    c = np.linalg.inv(TENDONS)
    (tmp_path / "c.json").write_text(
        json.dumps({"joints": list(joints[2:]), "motors": ["m3", "m4"], "matrix": c[2:, 2:].tolist()})
    )
    matrix, motors = read_coupling(tmp_path / "c.json", joints)
    assert motors == ("m3", "m4", joints[0], joints[1])
    np.testing.assert_allclose(np.array(matrix)[2:, :2], c[2:, 2:])
    np.testing.assert_allclose(np.array(matrix)[:2, 2:], np.eye(2))
    rows = "\n".join(f"{j}," + ",".join(repr(float(v)) for v in row) for j, row in zip(joints, c, strict=True))
    (tmp_path / "c.csv").write_text("joint," + ",".join(MOTORS) + "\n" + rows + "\n")
    matrix, motors = read_coupling(tmp_path / "c.csv", joints)
    assert motors == MOTORS and np.allclose(matrix, c)
    urdf = f"""<robot name="r">
      <transmission name="t1"><type>transmission_interface/SimpleTransmission</type>
        <joint name="{joints[0]}"/><actuator name="a1"><mechanicalReduction>50</mechanicalReduction></actuator>
      </transmission>
      <transmission name="wrist"><type>transmission_interface/DifferentialTransmission</type>
        <actuator name="a3"><role>actuator1</role><mechanicalReduction>10</mechanicalReduction></actuator>
        <actuator name="a4"><role>actuator2</role><mechanicalReduction>20</mechanicalReduction></actuator>
        <joint name="{joints[2]}"><role>joint1</role><mechanicalReduction>1</mechanicalReduction></joint>
        <joint name="{joints[3]}"><role>joint2</role><mechanicalReduction>2</mechanicalReduction></joint>
      </transmission></robot>"""
    (tmp_path / "r.urdf").write_text(urdf)
    matrix, motors = read_coupling(tmp_path / "r.urdf", joints)
    assert motors == ("a1", "a3", "a4", joints[1])
    expected = np.zeros((4, 4))
    expected[0, 0], expected[1, 3] = 1 / 50, 1
    expected[2, 1:3] = [1 / (2 * 10), 1 / (2 * 20)]  # ros_control: q_j1 = (q_a1 / r_a1 + q_a2 / r_a2) / (2 r_j1)
    expected[3, 1:3] = [1 / (4 * 10), -1 / (4 * 20)]
    np.testing.assert_allclose(matrix, expected)
    bad = [
        ("s.json", json.dumps({"joints": [joints[0]], "motors": ["a"], "matrix": [[0.0]]}), "singular"),
        ("u.json", json.dumps({"joints": ["wrist"], "motors": ["a"], "matrix": [[1.0]]}), "not the model's"),
        ("n.txt", "", "give a .json, .csv or .urdf file"),
        ("x.urdf", "<robot/>", "no <transmission> element"),
    ]
    for name, text, message in bad:
        (tmp_path / name).write_text(text)
        with pytest.raises(DatasetError, match=message):
            read_coupling(tmp_path / name, joints)


def test_cli_coupling(run, tmp_path, model):
    path = tmp_path / "t.h5"
    r = run("-q", "data", "generate", "--n-configs", "1", "--n-frames", "40", "--channels", "torque", "--out", path)
    assert r.exit_code == 0, r.output
    (tmp_path / "c.json").write_text(
        json.dumps({"joints": list(model.joint_names), "motors": list(MOTORS), "matrix": TENDONS.tolist()})
    )
    out = tmp_path / "r.h5"
    r = run(
        "solve", path, "--friction", "viscous", "--coupling", tmp_path / "c.json", "--backend", "casadi", "--out", out
    )
    assert r.exit_code == 0, r.output
    from ineid.identify import load_results

    res = load_results(out)
    assert res.meta["channels"][0]["motors"] == list(MOTORS) and "m1.fv" in res.param_names
    r = run("solve", path, "--coupling", tmp_path / "none.json", "--out", tmp_path / "bad.h5")
    assert r.exit_code != 0 and "cannot be read" in r.output and "Traceback" not in r.output, r.output


def test_import_per_motor_torques(run, tmp_path, model):
    """``data import --coupling``: a CSV's tau1..tau4 are the motors' (in the coupling's order); the dataset's channel
    carries the coupling, and a solve of it reads per motor without being told again."""
    t = np.arange(0, 3.0, 1e-3)
    f = np.array([0.3, 0.5, 0.7, 0.4])
    q = 0.5 * np.sin(2 * np.pi * f * t[:, None])
    tau = np.cos(2 * np.pi * f * t[:, None])
    header = "time," + ",".join(f"q{i}" for i in range(1, 5)) + "," + ",".join(f"tau{i}" for i in range(1, 5))
    rows = np.column_stack([t, q, tau])
    (tmp_path / "arm.csv").write_text(header + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows))
    (tmp_path / "c.json").write_text(
        json.dumps({"joints": list(model.joint_names), "motors": list(MOTORS), "matrix": TENDONS.tolist()})
    )
    out = tmp_path / "arm.h5"
    r = run(
        "-q",
        "data",
        "import",
        tmp_path / "arm.csv",
        "--robot",
        "sweaty-arm",
        "--coupling",
        tmp_path / "c.json",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    from ineid.data import load_dataset
    from ineid.identify import load_results

    channel = load_dataset(out).meta.channels["tau"]
    assert channel.motors == MOTORS and np.allclose(channel.coupling, TENDONS)
    r = run("solve", out, "--friction", "viscous", "--backend", "casadi", "--out", tmp_path / "r.h5")
    assert r.exit_code == 0, r.output
    assert load_results(tmp_path / "r.h5").param_names[-4:] == tuple(f"{m}.fv" for m in MOTORS)
    r = run(
        "data",
        "import",
        tmp_path / "arm.csv",
        "--robot",
        "sweaty-arm",
        "--coupling",
        tmp_path / "c.txt",
        "--out",
        tmp_path / "bad.h5",
    )
    assert r.exit_code != 0 and "c.txt: cannot be read" in r.output and not (tmp_path / "bad.h5").exists()
