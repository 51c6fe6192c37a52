"""The std of ``consistent`` (and ``nonlinear``) on filtered recordings, against the truth of MuJoCo-simulated ones
(:mod:`ineid.studies.std_recordings`): the linear fit's covariance of correlated frames
(:mod:`ineid.identify.time_correlation`) through the active constraints (:mod:`ineid.identify.constrained_std`),
on a truth whose forearm is a thin rod (on the physical set's boundary: constraints active)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.data.recordings.pipeline import recording_dataset
from ineid.data.recordings.settings import ImportSettings
from ineid.identify import SolveSettings, load_results, save_results, solve_dataset
from ineid.identify.constrained_std import std_note
from ineid.studies.std_recordings import POSE_TEXT, noisy_streams, rms_z, scenario, z_scores

N_RECORDINGS = 30
NOISE_SCALE = 10.0
"""Times the study's noise: loud enough that the rod's boundary binds in every recording."""


def thin_rod(mass: float, length: float) -> np.ndarray:
    """A thin rod along the link's -z axis (a 1e-7 kg m^2 moment about it keeps MuJoCo's inertia positive)."""
    i = mass * length**2 / 3
    return np.array([mass, 0.0, 0.0, -mass * length / 2, i, 0.0, i, 0.0, 0.0, 1e-7])


def recordings(sc, n: int, step: int, cutoff: float, seed: int = 5):
    """``n`` noise draws of ``sc``'s recording, each imported at ``1000 / step`` Hz and ``cutoff`` Hz, as the
    configurations of one dataset (one solve: the draws share the trajectory and the import)."""
    rng = np.random.default_rng(seed)
    settings = ImportSettings(sensor_pose=POSE_TEXT, cutoff=cutoff)
    dss = [recording_dataset(noisy_streams(sc, step, rng, NOISE_SCALE), sc.model, settings)[0] for _ in range(n)]

    def joined(key):
        return np.concatenate([getattr(d, key) for d in dss])

    arrays = {k: joined(k) for k in ("q", "qd", "qdd", "wrench", "time")}
    return dataclasses.replace(dss[0], **arrays, config_index=np.arange(n))


def z_per_draw(sc, ds, method: str = "consistent", independent: bool = False):
    """The z-scores of every draw solved by ``method`` (``independent``: the import record left out, every frame
    counted as an independent draw), and the results."""
    if independent:
        ds = dataclasses.replace(ds, meta=dataclasses.replace(ds.meta, origin={}))
    res = solve_dataset(ds, SolveSettings(method=method, bias="estimate"), model=sc.model)
    return [z_scores(sc, ds, res, row) for row in range(ds.n_configs)], res


@pytest.fixture(scope="module")
def rod_arm():
    """Three seconds of the lab arm (forearm a thin rod) on its turned, biased sensor, at 1 kHz."""
    return scenario(torque=False, duration=3.0, links={"forearm": thin_rod(1.2, 0.3)})


def test_consistent_std_calibrated_on_30_filtered_recordings(rod_arm, tmp_path):
    """30 recordings at 200 Hz, 10 Hz cut-off, constraints active in every one: RMS z over the 16 base parameters
    and over the 6 offsets within 0.8..1.25 and 0.7..1.3 (``docs/identification.md``); the std of independent frames
    on the first three gives 2.7 and 2.5. The results say how the std was computed."""
    ds = recordings(rod_arm, N_RECORDINGS, 5, 10.0)
    z, res = z_per_draw(rod_arm, ds)
    after = rms_z(z)
    active = res.meta["std"]["active"]
    assert min(active) > 0, active
    assert 0.8 < after["links"] < 1.25 and 0.7 < after["offsets"] < 1.3, after
    before = rms_z(z_per_draw(rod_arm, ds.select(configs=slice(0, 3)), independent=True)[0])
    assert before["links"] > 2.0 and before["offsets"] > 2.0, before
    note = std_note("consistent", res.meta["std"])
    assert f"active in {N_RECORDINGS} of {N_RECORDINGS} configurations, up to {max(active)}" in note
    assert "frames correlated over the 10 Hz cut-off at 200 Hz" in note
    assert load_results(save_results(res, tmp_path / "r.h5")).meta["std"] == res.meta["std"]  # results info reads it


@pytest.mark.slow  # 30 recordings at 1 kHz and at 500 Hz, each rate one solve of 30 configurations: about two minutes
@pytest.mark.parametrize(("step", "method"), [(1, "consistent"), (2, "consistent"), (2, "nonlinear")])
def test_calibration_at_higher_rates(rod_arm, step, method):
    """RMS z per group within 0.75..1.3 (links) and 0.65..1.4 (offsets) at 1 kHz and 500 Hz, 10 Hz cut-off."""
    z, res = z_per_draw(rod_arm, recordings(rod_arm, N_RECORDINGS, step, 10.0, seed=8), method)
    after = rms_z(z)
    assert 0.75 < after["links"] < 1.3 and 0.65 < after["offsets"] < 1.4, after


def test_recording_too_short_for_the_filter_error_still_has_a_std(rod_arm):
    """Three seconds at a 5 Hz cut-off leave too few frames past the filter's start-up for its error estimate: the
    std is the band density's alone, finite (not an error)."""
    z, res = z_per_draw(rod_arm, recordings(rod_arm, 1, 5, 5.0), "linear")
    assert np.all(np.isfinite(res.base_std)) and np.all(np.isfinite(z[0]["links"]))


def test_the_std_line_writes_rates_as_numbers():
    from ineid.identify.constrained_std import frames_note

    note = frames_note({"filtered": [{"cutoff": 11.894, "rate": 999.9996}, {"cutoff": 11.9, "rate": 1000.0}]})
    assert "over the 11.9 Hz cut-off at 1000 Hz" in note and "e+" not in note
