"""The backward pass (:mod:`ineid.robots.cuts`): joint torques and the wrench at a link, against Pinocchio.

For each robot, on random states: the joint-torque regressor equals Pinocchio's
``computeJointTorqueRegressor``, the torques its ``rnea``, and the wrench the links beyond
each link exert on it equals ``-liMi[c].act(data.f[c])`` of its child joint; CasADi equals JAX.
The built-in arm and the test chain (prismatic joint, welded links, a tool) agree to 1e-12;
example-robot-data's arms to 1e-10, like their base regressors: ineid snaps their CAD-rounded
``rpy`` (3.14159265359) to exact multiples of pi/2, Pinocchio does not.
"""

from __future__ import annotations

import zlib

import casadi as ca
import numpy as np
import pytest

import ineid
from ineid.channels.pose import wrench_transform
from ineid.errors import RobotModelError
from ineid.reference import (
    pinocchio_joint_torque_regressor,
    pinocchio_joint_torques,
    pinocchio_link_wrench,
    pinocchio_theta,
)

from .conftest import FIXTURES, random_states, rel_err, robot_and_pinocchio

N_STATES = 60
GRAVITY = (0.3, -0.4, -9.81)
EXACT = {"sweaty-arm": 1e-12, "mixed-chain": 1e-12}


def _case(name):
    return robot_and_pinocchio(name, GRAVITY)


@pytest.fixture(
    scope="module",
    params=[
        "sweaty-arm",
        "mixed-chain",
        "ur5",  # 7-joint arms compile for minutes:
        pytest.param("panda", marks=pytest.mark.slow),  # make test-slow
        pytest.param("kinova", marks=pytest.mark.slow),
    ],
)
def case(request):
    model, pin_model = _case(request.param)
    rng = np.random.default_rng(zlib.crc32(request.param.encode()))
    return model, pin_model, random_states(model, N_STATES, rng), EXACT.get(request.param, 1e-10)


def test_joint_torque_regressor_matches_pinocchio(case):
    model, pin_model, (q, qd, qdd), tol = case
    y = model.joint_torque_regressor(q, qd, qdd)
    assert y.shape == (N_STATES, model.n_dof, 10 * model.n_links) and y.dtype == np.float64
    assert rel_err(y, pinocchio_joint_torque_regressor(pin_model, q, qd, qdd)) < tol
    # Pinocchio's identity: tau = Y_tau theta = rnea
    tau = pinocchio_joint_torques(pin_model, q, qd, qdd)
    assert rel_err(y @ pinocchio_theta(pin_model), tau) < tol
    assert rel_err(model.joint_torques(q, qd, qdd), tau) < tol


def test_joint_torque_structure(case):
    """A joint carries only what lies beyond it: the columns of earlier links are structurally zero."""
    model, _, (q, qd, qdd), _ = case
    nonzero = model.joint_torque_nonzero
    for j in range(model.n_dof):
        assert all(c >= 10 * j for c in nonzero[j])
    y = model.joint_torque_regressor(q[:5], qd[:5], qdd[:5])
    mask = np.zeros(y.shape[1:], dtype=bool)
    for j, cols in enumerate(nonzero):
        mask[j, list(cols)] = True
    assert np.all(y[:, ~mask] == 0)


def test_joint_torques_per_frame_theta_and_broadcast(case):
    model, _, (q, qd, qdd), tol = case
    if tol > 1e-12:
        pytest.skip("one robot of each kind suffices for the evaluator's shapes (compiling 7-joint kernels is slow)")
    rng = np.random.default_rng(3)
    theta = model.theta_cad * (1 + 0.1 * rng.standard_normal((N_STATES, model.theta_cad.size)))
    y = model.joint_torque_regressor(q, qd, qdd)
    assert rel_err(model.joint_torques(q, qd, qdd, theta), np.einsum("npc,nc->np", y, theta)) < 1e-13
    # one state against a batch of accelerations
    assert model.joint_torques(q[0], qd[0], qdd[:7]).shape == (7, model.n_dof)


