"""The joint-torque and motor-current channels (:mod:`ineid.channels.torque`): rows, actuation columns,
records (the link-wrench channel's among them)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.channels import (
    BaseWrench,
    ChannelSet,
    JointTorque,
    LinkWrench,
    MotorCurrent,
    channel_from_dict,
)
from ineid.errors import DatasetError

from .conftest import random_states, rel_err

FULL = JointTorque().with_actuation(friction=("viscous", "coulomb"), armature=True, torque_offset=True)


@pytest.fixture(scope="module")
def frames(model):
    return random_states(model, 40, np.random.default_rng(11))


def test_torque_rows_and_prediction_are_the_models(model, frames):
    q, qd, qdd = frames
    ch = JointTorque()
    assert ch.axes(model) == model.joint_names and ch.units(model) == ("N*m",) * 4
    assert rel_err(ch.rows(model, q, qd, qdd), model.joint_torque_regressor(q, qd, qdd)) == 0
    assert rel_err(ChannelSet.of(ch).rows(model, q, qd, qdd), model.joint_torque_regressor(q, qd, qdd)) < 1e-15
    assert rel_err(ch.predict(model, q, qd, qdd, model.theta_cad), model.joint_torques(q, qd, qdd)) == 0
    assert ch.extra_names(model) == () and ch.extra_rows(model, q, qd, qdd).shape == (40, 4, 0)


def test_actuation_columns(model, frames):
    """Row j of E holds joint j's qd, sign(qd), 1, qdd, named <joint>.fv, .fc, .offset, .Ia."""
    q, qd, qdd = frames
    names = FULL.extra_names(model)
    assert names[:4] == ("shoulder_pitch.fv", "shoulder_pitch.fc", "shoulder_pitch.offset", "shoulder_pitch.Ia")
    assert len(names) == 16 and FULL.extra_units(model)[:4] == ("N*m*s/rad", "N*m", "N*m", "kg*m^2")
    e = FULL.extra_rows(model, q, qd, qdd)
    expected = np.zeros((40, 4, 16))
    for j in range(4):
        expected[:, j, 4 * j : 4 * j + 4] = np.stack([qd[:, j], np.sign(qd[:, j]), np.ones(40), qdd[:, j]], -1)
    assert np.array_equal(e, expected)
    casadi = np.array(FULL.casadi_extra_function(model)(q[3], qd[3], qdd[3]))
    assert np.abs(casadi - e[3]).max() < 1e-15


def test_asymmetric_and_smooth_friction(model, frames):
    q, qd, qdd = frames
    ch = JointTorque().with_actuation(friction=("viscous", "coulomb"), asymmetric=True, coulomb_zone=0.05)
    assert ch.extra_names(model)[:4] == (
        "shoulder_pitch.fv+",
        "shoulder_pitch.fv-",
        "shoulder_pitch.fc+",
        "shoulder_pitch.fc-",
    )
    e = ch.extra_rows(model, q, qd, qdd)[:, 0, :4]
    v, c = qd[:, 0], np.tanh(qd[:, 0] / 0.05)
    assert np.allclose(
        e, np.stack([np.maximum(v, 0), np.minimum(v, 0), np.maximum(c, 0), np.minimum(c, 0)], -1), rtol=0, atol=1e-15
    )
    # a symmetric coefficient is the asymmetric pair with equal values
    assert np.allclose(e[:, 0] + e[:, 1], v) and np.allclose(e[:, 2] + e[:, 3], c)


def test_motor_current_reads_torques_through_the_drive(model, frames):
    q, qd, qdd = frames
    k, g = (0.05, 0.07, 0.1, 0.2), (100.0, 120.0, -80.0, 50.0)
    ch = MotorCurrent(torque_constant=k, gear_ratio=g, friction=("viscous",))
    scale = 1 / (np.array(k) * np.array(g))
    assert ch.units(model) == ("A",) * 4
    assert rel_err(ch.rows(model, q, qd, qdd), scale[:, None] * model.joint_torque_regressor(q, qd, qdd)) < 1e-15
    assert rel_err(ch.extra_rows(model, q, qd, qdd)[:, np.arange(4), np.arange(4)], scale * qd) < 1e-15
    with pytest.raises(DatasetError, match="3 gear ratios for 4 joints"):
        MotorCurrent(torque_constant=(1, 1, 1), gear_ratio=(1, 1, 1)).units(model)
    with pytest.raises(DatasetError, match="finite, non-zero"):
        MotorCurrent(torque_constant=(0, 1), gear_ratio=(1, 1))


@pytest.mark.parametrize(
    "channel",
    [
        FULL,
        JointTorque(key="tau_motor", friction=("coulomb",), coulomb_zone=0.1, asymmetric=True, offsets=True),
        MotorCurrent(torque_constant=(0.1, 0.2), gear_ratio=(50, 60), armature=True),
        LinkWrench(link="upper_arm", offsets=True),
    ],
)
def test_records_round_trip(channel):
    assert channel_from_dict(channel.to_dict()) == channel


@pytest.mark.parametrize(
    "record, message",
    [
        (
            {"kind": "joint_torque", "key": "tau", "friction": ["stiction"]},
            "friction must be a list of viscous, coulomb",
        ),
        ({"kind": "joint_torque", "key": "tau", "friction": "viscous"}, "friction must be a list"),
        ({"kind": "joint_torque", "key": "tau", "coulomb_zone": -1}, "Coulomb zone must be a finite number >= 0"),
        ({"kind": "joint_torque", "key": "tau", "armature": "yes"}, "armature must be true or false"),
        ({"kind": "link_wrench", "key": "w"}, "must name its link"),
        ({"kind": "motor_current", "key": "i", "torque_constant": [1], "gear_ratio": [1, 2]}, "1 torque constants"),
    ],
)
def test_bad_records_are_one_line(record, message):
    with pytest.raises(DatasetError, match=message) as info:
        channel_from_dict(record)
    assert "\n" not in str(info.value)


def test_stacked_wrench_and_torques(model, frames):
    q, qd, qdd = frames
    cs = ChannelSet.of(BaseWrench(), FULL)
    assert cs.n_axes(model) == 10 and cs.n_extra(model) == 16
    e = cs.extra_rows(model, q, qd, qdd)
    assert np.all(e[:, :6] == 0) and np.array_equal(e[:, 6:], FULL.extra_rows(model, q, qd, qdd))
    rows = cs.rows(model, q, qd, qdd)
    assert rel_err(rows[:, 6:], model.joint_torque_regressor(q, qd, qdd)) < 1e-15
    assert dataclasses.replace(FULL, friction=()).extra_names(model) == tuple(
        f"{j}.{t}" for j in model.joint_names for t in ("offset", "Ia")
    )
