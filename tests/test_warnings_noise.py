"""Every warning true, none missing: the noise a residual is judged against, offsets, bad fits.

The import's noise estimate against white noise of known std (raw, filtered, differentiated); a MuJoCo
recording of a biased, turned-over sensor with white noise on the wrench and the angles, imported like a lab's:
fitted with ``--bias estimate --validate`` it is silent (the report's residual is the noise, not 485 x it); fitted
without ``--bias`` the offsets are named; a wrong sensor pose is still warned.
"""

from __future__ import annotations

import numpy as np
import pytest

from ineid.data.recordings.imus import NOISE_BANDWIDTH
from ineid.data.recordings.noise_estimate import derivative_noise, stream_noise
from ineid.data.recordings.signals import LowPass, derivatives

from .test_plausibility import POSE_TEXT, invoke, warnings_of

SAMPLES = 3000
"""3 s at 1 kHz fitted, the next 3 s validated."""
WRENCH_NOISE = np.array([0.05, 0.05, 0.05, 0.005, 0.005, 0.005])
ANGLE_NOISE = 1e-4


def test_stream_noise_against_white_noise():
    """A 0.7 Hz motion plus white noise of std 0.05 at 1 kHz: the raw std and what a 10 Hz low-pass keeps,
    against the truth (and the filtered noise itself); without a filter the second differences."""
    rng = np.random.default_rng(0)
    t = np.arange(20_000) / 1000.0
    noise = 0.05 * rng.standard_normal((len(t), 2))
    x = np.column_stack([3 * np.sin(2 * np.pi * 0.7 * t), np.cos(2 * np.pi * 0.3 * t)]) + noise
    raw, frames = stream_noise(t, x, 10.0)
    assert np.allclose(raw, 0.05, rtol=0.03), raw
    assert np.allclose(frames, raw * np.sqrt(NOISE_BANDWIDTH * 10.0 / 500.0))
    long = 0.05 * rng.standard_normal(400_000)  # what the filter keeps of the noise, measured
    assert abs(LowPass(10.0, 1000.0).apply(long)[500:-500].std() / frames.mean() - 1) < 0.04
    raw, frames = stream_noise(t, x, None)
    assert np.allclose(raw, 0.05, rtol=0.03) and np.array_equal(raw, frames)


def test_derivative_noise_against_filtered_differences():
    rng = np.random.default_rng(1)
    q = 1e-4 * rng.standard_normal((40_000, 2))
    qd, qdd = derivatives(LowPass(12.0, 1000.0).apply(q), 1e-3)
    sd_qd, sd_qdd = derivative_noise(np.full(2, 1e-4), 12.0, 1000.0)
    assert np.allclose(qd[1000:-1000].std(axis=0), sd_qd, rtol=0.05)
    assert np.allclose(qdd[1000:-1000].std(axis=0), sd_qdd, rtol=0.05)


def test_mean_z_counts_the_correlation_in_time():
    """Low-passed white noise (no offset): z over 40 draws has a spread near 1 (the naive one, samples taken
    as independent, about sqrt(tau) = 10 x more); an offset of 3 x the noise is far off zero."""
    from ineid.identify.noise_figures import mean_z

    rng = np.random.default_rng(2)
    low = LowPass(5.0, 1000.0)
    zs, naive = [], []
    for _ in range(40):
        r = low.apply(rng.standard_normal((6000, 1)))
        zs.append(mean_z(r, True)[1][0])
        naive.append(r.mean() / (r.std() / np.sqrt(len(r))))
    assert 0.6 < np.std(zs) < 1.5 and np.max(np.abs(zs)) < 4.5, np.std(zs)
    assert np.std(naive) > 5 * np.std(zs)
    mean, z = mean_z(r + 3 * r.std(), True)
    assert z[0] > 20


@pytest.fixture(scope="module")
def noisy(lab, tmp_path_factory):
    """The MuJoCo recording (untared, offsets) with white noise on the wrench and the angles, imported: the first
    3 s (``fit``), the next 3 s (``val``), and both with the sensor's yaw 0.5 rad off (``bad_fit``, ``bad_val``)."""
    from .bag_files import write_angles_csv

    folder = tmp_path_factory.mktemp("warnings-noise")
    rng = np.random.default_rng(5)
    n = 2 * SAMPLES
    w = lab.reading[:n] + WRENCH_NOISE * rng.standard_normal((n, 6))
    q = lab.sim.q[:n] + ANGLE_NOISE * rng.standard_normal((n, lab.model.n_dof))
    t = lab.sim.time[:n]
    bad_pose = POSE_TEXT.rsplit(",", 1)[0] + ",1.2"
    out = {}
    for name, part in (("fit", slice(0, SAMPLES)), ("val", slice(SAMPLES, n))):
        csv = write_angles_csv(folder / f"{name}.csv", t[part], q[part], w[part])
        for prefix, pose in (("", POSE_TEXT), ("bad_", bad_pose)):
            h5 = folder / f"{prefix}{name}.h5"
            r = invoke(  # one filter for the fitted and the validation recording, as solve asks
                "-q",
                "data",
                "import",
                csv,
                "--robot",
                "sweaty-arm",
                "--sensor-pose",
                pose,
                "--cutoff",
                "12",
                "--out",
                h5,
            )
            assert r.exit_code == 0, r.output
            out[prefix + name] = h5
    return out


