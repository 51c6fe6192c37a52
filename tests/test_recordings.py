"""Recordings as a lab makes them (:mod:`ineid.data.recordings`), checked against MuJoCo: the sensor frame and
its offsets, joint angles only, two clocks, CSV and ROS bags, and the identified parameters."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

import ineid
from ineid import DatasetError, RobotModelError
from ineid.channels.pose import (
    SensorPose,
    matrix_rpy,
    parse_sensor_pose,
    rpy_matrix,
    wrench_in_sensor,
    wrench_transform,
)
from ineid.data import load_dataset
from ineid.data.dataset.meta import VERSION
from ineid.data.recordings.pipeline import Streams, import_recording, recording_dataset
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.signals import LowPass, choose_cutoff
from ineid.identify import (
    SolveSettings,
    bias_cost,
    estimate_delay,
    generic_frames,
    load_results,
    save_results,
    solve_dataset,
)

POSE_TEXT = "0.03,-0.02,-0.05,3.1,0.2,0.7"
TOL_1KHZ = 1e-4
"""Base-parameter error allowed at 1 kHz without noise: the filtering's measured error is 2.1e-5 to
2.5e-5 (largest over the 16-17 base parameters, every method, with and without offsets)."""
TOL_TWO_CLOCKS = 5e-4
"""Joints at 500 Hz, wrench at 500 Hz half a sample later and 3 ms late: measured 1.6e-4."""


def base_error(res, theta_unknown, row: int = 0) -> np.ndarray:
    """Per base parameter ``|beta_hat - beta_true| / max(|beta_true|, scale)``: relative, except for
    base parameters much smaller than their scale (those near zero), where it is relative to the scale."""
    b = res.base
    truth = theta_unknown @ b.B.T
    return np.abs(res.base_hat[row] - truth) / np.maximum(np.abs(truth), b.scales[b.base_index])


# -- the independent engine and the sensor frame ----------------------------------------------


def test_mujoco_sensor_reads_ineids_base_wrench_in_its_frame(lab):
    """MuJoCo's F/T sensor (its own Newton-Euler) = X (ineid's base wrench + the root's weight), frame by frame."""
    sim, model = lab.sim, lab.model
    w_base = np.asarray(model.base_wrench(sim.q, sim.qd, sim.qdd, lab.theta))
    rt = sim.root_theta
    root = np.concatenate([rt[0] * model.gravity, np.cross(rt[1:4], model.gravity)])
    expected = wrench_in_sensor(lab.pose.transform(), w_base + root)
    scale = np.abs(sim.wrench_sensor).max()
    assert np.abs(expected - sim.wrench_sensor).max() < 1e-10 * scale
    # the recording moves: velocities and accelerations of a real excitation, friction on
    assert np.abs(sim.qd).max() > 1.0 and np.abs(sim.qdd).max() > 4.0


def test_wrench_transform_and_rpy_match_pinocchio(rng):
    pin = pytest.importorskip("pinocchio")
    for _ in range(20):
        rpy = rng.uniform(-np.pi, np.pi, 3) * np.array([1, 0.5, 1])
        p = rng.normal(0, 0.3, 3)
        r = rpy_matrix(*rpy)
        assert np.allclose(r, pin.rpy.rpyToMatrix(*rpy), atol=1e-14)
        assert np.allclose(rpy_matrix(*matrix_rpy(r)), r, atol=1e-12)
        w = rng.normal(size=6)
        # the force in the base frame, expressed in the sensor frame: base_M_sensor^-1 acting on it
        expected = pin.SE3(r, p).actInv(pin.Force(w[:3], w[3:])).vector
        assert np.allclose(wrench_transform(r, p) @ w, expected, atol=1e-12)


