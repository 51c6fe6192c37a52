"""Properties of the robot model's regressor (:mod:`ineid.robots.model`) that hold for any state: linearity,
splitting, gradients."""

from __future__ import annotations

import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

import ineid

from .conftest import casadi_regressor_frames, random_states, real_robot, regressor_in_another_process, rel_err


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


finite = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False)
vec4 = st.lists(finite, min_size=4, max_size=4)
theta40 = st.lists(st.floats(min_value=-2.0, max_value=2.0, allow_nan=False), min_size=40, max_size=40)


@settings(max_examples=60, deadline=None)
@given(q=vec4, qd=vec4, qdd=vec4, t1=theta40, t2=theta40, a=finite, b=finite)
def test_wrench_is_linear_in_theta(arm, q, qd, qdd, t1, t2, a, b):
    t1, t2 = np.array(t1), np.array(t2)
    w = lambda t: np.asarray(arm.base_wrench(q, qd, qdd, t))  # noqa: E731
    lhs = w(a * t1 + b * t2)
    rhs = a * w(t1) + b * w(t2)
    assert np.allclose(lhs, rhs, rtol=1e-12, atol=1e-12 * (1 + np.max(np.abs(rhs))))


def test_split_adds_up(arm, rng):
    q, qd, qdd = random_states(arm, 50, rng)
    y_u, y_k = arm.regressor_split(q, qd, qdd)
    assert y_u.shape == (50, 6, 20) and y_k.shape == (50, 6, 20)
    theta = arm.theta_cad
    w = y_u @ theta[arm.unknown_index] + y_k @ theta[arm.known_index]
    assert rel_err(w, arm.base_wrench(q, qd, qdd)) < 1e-14
    assert list(arm.unknown_links) == ["upper_arm", "forearm"]
    assert arm.unknown_index.tolist() == list(range(20, 40))


def test_batching_over_leading_axes(arm, rng):
    q, qd, qdd = (x.reshape(3, 5, 4) for x in random_states(arm, 15, rng))
    y = np.asarray(arm.regressor(q, qd, qdd))
    assert y.shape == (3, 5, 6, 40)
    assert np.array_equal(y[1, 2], np.asarray(arm.regressor(q[1, 2], qd[1, 2], qdd[1, 2])))


def test_jit_and_gradients(arm, rng):
    q, qd, qdd = (jnp.asarray(x[0]) for x in random_states(arm, 1, rng))
    f = jax.jit(arm.jax_regressor)
    assert rel_err(f(q, qd, qdd, arm.gravity), arm.regressor(q, qd, qdd)) < 1e-14  # XLA may fuse differently
    g = jnp.asarray(arm.gravity)
    check_grads(lambda a, b, c: arm.jax_regressor(a, b, c, g), (q, qd, qdd), order=2, modes=("fwd", "rev"))
    theta = jnp.asarray(arm.theta_cad)
    check_grads(lambda a, t: arm.jax_regressor(a, qd, qdd, g) @ t, (q, theta), order=1, modes=("rev",))


def test_gravity_is_a_model_setting(rng):
    default = ineid.load_robot("sweaty-arm")
    moon = ineid.load_robot("sweaty-arm", gravity=(0, 0, -1.62))
    z = np.zeros(4)
    m_total = default.theta_cad[::10].sum()
    assert np.allclose(np.asarray(default.base_wrench(z, z, z))[:3], [0, 0, -9.81 * m_total])
    assert np.allclose(np.asarray(moon.base_wrench(z, z, z))[:3], [0, 0, -1.62 * m_total])


def test_shape_errors_name_the_argument(arm):
    with pytest.raises(ValueError, match=r"qd must have shape \(\.\.\., 4\), got \(3,\)"):
        arm.regressor(np.zeros(4), np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="theta must have shape"):
        arm.base_wrench(np.zeros(4), np.zeros(4), np.zeros(4), np.zeros(20))


@pytest.mark.parametrize("name", ["sweaty-arm", "panda"])
def test_a_pickled_model_is_the_same_model_in_another_process(name, rng):
    """A model sent to a worker process (pickled: the chain, its settings and its generated code by reference) has the
    same regressor there, a built-in's and a URDF's derived into the cache alike (its code travels as the bytes that
    were checked, not read again)."""
    if name == "sweaty-arm":
        model = ineid.load_robot(name, unknown_links=["forearm"], gravity=(0.0, 9.81, 0.0))
    else:
        path, locked = real_robot(name)
        model = ineid.load_robot(path, locked_joints=locked)
    q = rng.uniform(-1.0, 1.0, (4, model.n_dof))
    there = regressor_in_another_process(model, q)
    np.testing.assert_array_equal(there, casadi_regressor_frames(model, q))
    copy = pickle.loads(pickle.dumps(model))
    assert (copy.unknown_links, copy.locked_joints, copy.urdf_text) == (
        model.unknown_links,
        model.locked_joints,
        model.urdf_text,
    )
    np.testing.assert_array_equal(copy.gravity, model.gravity)
    np.testing.assert_array_equal(copy.regressor(q, q, q), model.regressor(q, q, q))  # the JAX module too
