"""What was fitted is what is reported: a recording's torque-only and mixed fits in the solve summary, `results
info` and the report; the report's version; no Python reprs; the gravity in use stated.

The recording: a Fourier trajectory of sweaty-arm sampled at 100 Hz with its base wrench and joint torques
(noisy), written as a lab's CSV and imported (filtered and differentiated as any recording).
"""

from __future__ import annotations

import csv
import html
import re

import numpy as np
import pytest

from ineid._version import __version__
from ineid.data import load_dataset
from ineid.identify import load_results
from ineid.robots import load_robot

JOINTS = ("shoulder_pitch", "shoulder_roll", "upper_arm_yaw", "elbow")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """``rec.h5``: the imported CSV of a simulated run (wrench and joint torques), in a module-wide folder."""
    from click.testing import CliRunner

    from ineid.cli import main

    folder = tmp_path_factory.mktemp("reporting")
    syn = folder / "syn.h5"
    r = CliRunner().invoke(
        main,
        [
            *("data", "generate", "--frame-mode", "fourier", "--n-configs", "1", "--n-frames", "1000"),
            *("--channels", "wrench,torque", "--noise", "force=0.05,moment=0.005,tau=0.005", "--seed", "3"),
            *("--out", str(syn)),
        ],
    )
    assert r.exit_code == 0, r.output
    ds = load_dataset(syn)
    path = folder / "rec.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "q1", "q2", "q3", "q4", "tau1", "tau2", "tau3", "tau4", "fx", "fy", "fz", "mx", "my", "mz"])
        for row in np.column_stack([ds.time[0], ds.q[0], ds.channel_values["tau"][0], ds.wrench[0]]):
            w.writerow([f"{v:.12g}" for v in row])
    rec = folder / "rec.h5"
    r = CliRunner().invoke(main, ["-q", "data", "import", str(path), "--robot", "sweaty-arm", "--out", str(rec)])
    assert r.exit_code == 0, r.output
    assert "gravity (0, 0, -9.81) m/s^2 (ineid's default; --gravity standard for 9.80665)" in r.output
    return rec


def _page_text(path) -> str:
    """The report's text as a reader sees it: no figures, no style, tags removed, entities decoded."""
    s = path.read_text()
    s = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", s)
    s = re.sub(r"<style>.*?</style>", "", s, flags=re.S)
    return html.unescape(re.sub(r"<[^>]+>", " ", s))


def _rms_line(res, prefix: str = "") -> str:
    """The per-joint held-out RMS line the outputs must print, from the results file's own numbers."""
    cols = [res.axes.index(prefix + j) for j in JOINTS]
    values = ", ".join(f"{j} {res.validation_rms[0, k]:.3g}" for j, k in zip(JOINTS, cols, strict=True))
    return f"joint torques 'tau' (N*m): {values}"


def test_a_torque_only_fit_is_reported_as_one(recording, run, tmp_path):
    out = tmp_path / "r.h5"
    r = run("-q", "solve", recording, "--use", "torque", "--backend", "casadi", "--out", out)
    assert r.exit_code == 0, r.output
    res = load_results(out)
    assert res.axes == JOINTS and np.all(np.isfinite(res.validation_rms))
    line = _rms_line(res)
    assert "fitted: joint torques 'tau'; gravity (0, 0, -9.81) m/s^2" in r.output
    assert "held-out relative error of joint torques 'tau'" in r.output and line in r.output
    assert "wrench" not in r.output.split("Estimates")[0], "a torque-only fit's summary names no wrench"
    info = run("results", "info", out)
    assert info.exit_code == 0, info.output
    assert "fitted: joint torques 'tau'" in info.output and line in info.output
    assert "held-out relative error of joint torques 'tau'" in info.output and "wrench error" not in info.output
    assert f"held-out RMS ({res.n_frames_validation} held-out frames):" in info.output