SENSOR_URDF = """<robot name="arm-on-sensor">
  <link name="world"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="ft_sensor"/>
    <origin xyz="0.1 0.2 0.3" rpy="3.14159 0 0.5"/></joint>
  <link name="ft_sensor"/>
  <joint name="plate" type="fixed"><parent link="ft_sensor"/><child link="base_link"/>
    <origin xyz="0 0 -0.02" rpy="0 0.1 0"/></joint>
  <link name="base_link">
    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
  <link name="l1">
    <inertial><origin xyz="0.1 0 0"/>
      <mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
</robot>"""


def test_sensor_pose_from_numbers_or_a_urdf_frame():
    pose = parse_sensor_pose("0.1, 0.2, 0.3, 3.14159, 0, 0.5")
    assert pose.xyz == (0.1, 0.2, 0.3) and pose.rpy == (3.14159, 0.0, 0.5) and pose.frame is None
    named = parse_sensor_pose("ft_sensor", SENSOR_URDF)
    assert named.frame == "ft_sensor"
    assert np.allclose(named.transform(), pose.transform(), atol=1e-12)
    chained = parse_sensor_pose("base_link", SENSOR_URDF)  # two fixed joints composed
    r = rpy_matrix(3.14159, 0, 0.5) @ rpy_matrix(0, 0.1, 0)
    p = np.array([0.1, 0.2, 0.3]) + rpy_matrix(3.14159, 0, 0.5) @ np.array([0, 0, -0.02])
    assert np.allclose(chained.base_R_sensor, r, atol=1e-12) and np.allclose(chained.base_p_sensor, p)
    with pytest.raises(RobotModelError, match="moves with revolute joint 'j1'"):
        parse_sensor_pose("l1", SENSOR_URDF)
    with pytest.raises(RobotModelError, match="'mount' is a joint; give its child link 'ft_sensor'"):
        parse_sensor_pose("mount", SENSOR_URDF)
    for bad in ("1,2,3", "0,0,0,0,0,nan", "up,side,down", "0.1;0.2;0.3;0;0;0"):
        with pytest.raises(DatasetError, match="expected six"):
            parse_sensor_pose(bad, SENSOR_URDF if "," in bad else None)


def test_version_3_stores_the_channels_and_versions_2_and_1_still_read(lab, tmp_path):
    ds, _ = import_recording(lab.file("csv"), lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    path = ds.save(tmp_path / "v3.h5")
    back = load_dataset(path)
    assert back.meta.version == VERSION and back.meta.sensor_pose() == SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
    assert np.allclose(back.meta.sensor_transform(), lab.pose.transform())
    assert back.meta.channels == ds.meta.channels and back.fingerprint() == ds.fingerprint()
    with h5py.File(path, "r+") as f:  # what ineid 0.1 wrote: version 2, the sensor attribute
        f.attrs["version"] = 2
        f.attrs["sensor"] = json.dumps(back.meta.sensor, sort_keys=True)
        del f.attrs["channels"]
    v2 = load_dataset(path)
    assert v2.meta.version == 2 and v2.meta.channels == back.meta.channels and v2.fingerprint() == back.fingerprint()
    with h5py.File(path, "r+") as f:  # what ineid 0.1 wrote first: version 1, no sensor attribute
        f.attrs["version"] = 1
        del f.attrs["sensor"]
    old = load_dataset(path)
    assert old.meta.version == 1 and old.meta.sensor is None and old.meta.sensor_transform() is None
    assert old.meta.channels.keys == ("wrench",) and old.meta.channels["wrench"].transform() is None
    assert np.array_equal(old.wrench, back.wrench)


# -- joint angles only: filter, derivatives, ends ------------------------------------------------


def test_derivatives_from_angles_match_mujoco(lab):
    ds, summary = import_recording(lab.file("csv"), lab.model, ImportSettings(sensor_pose=POSE_TEXT))
    sim = lab.sim
    k = np.searchsorted(sim.time, ds.time[0] - 1e-9)
    assert np.allclose(sim.time[k], ds.time[0], atol=1e-12)  # the frames are the recorded samples
    edge = int(np.ceil(3 * 1000 / summary.cutoff))  # EDGE_PERIODS cut-off periods
    assert summary.derived and summary.dropped_joint_samples == 2 * edge and summary.cutoff_choice.limited == "rate"

    def rel(a, b):
        return np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2))

    # measured at 100 Hz (noise-free, the upper bound): qd 2.5e-5, qdd 4.9e-3 (dry friction's kinks), wrench 6.5e-5
    assert rel(ds.q[0], sim.q[k]) < 1e-7
    assert rel(ds.qd[0], sim.qd[k]) < 5e-5
    assert rel(ds.qdd[0], sim.qdd[k]) < 1e-2
    # the same filter on the wrench keeps the model consistent: far better than qdd's own error
    predicted = wrench_in_sensor(
        lab.pose.transform(), np.asarray(lab.model.base_wrench(ds.q[0], ds.qd[0], ds.qdd[0], lab.theta))
    )
    resid = ds.wrench[0] - predicted
    resid -= resid.mean(axis=0)  # the offsets
    assert np.sqrt(np.mean(resid**2)) < 2e-4 * np.sqrt(np.mean((ds.wrench[0] - ds.wrench[0].mean(0)) ** 2))


