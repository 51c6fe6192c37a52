"""The parameter convention: converters and physical-validity checks."""

from __future__ import annotations

import numpy as np
import pytest

from ineid import PhysicalConsistencyError, check_physical, inertial_from_theta, is_physical, theta_from_inertial
from ineid.params import PARAM_NAMES, param_names, physical_violations, pseudo_inertia, theta_from_pseudo_inertia


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def random_body(rng):
    m = rng.uniform(0.1, 5)
    c = rng.normal(scale=0.2, size=3)
    a, b = rng.uniform(0.01, 0.1, 2)
    moments = np.array([a, b, rng.uniform(abs(a - b) + 1e-3, a + b - 1e-3)])
    rot = random_rotation(rng)
    return m, c, rot @ np.diag(moments) @ rot.T


def test_names_follow_pinocchio_order():
    assert PARAM_NAMES == ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
    assert param_names(["a"])[5] == "a.Ixy"


def test_round_trip_and_parallel_axis(rng):
    for _ in range(20):
        m, c, ic = random_body(rng)
        theta = theta_from_inertial(m, c, ic)
        m2, c2, ic2 = inertial_from_theta(theta)
        assert np.isclose(m2, m) and np.allclose(c2, c) and np.allclose(ic2, ic)
        # I_O = I_C + m (|c|^2 1 - c c^T)
        i_o = ic + m * (c @ c * np.eye(3) - np.outer(c, c))
        assert np.allclose(theta[[4, 5, 6, 7, 8, 9]], i_o[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]])
        assert np.allclose(theta_from_pseudo_inertia(pseudo_inertia(theta)), theta)
        assert np.all(np.linalg.eigvalsh(pseudo_inertia(theta)) > 0)
        assert not physical_violations(theta)


def test_batched(rng):
    bodies = [random_body(rng) for _ in range(5)]
    m = np.array([b[0] for b in bodies])
    c = np.stack([b[1] for b in bodies])
    ic = np.stack([b[2] for b in bodies])
    theta = theta_from_inertial(m, c, ic)
    assert theta.shape == (5, 10)
    assert is_physical(theta).all()
    m2, c2, ic2 = inertial_from_theta(theta)
    assert np.allclose(ic2, ic)


def test_checker_rejects_invalid(rng):
    m, c, ic = random_body(rng)
    good = theta_from_inertial(m, c, ic)
    neg_mass = good.copy()
    neg_mass[0] = -1
    assert "mass -1 kg is not positive" in physical_violations(neg_mass)[0]
    triangle = theta_from_inertial(1.0, c, np.diag([0.01, 0.01, 0.03]))
    assert "triangle inequality" in " ".join(physical_violations(triangle))
    not_pd = theta_from_inertial(1.0, c, np.diag([0.01, -0.001, 0.01]))
    assert "not positive definite" in " ".join(physical_violations(not_pd))
    assert physical_violations(np.full(10, np.nan)) == ["parameters are not finite"]
    stacked = np.concatenate([good, triangle])
    assert is_physical(stacked.reshape(2, 10)).tolist() == [True, False]
    with pytest.raises(PhysicalConsistencyError, match="link 'forearm': principal moments"):
        check_physical(stacked, ["upper_arm", "forearm"])
    check_physical(good)
    with pytest.raises(ValueError, match="theta must have shape"):
        check_physical(np.zeros(7))
