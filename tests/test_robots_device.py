"""The public evaluators on JAX arrays (:mod:`ineid.robots.device`, :mod:`ineid.robots.evaluate`) and the
NumPy path's streamed chunks (:mod:`ineid.robots.chunked`).

JAX states give ``jax.Array`` results on the states' device equal to the NumPy path's to 1e-12: on a CPU
device read in place, through the accelerators' path (run here on the CPU: ``CPU_IN_PLACE`` off, small
device pieces so that odd frame counts are windowed and padded), and traced inside a caller's ``jax.jit``.
The NumPy path gives the same numbers from one thread or several, and equals the pure kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ineid
from ineid.channels import BaseWrench, ChannelSet, JointTorque, LinkWrench, MotorCurrent, SensorPose
from ineid.robots import chunked, device

from .conftest import random_states, rel_err

N_FRAMES = 3101
"""Odd, and past one device piece (:data:`PIECE`): a full piece and a padded remainder."""
PIECE = 3000
"""Frames per device piece in these tests (above ``CHUNK_FRAMES``: the power-of-two sizes of an accelerator)."""


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="module")
def states(arm):
    return random_states(arm, N_FRAMES, np.random.default_rng(3))


@pytest.fixture(params=["in-place", "device-path"])
def mode(request, monkeypatch):
    """The CPU device's two JAX paths: the NumPy path in place, or the accelerators' windowed pieces."""
    if request.param == "device-path":
        monkeypatch.setattr(device, "CPU_IN_PLACE", False)
        monkeypatch.setattr(chunked, "DEVICE_CHUNK_FRAMES", PIECE)
    return request.param


def _evaluators(arm, theta):
    """name -> f(q, qd, qdd): every public evaluator, and the channels' rows and predictions."""
    link = arm.link_names[-1]
    pose = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
    motor = MotorCurrent(torque_constant=(0.1, 0.2, 0.3, 0.4), gear_ratio=(50, 60, 70, 80))
    return {
        "regressor": arm.regressor,
        "regressor_split": arm.regressor_split,
        "base_wrench": lambda q, qd, qdd: arm.base_wrench(q, qd, qdd, theta),
        "base_wrench_cad": arm.base_wrench,
        "joint_torque_regressor": arm.joint_torque_regressor,
        "joint_torques": lambda q, qd, qdd: arm.joint_torques(q, qd, qdd, theta),
        "link_wrench_regressor": lambda q, qd, qdd: arm.link_wrench_regressor(q, qd, qdd, link),
        "link_wrench": lambda q, qd, qdd: arm.link_wrench(q, qd, qdd, link, theta),
        "rows_wrench_at_pose": lambda q, qd, qdd: BaseWrench(sensor=pose).rows(arm, q, qd, qdd),
        "rows_split_wrench": lambda q, qd, qdd: BaseWrench().rows_split(arm, q, qd, qdd),
        "rows_torque": lambda q, qd, qdd: JointTorque().rows(arm, q, qd, qdd),
        "rows_current": lambda q, qd, qdd: motor.rows(arm, q, qd, qdd),
        "rows_link_wrench": lambda q, qd, qdd: LinkWrench(key="w", link=link).rows(arm, q, qd, qdd),
        "predict_wrench_at_pose": lambda q, qd, qdd: BaseWrench(sensor=pose).predict(arm, q, qd, qdd, theta),
        "set_rows_split": lambda q, qd, qdd: ChannelSet((BaseWrench(), motor)).rows_split(arm, q, qd, qdd),
        "set_predict": lambda q, qd, qdd: ChannelSet((BaseWrench(sensor=pose), JointTorque())).predict(
            arm, q, qd, qdd, theta
        ),
    }


CORE = ("regressor_split", "base_wrench", "joint_torques", "link_wrench", "rows_current", "set_rows_split")
"""A few evaluators covering each shape (several results, theta fixed, torques, a link, a channel's transform):
the paths that compile the pure functions for themselves take seconds per function."""


def _pairs(a, b):
    a = a if isinstance(a, tuple) else (a,)
    b = b if isinstance(b, tuple) else (b,)
    assert len(a) == len(b)
    return zip(a, b, strict=True)


def _close(got, expected):
    for g, e in _pairs(got, expected):
        assert g.shape == e.shape
        assert rel_err(g, e) < 1e-12


