"""Link IMUs (:mod:`ineid.data.imu`): the readings against MuJoCo's own sensors, and joint states estimated from
the gyros, accelerometers, angular-acceleration sensors and encoders together."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import ineid
from ineid import DatasetError
from ineid.channels.pose import SensorPose
from ineid.data.imu.estimation import estimate_joint_states
from ineid.data.imu.readings import ImuMount, imu_jacobians, imu_readings, parse_imu
from ineid.data.imu.settings import EstimationSettings, ImuNoise
from ineid.data.recordings.signals import LowPass, derivatives

mujoco = pytest.importorskip("mujoco")

RATE = 200.0
"""Hz: a low-cost arm's logging rate."""
EDGE = 60
"""Frames dropped at each end, as the import drops the filter's edges."""
BIAS = np.array([0.02, -0.01, 0.03])
"""rad/s, every gyro's bias in the noisy recording."""


def _mounts(model, rng) -> list[ImuMount]:
    """One IMU on every moving link, a few cm off its origin, turned arbitrarily."""
    return [
        ImuMount(link, SensorPose(tuple(rng.normal(0, 0.04, 3)), tuple(rng.uniform(-3, 3, 3))))
        for link in model.link_names
    ]


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="module")
def recording(arm):
    return simulated_recording(arm)


def simulated_recording(arm) -> dict:
    """MuJoCo: 6 s at 200 Hz of fast motion (0.6 Hz base, harmonics to 2.4 Hz), IMUs on every moving link,
    the unknown links' parameters drawn around the CAD values."""
    from ineid.data.synthesis.sampling import sample_link_parameters
    from tests.imu_mujoco import root_theta, simulate_imus

    rng = np.random.default_rng(7)
    theta = arm.theta_cad.copy()
    for link in arm.unknown_links:
        i = arm.link_names.index(link)
        theta[10 * i : 10 * i + 10] = sample_link_parameters(arm.theta_cad[10 * i : 10 * i + 10], 1, rng)[0]
    mounts = _mounts(arm, rng)
    root = root_theta(arm)
    t, q, qd, qdd, wrench, readings = simulate_imus(arm, mounts, theta, root, 6.0, RATE, seed=3, speed=3.0)
    g = arm.gravity
    tared = wrench - np.concatenate([root[0] * g, np.cross(root[1:4], g)])  # the root's weight off
    return {
        "t": t,
        "q": q,
        "qd": qd,
        "qdd": qdd,
        "wrench": tared,
        "readings": readings,
        "mounts": mounts,
        "theta": theta,
    }


def _encoders(rec, bits: int, cutoff: float, offset=0.0):
    """Angles quantized to ``bits`` per turn (the grid shifted by ``offset``, rad), low-passed at ``cutoff`` Hz and
    differentiated, edges dropped."""
    step = 2 * np.pi / 2**bits
    q = LowPass(cutoff, RATE).apply(np.round((rec["q"] + offset) / step) * step - offset)
    qd, qdd = derivatives(q, 1 / RATE)
    return q[EDGE:-EDGE], qd[EDGE:-EDGE], qdd[EDGE:-EDGE]


def _cut(readings):
    return {k: {kind: v[EDGE:-EDGE] for kind, v in kinds.items()} for k, kinds in readings.items()}


def _base_error(arm, recording, q, qd, qdd) -> float:
    """The largest base-parameter error of the linear identification from these states (edges dropped) and
    MuJoCo's wrench: ``|beta_hat - beta| / max(|beta|, scale)``."""
    from ineid.data.recordings.pipeline import Streams, recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.identify import SolveSettings, solve_dataset

    t, wrench = recording["t"][EDGE:-EDGE], recording["wrench"][EDGE:-EDGE]
    ds, _ = recording_dataset(Streams(t, q, qd, qdd, t, wrench, "imu test"), arm, ImportSettings())
    res = solve_dataset(ds, SolveSettings())
    b = res.base
    beta = recording["theta"][arm.unknown_index] @ b.B.T
    return float((np.abs(res.base_hat[0] - beta) / np.maximum(np.abs(beta), b.scales[b.base_index])).max())


def _rel(x, truth):
    return float(np.sqrt(np.mean((x - truth) ** 2)) / np.sqrt(np.mean(truth**2)))


# -- the forward model against MuJoCo --------------------------------------------------------------


