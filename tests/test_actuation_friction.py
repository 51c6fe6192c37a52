"""Smooth Coulomb and Stribeck friction (:mod:`ineid.channels.friction`), and their nonlinear velocities identified
by the 1-D search of :mod:`ineid.identify.friction_search`, against simulated truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.channels import BaseWrench, ChannelSet, JointTorque, channel_from_dict
from ineid.data import Combination, DatasetSpec, generate_dataset
from ineid.errors import DatasetError, IdentificationError
from ineid.identify import SolveSettings, load_results, save_results, solve_dataset

from .conftest import random_states

FRICTION = ("viscous", "coulomb", "stribeck")
ZONE, VS = 0.05, 0.3
CASADI = "casadi"  # the QR route: no kernels compiled for each velocity


def _with_friction(model, truth: JointTorque, n_frames: int, noise: float = 0.0, wrench: bool = False, seed=5):
    """A dataset of joint torques (and a wrench) with the friction law ``truth`` added at random coefficients;
    ``(dataset, coefficients)``."""
    channels = ChannelSet.of(BaseWrench(), JointTorque()) if wrench else ChannelSet.of(JointTorque())
    spec = DatasetSpec(Combination("random", n_configs=1), n_frames=n_frames, seed=seed, channels=channels)
    ds = generate_dataset(model, spec)
    x = np.random.default_rng(1).uniform(0.1, 0.5, len(truth.extra_names(model)))
    values = dict(ds.channel_values)
    values["tau"] = values["tau"] + truth.extra_rows(model, ds.q, ds.qd, ds.qdd) @ x
    if noise:
        values["tau"] = values["tau"] + np.random.default_rng(seed + 1).normal(0, noise, values["tau"].shape)
    return dataclasses.replace(ds, channel_values=values), x


def test_stribeck_and_smooth_columns(model):
    q, qd, qdd = random_states(model, 30, np.random.default_rng(2))
    ch = JointTorque().with_actuation(friction=FRICTION, coulomb_zone=ZONE, stribeck_velocity=VS)
    names = ch.extra_names(model)
    assert names[:3] == ("shoulder_pitch.fv", "shoulder_pitch.fc", "shoulder_pitch.fs")
    assert ch.extra_units(model)[:3] == ("N*m*s/rad", "N*m", "N*m")
    e = ch.extra_rows(model, q, qd, qdd)
    v = qd[:, 1]
    np.testing.assert_allclose(e[:, 1, 5], np.exp(-((v / VS) ** 2)) * np.tanh(v / ZONE), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(ch.numpy_extra_rows(model, qd, qdd), e, rtol=1e-14, atol=1e-15)
    casadi = np.array(ch.casadi_extra_function(model)(q[4], qd[4], qdd[4]))
    np.testing.assert_allclose(casadi, e[4], rtol=1e-13, atol=1e-15)
    sign = JointTorque().with_actuation(friction=("stribeck",), asymmetric=True, stribeck_velocity=VS)
    e = sign.extra_rows(model, q, qd, qdd)[:, 0, :2]
    s = np.exp(-((qd[:, 0] / VS) ** 2)) * np.sign(qd[:, 0])
    np.testing.assert_allclose(e, np.stack([np.maximum(s, 0), np.minimum(s, 0)], -1), rtol=1e-14, atol=1e-15)


def test_records_and_bad_values():
    ch = JointTorque().with_actuation(friction=FRICTION, coulomb_zone=ZONE, stribeck_velocity=VS)
    ch = dataclasses.replace(ch, identified=(("stribeck_velocity", 0.01),))
    d = ch.to_dict()
    assert d["stribeck_velocity"] == VS and d["identified"] == {"stribeck_velocity": 0.01}
    assert channel_from_dict(d) == ch
    assert "Stribeck velocity 0.3 rad/s (identified, std 0.01)" in ch.describe()
    assert "stribeck_velocity" not in JointTorque().to_dict()  # written only when set
    with pytest.raises(DatasetError, match="Stribeck friction needs a Stribeck velocity > 0"):
        JointTorque(friction=("stribeck",))
    with pytest.raises(DatasetError, match="identified names coulomb_zone or stribeck_velocity"):
        JointTorque(identified=(("zone", 1.0),))
    with pytest.raises(ValueError, match="Stribeck friction needs its velocity"):
        SolveSettings(friction=("stribeck",))
    with pytest.raises(ValueError, match="stribeck_velocity must be >= 0 rad/s or 'identify'"):
        SolveSettings(friction=("stribeck",), stribeck_velocity="fast")
    with pytest.raises(ValueError, match="coulomb_zone smooths Coulomb friction"):
        SolveSettings(friction=("viscous",), coulomb_zone="identify")


def test_a_still_arm_has_no_friction_velocity(model):
    ds, _ = _with_friction(model, JointTorque(), 30)
    still = dataclasses.replace(ds, qd=np.zeros_like(ds.qd))
    settings = SolveSettings(friction=("coulomb",), coulomb_zone="identify", backend=CASADI)
    with pytest.raises(IdentificationError, match="the drives do not move .* coulomb_zone cannot be identified"):
        solve_dataset(still, settings, model=model)


def test_stribeck_velocity_identified_exactly_on_clean_torques(model, tmp_path):
    truth = JointTorque().with_actuation(friction=FRICTION, stribeck_velocity=VS)
    ds, x = _with_friction(model, truth, 120)
    settings = SolveSettings(friction=FRICTION, stribeck_velocity="identify", backend=CASADI)
    res = solve_dataset(ds, settings, model=model)
    (record,) = res.meta["channels"]
    assert abs(record["stribeck_velocity"] / VS - 1) < 1e-6, record
    assert record["identified"]["stribeck_velocity"] < 1e-6
    np.testing.assert_allclose(res.theta_hat[0, -len(x) :], x, rtol=1e-5)
    back = load_results(save_results(res, tmp_path / "r.h5"))
    assert back.meta["channels"] == res.meta["channels"]
    assert ChannelSet.from_list(back.meta["channels"])["tau"].identified == (
        ("stribeck_velocity", record["identified"]["stribeck_velocity"]),
    )


def test_smooth_coulomb_zone_identified_within_its_std(model):
    """Noisy torques (0.02 N*m), the links and the zone identified together: the zone within 4 std of its truth,
    the std a small fraction of it."""
    truth = JointTorque().with_actuation(friction=("viscous", "coulomb"), coulomb_zone=ZONE)
    ds, _ = _with_friction(model, truth, 300, noise=0.02)
    res = solve_dataset(
        ds, SolveSettings(friction=("viscous", "coulomb"), coulomb_zone="identify", backend=CASADI), model=model
    )
    (record,) = res.meta["channels"]
    zone, std = record["coulomb_zone"], record["identified"]["coulomb_zone"]
    assert abs(zone - ZONE) < 4 * std and std < 0.3 * ZONE, (zone, std)
    # with the zone given at its truth, the same fit to within the noise
    given = solve_dataset(
        ds, SolveSettings(friction=("viscous", "coulomb"), coulomb_zone=ZONE, backend=CASADI), model=model
    )
    assert given.fit_rms[0, -4:].mean() == pytest.approx(res.fit_rms[0, -4:].mean(), rel=0.05)


def test_both_velocities_in_step_two(model):
    """--two-step: the links from the wrench, then the zone and the Stribeck velocity with the friction."""
    truth = JointTorque().with_actuation(friction=FRICTION, coulomb_zone=ZONE, stribeck_velocity=VS)
    ds, x = _with_friction(model, truth, 100, wrench=True)
    settings = SolveSettings(
        friction=FRICTION,
        coulomb_zone="identify",
        stribeck_velocity="identify",
        two_step=True,
        bias="estimate",
        backend=CASADI,
    )
    res = solve_dataset(ds, settings, model=model)
    record = ChannelSet.from_list(res.meta["channels"])["tau"]
    assert abs(record.coulomb_zone / ZONE - 1) < 1e-4 and abs(record.stribeck_velocity / VS - 1) < 1e-4, record
    np.testing.assert_allclose(res.theta_hat[0, -len(x) :], x, rtol=1e-3)


def test_cli_friction_options(run, tmp_path, model):
    path = tmp_path / "t.h5"
    r = run("-q", "data", "generate", "--n-configs", "1", "--n-frames", "40", "--channels", "torque", "--out", path)
    assert r.exit_code == 0, r.output
    bad = [
        (("--friction", "coulomb", "--coulomb-zone", "fast"), "neither a velocity >= 0 (rad/s) nor 'identify'"),
        (("--friction", "stribeck"), "Stribeck friction needs its velocity"),
        (("--friction", "sticky"), "is not none nor any of viscous, coulomb, stribeck"),
    ]
    for args, message in bad:
        r = run("solve", path, "--out", tmp_path / "bad.h5", *args)
        assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, (message, r.output)
    r = run(
        "solve",
        path,
        "--friction",
        "viscous,coulomb,stribeck",
        "--stribeck-velocity",
        "identify",
        "--backend",
        CASADI,
        "--out",
        tmp_path / "r.h5",
    )
    assert r.exit_code == 0, r.output
    r = run("identifiability", "sweaty-arm", "--use", "torque", "--friction", "coulomb", "--coulomb-zone", "identify")
    assert r.exit_code != 0 and "--coulomb-zone identify is found by the solve of one dataset" in r.output, r.output
    r = run("solve", path, path, "--friction", "coulomb", "--coulomb-zone", "identify", "--out", tmp_path / "j.h5")
    assert r.exit_code != 0 and "here give it in rad/s" in r.output and "Traceback" not in r.output, r.output
    info = run("results", "info", tmp_path / "r.h5").output
    found = load_results(tmp_path / "r.h5").meta["channels"][0]
    assert f'"stribeck_velocity": {found["stribeck_velocity"]!r}' in info and found["identified"], info


def test_mujoco_stribeck_velocity_identified(model):
    """MuJoCo simulates the arm with viscous damping and its Stribeck term ``fs exp(-(qd / vs)^2) tanh(qd / 0.2 vs)``
    (:class:`ineid.studies.mujoco_sim.JointFriction`) under its own dynamics: the torques its actuators apply, fitted
    with the zone ``0.2 vs`` given, give ``vs``, ``fs`` and ``fv`` to their truth."""
    pytest.importorskip("mujoco")
    from ineid.studies.mujoco_sim import JointFriction, simulate

    fv, fs, vs = np.array([0.05, 0.04, 0.01, 0.02]), np.array([0.05, 0.04, 0.02, 0.03]), 0.2
    sim = simulate(
        model,
        model.theta_cad,
        None,
        2.0,
        rate=200.0,
        steps_per_sample=5,
        seed=2,
        friction=JointFriction(viscous=fv, stribeck=fs, stribeck_velocity=vs),
    )
    n = len(sim.q)
    spec = DatasetSpec(Combination("random", n_configs=1), n_frames=n, seed=3, channels=ChannelSet.of(JointTorque()))
    ds = generate_dataset(model, spec)
    ds = dataclasses.replace(
        ds, q=sim.q[None], qd=sim.qd[None], qdd=sim.qdd[None], channel_values={"tau": sim.tau[None]}, clean={}
    )
    settings = SolveSettings(
        friction=("viscous", "stribeck"), coulomb_zone=0.2 * vs, stribeck_velocity="identify", backend=CASADI
    )
    res = solve_dataset(ds, settings, model=model)
    (record,) = res.meta["channels"]
    assert abs(record["stribeck_velocity"] / vs - 1) < 1e-6, record
    np.testing.assert_allclose(res.theta_hat[0, -8:], np.stack([fv, fs], -1).ravel(), rtol=1e-5)