def test_link_wrench_matches_pinocchio(case):
    model, pin_model, (q, qd, qdd), tol = case
    for i in (0, model.n_dof // 2):  # the first cut and one inside the chain (each compiles its own kernels)
        link = model.link_names[i]
        ref = pinocchio_link_wrench(pin_model, q, qd, qdd, i + 1)
        assert rel_err(model.link_wrench_regressor(q, qd, qdd, link) @ model.theta_cad, ref) < tol, link
        assert rel_err(model.link_wrench(q, qd, qdd, link), ref) < tol, link
    # nothing lies beyond the last link
    assert np.all(model.link_wrench_regressor(q[:3], qd[:3], qdd[:3], model.link_names[-1]) == 0)


def test_casadi_forms_match_jax(case):
    model, _, (q, qd, qdd), _ = case
    n = 20
    f = model.casadi_joint_torque_regressor.map(n)
    y_ca = np.array(f(q[:n].T, qd[:n].T, qdd[:n].T)).reshape(model.n_dof, n, -1).transpose(1, 0, 2)
    assert rel_err(y_ca, model.joint_torque_regressor(q[:n], qd[:n], qdd[:n])) < 1e-13
    assert model.casadi_joint_torque_regressor.name_in() == ["q", "qd", "qdd"]
    tau = np.array(model.casadi_joint_torques.map(n)(q[:n].T, qd[:n].T, qdd[:n].T, model.theta_cad)).T
    assert rel_err(tau, model.joint_torques(q[:n], qd[:n], qdd[:n])) < 1e-13
    link = model.link_names[0]
    w = np.array(model.casadi_link_wrench_regressor(link).map(n)(q[:n].T, qd[:n].T, qdd[:n].T))
    w = w.reshape(6, n, -1).transpose(1, 0, 2)
    assert rel_err(w, model.link_wrench_regressor(q[:n], qd[:n], qdd[:n], link)) < 1e-13
    assert isinstance(model.casadi_joint_torques, ca.Function)


def test_payload_is_beyond_a_sensor_on_its_body():
    """A tool named as a payload is its own block: the joints carry it, and a sensor on the link it is
    welded to sees it alone, as the base sees it moved to that link's frame."""
    path = FIXTURES / "mixed_chain.urdf"
    plain = ineid.load_robot(path, gravity=GRAVITY)
    model = ineid.load_robot(path, gravity=GRAVITY, unknown_links=["tool"])
    rng = np.random.default_rng(5)
    q, qd, qdd = random_states(model, 50, rng)
    # the same physics with the tool as its own block
    assert rel_err(model.joint_torques(q, qd, qdd), plain.joint_torques(q, qd, qdd)) < 1e-12
    body = model.link_names[model.link_names.index("tool") - 1]
    only_tool = np.zeros_like(model.theta_cad)
    block = 10 * model.link_names.index("tool")
    only_tool[block : block + 10] = model.theta_cad[block : block + 10]
    sensed = model.link_wrench(q, qd, qdd, body, only_tool)
    rot, pos = (np.asarray(x) for x in model.jax_link_poses(q))
    k = model.link_names.index(body)
    from_base = np.einsum(
        "nij,nj->ni",
        np.stack([wrench_transform(r, p) for r, p in zip(rot[:, k], pos[:, k], strict=True)]),
        model.base_wrench(q, qd, qdd, only_tool),
    )
    assert rel_err(sensed, from_base) < 1e-12
    assert np.abs(sensed).max() > 1e-3  # the tool has mass: the check is not vacuous


def test_link_wrench_names_the_choices():
    model = ineid.load_robot("sweaty-arm")
    with pytest.raises(RobotModelError, match="not a moving link of sweaty-arm; choose from shoulder_pitch_link"):
        model.link_wrench_regressor(np.zeros(4), np.zeros(4), np.zeros(4), "nowhere")
