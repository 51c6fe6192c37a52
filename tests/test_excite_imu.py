"""``ineid excite --encoder-bits N --imu LINK``: the design accounts for the joint-state errors of a lab's sensors
(:mod:`ineid.excite.states`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ineid.data.synthesis.imu_rehearsal import ImuRehearsal
from ineid.data.synthesis.trajectory import FourierTrajectory
from ineid.excite.states import inflated_noise, rehearsed_rms

DESIGN = ("-q", "excite", "sweaty-arm", "--duration", 5, "--harmonics", 3, "--starts", 1)
GYROS = ("--imu", "shoulder_roll_link", "--imu", "upper_arm", "--imu", "forearm")


def _trajectory(model) -> FourierTrajectory:
    rng = np.random.default_rng(5)
    a, b = rng.normal(0, 0.5, (2, model.n_dof, 3))
    a[:, -1] = -a[:, :-1].sum(1)  # at rest at t = 0: sum a = 0, sum l b_l = 0
    b[:, -1] = -(b[:, :-1] * [1, 2]).sum(1) / 3
    return FourierTrajectory(0.2, np.array([0.0, 1.2, 0.0, -1.2]), a, b, 5.0, tuple(model.joint_names))


def test_inflated_noise_is_the_first_order_error(model):
    """``sigma_eff^2 - sigma^2`` is the mean squared change of ``Psi theta_cad`` per unit state error."""
    _, q, qd, qdd = _trajectory(model).sample(20.0)
    sigma = np.array([0.5] * 3 + [0.05] * 3)
    for d, s in ((1, 0.01), (model.n_dof + 2, 0.03), (2 * model.n_dof + 3, 0.2)):  # a q, a qd, a qdd
        rms = np.zeros(3 * model.n_dof)
        rms[d] = s
        added = inflated_noise(model, q, qd, qdd, sigma, rms) ** 2 - sigma**2
        h = 1e-6
        x = [q.copy(), qd.copy(), qdd.copy()]
        k, j = divmod(d, model.n_dof)
        up, down = [a.copy() for a in x], [a.copy() for a in x]
        up[k][:, j] += h
        down[k][:, j] -= h
        y = [model.regressor(*z) @ model.theta_cad for z in (up, down)]
        fd = np.mean(((y[0] - y[1]) / (2 * h)) ** 2, axis=0) * s**2
        assert np.allclose(added, fd, rtol=1e-5, atol=1e-12), (d, added, fd)


def test_rehearsed_errors_shrink_with_finer_encoders(model):
    traj = _trajectory(model)
    coarse, fine = (rehearsed_rms(model, ImuRehearsal(encoder_bits=b), traj, 100.0) for b in (8, 16))
    assert coarse.shape == (3, model.n_dof)
    assert np.all(fine[1] < coarse[1]) and np.all(coarse > 0)


def _design(run, out: Path, *args) -> tuple[dict, str]:
    r = run(*DESIGN, *args, "--out", out)
    assert r.exit_code == 0, r.output
    return json.loads(out.with_suffix(".json").read_text())["design"], " ".join(r.output.split())  # rich wraps


def test_coarse_encoders_inflate_the_expected_std_and_gyros_bring_it_down(run, tmp_path):
    exact, text = _design(run, tmp_path / "exact.csv")
    assert "joint states exact" in text and "joint_state_errors" not in exact and "sensors" not in exact["settings"]
    coarse, text = _design(run, tmp_path / "coarse.csv", "--encoder-bits", 8)
    assert "joint states from 8-bit encoders, filtered, differentiated as the import does" in text
    assert "Joint-state errors the sensors give" in text and "joint states exact" not in text
    fused, text = _design(run, tmp_path / "fused.csv", "--encoder-bits", 8, *GYROS, "--noise", "gyro=0.005")
    assert "8-bit encoders and IMUs shoulder_roll_link, upper_arm, forearm (gyro 0.005 rad/s, accel 0.05 m/s^2" in text
    states = fused["joint_state_errors"]
    assert fused["settings"]["sensors"]["encoder_bits"] == 8 and len(states["sensors"]["mounts"]) == 3
    # the random comparison is the same trajectory in all three (same seed): only the sensors differ
    med = {
        k: np.median(d["random_fourier"]["std"]) for k, d in (("exact", exact), ("coarse", coarse), ("fused", fused))
    }
    assert med["coarse"] > 1.2 * med["exact"], med
    assert med["fused"] < 0.95 * med["coarse"], med
    designed = {
        k: np.median(d["optimized"]["std"]) for k, d in (("exact", exact), ("coarse", coarse), ("fused", fused))
    }
    assert designed["coarse"] > designed["exact"] and designed["fused"] < designed["coarse"], designed
    rms = {
        k: np.array(d["joint_state_errors"]["random_fourier"]["rms_qd"])
        for k, d in (("coarse", coarse), ("fused", fused))
    }
    assert np.all(rms["fused"] < rms["coarse"]), rms
    noise = np.array(coarse["joint_state_errors"]["optimized"]["noise_std"])
    assert np.all(noise >= np.array(coarse["wrench_noise_std"]))  # inflated, never below the sensor's own


def _refused(r, out: Path, code: int, *words: str) -> None:
    """One line (click's usage error: its Error line, after the usage), the words in it, no file."""
    assert r.exit_code == code, r.output
    assert "Traceback" not in r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    if code == 1:
        assert len(lines) == 1, r.output
    for w in words:
        assert w in lines[-1], r.output
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_bad_sensor_input_is_one_line_and_writes_nothing(run, tmp_path):
    out = tmp_path / "t.csv"
    _refused(run(*DESIGN, "--imu", "gripper", "--out", out), out, 1, "gripper", "shoulder_pitch_link")
    _refused(run(*DESIGN, "--imu", "forearm:1,2", "--out", out), out, 1, "forearm", "does not parse")
    _refused(run(*DESIGN, "--imu", "forearm", "--encoder-bits", 0, "--out", out), out, 2, "--encoder-bits")
    _refused(run(*DESIGN, "--noise", "gyro=0.01", "--out", out), out, 2, "gyro", "--imu")
    _refused(run(*DESIGN, "--encoder-bits", 12, "--noise", "qd=0.01", "--out", out), out, 2, "drop the q, qd, qdd")
    _refused(run(*DESIGN, "--imu", "forearm", "--imu", "forearm", "--out", out), out, 2, "given twice")
    _refused(
        run(
            "-q",
            "excite",
            "sweaty-arm",
            "--duration",
            1,
            "--rate",
            7,
            "--harmonics",
            2,
            "--encoder-bits",
            12,
            "--out",
            out,
        ),
        out,
        1,
        "too few to rehearse",
        "--rate",
    )
