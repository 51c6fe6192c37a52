"""The std of least-squares fits on filtered recordings (:mod:`ineid.identify.time_correlation`), against the truth
of MuJoCo-simulated recordings (:mod:`ineid.studies.std_recordings`); datasets of independent frames untouched."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.data.recordings.signals import LowPass
from ineid.identify import SolveSettings, solve_dataset
from ineid.identify.time_correlation import (
    FilteredFrames,
    band_long_run,
    filter_gain,
    filtered_frames,
    moving_sum_covariance,
)
from ineid.studies.std_recordings import rms_z, scenario, solve_draw


@pytest.fixture(scope="module")
def short_lab():
    """Six seconds of the lab arm on its turned, biased sensor (angles only), at 1 kHz."""
    return scenario(torque=False, duration=6.0)


def test_moving_sums_are_the_bartlett_weighted_autocovariances():
    s = np.random.default_rng(0).normal(size=(60, 3))
    lags = 5
    ref = sum(
        (1 - abs(lag) / (lags + 1)) * (s[: len(s) - lag].T @ s[lag:] if lag >= 0 else s[-lag:].T @ s[: len(s) + lag])
        for lag in range(-lags, lags + 1)
    )
    assert np.allclose(moving_sum_covariance(s, lags), ref, rtol=1e-12, atol=1e-12)


def test_long_run_ratio_of_filtered_white_noise_and_of_differentiated_noise():
    """White noise low-passed at 10 Hz of 200 Hz counts ``1 / sum g^2`` (12.0) times in a mean, and the band
    estimate from the noise itself finds it (within 15 % over 20 s); an angle noise differentiated twice has no power
    at low frequencies, and counts far less than the filter's gain."""
    filtered = FilteredFrames(10.0, 200.0)
    low = LowPass(10.0, 200.0)
    rng = np.random.default_rng(3)
    white = low.apply(rng.normal(size=(4000, 6)))
    gain = filter_gain(filtered)
    assert gain == pytest.approx(12.0, rel=0.02)
    kappa = band_long_run(white, filtered, np.zeros(6))
    assert np.all(np.abs(kappa / gain - 1) < 0.25) and abs(kappa.mean() / gain - 1) < 0.15, kappa
    qdd = np.diff(low.apply(rng.normal(size=(4002, 6))), 2, axis=0)
    assert np.all(band_long_run(qdd, filtered, np.zeros(6)) < 0.1 * gain)


def test_noisy_recording_z_near_one_where_independent_frames_gave_several(short_lab):
    """500 Hz, 10 Hz cut-off, two noise draws: RMS z over the 16 base parameters and the 6 offsets (measured: before
    5.3 and 6.3, after 1.06 and 1.23 over six draws, ``docs/identification.md``)."""
    rng = np.random.default_rng(4)
    draws = [solve_draw(short_lab, 2, 10.0, rng) for _ in range(2)]
    before, after = rms_z([d[0] for d in draws]), rms_z([d[1] for d in draws])
    assert before["links"] > 3.0 and before["offsets"] > 3.0, before
    assert 0.6 < after["links"] < 1.5 and 0.4 < after["offsets"] < 1.6, after


def test_noise_free_recording_std_covers_the_filter_error(short_lab):
    """No noise at all: what is left is the filter's and the differentiation's own error, systematic.
    Measured at 200 Hz, 10 Hz cut-off on ten seconds: RMS z before 6.0 (links), after 0.65."""
    before, after = solve_draw(short_lab, 5, 10.0, None)
    assert np.sqrt(np.mean(before["links"] ** 2)) > 3.0
    assert 0.3 < np.sqrt(np.mean(after["links"] ** 2)) < 1.3
    assert np.abs(after["links"]).max() < 3.0


def test_independent_frames_are_unchanged_bit_for_bit(model):
    """A synthetic dataset (no filter) and one whose import record names no cut-off give the same std, bit for bit:
    only a filtered recording's frames are correlated."""
    noise = NoiseModel(wrench=np.full(6, 0.1))
    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=4), n_frames=40, seed=2, noise=noise))
    assert filtered_frames(ds) is None
    res = solve_dataset(ds, SolveSettings(), model=model)
    raw = dataclasses.replace(ds.meta, origin={"import": {"cutoff": None, "rate": 1000.0}})
    ds.meta = raw
    assert filtered_frames(ds) is None
    again = solve_dataset(ds, SolveSettings(), model=model)
    assert np.array_equal(res.base_std, again.base_std) and np.array_equal(res.base_hat, again.base_hat)


def test_several_recordings_fitted_jointly_take_their_correlation(short_lab):
    """The two halves of one filtered recording fitted together (each centred on its own): before 8.4, after about 1
    (RMS z over the 16 base parameters, three draws of ten seconds at 1 kHz: 1.1 to 1.4)."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.identify.joint import solve_recordings
    from ineid.studies.std_recordings import POSE_TEXT, noisy_streams

    rng = np.random.default_rng(2)
    z_before, z_after = [], []
    for _ in range(2):
        streams = noisy_streams(short_lab, 2, rng)
        ds, _ = recording_dataset(streams, short_lab.model, ImportSettings(sensor_pose=POSE_TEXT, cutoff=10.0))
        assert filtered_frames(ds.select(frames=slice(None, None, 5))).rate == pytest.approx(100.0)  # every 5th frame
        halves = [ds.select(frames=slice(0, ds.n_frames // 2)), ds.select(frames=slice(ds.n_frames // 2, None))]
        res = solve_recordings(halves, SolveSettings(bias="estimate"), model=short_lab.model)
        truth = short_lab.theta_unknown @ res.base.B.T
        z_after.append((res.base_hat[0] - truth) / res.base_std[0])
        for h in halves:
            h.meta = dataclasses.replace(h.meta, origin={})
        res = solve_recordings(halves, SolveSettings(bias="estimate"), model=short_lab.model)
        z_before.append((res.base_hat[0] - truth) / res.base_std[0])
    before, after = np.sqrt(np.mean(np.square(z_before))), np.sqrt(np.mean(np.square(z_after)))
    assert before > 3.0 and 0.6 < after < 1.6, (before, after)


@pytest.mark.slow  # 24 solves of 10 s simulated recordings at three rates and cut-offs: about a minute
@pytest.mark.parametrize(("step", "cutoff"), [(1, 10.0), (1, 5.0), (5, 10.0), (2, 20.0)])
def test_calibration_over_rates_and_cutoffs(step, cutoff):
    """RMS z per group within 0.75-1.3 (the table in ``docs/identification.md``: 0.82-1.29 at six draws)."""
    sc = scenario(torque=False, duration=10.0)
    rng = np.random.default_rng(11)
    after = rms_z([solve_draw(sc, step, cutoff, rng)[1] for _ in range(6)])
    assert 0.75 < after["links"] < 1.3 and 0.7 < after["offsets"] < 1.4, after