def test_imu_readings_match_mujoco_gyro_accelerometer_and_body_acceleration(arm):
    """At random states (MuJoCo's forward dynamics under random torques), every IMU on every moving link:
    MuJoCo's gyro, accelerometer (specific force) and the site's angular acceleration are ineid's."""
    from tests.imu_mujoco import imu_mjcf, mujoco_imu, root_theta

    rng = np.random.default_rng(5)
    mounts = _mounts(arm, rng)
    m = mujoco.MjModel.from_xml_string(imu_mjcf(arm, mounts, arm.theta_cad, root_theta(arm)))
    d = mujoco.MjData(m)
    states, ref = [], []
    for _ in range(16):
        d.qpos[:], d.qvel[:], d.ctrl[:] = rng.uniform(-1, 1, 4), rng.normal(0, 3, 4), rng.normal(0, 3, 4)
        mujoco.mj_forward(m, d)
        states.append((d.qpos.copy(), d.qvel.copy(), d.qacc.copy()))
        ref.append(mujoco_imu(m, d, mounts))
    q, qd, qdd = (np.array(x) for x in zip(*states, strict=True))
    ours = imu_readings(arm, mounts, q, qd, qdd)
    for mount in mounts:
        for kind in ("gyro", "accel", "alpha"):
            theirs = np.array([r[mount.name][kind] for r in ref])
            assert np.abs(ours[mount.name][kind] - theirs).max() < 1e-9 * np.abs(theirs).max(), (mount.name, kind)
        maps = imu_jacobians(arm, mount, q, qd)  # the linear maps the estimator inverts
        r = ours[mount.name]
        assert np.allclose(np.einsum("fij,fj->fi", maps.gyro_qd, qd), r["gyro"], rtol=0, atol=1e-12)
        assert np.allclose(np.einsum("fij,fj->fi", maps.gyro_qd, qdd) + maps.alpha_0, r["alpha"], rtol=0, atol=1e-10)
        assert np.allclose(np.einsum("fij,fj->fi", maps.accel_qdd, qdd) + maps.accel_0, r["accel"], rtol=0, atol=1e-10)
    # at rest an accelerometer reads +g, turned into its frame
    rest = imu_readings(arm, mounts[:1], np.zeros(4), np.zeros(4), np.zeros(4))[mounts[0].name]
    assert np.allclose(np.linalg.norm(rest["accel"]), 9.81) and np.allclose(rest["gyro"], 0)


def test_parse_imu_forms(arm):
    assert parse_imu("forearm", arm) == ImuMount("forearm")
    mount = parse_imu("upper_arm:0.01,0,-0.1,0,0,1.5", arm, kinds=("gyro",))
    assert mount.link == "upper_arm" and mount.sensor.xyz == (0.01, 0.0, -0.1) and mount.kinds == ("gyro",)
    hand = parse_imu("hand", arm)  # a URDF frame welded to the forearm: its pose from the URDF
    assert hand.link == "forearm" and hand.name == "hand" and np.allclose(hand.sensor.xyz, (0, 0, -0.26))
    assert ImuMount.from_dict(mount.to_dict()) == replace(mount, sensor=replace(mount.sensor, frame=None))
    assert mount.columns("alpha") == ("imu_upper_arm_alx", "imu_upper_arm_aly", "imu_upper_arm_alz")


# -- the estimator ---------------------------------------------------------------------------------


def test_noise_free_imus_give_the_true_states_and_exact_identification(arm, recording):
    """Noise-free MuJoCo readings, a poor prior (10-bit encoders low-passed at 5 Hz): qd, qdd are MuJoCo's to
    round-off, and the linear identification from them and MuJoCo's wrench is exact."""
    _, qd_enc, qdd_enc = _encoders(recording, 10, 5.0)
    assert _rel(qd_enc, recording["qd"][EDGE:-EDGE]) > 0.01  # the prior is poor
    exact = EstimationSettings(noise=ImuNoise(1e-9, 1e-9, 1e-9), gyro_bias=False)
    truth = {k: recording[k][EDGE:-EDGE] for k in ("q", "qd", "qdd", "t", "wrench")}
    qd, qdd, summary = estimate_joint_states(
        arm, truth["q"], qd_enc, qdd_enc, recording["mounts"], _cut(recording["readings"]), exact
    )
    assert np.abs(qd - truth["qd"]).max() < 1e-10 * np.abs(truth["qd"]).max()
    assert np.abs(qdd - truth["qdd"]).max() < 1e-10 * np.abs(truth["qdd"]).max()
    assert all(v < 1e-6 for r in summary.residual_rms.values() for v in r.values())  # in units of 1e-9 noise
    assert _base_error(arm, recording, truth["q"], qd, qdd) < 1e-10  # measured 2.4e-14