def test_cutoff_follows_the_encoder_noise(lab):
    q = lab.sim.q
    chosen = []
    for bits in (20, 17, 14):
        res = 2 * np.pi / 2**bits
        c = choose_cutoff(np.round(q / res) * res, 1000.0)
        assert c.limited == "noise" and abs(c.acceleration_noise - 0.01) < 1e-3
        assert np.allclose(c.noise_rms, res / np.sqrt(12), rtol=0.3)  # quantization noise, from the spectrum
        chosen.append(c.cutoff)
    assert chosen[0] > chosen[1] > chosen[2] > 5.0
    clean = choose_cutoff(q, 1000.0)
    assert clean.limited == "rate" and clean.cutoff == pytest.approx(100.0)
    with pytest.raises(DatasetError, match="too close to the Nyquist"):
        LowPass(480.0, 1000.0)


# -- files: CSV, ROS 1, ROS 2 (sqlite3, MCAP), a bare MCAP -----------------------------------


def test_every_format_gives_the_same_frames(lab):
    settings = ImportSettings(sensor_pose=POSE_TEXT)
    ref, _ = import_recording(lab.file("csv"), lab.model, settings)
    for kind in ("ros1", "sqlite3", "mcap", "bare-mcap"):
        ds, _ = import_recording(lab.file(kind), lab.model, settings)
        assert ds.n_frames == ref.n_frames, kind
        assert np.allclose(ds.time - ds.time[0, 0], ref.time - ref.time[0, 0], atol=1e-9), kind
        for name in ("q", "qd", "qdd", "wrench"):  # joints matched by name (reversed, plus head_pan)
            a, b = getattr(ds, name), getattr(ref, name)
            assert np.abs(a - b).max() <= 1e-7 * np.abs(b).max(), (kind, name)
        assert ds.meta.sensor["frame_id"] == "ft_sensor" and ds.meta.origin["wrench_topic"] == "/ft_sensor/wrench"
        assert ds.meta.origin["joint_messages"] == len(lab.sim.time)