def test_a_mixed_fit_names_both_and_its_report_reads_in_words(recording, run, tmp_path):
    out, page = tmp_path / "r.h5", tmp_path / "r.html"
    r = run("-q", "solve", recording, "--backend", "casadi", "--out", out, "--report", page)
    assert r.exit_code == 0, r.output
    res = load_results(out)
    wrench = [res.axes.index(f"wrench.{a}") for a in ("fx", "fy", "fz", "mx", "my", "mz")]
    torques = _rms_line(res, "tau.")
    forces = f"base wrench 'wrench': fx {res.validation_rms[0, wrench[0]]:.3g} N"
    moments = f"mz {res.validation_rms[0, wrench[5]]:.3g} N*m"
    info = run("results", "info", out)
    fitted = " and ".join(("base wrench 'wrench'", "joint torques 'tau'")[:: 1 if wrench[0] == 0 else -1])
    for text in (r.output, info.output):
        assert f"fitted: {fitted}" in text
        assert torques in text and forces in text and moments in text
    # the report: the version both ways, what was fitted, no Python reprs in words
    text = _page_text(page)
    assert f"written by ineid {__version__}; this report by ineid {__version__}" in " ".join(text.split())
    assert f"Fitted: {fitted}." in text and torques in text
    shown = fitted.replace("'wrench'", "'wrench' (base frame)")
    assert f"held-out frames; {shown}." in " ".join(text.split())
    for repr_ in ("None", "False", "True"):
        assert not re.search(rf"\b{repr_}\b", text), repr_
        assert not re.search(rf"\b{repr_}\b", r.output + info.output), repr_
    assert "gravity (0, 0, -9.81) m/s^2 (ineid's default" in info.output


def test_data_info_on_a_recording_shows_the_imports_noise_estimate(recording, run):
    r = run("data", "info", recording)
    assert r.exit_code == 0, r.output
    assert "clean data" not in r.output and "noise (std, estimated at import above the" in r.output
    assert "gravity (0, 0, -9.81) m/s^2 (ineid's default; --gravity standard for 9.80665)" in r.output


def test_gravity_standard_is_in_the_dataset_and_every_summary(run, tmp_path):
    data = tmp_path / "g.h5"
    r = run("-q", "data", "generate", "--gravity", "standard", "--n-configs", 2, "--n-frames", 30, "--out", data)
    assert r.exit_code == 0, r.output
    assert "gravity (0, 0, -9.80665) m/s^2 (standard gravity)" in r.output
    ds = load_dataset(data)
    assert tuple(ds.meta.gravity) == (0.0, 0.0, -9.80665)
    # the dataset's wrench is the model's under that gravity: the static part scales with |g|
    model = ds.model()
    assert tuple(model.gravity) == (0.0, 0.0, -9.80665)
    known = np.asarray(ds.theta_known)
    theta = model.full_theta(np.asarray(ds.theta_unknown)[0], known[0] if known.ndim == 2 else known)
    predicted = np.asarray(model.base_wrench(ds.q[0], ds.qd[0], ds.qdd[0], theta))
    np.testing.assert_allclose(predicted, ds.wrench[0], rtol=1e-9, atol=1e-9)
    default = np.asarray(load_robot("sweaty-arm").base_wrench(ds.q[0], ds.qd[0], ds.qdd[0], theta))
    assert np.abs(default[:, 2] - ds.wrench[0, :, 2]).max() > 1e-4 * np.abs(ds.wrench[0, :, 2]).max()
    out = tmp_path / "r.h5"
    r = run("-q", "solve", data, "--out", out)
    assert r.exit_code == 0 and "gravity (0, 0, -9.80665) m/s^2 (standard gravity)" in r.output, r.output
    r = run("identifiability", "sweaty-arm", "--gravity", "0", "0", "-9.80665", "--n-frames", 40)
    assert r.exit_code == 0 and "gravity (0, 0, -9.80665) m/s^2 (standard gravity)" in r.output, r.output
    r = run("identifiability", "sweaty-arm", "--n-frames", 40)
    assert "gravity (0, 0, -9.81) m/s^2 (ineid's default; --gravity standard for 9.80665)" in r.output
    for bad in (("0", "0"), ("earth",), ("0", "0", "x")):
        r = run("robot", "show", "sweaty-arm", "--gravity", *bad)
        assert r.exit_code == 2 and "--gravity" in r.output and "Traceback" not in r.output, r.output