def _report_checks(out, validate, model):
    """The report's residual checks (:mod:`ineid.report.residuals`) of the results ``out`` on ``validate``."""
    from ineid.data import load_dataset
    from ineid.identify import load_results
    from ineid.report.plot import validation_on
    from ineid.report.residuals import check_residual, validation_noise

    res, ds = load_results(out), load_dataset(validate, clean=False)
    v = validation_on(res, ds, model, config=0)
    noise, source = validation_noise(res, ds, model, 0)
    return check_residual(v.time, v.measured, v.predicted, v.axes, v.units, v.blocks, v.qd, noise, source)


def test_the_import_measures_the_noise(noisy):
    from ineid.data import read_meta

    meta, _ = read_meta(noisy["fit"])
    record = meta.origin["noise"]
    ratio = np.array(record["raw"]["wrench"]) / WRENCH_NOISE
    # the moments' part above the cut-off holds some of the motion too (measured: 1.2-1.3x)
    assert np.all(np.abs(ratio[:3] - 1) < 0.1) and np.all((ratio[3:] > 0.95) & (ratio[3:] < 1.4)), ratio
    assert np.allclose(record["raw"]["q"], ANGLE_NOISE, rtol=0.2), record["raw"]
    info = invoke("data", "info", noisy["fit"])
    assert info.exit_code == 0 and "noise (std, estimated at import above the" in info.output
    assert "none (clean data)" not in info.output


def test_offsets_estimated_and_validated_is_silent(noisy, lab, tmp_path):
    """``--bias estimate --validate``: no "explains nothing", no offsets, and the residual is the noise (the
    report's ratio near 1, not hundreds)."""
    out = tmp_path / "r.h5"
    r = invoke("-q", "solve", noisy["fit"], "--bias", "estimate", "--validate", noisy["val"], "--out", out)
    assert r.exit_code == 0, r.output
    assert warnings_of(r) == []
    check = _report_checks(out, noisy["val"], lab.model)
    assert check.warnings == [], [w.message for w in check.warnings]
    ratios = np.array([c.ratio for c in check.axes])
    assert np.all((ratios > 0.5) & (ratios < 2.0)), ratios
    assert "estimated at import" in check.noise_source


def test_offsets_left_out_are_named(noisy, lab, tmp_path):
    """The same recording fitted without ``--bias``: the offsets the fit cannot hold (fx, fy) are named, with
    the option that identifies them, at the solve and in the report."""
    from ineid.identify import load_results

    out = tmp_path / "r.h5"
    r = invoke("-q", "solve", noisy["fit"], "--validate", noisy["val"], "--out", out)
    assert r.exit_code == 0, r.output
    (line,) = warnings_of(r)
    assert line.startswith("the fitted frames' residual has a mean far above the noise") and "(fx +" in line
    assert ", fy -" in line and line.endswith("(solve --bias estimate)")
    assert [w["code"] for w in load_results(out).meta["warnings"]] == ["unmodelled_offsets"]
    codes = [w.code for w in _report_checks(out, noisy["val"], lab.model).warnings]
    assert "offset" in codes and "model_error" in codes


def test_a_wrong_sensor_pose_is_still_warned(noisy, lab, tmp_path):
    """The sensor's yaw 0.5 rad off, offsets estimated: a good-looking relative error (a few %), and the residual
    many times the noise, at the solve and in the report."""
    out = tmp_path / "r.h5"
    r = invoke("-q", "solve", noisy["bad_fit"], "--bias", "estimate", "--validate", noisy["bad_val"], "--out", out)
    assert r.exit_code == 0, r.output
    (line,) = warnings_of(r)
    assert line.startswith("the held-out frames' residual RMS is more than 3 x the noise on")
    assert "--sensor-pose" in line
    assert "model_error" in [w.code for w in _report_checks(out, noisy["bad_val"], lab.model).warnings]


def test_joint_torque_offsets_point_to_torque_offset(tmp_path):
    """Joint torques with offsets on two joints (0.5 and -0.4 N*m against 0.05 N*m of noise): named, with
    ``--torque-offset``, which silences them."""
    import h5py

    data = tmp_path / "tq.h5"
    r = invoke(
        "-q", "data", "generate", "--channels", "torque", "--n-configs", "5", "--n-frames", "60", "--seed", "3",
        "--noise", "tau=0.05", "--out", data,
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    with h5py.File(data, "r+") as f:
        f["tau"][...] = f["tau"][()] + np.array([0.0, 0.5, -0.4, 0.0])
    r = invoke("-q", "solve", data, "--out", tmp_path / "r.h5")
    (line,) = warnings_of(r)
    assert "on 2 of 4 axes (shoulder_roll +0.49" in line and "upper_arm_yaw -0.40" in line
    assert line.endswith("(solve --torque-offset)")
    r = invoke("-q", "solve", data, "--torque-offset", "--out", tmp_path / "r2.h5")
    assert r.exit_code == 0 and warnings_of(r) == []