def test_two_clocks_and_a_delay_given_or_estimated(lab):
    """Joints at 500 Hz; the wrench at 500 Hz half a sample later, stamped 3 ms late."""
    t, q, w = lab.sim.time, lab.sim.q, lab.reading
    streams = Streams(t[0::2], q[0::2], None, None, t[1::2] + 0.003, w[1::2], "two clocks")
    errors = {}
    for delay in (0.003, 0.0):
        ds, summary = recording_dataset(streams, lab.model, ImportSettings(sensor_pose=POSE_TEXT, delay=delay))
        assert summary.rate == pytest.approx(500.0) and summary.joint_rate == pytest.approx(500.0)
        assert ("wrench" in summary.resampled) == (delay != 0.0)  # 3 ms late: on the joints' even milliseconds
        res = solve_dataset(ds, SolveSettings(bias="estimate"), model=lab.model)
        errors[delay] = base_error(res, lab.theta_unknown).max()
    assert errors[0.003] < TOL_TWO_CLOCKS
    assert errors[0.0] > 100 * errors[0.003]  # 3 ms unaccounted for costs far more than the filtering
    # the delay estimated from the model (measured: 3.0023 ms, residual 2.3e-4 against 1.3e-2 at 0)
    ds, summary = recording_dataset(
        streams, lab.model, ImportSettings(sensor_pose=POSE_TEXT, estimate_delay=True), estimate_delay
    )
    est = summary.delay_estimate
    assert abs(est.delay - 0.003) < 2e-5 and est.residual < 0.05 * est.residual_at_zero
    assert "wrench delay estimated: 3.00" in summary.lines()[-1] and ds.meta.origin["import"]["delay_estimated"]
    res = solve_dataset(ds, SolveSettings(bias="estimate"), model=lab.model)
    assert base_error(res, lab.theta_unknown).max() < TOL_TWO_CLOCKS


# -- identification against the simulated truth ----------------------------------------------------


@pytest.fixture(scope="module")
def recordings(lab):
    """The bag (untared sensor, offsets to estimate) and the tared CSV, imported once."""
    settings = ImportSettings(sensor_pose=POSE_TEXT)
    return {
        "estimate": import_recording(lab.file("ros1"), lab.model, settings)[0],
        "none": import_recording(lab.file("csv-tared"), lab.model, settings)[0],
    }


@pytest.mark.parametrize("bias", ["estimate", "none"])
@pytest.mark.parametrize("method", ["linear", "nonlinear", "consistent"])
def test_identified_base_parameters_match_the_simulation(lab, recordings, method, bias):
    ds = recordings[bias]
    res = solve_dataset(ds, SolveSettings(method=method, bias=bias), model=lab.model)
    assert res.success[0], res.status[0]
    err = base_error(res, lab.theta_unknown)
    assert err.max() < TOL_1KHZ, dict(zip(res.base.names, err.round(6), strict=True))
    assert res.base.rank == (16 if bias == "estimate" else 17)
    assert res.validation_rel[0] < 2e-5  # held-out frames, sensor frame, offsets included
    if method == "consistent":
        assert ineid.is_physical(res.theta_hat[0].reshape(-1, 10)).all()
    if bias == "none":
        assert res.bias_hat is None
        return
    # b_hat = ybar - Wbar theta_hat: the offsets plus what theta_hat leaves of the mean wrench, which
    # includes the weight of mass at the shoulder centre (never moving, so seen as an offset)
    fit = slice(0, res.n_frames_fit)
    theta_hat = lab.model.full_theta(res.theta_hat[0], ds.theta_known)
    moved = wrench_in_sensor(
        lab.pose.transform(),
        np.asarray(lab.model.base_wrench(ds.q[0, fit], ds.qd[0, fit], ds.qdd[0, fit], lab.theta - theta_hat)),
    )
    assert np.allclose(res.bias_hat[0], lab.bias + moved.mean(axis=0), atol=2e-4 * np.abs(lab.bias).max())
    assert np.all(res.bias_std[0] > 0)


