"""Excitation for any sensor set: designs for joint torques and their actuation model."""

from __future__ import annotations

import numpy as np
import pytest

from ineid.channels import BaseWrench, ChannelSet, JointTorque, MotorCurrent
from ineid.data.synthesis.noise import NoiseModel
from ineid.errors import ExcitationError
from ineid.excite.design import design_base, design_excitation, design_noise, evaluate_design
from ineid.excite.settings import ExcitationSettings
from ineid.identify import base_parameters

TORQUES = ChannelSet.of(JointTorque().with_actuation(friction=("viscous", "coulomb"), armature=True))


def test_design_noise_per_channel(model):
    both = ChannelSet.of(BaseWrench(), JointTorque())
    assert np.allclose(design_noise(None, both, model), [0.5] * 3 + [0.05] * 3 + [0.05] * 4)
    noise = NoiseModel(channels={"tau": [0.01, 0.02, 0.03, 0.04]})
    assert np.allclose(design_noise(noise, ChannelSet.of(JointTorque()), model), [0.01, 0.02, 0.03, 0.04])
    current = MotorCurrent(torque_constant=(0.1,) * 4, gear_ratio=(50,) * 4)
    assert np.allclose(design_noise(None, ChannelSet.of(current), model), 0.05 / 5)  # 0.05 N*m through 1 / (k G)
    with pytest.raises(ExcitationError, match="positive noise on every axis of channel 'tau'"):
        design_noise(NoiseModel(channels={"tau": 0.0}), ChannelSet.of(JointTorque()), model)


def test_design_base_covers_the_extra_parameters(model):
    """The design's parameters are the base parameters ``solve`` identifies, friction and armature included."""
    base = design_base(model, channels=TORQUES)
    solved = base_parameters(model, channels=TORQUES)
    assert base.names == solved.names
    extras = [n for n in base.names if n.endswith((".fv", ".fc", ".Ia"))]
    assert len(extras) == 12 and base.base.n_extra == 12
    assert np.all(base.cad[-12:] == 0)  # an extra's prior is 0
    # columns: the extras after the 10 n_links link columns of [I_A | T Phi | E]
    assert np.array_equal(base.columns[-12:], 4 + 10 * model.n_links + np.arange(12))


@pytest.mark.slow  # a second torque design (the CLI test below designs one by default): make test-slow
def test_torque_design_beats_random_and_predicts_its_spread(model):
    settings = ExcitationSettings(5.0, harmonics=3, starts=1, seed=3, channels=TORQUES)
    res = design_excitation(model, settings)
    assert res.optimized.d_opt < res.random.d_opt
    assert res.base.names[-1] == "elbow.Ia"
    # the expected std is that of least squares over [theta_u, x] on the designed frames
    t, q, qd, qdd = res.trajectory.sample(100.0)
    ev = evaluate_design(model, q, qd, qdd, res.base, res.sigma)
    assert ev.rank == res.base.rank and np.all(np.isfinite(ev.std))


def test_cli_excite_use_torque(run, tmp_path):
    out = tmp_path / "t.csv"
    r = run(
        "excite",
        "sweaty-arm",
        "--duration",
        5,
        "--harmonics",
        3,
        "--starts",
        1,
        "--use",
        "torque",
        "--friction",
        "viscous",
        "--noise",
        "tau=0.02",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "joint torques 'tau' (viscous friction): std 0.02 N*m" in r.output
    assert "shoulder_pitch.fv" in r.output and out.exists()
    r = run("excite", "sweaty-arm", "--duration", 5, "--armature", "--out", tmp_path / "w.csv")
    assert r.exit_code == 1 and "model joint torques" in r.output and "(--use torque)" in r.output
    assert not (tmp_path / "w.csv").exists()
