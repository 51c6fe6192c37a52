"""The friction's std on filtered recordings: the two-step fit's second step
(:mod:`ineid.identify.step_two_covariance`), the friction velocities' profile std
(:func:`ineid.identify.friction_search.long_run_factors`), and the study's friction truth at a smooth Coulomb zone
(:mod:`ineid.studies.std_recordings`), against simulated truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.channels import ChannelSet, JointTorque
from ineid.data.recordings.signals import LowPass
from ineid.identify.friction_search import Profile, long_run_factors
from ineid.identify.time_correlation import FilteredFrames, filter_gain
from ineid.studies.std_recordings import friction_zone, model_friction, rms_z, scenario, solve_draw


@pytest.fixture(scope="module")
def short_torque_lab():
    """Six seconds of the lab arm with joint torques and MuJoCo's joint friction, at 1 kHz."""
    return scenario(torque=True, duration=6.0)


def test_two_step_friction_std_on_a_filtered_recording_is_near_one(short_torque_lab):
    """``--two-step`` on a recording at 200 Hz, 10 Hz cut-off, the smooth Coulomb zone that fits MuJoCo's friction:
    step 2's friction std counted every frame as independent (RMS z 4.1 over two draws, measured) and takes the
    recording's covariance now (0.80); step 1's links keep theirs (0.76)."""
    sc = short_torque_lab
    zone = friction_zone(sc.sim)
    before, after = solve_draw(sc, 5, 10.0, np.random.default_rng(4), zone=zone, two_step=True)
    before, after = rms_z([before]), rms_z([after])
    assert before["friction"] > 2.5, before
    assert 0.5 < after["friction"] < 1.4 and 0.4 < after["links"] < 1.5, after


def test_model_friction_recovers_a_smooth_coulomb_law(short_torque_lab):
    """The study's friction truth at a zone: a ``fv qd + fc tanh(qd / zone)`` law put in place of MuJoCo's friction
    comes back exactly, and :func:`friction_zone` finds its zone."""
    sim = short_torque_lab.sim
    law = 0.05 * sim.qd + 0.3 * np.tanh(sim.qd / 0.03)
    exact = dataclasses.replace(sim, friction=law)
    assert np.allclose(model_friction(exact, 0.03), [[0.05, 0.3]] * sim.qd.shape[1], atol=1e-9)
    assert friction_zone(exact) == pytest.approx(0.03, rel=0.03)


def test_profile_std_grows_by_the_filtered_noise_long_run_factor(model):
    """A profile whose residual is white noise low-passed at 10 Hz of 200 Hz: the zone's variance grows by the
    filter's gain ``1 / sum g^2`` (12.0; the band density finds it within 25 %), and by 1 for white noise."""
    rng = np.random.default_rng(7)
    n, dof = 4000, model.n_dof
    t = np.arange(n) / 200.0
    qd = np.stack([np.sin(2 * np.pi * (0.3 + 0.1 * j) * t + j) for j in range(dof)], axis=1)
    q, qdd = np.zeros_like(qd), np.zeros_like(qd)
    channels = ChannelSet((JointTorque().with_actuation(friction=("viscous", "coulomb"), coulomb_zone=0.05),))
    truth = 0.05 * qd + 0.3 * np.tanh(qd / 0.05)
    filtered = FilteredFrames(10.0, 200.0)

    def factor(noise):
        profile = Profile(channels, model, [(q, qd, qdd)], [None], [truth + 0.02 * noise], 1)
        profile.set_weights(np.full((1, dof), 1.0 / np.std(0.02 * noise)))
        return long_run_factors(profile, ("coulomb_zone",), {"coulomb_zone": 0.05}, filtered)["coulomb_zone"]

    assert factor(LowPass(10.0, 200.0).apply(rng.normal(size=(n, dof)))) == pytest.approx(
        filter_gain(filtered), rel=0.25
    )
    assert factor(rng.normal(size=(n, dof))) < 1.6