def _noisy(recording, rng, noise: ImuNoise):
    n = len(recording["t"])
    return {
        name: {
            "gyro": r["gyro"] + BIAS + rng.normal(0, noise.gyro, (n, 3)),
            "accel": r["accel"] + rng.normal(0, noise.accel, (n, 3)),
            "alpha": r["alpha"] + rng.normal(0, noise.alpha, (n, 3)),
        }
        for name, r in recording["readings"].items()
    }


def test_fusion_beats_coarse_encoders_and_never_loses_to_fine_ones(arm, recording):
    """Gyro 0.005 rad/s with a 0.02-0.03 rad/s bias, accelerometer 0.05 m/s^2, alpha 0.17 rad/s^2 (the paper's
    group's sensor): clearly better than 10-bit encoders on fast motion, no worse than 16-bit ones (the biases'
    std: the next test)."""
    rng = np.random.default_rng(11)
    noisy = _noisy(recording, rng, ImuNoise())
    readings = _cut(noisy)
    low_passed = _cut({k: {kind: LowPass(10.0, RATE).apply(v) for kind, v in r.items()} for k, r in noisy.items()})
    qd_true, qdd_true = recording["qd"][EDGE:-EDGE], recording["qdd"][EDGE:-EDGE]
    for bits, cutoff, gain in ((10, 10.0, 0.5), (16, 20.0, 1.1)):
        q, qd_enc, qdd_enc = _encoders(recording, bits, cutoff)
        qd, qdd, summary = estimate_joint_states(arm, q, qd_enc, qdd_enc, recording["mounts"], readings)
        assert _rel(qd, qd_true) < gain * _rel(qd_enc, qd_true), bits
        assert _rel(qdd, qdd_true) < gain * _rel(qdd_enc, qdd_true), bits
        if bits == 10:  # and the identification from them (MuJoCo's wrench): measured 2.1e-2 -> 2.2e-3
            assert _base_error(arm, recording, q, qd, qdd) < 0.3 * _base_error(arm, recording, q, qd_enc, qdd_enc)
        # gyros alone (no accelerations measured): qd improves, qdd is the encoders'
        gyros = [replace(m, kinds=("gyro",)) for m in recording["mounts"]]
        qd_g, qdd_g, _ = estimate_joint_states(arm, q, qd_enc, qdd_enc, gyros, readings)
        assert _rel(qd_g, qd_true) < gain * _rel(qd_enc, qd_true) and np.array_equal(qdd_g, qdd_enc)
        if bits == 10:  # ... unless the low-passed gyros' derivative is qdd's prior
            _, qdd_g, _ = estimate_joint_states(
                arm,
                q,
                qd_enc,
                qdd_enc,
                gyros,
                low_passed,
                EstimationSettings(qdd_prior="gyros"),
                time=recording["t"][EDGE:-EDGE],
            )
            assert _rel(qdd_g, qdd_true) < 0.5 * _rel(qdd_enc, qdd_true)
        for name, rms in summary.residual_rms.items():  # residuals at the noise
            # at the noise, a little below it where an IMU fixes the fit (the last link's)
            assert all(0.4 < v / getattr(ImuNoise(), k) < 1.5 for k, v in rms.items()), (name, rms)
    assert "gyro bias" in "\n".join(summary.lines()) and summary.to_dict()["n_frames"] == len(qd)


def _bias_z(summary) -> list[float]:
    """``(b_hat - b) / std`` along every identifiable direction: the axes with a std, and for an IMU with an
    unidentified direction the two orthogonal to it (from its covariance)."""
    z = []
    for name, b in summary.gyro_bias.items():
        err, std = b - BIAS, summary.gyro_bias_std[name]
        free = summary.gyro_bias_unidentified.get(name)
        if free is None:
            z.extend(err / std)
            continue
        basis = np.linalg.svd(np.eye(3) - free.T @ free)[0][:, : 3 - len(free)]
        cov = summary.gyro_bias_cov[name]
        z.extend(d @ err / np.sqrt(d @ cov @ d) for d in basis.T)
    return z


