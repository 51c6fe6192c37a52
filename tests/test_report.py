"""The HTML report (``ineid report``, ``ineid solve --report``), its residual tests and the ``--plot`` figure.

One small synthetic recording-like dataset (Fourier frames, a time series with stated noise) is
solved once by the command line with ``--report`` and ``--plot``; a copy with the wrench two
frames late and a joint-torque dataset with Coulomb friction the solve does not model are the
corrupted twins. The page is checked for content against the results file, for escaping of
hostile names, for the missing-dataset and older-file cases, and in a real headless Chromium.
"""

from __future__ import annotations

import dataclasses
import html
import os
import re
import shutil
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from markupsafe import escape

from ineid.data import Combination, DatasetSpec, FrameSampling, NoiseModel, generate_dataset, load_dataset
from ineid.identify import load_results
from ineid.report.html import build_report, inputs_from_files
from ineid.report.residuals import check_residual

DELAY_FRAMES = 2
RATE = 40.0  # Hz: 400 frames over one 10 s period of the Fourier trajectory


def invoke(*args):
    from click.testing import CliRunner

    from ineid.cli import main

    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def ok(result) -> str:
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    return result.output


def codes(page: str) -> set[str]:
    """The warning codes the page's summary box shows."""
    return set(re.findall(r'class="warn-item" data-code="([a-z_]+)"', page))


@pytest.fixture(scope="module")
def solved(tmp_path_factory, model):
    """``{name: (dataset, results, report)}`` for the clean and the delayed wrench, solved by the CLI."""
    folder = tmp_path_factory.mktemp("report")
    spec = DatasetSpec(
        Combination("random", n_configs=1),
        n_frames=400,
        seed=5,
        frames=FrameSampling(mode="fourier"),
        noise=NoiseModel.create(model.n_dof, force=0.5, moment=0.05),
    )
    ds = generate_dataset(model, spec)
    late = ds.wrench.copy()
    late[:, DELAY_FRAMES:] = ds.wrench[:, :-DELAY_FRAMES]  # what a sensor 50 ms late reads
    out = {}
    for name, d in (("clean", ds), ("delayed", dataclasses.replace(ds, wrench=late))):
        data, results, page = folder / f"{name}.h5", folder / f"{name}_r.h5", folder / f"{name}.html"
        d.save(data)
        extra = ("--plot", folder / f"{name}.png") if name == "clean" else ()
        # the CasADi backend: no JAX compilation for the solve (the tests' time)
        ok(
            invoke(
                "-q",
                "solve",
                data,
                "--method",
                "linear",
                "--backend",
                "casadi",
                "--out",
                results,
                "--report",
                page,
                *extra,
            )
        )
        out[name] = (data, results, page)
    return out


