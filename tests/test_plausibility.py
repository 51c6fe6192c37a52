"""Plausibility warnings: unit and sign mistakes named with their fix, silence on clean data.

Each mistake (angles in degrees, a wrench x1000, a flipped, zero or random wrench) gives
exactly its warning, exit status 0; the import options that fix it remove the warning and
give the right total mass; every dataset the project makes gives none.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from ineid import DatasetError
from ineid.cli import main
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.data.plausibility import Finding, check_angle_units, check_dataset, check_static_force, moving_mass
from ineid.data.recording import ImportSettings, Streams, in_si_units
from ineid.data.sampling import FrameSampling
from ineid.identify import SolveSettings, load_results, solve_dataset
from ineid.identify.plausibility import check_solve, estimated_total_mass

from .conftest import FIXTURES

POSE_TEXT = "0.03,-0.02,-0.05,3.1,0.2,0.7"
LAB_SAMPLES = 3000
"""The first 3 s of the MuJoCo recording (1 kHz): enough to identify the links, fast to import."""


def invoke(*args):
    """The CLI in-process; stderr kept apart (warnings go there)."""
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def warnings_of(result) -> list[str]:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert all(line.startswith("ineid: warning: ") for line in lines), result.stderr
    return [line.removeprefix("ineid: warning: ") for line in lines]


# -- synthetic datasets: each mistake, its one warning ---------------------------------------------


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    path = tmp_path_factory.mktemp("plausible") / "g.h5"
    r = invoke("-q", "data", "generate", "--n-configs", "5", "--n-frames", "30", "--seed", "4", "--out", path)
    assert r.exit_code == 0, r.output
    return path


def _altered(src, dst, kind: str):
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        q, w = f["q"][()], f["wrench"][()]
        if kind == "degrees":
            f["q"][...] = np.degrees(q)
        elif kind == "x1000":
            f["wrench"][...] = 1000 * w
        elif kind == "flipped":
            f["wrench"][...] = -w
        elif kind == "zero":
            f["wrench"][...] = 0.0
        elif kind == "random":
            f["wrench"][...] = np.random.default_rng(2).normal(size=w.shape) * w.std()
    return dst


MISTAKES = {
    "clean": (None, None),
    "degrees": ("angles_in_degrees", "data import --angle-unit deg"),
    "x1000": ("total_mass_scale", "is the wrench in mN or N*mm? (data import --wrench-scale 0.001)"),
    "flipped": ("total_mass_negative", "the wrench's sign looks flipped (data import --flip-wrench)"),
    "zero": ("held_out_error", "the held-out wrench is zero"),
    "random": ("held_out_error", "whether the wrench channel holds the sensor at all"),
}


@pytest.mark.parametrize("kind", list(MISTAKES))
def test_each_mistake_gives_exactly_its_warning(generated, kind, tmp_path):
    code, text = MISTAKES[kind]
    data, out = _altered(generated, tmp_path / f"{kind}.h5", kind), tmp_path / "r.h5"
    r = invoke("-q", "solve", data, "--out", out)
    assert r.exit_code == 0, r.output
    found = warnings_of(r)
    recorded = load_results(out).meta["warnings"]
    if code is None:
        assert found == [] and recorded == []
        return
    assert len(found) == 1 and text in found[0], found
    assert recorded == [{"code": code, "message": found[0]}]
    info = invoke("results", "info", out)
    assert info.exit_code == 0 and "plausibility warnings: 1" in info.output and text in info.output


def test_total_mass_message_names_the_numbers(generated, model, tmp_path):
    r = invoke("-q", "solve", _altered(generated, tmp_path / "x.h5", "x1000"), "--out", tmp_path / "r.h5")
    (line,) = warnings_of(r)
    mass = float(np.median(estimated_total_mass(load_results(tmp_path / "r.h5"), model)))
    assert 900 < mass / 3.0 < 1100
    assert line.startswith(f"the estimated total mass of the moving links {mass:.4g} kg (median over 5 configurations) "
                           f"is {mass / 3.0:.0f}x the URDF's 3 kg")


def test_results_without_warnings_still_read(generated, tmp_path):
    """A results file from before the checks (no ``warnings`` attribute) reads and shows as not checked."""
    out = tmp_path / "r.h5"
    assert invoke("-q", "solve", generated, "--out", out).exit_code == 0
    with h5py.File(out, "r+") as f:
        del f.attrs["warnings"]
    assert load_results(out).meta["warnings"] is None
    info = invoke("results", "info", out)
    assert info.exit_code == 0 and "plausibility warnings: not checked" in info.output


# -- no false positives on what the project makes -----------------------------------------------


@pytest.mark.parametrize("mode", ["uniform", "fourier"])
def test_clean_and_noisy_generated_data_stay_silent(model, mode):
    """Heavier noise than the options' examples, glitches too; with and without held-out frames.

    (30 frames, the settings test_identify compiles for: the kernels are shared. ``--bias estimate``
    and estimated weights on such data, measured: no warning either, see docs/recordings.md.)"""
    noisy = NoiseModel.create(model.n_dof, force=2.0, moment=0.2, q=0.002, qd=0.05, qdd=0.5, glitch_rate=0.02)
    for seed, noise in ((0, NoiseModel()), (1, noisy)):
        ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=5), 30, seed,
                                                 frames=FrameSampling(mode), noise=noise))
        assert check_dataset(ds, model) == []
        for settings in (SolveSettings(), SolveSettings(frames=30), SolveSettings(method="consistent")):
            res = solve_dataset(ds, settings, model=model)
            assert check_solve(ds, res, model) == [], (seed, settings)


def test_the_demo_stays_silent(tmp_path):
    """``make demo``'s data and solve commands, smaller (40 frames: test_identify's noisy data compile those)."""
    data, out = tmp_path / "demo.h5", tmp_path / "r.h5"
    r = invoke("-q", "data", "generate", "sweaty-arm", "--factorial", "3", "--n-frames", "40", "--seed", "1",
               "--noise", "force=0.5,moment=0.05", "--out", data)
    assert r.exit_code == 0 and not r.stderr
    r = invoke("-q", "solve", data, "--method", "consistent", "--weights", "estimate", "--select", "0:5", "--out", out)
    assert r.exit_code == 0 and warnings_of(r) == []


# -- a lab's recording: the mistakes at import, and the options that fix them --------------------------


@pytest.fixture(scope="module")
def lab_files(lab, tmp_path_factory):
    """Short CSVs of the MuJoCo recording: as recorded (untared, offsets), tared, and with each mistake."""
    from .bag_files import write_angles_csv

    folder = tmp_path_factory.mktemp("plausible-lab")
    t, q = lab.sim.time[:LAB_SAMPLES], lab.sim.q[:LAB_SAMPLES]
    tared, reading = lab.tared[:LAB_SAMPLES], lab.reading[:LAB_SAMPLES]
    files = {
        "untared": (q, reading), "tared": (q, tared), "degrees": (np.degrees(q), tared),
        "x1000": (q, 1000 * tared), "flipped": (q, -tared),
    }  # fmt: skip
    return {k: write_angles_csv(folder / f"{k}.csv", t, *v) for k, v in files.items()}


def _import(path, out, *extra):
    return invoke("-q", "data", "import", path, "--robot", "sweaty-arm", "--sensor-pose", POSE_TEXT, *extra,
                  "--out", out)


def test_lab_recording_stays_silent(lab_files, tmp_path):
    """Sensor frame, offsets, --bias estimate (and the tared recording without): no warning."""
    for name, bias in (("untared", "estimate"), ("tared", "none")):
        rec = tmp_path / f"{name}.h5"
        r = _import(lab_files[name], rec)
        assert r.exit_code == 0 and warnings_of(r) == [], r.output
        r = invoke("-q", "solve", rec, "--bias", bias, "--out", tmp_path / f"{name}_r.h5")
        assert r.exit_code == 0 and warnings_of(r) == [], r.output


@pytest.mark.parametrize(("kind", "at_import", "at_solve", "fix"), [
    ("degrees", "data import --angle-unit deg", "data import --angle-unit deg", ("--angle-unit", "deg")),
    ("x1000", None, "data import --wrench-scale 0.001", ("--wrench-scale", "0.001")),
    ("flipped", "points against gravity", "the wrench's sign looks flipped (data import --flip-wrench)",
     ("--flip-wrench",)),
])  # fmt: skip
def test_lab_mistake_warns_and_its_fix_gives_the_right_mass(lab, lab_files, tmp_path, kind, at_import, at_solve, fix):
    rec, out = tmp_path / "rec.h5", tmp_path / "r.h5"
    r = _import(lab_files[kind], rec)
    assert r.exit_code == 0, r.output
    found = warnings_of(r)
    assert (found == []) if at_import is None else (len(found) == 1 and at_import in found[0]), found
    r = invoke("-q", "solve", rec, "--out", out)
    assert r.exit_code == 0, r.output
    (line,) = warnings_of(r)
    assert at_solve in line
    # the fix: no warning, and the total mass of the simulated arm
    r = _import(lab_files[kind], rec, *fix, "--overwrite")
    assert r.exit_code == 0 and warnings_of(r) == [], r.output
    r = invoke("-q", "solve", rec, "--out", out, "--overwrite")
    assert r.exit_code == 0 and warnings_of(r) == [], r.output
    mass = estimated_total_mass(load_results(out), lab.model)[0]
    assert abs(mass - lab.theta[0::10].sum()) < 1e-4 * mass


def test_flipped_recording_under_the_consistent_method(lab_files, tmp_path):
    """The recordings' recommended solve: a consistent fit cannot follow a flipped wrench to negative
    masses; the linear fit's mass (with offsets) or the data's mean force (without) still says so."""
    rec = tmp_path / "rec.h5"
    assert _import(lab_files["flipped"], rec).exit_code == 0
    for bias, expected in (("estimate", "the wrench's sign looks flipped (data import --flip-wrench)"),
                           ("none", "the mean force over the fitted frames points against gravity")):
        r = invoke("-q", "solve", rec, "--method", "consistent", "--bias", bias, "--out", tmp_path / f"{bias}.h5")
        assert r.exit_code == 0, r.output
        (line,) = warnings_of(r)
        assert expected in line and "--flip-wrench" in line


def test_sensor_pose_forgotten_is_caught(lab_files, tmp_path):
    """The turned-over sensor imported as if it were the base frame: its weight points up."""
    rec = tmp_path / "rec.h5"
    r = invoke("-q", "data", "import", lab_files["tared"], "--robot", "sweaty-arm", "--out", rec)
    (line,) = warnings_of(r)
    assert r.exit_code == 0 and "points against gravity" in line and "--sensor-pose" in line


def test_checks_never_stop_a_solve_the_linear_fit_cannot_repeat(model):
    """A trained run may fit fewer frames than the linear least squares needs: the mass check is left out."""
    import dataclasses

    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=5), 30, 0))
    res = solve_dataset(ds, SolveSettings(), model=model)
    short = dataclasses.replace(res, settings=SolveSettings(method="nonlinear"), n_frames_fit=2,
                                n_frames_validation=28)  # fmt: skip
    assert check_solve(ds, short, model) == []
    res.theta_hat[:, 0::10] *= -1  # negative masses: the linear fit (res itself) says so
    assert [f.code for f in check_solve(ds, res, model)] == ["total_mass_negative"]


# -- the pieces -------------------------------------------------------------------------------------


def _mixed_chain():
    from ineid.robots.urdf import parse_chain

    chain = parse_chain((FIXTURES / "mixed_chain.urdf").read_text(), source="mixed_chain.urdf")
    return SimpleNamespace(chain=chain, n_dof=len(chain.joints), joint_types=tuple(j.type for j in chain.joints),
                           q_lower=np.array([j.q_lower for j in chain.joints]),
                           q_upper=np.array([j.q_upper for j in chain.joints]))


def test_degrees_convert_revolute_joints_only():
    m = _mixed_chain()
    assert m.joint_types[:2] == ("revolute", "prismatic") and m.chain.joints[0].continuous
    q = np.tile([90.0, 0.1] + [45.0] * (m.n_dof - 2), (4, 1))
    streams = Streams(np.arange(4.0), q, q, q, np.arange(4.0), np.ones((4, 6)), "x")
    si = in_si_units(streams, m, "deg", 0.001)
    for a in (si.q, si.qd, si.qdd):
        assert np.allclose(a[0], [math.pi / 2, 0.1] + [math.pi / 4] * (m.n_dof - 2))
    assert np.allclose(si.wrench, 0.001) and si.origin == {"angle_unit": "deg", "wrench_scale": 0.001,
                                                           "time_unit": "s", "force_unit": "N", "moment_unit": "Nm"}


def test_degree_rule_skips_continuous_and_prismatic_joints():
    m = _mixed_chain()
    lo, hi = m.q_lower, m.q_upper
    mid = 0.5 * (lo + hi)
    rng = np.random.default_rng(0)
    q_rad = mid + (hi - lo) * rng.uniform(-0.45, 0.45, (200, m.n_dof))
    q_deg = q_rad.copy()
    limited = [k for k, j in enumerate(m.chain.joints) if j.type == "revolute" and not j.continuous]
    q_deg[:, limited] = np.degrees(q_rad[:, limited])
    assert limited == [2]  # j3, limits -2..2 rad
    assert check_angle_units(m, q_rad) is None
    assert check_angle_units(m, q_deg).code == "angles_in_degrees"
    wound = q_rad.copy()
    wound[:, 0] += 40.0  # a continuous joint may wind up: not evidence of degrees
    assert check_angle_units(m, wound) is None


def test_static_force_rule(model):
    weight = moving_mass(model) * 9.81
    assert check_static_force(model, [0, 0, -weight]) is None
    assert check_static_force(model, [0, 0, 0.4 * weight]) is None  # a small upward mean: an offset, tolerated
    assert check_static_force(model, [2 * weight, 0, 0.6 * weight]) is None  # mostly sideways
    found = check_static_force(model, [0.1, 0, weight])
    assert isinstance(found, Finding) and found.code == "static_wrench_against_gravity"
    assert "--flip-wrench" in found.message and "--sensor-pose" in found.message


def test_bad_wrench_scale_is_refused(tmp_path):
    for bad in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(DatasetError, match="wrench_scale"):
            ImportSettings(wrench_scale=bad)
    with pytest.raises(DatasetError, match="angle_unit"):
        ImportSettings(angle_unit="grad")
    for bad in ("0", "-2", "inf", "nan"):
        r = invoke("data", "import", tmp_path / "x.csv", "--robot", "sweaty-arm", "--wrench-scale", bad,
                   "--out", tmp_path / "x.h5")
        assert r.exit_code == 2 and "--wrench-scale" in r.output, r.output