def test_gyro_bias_std_is_honest_for_fine_and_coarse_encoders(arm, recording):
    """Over noise draws (gyro noise, and the encoders' quantization grid shifted at random), the gyro biases'
    z-scores along every identifiable direction have RMS near 1 with 16-, 12- and 10-bit encoders (the white-noise
    std gave RMS 2.3 and 3.1, |z| up to 6.4 and 8.9, with 12- and 10-bit ones), and the last link's IMU's bias
    along the last joint's axis is reported as not identified: no std on the axes leaning on it."""
    gyros = [replace(m, kinds=("gyro",)) for m in recording["mounts"]]
    last = gyros[-1]
    axis = imu_jacobians(arm, last, recording["q"][:1], recording["qd"][:1]).gyro_qd[0, :, -1]
    rng = np.random.default_rng(23)
    n = len(recording["t"])
    for bits, cutoff in ((16, 20.0), (12, 10.0), (10, 10.0)):
        z = []
        for _ in range(8):
            q, qd_enc, qdd_enc = _encoders(recording, bits, cutoff, rng.uniform(0, 2 * np.pi / 2**bits, 4))
            noisy = {
                k: {"gyro": r["gyro"] + BIAS + rng.normal(0, 0.005, (n, 3))} for k, r in recording["readings"].items()
            }
            _, _, summary = estimate_joint_states(arm, q, qd_enc, qdd_enc, gyros, _cut(noisy))
            z.extend(_bias_z(summary))
            assert list(summary.gyro_bias_unidentified) == [last.name]
            free = summary.gyro_bias_unidentified[last.name]
            assert free.shape == (1, 3) and abs(free[0] @ axis) > (1 - 1e-9) * np.linalg.norm(axis)
            assert np.all(np.isnan(summary.gyro_bias_std[last.name]))  # turned arbitrarily: every axis leans on it
            assert all(np.all(np.isfinite(summary.gyro_bias_std[m.name])) for m in gyros[:-1])
        z = np.array(z)
        rms = float(np.sqrt(np.mean(z**2)))  # measured 0.73, 1.07, 0.83 (max |z| 2.0, 2.8, 2.6); 0.66-1.18 over 5 seeds
        assert 0.5 < rms < 1.5 and np.abs(z).max() < 4.0, (bits, rms, np.abs(z).max())
    text = "\n".join(summary.lines())
    assert "not identified" in text and "angle error" in text
    record = summary.to_dict()
    assert (
        record["gyro_bias_std"][last.name] == [None, None, None]
        and len(record["gyro_bias_unidentified"][last.name]) == 1
    )
    # the angle error given (raw 10-bit quantization, an upper bound once low-passed) instead of from the residuals
    step = 2 * np.pi / 2**10 / np.sqrt(12)
    _, _, given = estimate_joint_states(
        arm, q, qd_enc, qdd_enc, gyros, _cut(noisy), EstimationSettings(encoder_q_std=step)
    )
    assert np.allclose(given.q_error_std, step) and all(
        np.all(given.gyro_bias_std[m.name] >= summary.gyro_bias_std[m.name]) for m in gyros[:-1]
    )
    with pytest.raises(DatasetError) as e:
        estimate_joint_states(arm, q, qd_enc, qdd_enc, gyros, _cut(noisy), EstimationSettings(encoder_q_std=-1.0))
    _one_line(e, "encoder_q_std")


# -- bad input: one line each ----------------------------------------------------------------------


def _one_line(excinfo, *words):
    text = str(excinfo.value)
    assert "\n" not in text and all(w in text for w in words), text


