"""Joint torques in the data (:mod:`ineid.data`): the dataset format (version 4), CSV and bag import of
torques (filtered like the wrench, with or without a wrench), ``data generate`` with friction and
noise, and bad input as one line."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from ineid.data import NoiseModel, load_dataset
from ineid.data.recordings.pipeline import import_recording
from ineid.data.recordings.settings import ImportSettings
from ineid.errors import DatasetError

POSE_TEXT = "0.03,-0.02,-0.05,3.1,0.2,0.7"
TOL_FILTER = 5e-4
"""Imported torques against MuJoCo's at the same instants, relative to the largest: the 100 Hz filter's error,
measured 1.5e-4 at worst (where MuJoCo's dry friction kinks the motion), 1e-8 in the median."""


def _torque_csv(lab, path, wrench: bool = True, spelling: str = "tau{i}", rows: slice = slice(None)):
    """The lab recording as a CSV with joint torques (MuJoCo's actuator torques) beside the angles."""
    sim, n = lab.sim, lab.model.n_dof
    names = [spelling.format(i=i, joint=j) for i, j in enumerate(lab.model.joint_names, start=1)]
    header = ["time", *(f"q{i}" for i in range(1, n + 1)), *names]
    columns = [sim.time[rows, None], sim.q[rows], sim.tau[rows]]
    if wrench:
        header += ["fx", "fy", "fz", "mx", "my", "mz"]
        columns.append(lab.reading[rows])
    np.savetxt(path, np.concatenate(columns, axis=1), delimiter=",", header=",".join(header), comments="", fmt="%.17g")
    return path


def _at_grid(lab, ds) -> np.ndarray:
    """The MuJoCo samples at the dataset's frames (the grid is a subset of the recording's instants)."""
    idx = np.searchsorted(lab.sim.time, ds.time[0] - 1e-9)
    assert np.allclose(lab.sim.time[idx], ds.time[0], atol=1e-9)
    return idx


# -- data generate: Phi theta + E x, against Pinocchio ------------------------------------------------


def _truth(model) -> dict[str, float]:
    """Different actuation on every joint: viscous, Coulomb, offset, armature."""
    return {
        f"{j}.{t}": v
        for k, j in enumerate(model.joint_names)
        for t, v in (("fv", 0.05 * (k + 1)), ("fc", 0.2 + 0.1 * k), ("offset", 0.2 * k - 0.3), ("Ia", 0.01 * (k + 1)))
    }


def _pinocchio_torques(model, theta, q, qd, qdd) -> np.ndarray:
    """``pin.rnea`` with each configuration's parameters: (C, F, n_dof)."""
    import pinocchio as pin

    from ineid.reference import pinocchio_joint_torques, pinocchio_model

    pm = pinocchio_model(model.urdf_path, gravity=model.gravity)
    out = np.empty(q.shape)
    for c in range(q.shape[0]):
        for i in range(1, pm.njoints):
            pm.inertias[i] = pin.Inertia.FromDynamicParameters(theta[c, 10 * (i - 1) : 10 * i])
        out[c] = pinocchio_joint_torques(pm, q[c], qd[c], qdd[c])
    return out


@pytest.mark.parametrize("path", ["casadi", "jax"])
def test_generated_torques_are_the_channel_and_pinocchios_rnea_plus_friction(model, tmp_path, monkeypatch, path):
    pytest.importorskip("pinocchio")
    import ineid.robots.model as robot_model
    from ineid.channels import BaseWrench, ChannelSet
    from ineid.channels.torque import JointTorque
    from ineid.data import Combination, DatasetSpec, generate_dataset, write_dataset
    from ineid.data.synthesis.generate import actuated

    if path == "jax":  # a small dataset goes through CasADi; the big ones' compiled JAX path, forced
        monkeypatch.setattr(robot_model, "SMALL_JOB_FRAMES", 0)
    truth = _truth(model)
    channels = ChannelSet.of(BaseWrench(), JointTorque())
    spec = DatasetSpec(Combination("random", n_configs=3), n_frames=40, seed=2, channels=channels, extra_truth=truth)
    ds = load_dataset(write_dataset(model, spec, tmp_path / "t.h5"))
    assert ds.meta.version == 4 and ds.meta.extra_truth == truth and ds.meta.channels == channels
    theta, q, qd, qdd = ds.theta(), ds.q, ds.qd, ds.qdd
    tau = ds.channel_values["tau"]
    full = actuated(JointTorque())
    x = np.array([truth[name] for name in full.extra_names(model)])
    expected = JointTorque().predict(model, q, qd, qdd, theta[:, None, :]) + full.extra_rows(model, q, qd, qdd) @ x
    scale = np.abs(expected).max()
    assert np.abs(tau - expected).max() < 1e-13 * scale
    per_joint = {t: np.array([truth[f"{j}.{t}"] for j in model.joint_names]) for t in ("fv", "fc", "offset", "Ia")}
    friction = per_joint["fv"] * qd + per_joint["fc"] * np.sign(qd) + per_joint["offset"] + per_joint["Ia"] * qdd
    assert np.abs(tau - (_pinocchio_torques(model, theta, q, qd, qdd) + friction)).max() < 1e-10 * scale
    # the wrench and the frames are those of a wrench-only file
    plain = generate_dataset(model, DatasetSpec(Combination("random", n_configs=3), n_frames=40, seed=2))
    assert np.array_equal(plain.q, ds.q) and np.abs(plain.wrench - ds.wrench).max() < 1e-12 * np.abs(ds.wrench).max()


def test_asymmetric_friction_and_torque_noise(model):
    from ineid.channels import ChannelSet
    from ineid.channels.torque import JointTorque
    from ineid.data import Combination, DatasetSpec, generate_dataset

    channels = ChannelSet.of(JointTorque())
    base = DatasetSpec(Combination("random", n_configs=2), n_frames=30, seed=4, channels=channels)
    clean = generate_dataset(model, base)
    elbow = model.joint_names.index("elbow")
    asym = generate_dataset(model, dataclasses.replace(base, extra_truth={"elbow.fv+": 0.3, "elbow.fc-": 0.5}))
    qd = clean.qd[..., elbow]
    added = asym.channel_values["tau"] - clean.channel_values["tau"]
    assert np.allclose(added[..., elbow], 0.3 * np.maximum(qd, 0) - 0.5 * (qd < 0), atol=1e-12)
    assert np.all(added[..., [k for k in range(model.n_dof) if k != elbow]] == 0)
    noise = NoiseModel.create(model.n_dof, q=0.001, channels={"tau": 0.02})
    noisy = generate_dataset(model, dataclasses.replace(base, noise=noise))
    assert np.array_equal(noisy.clean["tau"], clean.channel_values["tau"])
    err = noisy.channel_values["tau"] - noisy.clean["tau"]
    assert abs(err.std() / 0.02 - 1) < 0.15 and noisy.meta.noise["tau"] == [0.02]
    q_only = generate_dataset(model, dataclasses.replace(base, noise=NoiseModel.create(model.n_dof, q=0.001)))
    assert np.array_equal(q_only.q, noisy.q)  # the torque noise is drawn after the others
    with pytest.raises(DatasetError, match=r"no simulated extra parameter 'elbow\.fv'; the channels take"):
        generate_dataset(model, dataclasses.replace(base, extra_truth={"elbow.fv+": 0.3, "elbow.fv": 0.1}))
    with pytest.raises(DatasetError, match="actuation values .* are for joint torques"):
        generate_dataset(
            model, DatasetSpec(Combination("random", n_configs=2), n_frames=3, extra_truth={"elbow.fv": 1})
        )


def test_cli_generate_torques_and_info(run, tmp_path):
    out = tmp_path / "both.h5"
    r = run(
        "-q",
        "data",
        "generate",
        "--n-configs",
        "2",
        "--n-frames",
        "10",
        "--channels",
        "wrench,torque",
        "--friction-truth",
        "fv=0.05,fc=0.2,elbow.Ia=0.01",
        "--noise",
        "force=0.5,tau=0.02",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    ds = load_dataset(out)
    assert ds.meta.channels.keys == ("wrench", "tau") and ds.meta.noise["tau"] == [0.02]
    assert ds.meta.extra_truth["shoulder_pitch.fv"] == 0.05 and ds.meta.extra_truth["elbow.Ia"] == 0.01
    assert "shoulder_pitch.Ia" not in ds.meta.extra_truth
    r = run("data", "info", out)
    assert r.exit_code == 0, r.output
    assert "simulated actuation (extra_truth)" in r.output and "N*m" in r.output
    assert all(j in r.output for j in ("shoulder_pitch", "elbow")), r.output
    bad = [
        (("--friction-truth", "fv=0.1"), "--friction-truth is what joint torques add"),
        (("--noise", "tau=0.1"), "tau noise is the joint torques'"),
        (("--channels", "torque", "--noise", "force=0.1"), "force and moment noise is the base wrench's"),
        (("--channels", "torque", "--friction-truth", "wrist.fv=1"), "the robot has no moving joint 'wrist'"),
        (("--channels", "torque", "--friction-truth", "fq=1"), "expected TERM=VALUE or JOINT.TERM=VALUE"),
        (("--channels", "wrench,strain"), "expected a comma-separated list of wrench, torque"),
    ]
    for args, message in bad:
        bad_out = tmp_path / "bad.h5"
        r = run("-q", "data", "generate", "--n-configs", "2", "--n-frames", "5", *args, "--out", bad_out)
        assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, (message, r.output)
        assert not bad_out.exists()


def test_cli_generate_a_wrist_sensor(run, tmp_path, model):
    """``--sensor-pose LINK:...`` (or a frame on a link): the wrench at that link, with the force and moment noise."""
    from ineid.channels import BaseWrench, LinkWrench, SensorPose, sensor_channel

    out = tmp_path / "wrist.h5"
    r = run(
        "-q",
        "data",
        "generate",
        "--n-configs",
        "2",
        "--n-frames",
        "8",
        "--channels",
        "wrench,torque",
        "--sensor-pose",
        "upper_arm:0.01,0,0.05,0,0,0.3",
        "--noise",
        "force=0.5,moment=0.05,tau=0.01",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    ds = load_dataset(out)
    wrist = ds.meta.channels["wrench_upper_arm"]  # what the forearm exerts on the upper arm, at the sensor
    assert isinstance(wrist, LinkWrench) and wrist.link == "upper_arm" and wrist.sensor.xyz == (0.01, 0, 0.05)
    assert ds.meta.channels.keys == ("wrench_upper_arm", "tau") and ds.wrench is None
    assert ds.meta.noise["wrench_upper_arm"] == [0.5, 0.5, 0.5, 0.05, 0.05, 0.05]
    clean = wrist.predict(model, ds.q, ds.qd, ds.qdd, ds.theta()[:, None, :])
    assert np.abs(ds.clean["wrench_upper_arm"] - clean).max() < 1e-12 * np.abs(clean).max()
    assert 0.2 < np.std(ds.channel_values["wrench_upper_arm"][..., 0] - clean[..., 0]) < 0.8
    hand = sensor_channel("hand", model)  # a frame welded to the forearm: the wrench at the forearm
    assert hand.key == "wrench_forearm" and np.allclose(hand.sensor.xyz, (0, 0, -0.26))
    out = tmp_path / "base.h5"
    r = run("-q", "data", "generate", "--n-configs", "2", "--n-frames", "8", "--sensor-pose", POSE_TEXT, "--out", out)
    assert r.exit_code == 0, r.output
    ds = load_dataset(out)
    base = ds.meta.channels["wrench"]
    assert isinstance(base, BaseWrench) and base.sensor == SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
    w = base.sensor.transform() @ model.base_wrench(ds.q, ds.qd, ds.qdd, ds.theta()[:, None, :])[..., None]
    assert np.abs(ds.wrench - w[..., 0]).max() < 1e-12 * np.abs(w).max()
    r = run("-q", "data", "generate", "--channels", "torque", "--sensor-pose", "hand", "--out", tmp_path / "bad.h5")
    assert r.exit_code == 2 and "--sensor-pose places the F/T sensor of the wrench channel" in r.output


# -- recordings: CSV and bags ------------------------------------------------------------------------


def test_csv_torques_are_filtered_like_the_wrench_and_read_back(lab, tmp_path):
    path = _torque_csv(lab, tmp_path / "rec.csv")
    ds, summary = import_recording(path, lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    assert ds.meta.channels.keys == ("wrench", "tau") and ds.meta.channels["tau"].kind == "joint_torque"
    assert "joint torques on the joints' clock" in "\n".join(summary.lines())
    assert "joint torques and the wrench filtered the same" in "\n".join(summary.lines())
    idx = _at_grid(lab, ds)
    tau = ds.channel_values["tau"][0]
    scale = np.abs(lab.sim.tau).max()
    err = np.abs(tau - lab.sim.tau[idx])
    assert err.max() < TOL_FILTER * scale and np.median(err) < 1e-7 * scale
    # the same filter as the angles: the torques keep their instants (a zero-phase filter)
    plain, _ = import_recording(lab.file("csv"), lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    assert (
        np.array_equal(plain.time, ds.time)
        and np.array_equal(plain.q, ds.q)
        and np.array_equal(plain.wrench, ds.wrench)
    )
    back = load_dataset(ds.save(tmp_path / "rec.h5"))
    assert back.meta.channels == ds.meta.channels
    assert np.array_equal(back.channel_values["tau"], ds.channel_values["tau"])
    assert back.fingerprint() == ds.fingerprint() != plain.fingerprint()


@pytest.mark.parametrize("coulomb", [False, True])
def test_imported_torques_are_the_model_at_the_filtered_states(model, tmp_path, coulomb):
    """Angles and torques through the same filter stay consistent: the imported torques are the channel's
    ``Phi theta + E x`` at the filtered states (as the wrench is), except where a Coulomb step is smeared."""
    from ineid.channels import BaseWrench, ChannelSet
    from ineid.channels.torque import JointTorque
    from ineid.data import Combination, DatasetSpec, FrameSampling, generate_dataset, write_recording_csv
    from ineid.data.synthesis.generate import actuated

    truth = {"elbow.fc": 0.3} if coulomb else {"elbow.fv": 0.1, "shoulder_roll.Ia": 0.02, "elbow.offset": 0.5}
    spec = DatasetSpec(
        Combination("random", n_configs=1),
        n_frames=4000,
        frames=FrameSampling("fourier", base_frequency=0.25),
        channels=ChannelSet.of(BaseWrench(), JointTorque()),
        extra_truth=truth,
    )
    ds = generate_dataset(model, spec)  # 1 kHz, 4 s, one period
    rec, _ = import_recording(write_recording_csv(tmp_path / "t.csv", ds, derivatives=False), model, ImportSettings())
    full = actuated(JointTorque())
    x = np.array([truth.get(name, 0.0) for name in full.extra_names(model)])
    q, qd, qdd = rec.q[0], rec.qd[0], rec.qdd[0]
    expected = JointTorque().predict(model, q, qd, qdd, ds.theta()[0]) + full.extra_rows(model, q, qd, qdd) @ x
    err = np.abs(rec.channel_values["tau"][0] - expected) / np.abs(expected).max()
    wrench = BaseWrench().predict(model, q, qd, qdd, ds.theta()[0])
    assert np.abs(rec.wrench[0] - wrench).max() < 1e-5 * np.abs(wrench).max()
    if coulomb:  # sign(qd) is a step the filter spreads over its width: 2.2 % at worst, in 0.6 % of the frames
        assert np.median(err) < 1e-6 and np.mean(err > 1e-4) < 0.02 and err.max() < 0.05
    else:  # measured 2.2e-6 (the wrench's: 4e-6)
        assert err.max() < 1e-5


def test_torques_without_a_wrench(lab, tmp_path):
    """A lab with joint torque sensors only: no wrench columns, a dataset of one joint-torque channel."""
    both, _ = import_recording(_torque_csv(lab, tmp_path / "both.csv"), lab.model, ImportSettings())
    named = _torque_csv(lab, tmp_path / "named.csv", wrench=False, spelling="TAU_{joint}")
    ds, summary = import_recording(named, lab.model, ImportSettings())
    assert ds.meta.channels.keys == ("tau",) and ds.wrench is None and ds.meta.sensor is None
    assert "no wrench" in "\n".join(summary.lines()) and not any("sensor frame" in s for s in summary.lines())
    assert np.array_equal(ds.time, both.time) and np.array_equal(ds.channel_values["tau"], both.channel_values["tau"])
    back = load_dataset(ds.save(tmp_path / "tau.h5"))
    assert back.meta.channels.keys == ("tau",) and back.wrench is None
    assert np.array_equal(back.measured(), ds.channel_values["tau"])
    # write_recording_csv writes the torques (and no wrench); with qd, qdd the rows are the frames again
    from ineid.data import write_recording_csv

    again, _ = import_recording(write_recording_csv(tmp_path / "again.csv", ds), lab.model, ImportSettings())
    assert again.meta.channels.keys == ("tau",) and np.array_equal(
        again.channel_values["tau"], ds.channel_values["tau"]
    )


def test_bag_efforts_are_the_joint_torques_matched_by_name(lab, tmp_path):
    from tests.bag_files import write_bag

    sim, model = lab.sim, lab.model
    names = [*reversed(model.joint_names), "head_pan"]  # another order, an extra joint
    q_msg = np.column_stack([sim.q[:, ::-1], np.zeros(len(sim.q))])
    effort = np.column_stack([sim.tau[:, ::-1], np.full(len(sim.q), 7.0)])
    csv, _ = import_recording(_torque_csv(lab, tmp_path / "rec.csv"), model, ImportSettings(sensor_pose=POSE_TEXT))
    bag = write_bag(tmp_path / "rec.bag", "ros1", names, sim.time, q_msg, sim.time, lab.reading, effort=effort)
    ds, _ = import_recording(bag, model, ImportSettings(sensor_pose=POSE_TEXT))
    assert ds.meta.channels.keys == ("wrench", "tau") and ds.meta.origin["effort"] is True
    scale = np.abs(csv.channel_values["tau"]).max()
    assert np.abs(ds.channel_values["tau"] - csv.channel_values["tau"]).max() < 1e-7 * scale
    only = write_bag(tmp_path / "only", "mcap", names, sim.time, q_msg, None, None, effort=effort)
    ds2, _ = import_recording(only, model, ImportSettings())
    assert ds2.meta.channels.keys == ("tau",) and ds2.wrench is None
    assert np.abs(ds2.channel_values["tau"] - csv.channel_values["tau"]).max() < 1e-7 * scale
    # empty efforts (the tests' other bags): the wrench alone, as before
    plain = import_recording(lab.file("ros1"), model, ImportSettings(sensor_pose=POSE_TEXT))[0]
    assert plain.meta.channels.keys == ("wrench",) and "effort" not in plain.meta.origin


def test_a_wrench_at_a_link_is_a_link_wrench_channel(lab, tmp_path, run):
    """A wrist sensor: ``--sensor-pose LINK:x,y,z,r,p,y`` or a URDF frame welded to a moving link."""
    from ineid.channels import SensorPose
    from ineid.data.recordings.channels import resolve_wrench_channel

    model = lab.model
    channel, where = resolve_wrench_channel("hand", None, model)  # welded to the forearm, 0.26 m down its z
    assert channel.kind == "link_wrench" and channel.key == "wrench_forearm" and channel.link == "forearm"
    assert np.allclose(channel.sensor.xyz, (0, 0, -0.26)) and channel.sensor.frame == "hand" and "forearm" in where
    channel, _ = resolve_wrench_channel("forearm:0.01,0,-0.24,0,0,1.5", "ft_wrist", model)
    assert channel.link == "forearm" and channel.sensor.frame_id == "ft_wrist"
    assert channel.sensor.xyz == (0.01, 0, -0.24) and channel.sensor.rpy == (0, 0, 1.5)
    base, where = resolve_wrench_channel(POSE_TEXT, "ft_sensor_base", model)  # six numbers: under the base
    assert base.kind == "wrench" and where == "the base frame" and base.sensor.frame_id == "ft_sensor_base"
    assert base.sensor == SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7), frame_id="ft_sensor_base")
    assert resolve_wrench_channel(None, "upper_arm", model)[0].link == "upper_arm"  # a bag's frame_id on a link
    ds, summary = import_recording(lab.file("csv"), model, ImportSettings(sensor_pose="forearm:0,0,-0.1,0,0,0"))
    assert ds.meta.channels.keys == ("wrench_forearm",) and ds.wrench is None
    assert np.array_equal(ds.channel_values["wrench_forearm"], import_recording(lab.file("csv"), model)[0].wrench)
    assert "sensor frame in link 'forearm''s frame: xyz=(0, 0, -0.1) m" in "\n".join(summary.lines())
    back = load_dataset(ds.save(tmp_path / "wrist.h5"))
    assert back.meta.channels == ds.meta.channels
    r = run("data", "info", tmp_path / "wrist.h5")
    assert r.exit_code == 0 and "sensor frame in link 'forearm''s frame" in r.output, r.output
    with pytest.raises(DatasetError, match=r"'gripper' is not a moving link of sweaty-arm \(choose from "):
        resolve_wrench_channel("gripper:0,0,0,0,0,0", None, model)


def test_motor_currents_with_their_drives(lab, tmp_path):
    """Currents ``i1..in`` with ``--torque-constant``/``--gear-ratio``: a motor-current channel under ``current``."""
    k, g = np.array([0.1, 0.12, 0.08, 0.05]), np.array([100.0, 120.0, -80.0, 50.0])
    rows = slice(0, 2000)
    tau_csv = _torque_csv(lab, tmp_path / "tau.csv", wrench=False, rows=rows)
    lines = tau_csv.read_text().splitlines()
    table = np.loadtxt(tau_csv, delimiter=",", skiprows=1)
    table[:, 5:9] /= k * g  # the drives' currents
    path = tmp_path / "i.csv"
    np.savetxt(path, table, delimiter=",", header=lines[0].replace("tau", "i"), comments="", fmt="%.17g")
    ds, _ = import_recording(path, lab.model, ImportSettings(torque_constant=tuple(k), gear_ratio=tuple(g)))
    assert ds.meta.channels.keys == ("current",) and ds.meta.channels["current"].kind == "motor_current"
    assert ds.meta.channels["current"].gear_ratio == tuple(g)
    torques, _ = import_recording(tau_csv, lab.model, ImportSettings())
    assert np.allclose(ds.channel_values["current"] * k * g, torques.channel_values["tau"], rtol=1e-12, atol=1e-12)
    back = load_dataset(ds.save(tmp_path / "i.h5"))
    assert back.meta.channels == ds.meta.channels
    with pytest.raises(DatasetError, match="3 gear ratios for 4 joints"):
        import_recording(path, lab.model, ImportSettings(torque_constant=(0.1,), gear_ratio=(1.0, 2.0, 3.0)))


# -- the dataset format ------------------------------------------------------------------------------


def test_version_4_is_refused_by_an_older_reader_with_one_line(lab, tmp_path, monkeypatch):
    import ineid.data.dataset.read as read

    ds, _ = import_recording(lab.file("csv"), lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    path = ds.save(tmp_path / "v4.h5")
    with h5py.File(path, "r") as f:
        assert int(f.attrs["version"]) == 4 and json.loads(f.attrs["extra_truth"]) is None
    monkeypatch.setattr(read, "VERSION", 3)  # what a reader of version 3 says
    with pytest.raises(
        DatasetError,
        match=r"format version 4 is not supported \(this ineid reads versions 1\.\.3\); "
        "upgrade ineid",
    ):
        load_dataset(path)


def test_extra_truth_is_stored_and_checked(lab, tmp_path):
    ds, _ = import_recording(lab.file("csv"), lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    truth = {"elbow.fv": 0.05, "elbow.fc": 0.2}
    meta = dataclasses.replace(ds.meta, extra_truth=truth)
    path = dataclasses.replace(ds, meta=meta).save(tmp_path / "truth.h5")
    back = load_dataset(path)
    assert back.meta.extra_truth == truth
    with h5py.File(path, "r+") as f:
        f.attrs["extra_truth"] = json.dumps({"elbow.fv": "fast"})
    with pytest.raises(
        DatasetError, match=r"truth\.h5: extra_truth: 'elbow\.fv' = 'fast' is not a named finite number"
    ):
        load_dataset(path)
    with h5py.File(path, "r+") as f:  # version 3 had none: the attribute is not read
        f.attrs["version"] = 3
    assert load_dataset(path).meta.extra_truth is None


def test_channel_noise_is_recorded_and_drawn_after_the_others():
    rng = np.random.default_rng
    arrays = {
        "q": np.zeros((2, 5, 4)),
        "qd": np.zeros((2, 5, 4)),
        "qdd": np.zeros((2, 5, 4)),
        "wrench": np.zeros((2, 5, 6)),
        "tau": np.ones((2, 5, 4)),
    }
    plain = NoiseModel.create(4, force=0.5, q=0.01)
    noisy = NoiseModel.create(4, force=0.5, q=0.01, channels={"tau": [0.1, 0.2, 0.3, 0.4]})
    a, b = plain.apply(arrays, rng(3)), noisy.apply(arrays, rng(3))
    assert all(np.array_equal(a[k], b[k]) for k in ("q", "qd", "qdd", "wrench"))  # the old draws are unchanged
    assert "tau" not in a and np.all(np.abs(b["tau"] - 1).std(axis=(0, 1)) > 0)
    assert noisy.noisy_keys() == ("q", "wrench", "tau")
    record = noisy.to_dict()
    assert record["tau"] == [0.1, 0.2, 0.3, 0.4] and NoiseModel.from_dict(record, 4).to_dict() == record
    with pytest.raises(ValueError, match="tau noise has 3 standard deviations for 4 axes"):
        NoiseModel.create(4, channels={"tau": [0.1, 0.2, 0.3]}).apply(arrays, rng(0))
    with pytest.raises(ValueError, match="channel noise key 'wrench' is the noise model's own"):
        NoiseModel(channels={"wrench": 1.0})


# -- bad input: one line each, no file -----------------------------------------------------------------


def test_bad_torque_recordings_are_one_line_and_leave_no_file(lab, run, tmp_path):
    from tests.bag_files import write_bag

    n = 300
    sim, model = lab.sim, lab.model
    rows = slice(0, n)
    three = tmp_path / "three.csv"
    header = ["time", *(f"q{i}" for i in range(1, 5)), "tau1", "tau2", "tau3", "fx", "fy", "fz", "mx", "my", "mz"]
    np.savetxt(
        three,
        np.concatenate([sim.time[rows, None], sim.q[rows], sim.tau[rows, :3], lab.reading[rows]], axis=1),
        delimiter=",",
        header=",".join(header),
        comments="",
        fmt="%.17g",
    )
    nan = _torque_csv(lab, tmp_path / "nan.csv", rows=rows)
    lines = nan.read_text().splitlines()
    cells = lines[101].split(",")
    cells[6] = "nan"
    lines[101] = ",".join(cells)
    nan.write_text("\n".join(lines) + "\n")
    other = _torque_csv(lab, tmp_path / "other.csv", rows=rows, spelling="tau_{joint}")
    other.write_text(other.read_text().replace("tau_elbow", "tau_wrist", 1))
    short = write_bag(
        tmp_path / "short.bag",
        "ros1",
        model.joint_names,
        sim.time[rows],
        sim.q[rows],
        sim.time[rows],
        lab.reading[rows],
        effort=[sim.tau[k, :3] for k in range(n)],
    )
    currents = tmp_path / "currents.csv"
    currents.write_text(_torque_csv(lab, tmp_path / "c.csv", rows=rows).read_text().replace("tau", "i"))
    only = _torque_csv(lab, tmp_path / "only.csv", wrench=False, rows=rows)
    cases = [
        ((lab.file("csv"), "--sensor-pose", "wrist:0,0,0.1,0,0,0"), "'wrist' is not a moving link of sweaty-arm"),
        (
            (only, "--flip-wrench", "--sensor-pose", "hand"),
            "--sensor-pose, --flip-wrench set up the F/T sensor, and the recording has no wrench",
        ),
        ((only, "--gear-ratio", "100"), "--torque-constant and --gear-ratio are the motor currents' drives"),
        (three, "the joint torque columns are for 3 joints (up to tau3), but sweaty-arm has 4"),
        (nan, "line 102, column 'tau2' is nan; values must be finite"),
        (other, "column 'tau_wrist' names no joint of sweaty-arm"),
        (short, "joint state message 0 on /joint_states has 3 efforts for 4 names"),
        (currents, "motor currents are read through the drives: give their torque constants and gear ratios"),
    ]
    for args, message in cases:
        out = tmp_path / "out.h5"
        r = run(
            "-q",
            "data",
            "import",
            *(args if isinstance(args, tuple) else (args,)),
            "--robot",
            "sweaty-arm",
            "--out",
            out,
        )
        assert r.exit_code == 1 and "Traceback" not in r.output, r.output
        text = [line for line in r.output.splitlines() if line.strip()]
        assert len(text) == 1 and text[0].startswith("Error: ") and message in text[0], (message, r.output)
        assert not out.exists() and not list(tmp_path.glob(".out.h5*"))
