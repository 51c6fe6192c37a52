"""Motor currents with unknown torque constants: ``<joint>.k = k0 (1 + d)`` identified in step 2 of
``--two-step`` (:mod:`ineid.identify.two_step`) from the currents' residual (the column ``-i_j``), the record of the
channel, and bad input as one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.channels import BaseWrench, ChannelSet, JointTorque, MotorCurrent, channel_from_dict
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.errors import IdentificationError
from ineid.identify import SolveSettings, load_results, save_results, solve_dataset
from ineid.identify.steps import predicted_wrench
from tests.conftest import SEED

K0 = np.array([0.1, 0.12, 0.08, 0.05])
K_TRUE = K0 * np.array([1.1, 0.93, 1.05, 1.2])
GEAR = np.array([100.0, 120.0, -80.0, 50.0])
FRICTION = dict(friction=("viscous", "coulomb"))


def _currents(model, n_configs: int, noise: NoiseModel | None = None):
    """A wrench and currents simulated with ``K_TRUE`` and viscous + Coulomb friction, the channel recorded with
    the nominal ``K0``; ``(dataset, friction truth)``."""
    true = MotorCurrent(torque_constant=tuple(K_TRUE), gear_ratio=tuple(GEAR))
    spec = DatasetSpec(
        Combination("random", n_configs=n_configs), n_frames=60, seed=SEED, channels=ChannelSet.of(BaseWrench(), true)
    )
    ds = generate_dataset(model, spec)
    friction = dataclasses.replace(true, **FRICTION)
    x = np.random.default_rng(3).uniform(0.05, 0.5, len(friction.extra_names(model)))
    values = dict(ds.channel_values)
    values["current"] = values["current"] + friction.extra_rows(model, ds.q, ds.qd, ds.qdd) @ x
    if noise is not None:
        rng = np.random.default_rng(7)
        values["current"] = values["current"] + rng.normal(0, noise, values["current"].shape)
    nominal = dataclasses.replace(true, torque_constant=tuple(K0))
    meta = dataclasses.replace(ds.meta, channels=ChannelSet.of(BaseWrench(), nominal))
    return dataclasses.replace(ds, channel_values=values, meta=meta), x


def _settings(**kw) -> SolveSettings:
    return SolveSettings(
        weights="none", backend="casadi", two_step=True, torque_constant_unknown=True, **FRICTION, **kw
    )


def test_the_record_and_describe():
    c = MotorCurrent(torque_constant=tuple(K0), gear_ratio=tuple(GEAR))
    assert "identify_k" not in c.to_dict() and "identified" not in c.describe()
    k = dataclasses.replace(c, identify_k=True)
    assert channel_from_dict(k.to_dict()) == k and k.to_dict()["identify_k"] is True
    assert "torque constants identified" in k.describe()


def test_clean_currents_give_the_true_torque_constants(model, tmp_path):
    ds, x = _currents(model, 2)
    res = solve_dataset(ds, _settings(), model=model)
    k_names = tuple(f"{j}.k" for j in model.joint_names)
    assert res.success.all() and res.param_names[-len(k_names) :] == k_names
    assert res.n_extra == len(x) + len(k_names)
    np.testing.assert_allclose(res.theta_hat[:, -4:], np.broadcast_to(K_TRUE, (2, 4)), rtol=1e-8, atol=0)
    np.testing.assert_allclose(
        res.theta_hat[:, -4 - len(x) : -4], np.broadcast_to(x, (2, len(x))), rtol=1e-7, atol=1e-9
    )
    np.testing.assert_allclose(res.theta_prior[-4:], K0)
    # the residuals use the identified constants: clean data fit to round-off
    assert np.max(res.fit_rms[:, 6:]) < 1e-9 * np.max(np.abs(ds.channel_values["current"]))
    channels = ChannelSet.from_list(res.meta["channels"], "the results' channels")
    assert channels["current"].identify_k and channels["current"].torque_constant == tuple(K0)
    pred = predicted_wrench(model, ds, res.theta_hat, channels=channels)
    np.testing.assert_allclose(
        pred[..., 6:], ds.channel_values["current"], rtol=0, atol=1e-8 * np.max(np.abs(ds.channel_values["current"]))
    )
    back = load_results(save_results(res, tmp_path / "r.h5"))
    assert back.param_names == res.param_names and back.meta["channels"] == res.meta["channels"]
    np.testing.assert_array_equal(back.theta_hat, res.theta_hat)
    # without the flag the nominal constants bias the friction
    plain = solve_dataset(ds, dataclasses.replace(_settings(), torque_constant_unknown=False), model=model)
    assert plain.n_extra == len(x) and not np.allclose(plain.theta_hat[:, -len(x) :], x, rtol=1e-3)


def test_noisy_currents_within_a_few_std(model):
    ds, x = _currents(model, 3, noise=2e-3)
    res = solve_dataset(ds, _settings(bias="estimate"), model=model)
    assert res.success.all()
    z = (res.theta_hat[:, -4:] - K_TRUE) / res.theta_std[:, -4:]
    assert np.all(np.abs(z) < 5), z
    assert np.all(res.theta_std[:, -4:] < 0.05 * K0)


def test_bad_inputs_are_one_line(model, run, tmp_path):
    with pytest.raises(ValueError, match="second of two steps .* add --two-step"):
        SolveSettings(torque_constant_unknown=True, friction=("viscous",))
    tau = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=1),
            n_frames=30,
            seed=SEED,
            channels=ChannelSet.of(BaseWrench(), JointTorque()),
        ),
    )
    with pytest.raises(IdentificationError, match="no motor currents") as e:
        solve_dataset(tau, _settings(), model=model)
    assert "\n" not in str(e.value)
    out = tmp_path / "r.h5"
    path = tau.save(tmp_path / "tau.h5")
    for args, code, text in (
        (("--torque-constant-unknown", "--friction", "viscous"), 2, "add --two-step"),
        (("--two-step", "--torque-constant-unknown"), 1, "no motor currents"),
    ):
        r = run("solve", path, *args, "--out", out)
        assert r.exit_code == code, r.output
        lines = [line for line in r.output.splitlines() if line.strip()]
        assert text in lines[-1] and "Traceback" not in r.output and not out.exists()