def _check_on_device(arm, states, names):
    theta = arm.theta_cad * 1.1
    cpu = jax.devices("cpu")[0]
    js = [jax.device_put(x, cpu) for x in states]
    for name, f in _evaluators(arm, theta).items():
        if name not in names:
            continue
        expected = f(*states)
        got = f(*js)
        for g, e in _pairs(got, expected):
            assert isinstance(e, np.ndarray), name
            assert isinstance(g, jax.Array) and g.devices() == {cpu}, name
        _close(got, expected)


def test_jax_states_give_jax_arrays_on_their_device(arm, states, mode):
    _check_on_device(arm, states, CORE)


@pytest.mark.slow  # every evaluator and channel compiled for both paths (a minute): make test-slow
def test_every_evaluator_on_jax_states(arm, states, mode):
    _check_on_device(arm, states, tuple(_evaluators(arm, None)))


def test_per_frame_theta_and_batch_shapes(arm, states, mode):
    q, qd, qdd = (x[:60].reshape(3, 4, 5, arm.n_dof) for x in states)
    thetas = arm.theta_cad * np.linspace(0.5, 1.5, 5)[:, None]  # (5, p): broadcasts over the last batch axis
    expected = arm.base_wrench(q, qd, qdd, thetas)
    got = arm.base_wrench(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd), jnp.asarray(thetas))
    assert isinstance(got, jax.Array) and got.shape == expected.shape
    _close(got, expected)
    qd1 = jnp.asarray(qd[0, 0, 0])  # one velocity for every frame
    _close(arm.regressor(jnp.asarray(q), qd1, jnp.asarray(qdd)), arm.regressor(q, qd[0, 0, 0], qdd))
    empty = arm.regressor(*(jnp.zeros((0, arm.n_dof)) for _ in range(3)))
    assert isinstance(empty, jax.Array) and empty.shape == (0, 6, 10 * arm.n_links)


def test_inside_a_callers_jit(arm, states):
    theta = arm.theta_cad * 0.9
    q, qd, qdd = (x[:37] for x in states)
    for name, f in _evaluators(arm, theta).items():
        if name not in (
            "regressor_split",
            "base_wrench",
            "rows_current",
            "set_predict",
        ):  # tracing: the pure functions, each compiled
            continue
        expected = f(q, qd, qdd)
        got = jax.jit(f)(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd))
        for g in got if isinstance(got, tuple) else (got,):
            assert isinstance(g, jax.Array), name
        _close(got, expected)
    grad = jax.grad(lambda q: arm.base_wrench(q, jnp.asarray(qd[0]), jnp.asarray(qdd[0]))[2])(jnp.asarray(q[0]))
    assert grad.shape == (arm.n_dof,) and np.all(np.isfinite(grad))


def test_numpy_streaming_equals_one_thread_and_the_pure_kernels(arm, states, monkeypatch):
    theta = arm.theta_cad * 1.2
    monkeypatch.setenv("INEID_EVAL_THREADS", "1")
    one = {name: f(*states) for name, f in _evaluators(arm, theta).items() if not name.startswith(("rows", "pred"))}
    monkeypatch.setenv("INEID_EVAL_THREADS", "3")
    for name, f in _evaluators(arm, theta).items():
        if name in one:
            for a, b in _pairs(f(*states), one[name]):
                assert isinstance(a, np.ndarray) and np.array_equal(a, b), name  # the same chunks, bit for bit
    pure = jax.jit(arm.jax_regressor)(*(jnp.asarray(x) for x in states), arm.gravity)
    assert rel_err(one["regressor"], pure) < 1e-12
    wrench = jax.jit(arm.jax_base_wrench)(*(jnp.asarray(x) for x in states), arm.gravity, theta)
    assert rel_err(one["base_wrench"], wrench) < 1e-12


def test_mixed_states_take_the_numpy_path_and_bad_shapes_are_named(arm, states):
    q, qd, qdd = (x[:5] for x in states)
    mixed = arm.regressor(jnp.asarray(q), qd, qdd)  # any NumPy state: the NumPy path
    assert isinstance(mixed, np.ndarray) and np.array_equal(mixed, arm.regressor(q, qd, qdd))
    with pytest.raises(ValueError, match="must have shape"):
        arm.regressor(jnp.asarray(q[:, :3]), jnp.asarray(qd), jnp.asarray(qdd))
    with pytest.raises(ValueError, match="theta must have shape"):
        arm.base_wrench(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd), jnp.zeros(3))
