"""The friction's std on filtered recordings: the two-step fit's second step
(:mod:`ineid.identify.step_two_covariance`), the friction velocities' profile std
(:func:`ineid.identify.friction_search.long_run_factors`), and the study's friction truth at a smooth Coulomb zone
(:mod:`ineid.studies.std_recordings`), against simulated truth."""

from __future__ import annotations

import numpy as np
import pytest

from ineid.channels import ChannelSet, JointTorque
from ineid.data.recordings.signals import LowPass
from ineid.identify.friction_search import Profile, filter_shifts, long_run_factors, search_1d
from ineid.identify.identifiability import base_parameters_from_regressor
from ineid.identify.least_squares import fit_base
from ineid.identify.step_two_covariance import StepTwoFrames, step_two_covariance
from ineid.identify.time_correlation import FilteredFrames, filter_gain
from ineid.studies.std_recordings import (
    LAW_ZONE,
    friction_zone,
    model_friction,
    rms_z,
    scenario,
    solve_draw,
    with_friction_law,
)


@pytest.fixture(scope="module")
def law_lab():
    """Four seconds of the lab arm at 1 kHz with joint torques, the joints' friction the smooth Coulomb law
    ``0.05 qd + 0.3 tanh(qd / 0.05)``."""
    return with_friction_law(scenario(torque=True, duration=4.0))


@pytest.mark.slow  # an import and two two-step solves of a MuJoCo recording: 75 s at load 9, mostly compilation
def test_two_step_friction_std_on_a_filtered_recording_is_near_one(law_lab):
    """``--two-step`` on a recording at 200 Hz, 10 Hz cut-off: step 2's friction std counting every frame as
    independent gave RMS z 3.7 on this draw (4.8 on the next); with the recording's covariance 0.79 (1.13), and
    step 1's links 0.83 (0.94)."""
    before, after = solve_draw(law_lab, 5, 10.0, np.random.default_rng(4), zone=LAW_ZONE, two_step=True)
    before, after = rms_z([before]), rms_z([after])
    assert before["friction"] > 2.5, before
    assert 0.5 < after["friction"] < 1.4 and 0.5 < after["links"] < 1.4, after


def test_model_friction_recovers_the_smooth_coulomb_law(law_lab):
    """The study's friction truth at a zone: the law the scenario puts in the joints comes back exactly, and
    :func:`friction_zone` finds its zone."""
    sim = law_lab.sim
    assert np.allclose(model_friction(sim, LAW_ZONE), [[0.05, 0.3]] * sim.qd.shape[1], atol=1e-9)
    assert friction_zone(sim) == pytest.approx(LAW_ZONE, rel=0.03)


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


def test_step_two_covariance_counts_filtered_noise_by_the_filter_gain():
    """Step 2's fit of two columns to white noise low-passed at 10 Hz of 200 Hz (F = 4000 frames, two axes): the
    variance of the estimates grows by the filter's gain ``1 / sum g^2`` (12.0) over independent frames (the band
    density finds it within 25 %); the axes' ``axis_long_run`` take it. Monte-Carlo truth: the spread of the
    estimates over 200 draws of the same noise is that many times the independent frames' variance."""
    rng = np.random.default_rng(8)
    n, n_axes = 4000, 2
    t = np.arange(n) / 200.0
    cols = np.stack([np.sin(2 * np.pi * 0.4 * t), np.cos(2 * np.pi * 0.25 * t)], axis=1)
    w = np.zeros((n, n_axes, 2))
    w[:, 0, 0], w[:, 1, 1] = cols[:, 0], cols[:, 1]
    low, filtered = LowPass(10.0, 200.0), FilteredFrames(10.0, 200.0)
    base = base_parameters_from_regressor(w.reshape(-1, 2), ("a.fv", "b.fv"), np.ones(2), n_extra=2)
    wide = w.reshape(1, n * n_axes, 2)
    draws = [low.apply(rng.normal(size=(n, n_axes))).reshape(1, -1) for _ in range(200)]
    spread = np.var([fit_base(wide, y, base, "none", None, n_axes).beta[0] for y in draws], axis=0)
    y = draws[0]
    fit = fit_base(wide, y, base, "none", None, n_axes)
    states = tuple(np.zeros((1, n, n_axes)) for _ in range(3))
    frames = StepTwoFrames(states, wide, y, None, np.full((1, 20), np.nan), np.zeros(n_axes, dtype=bool))
    out = step_two_covariance(None, None, base, fit, frames, filtered)
    gain = filter_gain(filtered)
    growth = np.diag(out.cov_beta[0]) / np.diag(fit.cov_beta[0])
    assert np.all(np.abs(growth / gain - 1) < 0.25), growth
    assert np.all(np.abs(np.diag(out.cov_beta[0]) / spread - 1) < 0.4), (np.diag(out.cov_beta[0]), spread)
    assert np.all(np.abs(out.axis_long_run[0] / gain - 1) < 0.25)


def test_filter_shift_of_the_zone_matches_what_the_filter_does(model):
    """A smooth Coulomb law recorded through the low-pass (5 Hz of 200 Hz, the states filtered alike): the zone
    found on the filtered frames is off by what the filter does to ``tanh``, and :func:`filter_shifts` estimates that
    move from the filtered data alone (same sign, within a factor of two)."""
    n, dof = 2400, model.n_dof
    t = np.arange(n) / 200.0
    q = np.stack([0.8 * np.sin(2 * np.pi * (0.4 + 0.15 * j) * t + j) for j in range(dof)], axis=1)
    qd = np.gradient(q, t, axis=0)
    low = LowPass(5.0, 200.0)
    zone = 0.05
    y = low.apply(0.05 * qd + 0.3 * np.tanh(qd / zone))
    states = tuple(low.apply(a) for a in (q, qd, np.zeros_like(q)))
    channels = ChannelSet((JointTorque().with_actuation(friction=("viscous", "coulomb"), coulomb_zone=zone),))
    profile = Profile(channels, model, [states], [None], [y], 1)
    profile.rebuild = lambda c, q, qd, qdd: (np.zeros(q.shape), None)
    profile.set_weights(np.ones((1, dof)))
    grid = zone * np.geomspace(0.2, 5.0, 41)
    found, _ = search_1d(profile, {}, "coulomb_zone", grid)
    shift = filter_shifts(profile, ("coulomb_zone",), {"coulomb_zone": found}, FilteredFrames(5.0, 200.0))
    moved = found - zone
    assert abs(moved) > 0.02 * zone, moved
    assert 0.5 < shift["coulomb_zone"] / moved < 2.0, (shift, moved)