@pytest.mark.parametrize("weights", ["none", "estimate"])
def test_fused_blocks_in_the_sensor_frame_match_casadis_stacks(lab, recordings, weights):
    """The fused kernel (sensor transform, frame sums, the first-frame shift) against CasADi's stacks and QR.

    Measured with 0.05 noise on every axis: base parameters 8e-11 (scaled), offsets 2e-12 N, their std 7e-13
    relative."""
    ds = recordings["estimate"].select(frames=slice(0, 4000))
    ds.wrench = ds.wrench + np.random.default_rng(1).normal(size=ds.wrench.shape) * 0.05
    fused = solve_dataset(ds, SolveSettings(bias="estimate", weights=weights), model=lab.model)
    ref = solve_dataset(ds, SolveSettings(bias="estimate", weights=weights, backend="casadi"), model=lab.model)
    scales = ref.base.scales[ref.base.base_index]
    assert np.abs((fused.base_hat - ref.base_hat) / scales).max() < 1e-9
    assert np.allclose(fused.base_std, ref.base_std, rtol=1e-9, atol=0)
    assert np.abs(fused.bias_hat - ref.bias_hat).max() < 1e-9
    assert np.allclose(fused.bias_std, ref.bias_std, rtol=1e-9, atol=0)
    assert np.allclose(fused.validation_rms, ref.validation_rms, rtol=1e-9, atol=0)
    with pytest.raises(ValueError, match="casadi-c"):
        SolveSettings(bias="estimate", backend="casadi-c")


def test_bias_std_matches_the_scatter(lab, recordings):
    """The offsets' standard deviations against 48 noise draws on the same frames (noise-weighted fit:
    the covariance assumes the weights whiten the noise)."""
    ds = recordings["estimate"].select(frames=slice(0, 3000, 5))
    rng = np.random.default_rng(5)
    sigma = np.array([0.2, 0.2, 0.3, 0.01, 0.01, 0.005])
    n = 48
    many = ds.select(configs=np.zeros(n, dtype=int))
    many.wrench = many.wrench + rng.normal(size=many.wrench.shape) * sigma
    settings = SolveSettings(bias="estimate", frames=ds.n_frames, weights="noise", axis_sigma=tuple(sigma))
    res = solve_dataset(many, settings, model=lab.model)
    spread = res.bias_hat.std(axis=0, ddof=1)
    predicted = np.sqrt(np.mean(res.bias_std**2, axis=0))
    assert np.all(np.abs(spread / predicted - 1) < 0.35), (spread, predicted)


def test_what_the_offsets_cost(lab):
    q, qd, qdd = generic_frames(lab.model, 200, 1)
    cost = bias_cost(lab.model, q, qd, qdd)
    assert (cost.base.rank, cost.base_bias.rank) == (17, 16)
    # the lost direction: a point mass at the shoulder centre (0.06 m up the upper arm's z axis,
    # where the three shoulder axes meet): m, m z = 0.06 m, Ixx = Iyy = m z^2
    (direction,) = cost.new_null_directions
    assert direction == "+277.8 upper_arm.m, +16.67 upper_arm.mz, +1 upper_arm.Ixx, +1 upper_arm.Iyy"
    assert np.all(cost.std_inflation > 0.99) and cost.condition[1] > cost.condition[0]


def test_results_keep_the_offsets(lab, recordings, tmp_path):
    res = solve_dataset(recordings["estimate"], SolveSettings(bias="estimate"), model=lab.model)
    back = load_results(save_results(res, tmp_path / "r.h5"))
    assert back.settings.bias == "estimate" and np.array_equal(back.bias_hat, res.bias_hat)
    assert np.array_equal(back.bias_std, res.bias_std) and back.meta["sensor"]["frame_id"] == "ft_sensor"


def test_offsets_are_what_the_base_frame_solver_cannot_absorb(lab, recordings):
    """Without --bias, the untared recording cannot be fitted: the held-out error is large."""
    res = solve_dataset(recordings["estimate"], SolveSettings(bias="none"), model=lab.model)
    assert res.validation_rel[0] > 1e-2


# -- the command line -----------------------------------------------------------------------------


