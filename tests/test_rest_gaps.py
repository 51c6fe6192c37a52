"""The gaps closed after the first round: the link IMU streams' time stamps audited like the joints' and the
wrench's; the mixed-filters check on the library path; a coupling's per-motor columns named after the motors;
the MJCF writer's non-physical links, the report's friction check on coupled channels, Stribeck friction in
``data generate --friction-truth``."""

from __future__ import annotations

import numpy as np
import pytest

from ineid import DatasetError
from tests.test_recordings_imus import DURATION, FOREARM_POSE, check_fused, trajectory

IMU_H = 4e-3
"""s, the forearm IMU's nominal step (250 Hz)."""


def jittery_imu(model, rng: np.random.Generator, gap: tuple[float, float] | None = None):
    """``(stamps, readings, held)`` of a forearm IMU (all kinds, at a pose) logged at 250 Hz by a loop that wakes
    0 to 1.6 ms late (steps 2.4 to 5.6 ms), misses cycles in runs of 2 to 4, and writes the value it holds again
    under a new stamp in 5 % of its rows (``held`` of them); ``gap`` drops the stamps within it."""
    from ineid.channels.pose import parse_sensor_pose
    from ineid.data.imu.readings import ImuMount, imu_readings

    k = np.arange(int((DURATION - 0.01) / IMU_H))
    t = k * IMU_H + rng.uniform(0.0, 1.6e-3, len(k))
    missed = np.zeros(len(k), dtype=bool)
    for start in rng.choice(np.arange(20, len(k) - 20), 6, replace=False):
        missed[start : start + rng.integers(2, 5)] = True
    if gap is not None:
        missed |= (t > gap[0]) & (t < gap[1])
    t = t[~missed]
    mount = ImuMount("forearm", parse_sensor_pose(FOREARM_POSE))
    r = imu_readings(model, [mount], *trajectory(t))["forearm"]
    held = np.zeros(len(t), dtype=bool)
    held[rng.choice(np.arange(10, len(t) - 10), int(0.05 * len(t)), replace=False)] = True
    held &= ~np.roll(held, 1)  # single held rows: each repeats a measured one
    for kind in r:
        for i in np.flatnonzero(held):
            r[kind][i] = r[kind][i - 1]
    return t, r, int(held.sum())


def imu_import(model, t, r, **settings):
    """``recording_dataset`` of the arm's joints and wrench at 200 Hz (uniform) and the forearm IMU ``(t, r)``."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.data.recordings.streams import ImuStream, Streams

    tq = np.arange(0.0, DURATION, 1 / 200.0)
    q, qd, qdd = trajectory(tq)
    streams = Streams(
        tq, q, None, None, tq, model.base_wrench(q, qd, qdd), "lab.csv", imus=(ImuStream("forearm", t, r),)
    )
    return recording_dataset(streams, model, ImportSettings(cutoff=20.0, imus=(f"forearm:{FOREARM_POSE}",), **settings))


def test_imu_stream_audited_nominal_rate_held_rows_warnings(model):
    from ineid.data.recordings.timing import TimingReport

    t, r, held = jittery_imu(model, np.random.default_rng(3))
    ds, summary = imu_import(model, t, r)
    record = TimingReport.from_dict(ds.meta.origin["import"]["timing"])
    imu = next(s for s in record.streams if s.name == "IMU 'forearm'")
    assert imu.rate == 250.0 and imu.how == "snapped" and imu.held == held and imu.gaps > 0
    assert imu.jitter > 0.25
    assert ds.meta.origin["imu"]["rates"] == {"forearm.gyro+accel+alpha": 250.0}
    line = next(x for x in summary.lines() if x.startswith("IMU 'forearm' time stamps"))
    assert "250 Hz nominal" in line and f"{held} rows" in line and "dropped as missing" in line
    codes = {c: m for c, m in record.warnings}
    assert "IMU 'forearm'" in codes["timing_jitter"] and "IMU 'forearm'" in codes["timing_repeats"]
    check_fused(ds, tol=4e-3)
    _, summary = imu_import(model, t, r, keep_repeats=True)
    assert "kept as data" in next(x for x in summary.lines() if x.startswith("IMU 'forearm'"))


def test_imu_gap_longer_than_the_filter_is_an_error_unless_allowed(model):
    t, r, _ = jittery_imu(model, np.random.default_rng(4), gap=(1.2, 1.4))
    with pytest.raises(DatasetError, match=r"the IMU 'forearm' stream has a gap of .*--allow-gaps"):
        imu_import(model, t, r)
    ds, _ = imu_import(model, t, r, allow_gaps=True)
    warnings = {w["code"]: w["message"] for w in ds.meta.origin["import"]["timing"]["warnings"]}
    assert "IMU 'forearm'" in warnings["timing_gaps"]


# -- the mixed-filters check on the library path ----------------------------------------------------------


@pytest.fixture(scope="module")
def two_filters(model, tmp_path_factory):
    """``(a, b, c)``: two Fourier runs of the arm (CAD parameters, 12-bit encoders, 500 Hz) imported at 6 Hz, and
    the second imported again at 9 Hz."""
    from ineid.data.recordings.pipeline import import_recording
    from ineid.data.recordings.settings import ImportSettings
    from tests.bag_files import write_angles_csv
    from tests.test_filters_experiment import fourier_states

    folder = tmp_path_factory.mktemp("filters")
    rng = np.random.default_rng(8)
    step = 2 * np.pi / 2**12
    paths = []
    for k in range(2):
        t, q, qd, qdd = fourier_states(model, rng, 0.8)
        w = np.asarray(model.base_wrench(q, qd, qdd, model.theta_cad))
        paths.append(write_angles_csv(folder / f"run{k + 1}.csv", t, np.round(q / step) * step, w))
    a, b = (import_recording(p, model, ImportSettings(cutoff=6.0))[0] for p in paths)
    c = import_recording(paths[1], model, ImportSettings(cutoff=9.0))[0]
    return a, b, c


def test_solve_recordings_from_python_refuses_mixed_filters(model, two_filters):
    from ineid.identify import SolveSettings
    from ineid.identify.joint import solve_recordings

    a, b, c = two_filters
    settings = SolveSettings(method="linear")
    with pytest.raises(DatasetError, match=r"different cut-offs: .*run1.csv 6 Hz, .*run2.csv 9 Hz.*--mixed-filters"):
        solve_recordings([a, c], settings, model=model)
    with pytest.raises(DatasetError, match=r"different cut-offs: .*run2.csv 6 Hz, .*run2.csv 9 Hz"):
        solve_recordings([a, b], settings, model=model, validate=c)
    res = solve_recordings([a, b], settings, model=model, validate=c, mixed_filters=True)
    assert "different cut-offs" in res.meta["mixed_filters"] and np.isfinite(res.validation_rel).all()
    res = solve_recordings([a, b], settings, model=model)
    assert "mixed_filters" not in res.meta
