"""The derivation (:mod:`ineid.symbolic`) through its generated regressor, against an engine we did not write
(Pinocchio), and SymPy itself.

For each robot, on 1000 random states: generated JAX, generated CasADi, SymPy's own
evaluation (lambdify, no CSE) and Pinocchio's base regressor and RNEA base wrench agree
to 1e-10 relative.
"""

from __future__ import annotations

import zlib

import casadi as ca
import numpy as np
import pytest

from ineid.reference import (
    pinocchio_base_regressor,
    pinocchio_base_wrench,
    pinocchio_theta,
)
from ineid.symbolic import derive_base_wrench_regressor

from .conftest import random_states, rel_err, robot_and_pinocchio

N_STATES = 1000
TOL = 1e-10
GRAVITY = (0.3, -0.4, -9.81)  # tilted, so every gravity component is exercised


def _case(name):
    return robot_and_pinocchio(name, GRAVITY)


ROBOTS = ["sweaty-arm", "ur5", "panda", "kinova", "mixed-chain"]


@pytest.fixture(scope="module", params=ROBOTS)
def case(request):
    model, pin_model = _case(request.param)
    rng = np.random.default_rng(zlib.crc32(request.param.encode()))
    states = random_states(model, N_STATES, rng)
    return model, pin_model, states


def test_cad_parameters_match_pinocchio(case):
    model, pin_model, _ = case
    assert model.n_dof == pin_model.nv
    assert np.allclose(model.theta_cad, pinocchio_theta(pin_model), rtol=0, atol=1e-14)


def test_jax_regressor_matches_pinocchio(case):
    model, pin_model, (q, qd, qdd) = case
    y_ref = pinocchio_base_regressor(pin_model, q, qd, qdd)
    y = np.asarray(model.regressor(q, qd, qdd))
    assert y.shape == (N_STATES, 6, 10 * model.n_links)
    assert y.dtype == np.float64
    assert rel_err(y, y_ref) < TOL


def test_base_wrench_matches_pinocchio_rnea(case):
    model, pin_model, (q, qd, qdd) = case
    w_ref = pinocchio_base_wrench(pin_model, q, qd, qdd)
    assert rel_err(model.base_wrench(q, qd, qdd), w_ref) < TOL


def test_casadi_regressor_matches_jax(case):
    model, _, (q, qd, qdd) = case
    f = model.casadi_regressor.map(N_STATES)
    y_ca = np.array(f(q.T, qd.T, qdd.T))  # (6, N * 10n), frames side by side
    y_ca = y_ca.reshape(6, N_STATES, 10 * model.n_links).transpose(1, 0, 2)
    assert rel_err(y_ca, np.asarray(model.regressor(q, qd, qdd))) < TOL
    # the named signature users rely on
    assert model.casadi_regressor.name_in() == ["q", "qd", "qdd"]
    assert model.casadi_regressor.name_out() == ["Y"]
    assert isinstance(model.casadi_regressor, ca.Function)


def test_sympy_evaluation_matches_generated(case):
    model, _, (q, qd, qdd) = case
    sym = derive_base_wrench_regressor(model.chain)
    y_sym = sym.numpy_function()(q, qd, qdd, model.gravity)
    assert rel_err(model.regressor(q, qd, qdd), y_sym) < TOL


def test_static_load_is_total_weight(case):
    """At rest the fixture carries the arm's weight: F = m_total * g."""
    model, _, (q, _, _) = case
    zeros = np.zeros_like(q)
    w = np.asarray(model.base_wrench(q, zeros, zeros))
    m_total = model.theta_cad[::10].sum()
    assert np.allclose(w[:, :3], m_total * model.gravity, rtol=0, atol=1e-12 * m_total * 10)
    # and the moment is that of the weight acting at the centre of mass
    y = np.asarray(model.regressor(q, zeros, zeros))
    assert np.allclose(w, y @ model.theta_cad, atol=1e-12)