def test_report_shows_the_results(solved):
    data, results, page = solved["clean"]
    text = page.read_text()
    res = load_results(results)
    assert text.startswith("<!DOCTYPE html>") and "<script" not in text
    assert not re.search(r'(src|href)="(?!data:image/png;base64,|#)', text)  # self-contained: nothing to fetch
    assert f"Rank <strong>{len(res.base.names)}</strong> of {len(res.param_names)}" in text
    for name in res.base.names:
        assert f'<li class="name">{html.escape(name)}</li>' in text
    for direction in res.base.null_directions():
        assert html.escape(direction) in text
    # every standard parameter with its CAD value (the prior), estimate and std, formatted as the page does
    for k, name in enumerate(res.param_names):
        row = re.search(
            rf'<td class="name">{re.escape(name)}</td><td class="num">([^<]*)</td><td class="num">'
            rf'([^<]*)</td>\s*<td class="num">([^<]*)</td>',
            text,
        )
        assert row, name
        cad, est, std = row.groups()
        assert float(cad) == pytest.approx(np.atleast_2d(res.theta_prior)[0, k], rel=1e-3)
        assert float(est) == pytest.approx(res.theta_hat[0, k], rel=1e-3)
        if res.base.identifiable[k]:
            assert float(std) == pytest.approx(res.theta_std[0, k], rel=1e-2)
        else:
            assert std == "- (prior)"
    # the residual RMS the page computes is the solver's held-out RMS, axis by axis
    rms = re.findall(r'<tr><td class="name">(f[xyz]|m[xyz])</td><td>(?:N|N\*m)</td><td class="num">([^<]*)</td>', text)
    assert [a for a, _ in rms] == ["fx", "fy", "fz", "mx", "my", "mz"]
    np.testing.assert_allclose([float(r) for _, r in rms], res.validation_rms[0], rtol=2e-3)
    assert "Noise: stated by the synthetic dataset" in text and load_dataset(data).fingerprint() in text
    # physical validity, figures (the whole validation span and the residual spectrum), inline
    assert "pseudo-inertia eigenvalues" in text and text.count('<img src="data:image/png;base64,') == 2
    assert codes(text) <= {"not_physical"}, "clean data: no residual warning"
    assert (page.parent / "clean.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_of_data_on_an_excite_trajectory(solved, tmp_path, model):
    """Data sampled on a designed trajectory (the CSV of `ineid excite`, its design JSON beside it): the page
    shows the trajectory's record and the design's condition number and expected std, which the solve's std
    bear out (independent: the design's information matrix against the fit's residual-based covariance)."""
    import json

    from ineid.data.synthesis.trajectory import write_trajectory_csv
    from ineid.identify import base_parameters
    from ineid.identify.systems import stack_casadi

    ds = load_dataset(solved["clean"][0])
    q, qd, qdd, t = ds.q[0], ds.qd[0], ds.qdd[0], ds.time[0]
    write_trajectory_csv(tmp_path / "traj.csv", t, q, qd, qdd)
    # the design record `ineid excite` writes: the expected std of the base parameters under the stated noise,
    # sigma^2 (W_b^T W_b)^-1 with W_b the base columns of the noise-scaled regressor of every frame
    base = base_parameters(model)
    sigma = np.array([0.5, 0.5, 0.5, 0.05, 0.05, 0.05])
    w, _ = stack_casadi(model, q, qd, qdd, np.zeros((len(q), 6)), ds.theta_known)
    w_b = (w.reshape(len(q), 6, -1) / sigma[:, None]).reshape(6 * len(q), -1)[:, base.base_index]
    std = np.sqrt(np.diag(np.linalg.inv(w_b.T @ w_b)))
    record = {
        "criterion": "d-opt",
        "base_parameters": list(base.names),
        "wrench_noise_std": sigma.tolist(),
        "optimized": {"condition_number": 123.4, "std": std.tolist()},
        "random_fourier": {"condition_number": 567.8},
    }
    (tmp_path / "traj.json").write_text(json.dumps({"design": record}))
    data, results, page = tmp_path / "d.h5", tmp_path / "r.h5", tmp_path / "r.html"
    ok(
        invoke(
            "-q",
            "data",
            "generate",
            "sweaty-arm",
            "--frame-mode",
            "trajectory",
            "--trajectory",
            tmp_path / "traj.csv",
            "--n-configs",
            1,
            "--noise",
            "force=0.5,moment=0.05",
            "--seed",
            2,
            "--out",
            data,
        )
    )
    ok(invoke("-q", "solve", data, "--backend", "casadi", "--out", results, "--report", page))
    text = page.read_text()
    assert "Trajectory of <code>ineid excite</code>" in text and "traj.json" in text
    assert "condition number 123.4 (a random Fourier trajectory of the same bounds: 567.8)" in " ".join(text.split())
    rows = re.findall(
        r'<tr><td class="name">([^<]*)</td><td class="num">([^<]*)</td><td class="num">([^<]*)</td>'
        r"</tr>",
        text.split("Its design")[1],
    )
    res = load_results(results)
    assert [html.unescape(n) for n, _, _ in rows] == list(res.base.names)
    expected, estimated = (np.array([float(r[k]) for r in rows]) for k in (1, 2))
    np.testing.assert_allclose(expected, std, rtol=5e-3)  # 3 digits shown
    # 80 % of the frames fitted: std about sqrt(1.25) x the design's, with the noise estimated from the residuals
    assert np.all((estimated / expected > 0.9) & (estimated / expected < 1.5)), estimated / expected


def test_report_on_a_separate_validation_recording(solved, tmp_path):
    """solve --validate: the page validates on every frame of the other recording (here the delayed twin of the
    same arm: its delay is found there), with the RMS the solve recorded; moved, it is named missing."""
    clean, delayed = solved["clean"][0], solved["delayed"][0]
    results, page = tmp_path / "r.h5", tmp_path / "r.html"
    ok(invoke("-q", "solve", clean, "--validate", delayed, "--out", results, "--report", page))
    text, res = page.read_text(), load_results(results)
    assert "400 frames of the recording delayed.h5" in text and "delay" in codes(text)
    rms = re.findall(r'<tr><td class="name">(?:f|m)[xyz]</td><td>(?:N|N\*m)</td><td class="num">([^<]*)</td>', text)
    np.testing.assert_allclose([float(r) for r in rms], res.meta["validation"]["rms"], rtol=2e-3)
    moved = tmp_path / "elsewhere.h5"
    shutil.copy(delayed, moved)
    with h5py.File(results, "a") as f:
        f.attrs["validation"] = f.attrs["validation"].replace(str(delayed), str(tmp_path / "gone.h5"))
    out = invoke("report", results, "--out", tmp_path / "a.html")
    assert out.exit_code == 0 and "the validation recording" in out.output and "--validate NEW_PATH" in out.output
    ok(invoke("report", results, "--validate", moved, "--out", tmp_path / "b.html"))
    assert "frames of the recording elsewhere.h5" in (tmp_path / "b.html").read_text()


def test_residual_tests_find_the_delay(solved):
    """The wrench two frames (50 ms) late warns delay, found exactly by the shifted refit; the clean dataset
    warns nothing (test above)."""
    text = solved["delayed"][2].read_text()
    assert {"delay", "model_error"} <= codes(text) and "friction" not in codes(text)
    late_ms = float(re.search(r"the measurements read ([0-9.]+) ms late", text).group(1))
    assert late_ms == pytest.approx(1e3 * DELAY_FRAMES / RATE, rel=1e-6)


@pytest.mark.slow
def test_residual_tests_find_friction_in_joint_torques(tmp_path):
    """Joint torques with Coulomb friction that the solve does not model warn friction, not delay."""
    data, results, page = tmp_path / "f.h5", tmp_path / "f_r.h5", tmp_path / "f.html"
    ok(
        invoke(
            "-q",
            "data",
            "generate",
            "sweaty-arm",
            "--n-configs",
            1,
            "--n-frames",
            400,
            "--frame-mode",
            "fourier",
            "--seed",
            1,
            "--channels",
            "torque",
            "--friction-truth",
            "fc=0.5",
            "--noise",
            "tau=0.05",
            "--out",
            data,
        )
    )
    ok(invoke("-q", "solve", data, "--method", "linear", "--out", results, "--report", page))
    found = codes(page.read_text())
    assert {"friction", "model_error"} <= found and "delay" not in found


def test_friction_test_on_joint_torques():
    """:func:`check_residual` on two joint torques: Coulomb friction of 6 x the noise on joint 1 warns friction on
    it alone; the same residual on a wrench channel (which does not feel joint friction) is not tested for it."""
    rng = np.random.default_rng(1)
    t = np.arange(600) / 100.0
    qd = np.column_stack([np.cos(1.3 * t), np.cos(0.7 * t + 1)])
    pred = np.column_stack([np.sin(2.9 * t) + t / 6, 0.5 * np.sin(0.4 * t + 1)])  # torques: not the velocities
    meas = pred + 0.05 * rng.standard_normal(pred.shape)
    meas[:, 0] += 0.3 * np.sign(qd[:, 0])
    noise = np.full(2, 0.05)
    torques = check_residual(t, meas, pred, ("j1", "j2"), ("N*m", "N*m"), (("tau", 0, 2, "joint_torque"),), qd, noise)
    assert {w.code for w in torques.warnings} == {"model_error", "friction"}
    assert torques.axes[0].friction_share > 0.9 and torques.axes[1].friction_share < 0.05
    assert "j1 follows the joint's velocity" in next(w.message for w in torques.warnings if w.code == "friction")
    wrench = check_residual(t, meas, pred, ("fx", "fy"), ("N", "N"), (("wrench", 0, 2, "wrench"),), qd, noise)
    assert {w.code for w in wrench.warnings} == {"model_error"} and np.isnan(wrench.axes[0].friction_share)
    clean = check_residual(
        t,
        pred + 0.05 * rng.standard_normal(pred.shape),
        pred,
        ("j1", "j2"),
        ("N*m", "N*m"),
        (("tau", 0, 2, "joint_torque"),),
        qd,
        noise,
    )
    assert not clean.warnings


def test_residual_tests_on_white_noise_and_a_periodic_error():
    """Unit check of :func:`check_residual`: white noise at the stated level passes; a sinusoid in the residual
    at 3 x the noise warns model error and spectral peak at its frequency."""
    rng = np.random.default_rng(0)
    t = np.arange(500) / 100.0
    pred = np.column_stack([np.sin(0.4 * t), np.cos(0.3 * t)])
    blocks = (("wrench", 0, 2, "wrench"),)
    white = check_residual(
        t, pred + 0.01 * rng.standard_normal(pred.shape), pred, ("a", "b"), ("N", "N"), blocks, noise=np.full(2, 0.01)
    )
    assert not white.warnings and all(abs(c.ratio - 1) < 0.15 for c in white.axes)
    hum = pred + 0.01 * rng.standard_normal(pred.shape) + 0.05 * np.sin(2 * np.pi * 7.0 * t)[:, None]
    found = check_residual(t, hum, pred, ("a", "b"), ("N", "N"), blocks)  # noise estimated from the signal
    assert {w.code for w in found.warnings} == {"model_error", "spectral_peak"}
    assert found.axes[0].peak_hz == pytest.approx(7.0, abs=0.2) and found.axes[0].noise == pytest.approx(0.01, rel=0.3)


def test_hostile_names_are_escaped(solved):
    """Robot, link and parameter names are data: markup, quotes and newlines appear as text, nothing runs."""
    evil = "<script>alert('x')</script>\"q\" & it's\n<b>bold</b>"
    inputs = inputs_from_files(solved["clean"][1])
    inputs.ds = None  # the names' sections only (no figures: quicker)
    res = inputs.res
    res.meta["robot"] = evil
    res.meta["unknown_links"] = [evil + " 1", evil + " 2"]
    res.param_names = tuple(evil + n for n in res.param_names)
    res.base = dataclasses.replace(res.base, names=tuple(evil + n for n in res.base.names), param_names=res.param_names)
    page = build_report(inputs)
    assert "<script" not in page and "<b>bold" not in page and "alert(&#39;x&#39;)" in page
    assert str(escape(evil)) in page and str(escape(res.base.names[0])) in page


def test_missing_dataset_and_older_results(solved, tmp_path):
    data, results, _ = solved["clean"]
    moved_results, moved_data = tmp_path / "r.h5", tmp_path / "moved" / "data.h5"
    moved_data.parent.mkdir()
    shutil.copy(results, moved_results)
    with h5py.File(moved_results, "a") as f:
        f.attrs["dataset_path"] = str(tmp_path / "gone.h5")
    out = invoke("report", moved_results, "--out", tmp_path / "a.html")
    assert out.exit_code == 0 and "Traceback" not in out.output
    (line,) = [x for x in out.output.splitlines() if x.startswith("warning:")]
    assert "gone.h5 is not there (moved or deleted since the solve)" in line and "--data NEW_PATH" in line
    page = (tmp_path / "a.html").read_text()
    assert "<strong>Missing:</strong>" in page and "--data NEW_PATH" in page and "Rank <strong>" in page
    assert "<img" not in page  # no validation without the data, the rest shown
    # --data with the dataset where it now is: the whole page; a different dataset is refused by fingerprint
    shutil.copy(data, moved_data)
    ok(invoke("report", moved_results, "--data", moved_data, "--out", tmp_path / "b.html"))
    assert "<img" in (tmp_path / "b.html").read_text() and "Missing" not in (tmp_path / "b.html").read_text()
    other = tmp_path / "other.h5"  # another seed: another fingerprint (the delayed twin shares the clean one's)
    ds = load_dataset(data)
    dataclasses.replace(ds, meta=dataclasses.replace(ds.meta, seed=ds.meta.seed + 1)).save(other)
    ok(invoke("report", moved_results, "--data", other, "--out", tmp_path / "c.html"))
    assert "is not the one these results were solved on" in (tmp_path / "c.html").read_text()
    # a results file of ineid 0.1 (format version 1): no dataset path, channels, axes or warnings recorded
    old = tmp_path / "old.h5"
    shutil.copy(results, old)
    with h5py.File(old, "a") as f:
        for key in ("dataset_path", "dataset_fingerprint", "channels", "axes", "units", "warnings"):
            del f.attrs[key]
        f.attrs["version"] = 1
    out = invoke("report", old, "--out", tmp_path / "old.html")
    assert out.exit_code == 0 and sum(x.startswith("warning:") for x in out.output.splitlines()) == 1
    page = (tmp_path / "old.html").read_text()
    assert "records no path of the dataset (written by an older ineid" in page and "Rank <strong>" in page


def test_bad_inputs_are_one_line(solved, tmp_path):
    data, results, _ = solved["clean"]
    text = tmp_path / "notes.txt"
    text.write_text("not hdf5")
    for bad, expect in (
        (data, "not an ineid results file"),
        (text, "notes.txt"),
        (tmp_path / "nope.h5", "does not exist"),
    ):
        out = invoke("report", bad, "--out", tmp_path / "x.html")
        assert out.exit_code != 0 and expect in out.output and len(out.output.strip().splitlines()) == 1, out.output
        assert not (tmp_path / "x.html").exists()
    out = invoke("report", results, "--config", 7, "--out", tmp_path / "x.html")
    assert out.exit_code != 0 and "configuration 7 is not in the results" in out.output
    assert not (tmp_path / "x.html").exists()
    out = invoke("solve", data, "--plot-span", "5:1", "--plot", tmp_path / "p.png", "--out", tmp_path / "r.h5")
    assert out.exit_code == 2 and "START:STOP" in out.output and not (tmp_path / "r.h5").exists()
    out = invoke("solve", data, "--plot-span", "0:1", "--out", tmp_path / "r.h5")
    assert out.exit_code == 2 and "--plot-span chooses what --plot shows" in out.output


def test_plot_has_a_residual_panel_per_axis_and_a_readable_span(solved):
    from ineid.report.figures import default_span, validation_figure
    from ineid.report.plot import validation

    data, results, _ = solved["clean"]
    res, ds = load_results(results), load_dataset(data, clean=False)
    v = validation(res, ds)
    fig = validation_figure(v, span=(v.time[0], v.time[0] + 1.0))
    tops = [ax for ax in fig.axes if ax.get_title()]
    assert len(fig.axes) == 2 * len(v.axes) and len(tops) == len(v.axes)
    bottom = fig.axes[1].lines[0]  # the residual of fx, over the first second only
    np.testing.assert_allclose(bottom.get_ydata(), (v.measured - v.predicted)[: len(bottom.get_ydata()), 0])
    assert bottom.get_xdata()[-1] <= v.time[0] + 1.0 < v.time[-1]
    assert default_span(np.arange(0, 60, 0.01), True) == (0.0, 10.0) and default_span(v.time, True) is None


# -- a real browser ------------------------------------------------------------------------------------

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


def _browser_or_skip():
    required = os.environ.get("INEID_REQUIRE_BROWSER") == "1"
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        if required:
            raise
        pytest.skip("playwright is not installed (pip install playwright; the dev extra)")
    if not Path(CHROMIUM).exists():
        if required:
            pytest.fail(f"INEID_REQUIRE_BROWSER=1 but {CHROMIUM} is missing (apt-get install chromium)")
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    return sync_playwright


def test_report_in_a_headless_browser(solved, tmp_path):
    """The page loads from file:// with no console error, asks for nothing over the network, shows every figure
    (decoded, non-empty), and runs nothing planted in a name (no dialog)."""
    sync_playwright = _browser_or_skip()
    hostile = tmp_path / "hostile.html"
    inputs = inputs_from_files(solved["clean"][1])
    inputs.ds = None  # and the page that says what is missing
    inputs.missing.append(("the dataset <img src=x onerror=alert(2)> is not there", "give it with --data PATH"))
    inputs.res.meta["robot"] = "<script>alert('x')</script><img src=x onerror=alert(1)>"
    hostile.write_text(build_report(inputs))
    pages = [solved["clean"][2], solved["delayed"][2], hostile]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            for path in pages:
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                errors, requests, dialogs = [], [], []
                page.on("console", lambda m, errors=errors: errors.append(m.text) if m.type == "error" else None)
                page.on("pageerror", lambda e, errors=errors: errors.append(str(e)))
                page.on("dialog", lambda d, dialogs=dialogs: (dialogs.append(d.message), d.dismiss()))

                def route(r, requests=requests):
                    if r.request.url.startswith(("file:", "data:")):
                        return r.continue_()
                    requests.append(r.request.url)
                    return r.abort()

                page.route("**/*", route)
                page.goto(path.as_uri(), wait_until="load")
                images = page.evaluate("[...document.images].map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
                assert errors == [] and requests == [] and dialogs == [], (path, errors, requests, dialogs)
                assert all(c and w > 100 and h > 100 for c, w, h in images), (path, images)
                assert len(images) == (0 if path == hostile else 2), (path, images)
                assert page.title().startswith("ineid identification report")
                assert page.locator("h2").all_inner_texts()[:3] == ["Robot", "Data", "Method and settings"]
                if path == pages[0]:  # for a person to look at (not committed)
                    page.screenshot(path=str(Path(tempfile.gettempdir()) / "ineid-report.png"), full_page=True)
                page.close()
        finally:
            browser.close()


@pytest.mark.slow
def test_report_of_a_hostile_robot_end_to_end(tmp_path):
    """A URDF whose every name is hostile (tests/test_hostile_names.py) plus a script tag: derive, solve with
    --report; the page escapes them all (slow: the 2-DOF robot is derived with SymPy)."""
    from .test_hostile_names import CANARY, NASTY, hostile_urdf

    name = NASTY + "<script>alert('x')</script>"
    urdf = tmp_path / "n.urdf"
    urdf.write_text(hostile_urdf(name))
    data, page = tmp_path / "n.h5", tmp_path / "n.html"
    ok(
        invoke(
            "-q",
            "data",
            "generate",
            urdf,
            "--n-configs",
            1,
            "--n-frames",
            80,
            "--frame-mode",
            "fourier",
            "--seed",
            3,
            "--out",
            data,
        )
    )
    ok(invoke("-q", "solve", data, "--method", "linear", "--out", tmp_path / "r.h5", "--report", page))
    text = page.read_bytes().decode()  # not read_text: it would turn the names' "\r" into "\n"
    robot = load_results(tmp_path / "r.h5").meta["robot"]  # as the URDF parser read it (XML normalizes whitespace)
    assert "<script" not in text and str(escape(robot)) in text and "&lt;script&gt;" in text and not CANARY.exists()