def test_bad_imus_are_one_line_each(arm, recording):
    with pytest.raises(DatasetError) as e:
        parse_imu("wrist", arm)
    _one_line(e, "wrist", "forearm")
    with pytest.raises(DatasetError) as e:
        parse_imu("forearm:0.1,0.2,x", arm)
    _one_line(e, "six")
    with pytest.raises(DatasetError) as e:
        parse_imu("hand:0,0,0.1,0,0,0", arm)  # a URDF frame has its pose already
    _one_line(e, "hand", "forearm:x,y,z")
    with pytest.raises(DatasetError) as e:
        parse_imu("base_link", arm)  # the root does not move
    _one_line(e, "base_link", "moving link")
    with pytest.raises(DatasetError) as e:
        imu_readings(arm, [ImuMount("wrist")], np.zeros(4), np.zeros(4), np.zeros(4))
    _one_line(e, "wrist", "moving link")
    with pytest.raises(DatasetError) as e:
        ImuMount("forearm", kinds=("gyro", "magnetometer"))
    _one_line(e, "kinds")

    q, qd_enc, qdd_enc = _encoders(recording, 14, 20.0)
    readings = _cut(_noisy(recording, np.random.default_rng(3), ImuNoise()))
    mounts = recording["mounts"]
    with pytest.raises(DatasetError) as e:  # a kind without readings
        gyro_only = {**readings, "forearm": {"gyro": readings["forearm"]["gyro"]}}
        estimate_joint_states(arm, q, qd_enc, qdd_enc, mounts, gyro_only)
    _one_line(e, "forearm", "accel", "imu_forearm_ax")
    # a wrong mount: the forearm's IMU said to be turned 90 degrees about its z axis
    rpy = mounts[3].sensor.rpy
    turned = replace(mounts[3], sensor=replace(mounts[3].sensor, rpy=(rpy[0], rpy[1], rpy[2] + 1.57)))
    with pytest.raises(DatasetError) as e:
        estimate_joint_states(arm, q, qd_enc, qdd_enc, [*mounts[:3], turned], readings)
    _one_line(e, "'forearm'", "pose")
    # a lone gyro on the wrong link contradicts the encoders (nothing else to check it against)
    lone = [replace(mounts[2], kinds=("gyro",), link="forearm", name="upper_arm")]
    with pytest.raises(DatasetError) as e:
        estimate_joint_states(arm, q, qd_enc, qdd_enc, lone, readings)
    _one_line(e, "'upper_arm'", "gyro", "pose")


def _imported(arm, recording, readings, mounts, bits: int = 10):
    """The import (``recording_dataset``) of the recording with ``bits``-bit encoders, MuJoCo's wrench and these
    IMU readings: ``(dataset, relative qd error, relative qdd error, largest base error)`` against the truth."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.data.recordings.streams import ImuStream, Streams
    from ineid.identify import SolveSettings, solve_dataset

    t, step = recording["t"], 2 * np.pi / 2**bits
    q = np.round(recording["q"] / step) * step
    imus = tuple(ImuStream(m.name, t, {k: readings[m.name][k] for k in m.kinds}) for m in mounts)
    texts = tuple(f"{m.link}:{','.join(repr(float(v)) for v in (*m.sensor.xyz, *m.sensor.rpy))}" for m in mounts)
    ds, _ = recording_dataset(
        Streams(t, q, None, None, t, recording["wrench"], "imu test", imus=imus), arm, ImportSettings(imus=texts)
    )
    at = np.searchsorted(t, ds.time[0])
    assert np.allclose(t[at], ds.time[0])
    res = solve_dataset(ds, SolveSettings())
    b = res.base
    beta = recording["theta"][arm.unknown_index] @ b.B.T
    base = float((np.abs(res.base_hat[0] - beta) / np.maximum(np.abs(beta), b.scales[b.base_index])).max())
    return ds, _rel(ds.qd[0], recording["qd"][at]), _rel(ds.qdd[0], recording["qdd"][at]), base


@pytest.mark.parametrize("links", [("upper_arm", "forearm"), ("forearm",), ("upper_arm",)])
def test_imus_on_some_links_never_lose_to_the_encoders(arm, recording, links):
    """Gyros (0.005 rad/s, biased) on some links only, 10-bit encoders, fast motion, through the import: the fused
    qd, qdd and the identification are no worse than the encoders' alone, qd clearly better. The gyros leave a
    direction unseen (a joint beyond them, three axes for four joints, or the shoulder's axes lining up), where
    the encoders' derivatives at their own cut-off carry it. Measured: qd 0.0045 / 0.0041 / 0.0078 against 0.012,
    qdd 0.013 / 0.018 / 0.015 against 0.019, base 0.013 / 0.030 / 0.018 against 0.049."""
    rng = np.random.default_rng(21)
    noisy = _noisy(recording, rng, ImuNoise())
    mounts = [replace(m, kinds=("gyro",)) for m in recording["mounts"] if m.link in links]
    _, qd_e, qdd_e, base_e = _imported(arm, recording, noisy, [])
    ds, qd_f, qdd_f, base_f = _imported(arm, recording, noisy, mounts)
    assert ds.meta.origin["imu"]["mounts"] and qd_f < 0.7 * qd_e, (qd_f, qd_e)
    assert qdd_f < 1.0 * qdd_e and base_f < 1.0 * base_e, (qdd_f, qdd_e, base_f, base_e)
