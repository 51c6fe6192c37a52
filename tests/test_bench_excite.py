"""``benchmarks/excite.py``'s measures against simulation: the random Fourier trajectories it compares with keep
what they claim, the wrench-prediction error is the RMS error of wrenches predicted by least-squares fits, and the
CasADi regressor it evaluates is the model's and the design's."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import ineid
from ineid.data.synthesis.trajectory import FourierTrajectory
from ineid.excite.criterion import design_base, design_noise, design_phi, scaled_regressor
from ineid.robots.kinematics import frame_points, welded_frames

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCH))  # its ``machine`` module
    try:
        spec = importlib.util.spec_from_file_location("bench_excite", BENCH / "excite.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # its dataclasses look their module up
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCH))
    yield module
    sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def arm():
    model = ineid.load_robot("sweaty-arm")
    return model, design_base(model), design_noise()


def test_random_fourier_keeps_rest_bounds_floor_and_box(bench, arm):
    model = arm[0]
    limits = bench.ARMS["sweaty-arm"]
    shape = FourierTrajectory(0.5, np.zeros(model.n_dof), np.zeros((model.n_dof, 4)), np.zeros((model.n_dof, 4)), 2.0)
    rng = np.random.default_rng(3)
    welded = welded_frames(model.urdf_text, model.chain, model.locked_joints)
    box = np.asarray(limits.workspace).reshape(3, 2)
    span = model.q_upper - model.q_lower
    for _ in range(3):
        traj, kept = bench.random_fourier(model, limits, shape, rng, tries=50, rate=100.0)
        assert kept and traj.harmonics == 4 and traj.duration == 2.0
        qd0, qdd0 = traj.rest_residual()
        np.testing.assert_allclose(np.concatenate([qd0, qdd0]), 0.0, atol=1e-12)
        _, q, qd, qdd = traj.sample(400.0)
        assert np.all(q >= model.q_lower + 0.05 * span - 1e-9) and np.all(q <= model.q_upper - 0.05 * span + 1e-9)
        assert np.all(np.abs(qd) <= model.qd_max * (1 + 1e-6)) and np.all(np.abs(qdd) <= model.qdd_max * (1 + 1e-6))
        assert np.abs(qd).max() > 0.1  # it moves
        pts = frame_points(model.chain, traj.sample(100.0)[1], welded)
        assert pts[..., 2].min() >= limits.floor and np.all((pts >= box[:, 0]) & (pts <= box[:, 1]))


def test_wrench_prediction_error_is_the_rms_error_of_fitted_predictions(bench, arm):
    """Least-squares fits on simulated noisy wrenches along a trajectory, their predictions at other states: the
    RMS prediction error over fits, states and axes (in units of the noise) matches the formula within 5%."""
    model, base, sigma = arm
    rng = np.random.default_rng(0)
    shape = FourierTrajectory(0.5, np.zeros(model.n_dof), np.zeros((model.n_dof, 4)), np.zeros((model.n_dof, 4)), 2.0)
    traj, _ = bench.random_fourier(model, bench.ARMS["sweaty-arm"], shape, rng, tries=50, rate=100.0)
    _, q, qd, qdd = traj.sample(50.0)
    _, phi = bench.scaled_phi(model, base, sigma, q, qd, qdd)
    a = phi.reshape(-1, base.rank)
    cov = np.linalg.inv(a.T @ a)
    states = bench.model_uniform_states(model, 200, rng)
    _, phi_states = bench.scaled_phi(model, base, sigma, *states)
    beta = rng.standard_normal(base.rank)
    fits = 400
    y = a @ beta + rng.standard_normal((fits, len(a)))  # unit noise per axis, scaled units
    errors = np.linalg.lstsq(a, y.T, rcond=None)[0].T - beta  # (fits, r)
    predicted = np.einsum("kar,fr->fka", phi_states, errors)
    measured = np.sqrt(np.mean(predicted**2))
    assert bench.wrench_prediction_error(phi_states, cov) == pytest.approx(measured, rel=0.05)


def test_casadi_regressor_is_the_models_and_the_designs(bench, arm):
    model, base, sigma = arm
    q, qd, qdd = bench.model_uniform_states(model, 7, np.random.default_rng(1))
    psi, phi = bench.scaled_phi(model, base, sigma, q, qd, qdd)
    np.testing.assert_allclose(psi, model.regressor(q, qd, qdd), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(phi, scaled_regressor(psi, base, sigma))
    np.testing.assert_allclose(phi, design_phi(model, base, sigma, q, qd, qdd), rtol=1e-12, atol=1e-12)
