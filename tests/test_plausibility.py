"""Plausibility warnings: unit and sign mistakes named with their fix, silence on clean data.

Each mistake (angles in degrees, even with little motion, radians imported as degrees, time
stamps in ms, gravity in mm/s^2, a wrench in mN, kN or moments in N*mm, a flipped, zero or
random wrench) gives exactly its warning, exit status 0; the import options that fix it
remove the warning and give the right total mass; every dataset the project makes gives none.
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
from ineid.data.recordings.pipeline import Streams, in_si_units
from ineid.data.recordings.plausibility import (
    Finding,
    check_angle_units,
    check_dataset,
    check_gravity,
    check_static_force,
    check_time_unit,
    moving_mass,
)
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.streams import ImuStream, units_note
from ineid.data.synthesis.sampling import FrameSampling
from ineid.identify import SolveSettings, load_results, solve_dataset
from ineid.identify.plausibility import check_solve, estimated_total_mass

from .conftest import FIXTURES
from .test_faults import one_line

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
        elif kind == "kN":
            f["wrench"][...] = w / 1000
        elif kind == "Nmm":
            f["wrench"][..., 3:] = 1000 * w[..., 3:]
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
    "x1000": (
        "total_mass_scale",
        "the wrench looks like forces in mN and moments in N*mm (mN*m) (data import --force-unit mN --moment-unit Nmm)",
    ),
    "kN": (
        "wrench_unit",
        (
            "the wrench looks like forces in kN and moments in kN*m: with the wrench x 1000 the "
            "model explains the wrench over 1000x better",
            "): data import --force-unit kN --moment-unit kNm",
        ),
    ),
    "Nmm": (
        "wrench_unit",
        (
            "the wrench looks like forces in N and moments in N*mm (mN*m): with the moments x 0.001 "
            "the model explains the wrench over 1000x better",
            "): data import --moment-unit Nmm",
        ),
    ),
    "flipped": ("total_mass_negative", "the wrench's sign looks flipped (data import --flip-wrench)"),
    "zero": ("held_out_error", "the held-out wrench is zero"),
    "random": ("held_out_error", "whether the wrench channel holds the sensor at all"),
}


@pytest.mark.parametrize("kind", list(MISTAKES))
def test_each_mistake_gives_exactly_its_warning(generated, kind, tmp_path):
    code, text = MISTAKES[kind]
    texts = (text,) if isinstance(text, str) else text
    data, out = _altered(generated, tmp_path / f"{kind}.h5", kind), tmp_path / "r.h5"
    r = invoke("-q", "solve", data, "--out", out)
    assert r.exit_code == 0, r.output
    found = warnings_of(r)
    recorded = load_results(out).meta["warnings"]
    if code is None:
        assert found == [] and recorded == []
        return
    assert len(found) == 1 and all(t in found[0] for t in texts), found
    assert recorded == [{"code": code, "message": found[0]}]
    info = invoke("results", "info", out)
    assert info.exit_code == 0 and "plausibility warnings: 1" in info.output and texts[0] in info.output


def test_total_mass_message_names_the_numbers(generated, model, tmp_path):
    r = invoke("-q", "solve", _altered(generated, tmp_path / "x.h5", "x1000"), "--out", tmp_path / "r.h5")
    (line,) = warnings_of(r)
    mass = float(np.median(estimated_total_mass(load_results(tmp_path / "r.h5"), model)))
    assert 900 < mass / 3.0 < 1100
    assert line.startswith(
        f"the estimated total mass of the moving links {mass:.4g} kg (median over 5 configurations) "
        f"is {mass / 3.0:.0f}x the URDF's 3 kg"
    )


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
        ds = generate_dataset(
            model, DatasetSpec(Combination("random", n_configs=5), 30, seed, frames=FrameSampling(mode), noise=noise)
        )
        assert check_dataset(ds, model) == []
        for settings in (SolveSettings(), SolveSettings(frames=30), SolveSettings(method="consistent")):
            res = solve_dataset(ds, settings, model=model)
            assert check_solve(ds, res, model) == [], (seed, settings)


def test_the_demo_stays_silent(tmp_path):
    """``make demo``'s data and solve commands, smaller (40 frames: test_identify's noisy data compile those)."""
    data, out = tmp_path / "demo.h5", tmp_path / "r.h5"
    r = invoke(
        "-q",
        "data",
        "generate",
        "sweaty-arm",
        "--factorial",
        "3",
        "--n-frames",
        "40",
        "--seed",
        "1",
        "--noise",
        "force=0.5,moment=0.05",
        "--out",
        data,
    )
    assert r.exit_code == 0 and not r.stderr
    r = invoke("-q", "solve", data, "--method", "consistent", "--weights", "estimate", "--select", "0:5", "--out", out)
    assert r.exit_code == 0 and warnings_of(r) == []


# -- a lab's recording: the mistakes at import, and the options that fix them --------------------------


@pytest.fixture(scope="module")
def lab_files(lab, tmp_path_factory):
    """Short CSVs of the MuJoCo recording: as recorded (untared, offsets), tared, and with each mistake
    (``ms``: the time column in milliseconds)."""
    from .bag_files import write_angles_csv

    folder = tmp_path_factory.mktemp("plausible-lab")
    t, q = lab.sim.time[:LAB_SAMPLES], lab.sim.q[:LAB_SAMPLES]
    tared, reading = lab.tared[:LAB_SAMPLES], lab.reading[:LAB_SAMPLES]
    files = {
        "untared": (t, q, reading),
        "tared": (t, q, tared),
        "degrees": (t, np.degrees(q), tared),
        "x1000": (t, q, 1000 * tared),
        "kN": (t, q, tared / 1000),
        "Nmm": (t, q, tared * np.repeat([1, 1000], 3)),
        "flipped": (t, q, -tared),
        "ms": (1000 * t, q, tared),
    }
    return {k: write_angles_csv(folder / f"{k}.csv", *v) for k, v in files.items()}


def _import(path, out, *extra):
    return invoke(
        "-q", "data", "import", path, "--robot", "sweaty-arm", "--sensor-pose", POSE_TEXT, *extra, "--out", out
    )


def test_lab_recording_stays_silent(lab_files, tmp_path):
    """Sensor frame, offsets, --bias estimate (and the tared recording without): no warning."""
    for name, bias in (("untared", "estimate"), ("tared", "none")):
        rec = tmp_path / f"{name}.h5"
        r = _import(lab_files[name], rec)
        assert r.exit_code == 0 and warnings_of(r) == [], r.output
        r = invoke("-q", "solve", rec, "--bias", bias, "--out", tmp_path / f"{name}_r.h5")
        assert r.exit_code == 0 and warnings_of(r) == [], r.output


@pytest.mark.parametrize(
    ("kind", "at_import", "at_solve", "fix"),
    [
        ("degrees", "data import --angle-unit deg", "data import --angle-unit deg", ("--angle-unit", "deg")),
        (
            "x1000",
            None,
            "data import --force-unit mN --moment-unit Nmm",
            ("--force-unit", "mN", "--moment-unit", "Nmm"),
        ),
        ("kN", None, "data import --force-unit kN --moment-unit kNm", ("--force-unit", "kN", "--moment-unit", "kNm")),
        ("Nmm", None, "moments in N*mm (mN*m): with the moments x 0.001", ("--moment-unit", "Nmm")),
        (
            "flipped",
            "points against gravity",
            "the mean force over the fitted frames points against gravity",  # consistent, a recording's default
            ("--flip-wrench",),
        ),
    ],
)
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
    for bias, expected in (
        ("estimate", "the wrench's sign looks flipped (data import --flip-wrench)"),
        ("none", "the mean force over the fitted frames points against gravity"),
    ):
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
    short = dataclasses.replace(res, settings=SolveSettings(method="nonlinear"), n_frames_fit=2, n_frames_validation=28)
    assert check_solve(ds, short, model) == []
    res.theta_hat[:, 0::10] *= -1  # negative masses: the linear fit (res itself) says so
    assert [f.code for f in check_solve(ds, res, model)] == ["total_mass_negative"]


def test_time_column_in_milliseconds(lab, lab_files, tmp_path):
    """The import names the unit before the cut-off rule's own advice; a cut-off forced through imports garbage
    with the warning (and the solve repeats it); ``--time-unit ms`` is silent and gives the right mass."""
    rec, out = tmp_path / "rec.h5", tmp_path / "r.h5"
    line = one_line(_import(lab_files["ms"], rec))
    assert line.startswith(
        "Error: the time stamps are 1 s apart (1 Hz), slower than a robot recording's "
        "10 Hz..100 kHz: the time column looks like milliseconds (1 kHz"
    )
    assert "data import --time-unit ms (the import stopped at: cut-off 1 Hz is too close to the Nyquist" in line
    assert not rec.exists()
    r = _import(lab_files["ms"], rec, "--cutoff", "0.4")
    (found,) = warnings_of(r)
    assert r.exit_code == 0 and "looks like milliseconds" in found and found.endswith("data import --time-unit ms")
    r = invoke("-q", "solve", rec, "--out", out)
    assert r.exit_code == 0 and warnings_of(r) == [found]
    assert load_results(out).meta["warnings"][0]["code"] == "time_unit"
    r = _import(lab_files["ms"], rec, "--time-unit", "ms", "--overwrite")
    assert r.exit_code == 0 and warnings_of(r) == [] and "time stamps converted from ms" in r.stdout
    r = invoke("-q", "solve", rec, "--out", out, "--overwrite")
    assert r.exit_code == 0 and warnings_of(r) == [], r.output
    mass = estimated_total_mass(load_results(out), lab.model)[0]
    assert abs(mass - lab.theta[0::10].sum()) < 1e-4 * mass


@pytest.fixture(scope="module")
def small_motion(model, tmp_path_factory):
    """A recording that moves +-4 degrees about the zero pose (the CAD arm's exact base wrench, as many samples as
    the lab's: the same kernels): its angles in degrees stay inside +-(2 pi + 1), where the joint-limit rule cannot
    see them."""
    from .bag_files import write_angles_csv

    folder = tmp_path_factory.mktemp("plausible-small")
    t = np.arange(LAB_SAMPLES) / 1000.0
    amplitude, w = math.radians(4.0), 2 * np.pi * np.array([0.5, 0.75, 1.0, 1.25])
    q0, phase = np.array([0.0, 0.05, 0.0, -0.05]), w * t[:, None] + np.arange(4.0)
    q = q0 + amplitude * np.sin(phase)
    states = (q.T, (amplitude * w * np.cos(phase)).T, (-amplitude * w**2 * np.sin(phase)).T, model.theta_cad)
    wrench = np.array(model.casadi_base_wrench.map(len(t))(*states)).T  # CasADi: nothing to compile
    return {
        "rad": write_angles_csv(folder / "rad.csv", t, q, wrench),
        "deg": write_angles_csv(folder / "deg.csv", t, np.degrees(q), wrench),
    }


def _import_solve(path, tmp_path, *extra):
    """``data import`` (base frame) then ``solve``: (the import's warnings, the solve's, the results)."""
    rec, out = tmp_path / "rec.h5", tmp_path / "r.h5"
    r = invoke("-q", "data", "import", path, "--robot", "sweaty-arm", *extra, "--out", rec, "--overwrite")
    assert r.exit_code == 0, r.output
    s = invoke("-q", "solve", rec, "--out", out, "--overwrite")
    assert s.exit_code == 0, s.output
    return warnings_of(r), warnings_of(s), load_results(out)


def test_small_motion_in_degrees(model, small_motion, tmp_path):
    """+-4 degrees read as +-4 rad: the refit under degrees explains the wrench, the stored radians do not."""
    at_import, (line,), res = _import_solve(small_motion["deg"], tmp_path)
    assert at_import == [] and res.meta["warnings"][0]["code"] == "angles_in_degrees"
    assert line.startswith(
        "the joint angles look like degrees: read as degrees the model explains the wrench over 1000x better"
    )
    assert line.endswith("import the recording with data import --angle-unit deg")
    for path, extra in ((small_motion["deg"], ("--angle-unit", "deg")), (small_motion["rad"], ())):
        at_import, at_solve, res = _import_solve(path, tmp_path, *extra)
        assert at_import == [] and at_solve == []
        assert abs(estimated_total_mass(res, model)[0] - moving_mass(model)) < 1e-5


def test_radians_imported_as_degrees(small_motion, tmp_path):
    at_import, (line,), res = _import_solve(small_motion["rad"], tmp_path, "--angle-unit", "deg")
    assert at_import == [] and res.meta["warnings"][0]["code"] == "angles_in_radians"
    assert line.startswith("the joint angles look like radians that --angle-unit deg converted again: read as radians")
    assert line.endswith("import the recording without --angle-unit deg")


def test_gravity_in_millimetres(generated, tmp_path):
    """Warned where --gravity is parsed (any command that takes it), and by the solve instead of the total mass
    it spoils; zero gravity and the Moon's pass silently."""
    data = tmp_path / "g.h5"
    r = invoke(
        "-q",
        "data",
        "generate",
        "--n-configs",
        "5",
        "--n-frames",
        "30",
        "--seed",
        "4",
        "--gravity",
        "0",
        "0",
        "-9810",
        "--out",
        data,
    )
    expected = (
        "--gravity 0 0 -9810 has |g| = 9810, 1000x Earth's 9.807 m/s^2: it looks like mm/s^2; gravity is in "
        "m/s^2: --gravity 0 0 -9.81"
    )
    assert r.exit_code == 0 and warnings_of(r) == [expected]
    r = invoke("-q", "solve", data, "--out", tmp_path / "r.h5")
    (line,) = warnings_of(r)
    assert r.exit_code == 0 and line.startswith("the dataset's gravity 0 0 -9810 has |g| = 9810, 1000x Earth's")
    assert line.endswith("data import or data generate --gravity 0 0 -9.81")
    for g in (("0", "0", "0"), ("0", "0", "-1.62")):
        r = invoke("-q", "robot", "show", "sweaty-arm", "--gravity", *g)
        assert r.exit_code == 0 and warnings_of(r) == [], r.output


def test_wrench_in_kilonewtons_with_offsets(lab_files, tmp_path):
    """With offsets estimated the known links' weight no longer matches a wrench / 1000 and the fit explains
    nothing (that was the only warning); the refit with the known links' part scaled freely names the unit."""
    rec = tmp_path / "rec.h5"
    assert _import(lab_files["kN"], rec).exit_code == 0
    r = invoke("-q", "solve", rec, "--bias", "estimate", "--out", tmp_path / "r.h5")
    (line,) = warnings_of(r)
    assert r.exit_code == 0 and line.startswith("the wrench looks like forces in kN and moments in kN*m")
    assert line.endswith("data import --force-unit kN --moment-unit kNm")


# -- the pieces -------------------------------------------------------------------------------------


def _mixed_chain():
    from ineid.robots.urdf import parse_chain

    chain = parse_chain((FIXTURES / "mixed_chain.urdf").read_text(), source="mixed_chain.urdf")
    return SimpleNamespace(
        chain=chain,
        n_dof=len(chain.joints),
        joint_types=tuple(j.type for j in chain.joints),
        q_lower=np.array([j.q_lower for j in chain.joints]),
        q_upper=np.array([j.q_upper for j in chain.joints]),
    )


def test_degrees_convert_revolute_joints_only():
    m = _mixed_chain()
    assert m.joint_types[:2] == ("revolute", "prismatic") and m.chain.joints[0].continuous
    q = np.tile([90.0, 0.1] + [45.0] * (m.n_dof - 2), (4, 1))
    streams = Streams(np.arange(4.0), q, q, q, np.arange(4.0), np.ones((4, 6)), "x")
    si = in_si_units(streams, m, "deg", 0.001)
    for a in (si.q, si.qd, si.qdd):
        assert np.allclose(a[0], [math.pi / 2, 0.1] + [math.pi / 4] * (m.n_dof - 2))
    assert np.allclose(si.wrench, 0.001) and si.origin == {
        "angle_unit": "deg",
        "wrench_scale": 0.001,
        "time_unit": "s",
        "force_unit": "N",
        "moment_unit": "Nm",
    }


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
        r = invoke(
            "data",
            "import",
            tmp_path / "x.csv",
            "--robot",
            "sweaty-arm",
            "--wrench-scale",
            bad,
            "--out",
            tmp_path / "x.h5",
        )
        assert r.exit_code == 2 and "--wrench-scale" in r.output, r.output


def test_time_unit_rule():
    """The unit named is the one that puts the rate in 10 Hz..100 kHz with plausible joint speeds (nearest 1 kHz);
    a slow recording of a moving arm is not milliseconds; --time-unit ms on seconds names seconds."""
    t = np.arange(2000) / 1000.0
    q = 0.5 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.ones(4)  # 1.6 rad/s at most
    assert check_time_unit(t, q) is None
    for unit, name, factor in (("ms", "milliseconds", 1e3), ("us", "microseconds", 1e6), ("ns", "nanoseconds", 1e9)):
        found = check_time_unit(t * factor, q)
        assert found.code == "time_unit" and f"looks like {name} (1 kHz" in found.message
        assert found.message.endswith(f"--time-unit {unit}")
    found = check_time_unit(t * 1e-3, q, "ms")
    assert "apart after --time-unit ms (1 MHz)" in found.message and found.message.endswith("--time-unit s")
    slow = np.arange(20) / 5.0  # a 5 Hz recording of the arm moving at 1 rad/s: ms would be 1000 rad/s
    assert check_time_unit(slow, np.sin(slow)[:, None] * np.ones(4)) is None
    assert check_time_unit(t[:1], q[:1]) is None and check_time_unit(t, q[:, :, None]) is None


def test_gravity_rule():
    assert check_gravity([0, 0, -9.81]) is None and check_gravity([0, 0, 0]) is None
    assert check_gravity([0, 0, -1.62]) is None and check_gravity([0, 0, -24.8]) is None  # the Moon, Jupiter
    for g, unit, fixed in (
        ([0, 0, -981], "cm/s^2", "0 0 -9.81"),
        ([0, 0, -0.00981], "km/s^2", "0 0 -9.81"),
        ([0, -1, 0], "standard gravities (g)", "0 -9.807 0"),
    ):
        found = check_gravity(g)
        assert found.code == "gravity_unit" and f"it looks like {unit}" in found.message
        assert found.message.endswith(f"--gravity {fixed}")
    assert check_gravity([0, 0, -300]).message.endswith("--gravity 0 0 -9.807 for Earth's")


def test_time_force_and_moment_units_convert():
    m = _mixed_chain()
    n = m.n_dof
    imu = ImuStream("imu", np.arange(4.0), {"gyro": np.ones((4, 3))})
    streams = Streams(np.arange(4.0), np.ones((4, n)), None, None, np.arange(4.0), np.ones((4, 6)), "x", imus=(imu,))
    si = in_si_units(streams, m, time_unit="ms", force_unit="kN", moment_unit="Nmm")
    assert np.allclose(si.joint_time, np.arange(4) / 1000) and np.allclose(si.wrench_time, si.joint_time)
    assert np.allclose(si.imus[0].time, si.joint_time) and np.allclose(si.imus[0].readings["gyro"], 1)
    assert np.allclose(si.wrench, [1000, 1000, 1000, 0.001, 0.001, 0.001]) and np.allclose(si.q, 1)
    assert si.origin == {
        "angle_unit": "rad",
        "wrench_scale": 1.0,
        "time_unit": "ms",
        "force_unit": "kN",
        "moment_unit": "Nmm",
    }
    assert units_note(si.origin) == "time stamps converted from ms; forces from kN and moments from Nmm converted"
    for name, bad in (("time_unit", "min"), ("force_unit", "lbf"), ("moment_unit", "Nmmm")):
        with pytest.raises(DatasetError, match=name):
            ImportSettings(**{name: bad})