def test_cli_import_solve_plot_and_identifiability(lab, run, tmp_path):
    rec = tmp_path / "rec.h5"
    r = run("-q", "data", "import", lab.file("mcap"), "--robot", "sweaty-arm", "--sensor-pose", POSE_TEXT, "--out", rec)
    assert r.exit_code == 0, r.output
    assert "frames at 1000 Hz" in r.output and "low-pass at 100 Hz" in r.output and "frame 'ft_sensor'" in r.output
    assert "dropped 0.030 s at the start" in r.output
    out, png = tmp_path / "res.h5", tmp_path / "val.png"
    r = run("-q", "solve", rec, "--method", "consistent", "--bias", "estimate", "--plot", png, "--out", out)
    assert r.exit_code == 0, r.output
    assert "sensor offsets of configuration 0" in r.output and "residual RMS per axis" in r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and load_results(out).bias_hat.shape == (1, 6)
    r = run("identifiability", "sweaty-arm", "--bias", "estimate", "--data", rec)
    assert r.exit_code == 0, r.output
    assert "Structural rank 17 without offsets, 16 with" in r.output
    assert "+277.8 upper_arm.m, +16.67 upper_arm.mz, +1 upper_arm.Ixx, +1 upper_arm.Iyy" in r.output


def _small_bag(lab, path, joint_names=None, **kw):
    from .bag_files import write_bag

    n = 300
    names = list(joint_names or lab.model.joint_names)
    q = lab.sim.q[:n, [lab.model.joint_names.index(j) for j in names]]
    return write_bag(
        path, "ros1", names, lab.sim.time[:n], q, lab.sim.time[:n], kw.pop("wrench", lab.reading[:n]), **kw
    )


def test_cli_bad_recordings_are_one_line_and_leave_no_file(lab, run, tmp_path):
    good = _small_bag(lab, tmp_path / "good.bag")
    three = _small_bag(lab, tmp_path / "three.bag", joint_names=lab.model.joint_names[:2] + lab.model.joint_names[3:])
    nan_wrench = lab.reading[:300].copy()
    nan_wrench[120, 4] = np.nan
    nan_bag = _small_bag(lab, tmp_path / "nan.bag", wrench=nan_wrench)
    twice = _small_bag(lab, tmp_path / "twice.bag", extra_topics=["/ft_sensor/raw"])
    csv_text = lab.file("csv").read_text().splitlines()
    (tmp_path / "swapped.csv").write_text(
        "\n".join([csv_text[0], *csv_text[1:50], csv_text[51], csv_text[50], *csv_text[52:400]]) + "\n"
    )
    cases = [
        (
            (good, "--joint-topic", "/arm/joint_states"),
            "the bag has no topic '/arm/joint_states'; its JointState topics: /joint_states: pass --joint-topic",
        ),
        ((three,), "lacks joint 'upper_arm_yaw'"),
        ((tmp_path / "swapped.csv",), "time does not increase at line 52"),
        ((nan_bag,), "the wrench stream's wrench holds NaN at sample 120"),
        ((good, "--sensor-pose", "0.1,0.2,0.3"), "sensor pose '0.1,0.2,0.3': expected six finite numbers"),
        ((good, "--sensor-pose", "ft_link"), "no link named 'ft_link'"),
        ((twice,), "the bag has 2 wrench topics (/ft_sensor/raw, /ft_sensor/wrench); choose one with --wrench-topic"),
    ]
    for args, message in cases:
        out = tmp_path / "out.h5"
        r = run("-q", "data", "import", *args, "--robot", "sweaty-arm", "--out", out)
        assert r.exit_code == 1 and "Traceback" not in r.output, r.output
        text = [line for line in r.output.splitlines() if line.strip()]
        assert len(text) == 1 and text[0].startswith("Error: ") and message in text[0], (message, r.output)
        assert not out.exists() and not list(tmp_path.glob(".out.h5*"))
    r = run(
        "-q",
        "data",
        "import",
        twice,
        "--robot",
        "sweaty-arm",
        "--wrench-topic",
        "/ft_sensor/raw",
        "--sensor-pose",
        POSE_TEXT,
        "--out",
        tmp_path / "ok.h5",
    )
    assert r.exit_code == 0, r.output
