"""The ``ineid`` command, driven with click's CliRunner."""

from __future__ import annotations

import pytest

from ineid import __version__
from ineid.generated import BUILTIN_DIR

from .conftest import FIXTURES, real_robot


def one_line_error(result, code=1):
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    return lines[-1]


def test_version(run):
    r = run("--version")
    assert r.exit_code == 0 and __version__ in r.output


def test_robot_list_and_show(run):
    r = run("robot", "list")
    assert r.exit_code == 0 and r.output.startswith("sweaty-arm")
    r = run("robot", "show", "sweaty-arm")
    assert r.exit_code == 0
    for word in ("shoulder_pitch", "upper_arm_yaw", "forearm", "hand", "Ixy", "1173 operations"):
        assert word in r.output
    cells = [[c.strip() for c in line.split("│")[1:-1]] for line in r.output.splitlines() if line.startswith("│")]
    roles = {row[0]: row[1] for row in cells if row[1] in ("known", "unknown")}
    assert roles == {
        "shoulder_pitch_link": "known",
        "shoulder_roll_link": "known",
        "upper_arm": "unknown",
        "forearm": "unknown",
    }
    r = run("robot", "show", "sweaty-arm", "--unknown-links", "forearm", "--gravity", "0", "0", "-1.62")
    assert r.exit_code == 0 and "-1.62" in r.output


def test_robot_show_urdf_with_locks(run):
    path, _ = real_robot("panda")
    r = run("robot", "show", path, "--lock", "panda_finger_joint1=0", "--lock", "panda_finger_joint2=0")
    assert r.exit_code == 0, r.output
    assert "panda_joint7" in r.output and "panda_link7" in r.output


def test_user_errors_are_one_line(run):
    line = one_line_error(run("robot", "show", "nope"))
    assert line.startswith("Error: 'nope' is neither a built-in robot")
    line = one_line_error(run("robot", "show", "sweaty-arm", "--unknown-links", "elbow"))
    assert "'elbow' is not a moving link" in line
    path, _ = real_robot("panda")
    assert one_line_error(run("robot", "show", path, "--lock", "panda_finger_joint1"), code=2)


def test_non_finite_joint_origin_is_one_line_and_leaves_no_code(run, tmp_path, monkeypatch):
    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "cache"))
    text = (FIXTURES / "mixed_chain.urdf").read_text()
    assert text.count('xyz="0 0.1 0.25"') == 1
    bad = tmp_path / "nan.urdf"
    bad.write_text(text.replace('xyz="0 0.1 0.25"', 'xyz="0 nan 0.25"'))
    line = one_line_error(run("robot", "show", bad))
    assert line == (
        f"Error: {bad}: joint 'j3': <origin xyz='0 nan 0.25'> holds a non-finite value (nan or inf); "
        "give finite numbers"
    )
    assert not (tmp_path / "cache" / "generated").exists()


def test_generate_builtin_to_folder_matches_checked_in(run, tmp_path):
    r = run("generate", "sweaty-arm", "--out", tmp_path)
    assert r.exit_code == 0, r.output
    assert "1173 operations" in r.output
    for name in ("sweaty_arm_jax.py", "sweaty_arm_casadi.py"):
        assert (tmp_path / name).read_bytes() == (BUILTIN_DIR / name).read_bytes()


def test_generate_urdf(run, tmp_path):
    r = run("generate", FIXTURES / "mixed_chain.urdf", "--out", tmp_path)
    assert r.exit_code == 0, r.output
    assert "mixed-chain: 3 DOF, regressor 6 x 30" in r.output
    text = (tmp_path / "mixed_chain_jax.py").read_text()
    assert "regenerate with `ineid generate" in text
    # Regenerating over our own output is fine; over a foreign file needs --overwrite.
    assert run("generate", FIXTURES / "mixed_chain.urdf", "--out", tmp_path).exit_code == 0
    (tmp_path / "mixed_chain_jax.py").write_text("# my own file\n")
    line = one_line_error(run("generate", FIXTURES / "mixed_chain.urdf", "--out", tmp_path))
    assert line == f"Error: {tmp_path / 'mixed_chain_jax.py'} exists; pass --overwrite to replace it"
    assert (tmp_path / "mixed_chain_jax.py").read_text() == "# my own file\n"
    assert run("generate", FIXTURES / "mixed_chain.urdf", "--out", tmp_path, "--overwrite").exit_code == 0


def test_generate_usage_errors(run, tmp_path):
    assert one_line_error(run("generate"), code=2).startswith("Error: give either ROBOT or --builtin")
    assert "nor an existing URDF file" in one_line_error(run("generate", tmp_path / "x.urdf"), code=2)
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link name='a'>")
    assert "malformed XML" in one_line_error(run("generate", bad))


# -- ineid data ---------------------------------------------------------------------------


def test_data_generate_info_import(run, tmp_path):
    import numpy as np

    from ineid.data import load_dataset, write_recording_csv

    out = tmp_path / "d.h5"
    r = run(
        "data",
        "generate",
        "--factorial",
        3,
        "--n-frames",
        5,
        "--seed",
        4,
        "--frame-mode",
        "fourier",
        "--noise",
        "force=0.5,mz=0.01,qd=0.02",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "9 configurations x 5 frames" in r.output and out.is_file()
    ds = load_dataset(out)
    assert ds.meta.seed == 4 and ds.meta.noise["wrench"] == [0.5, 0.5, 0.5, 0.0, 0.0, 0.01]
    assert ds.meta.sampling["frames"]["mode"] == "fourier" and set(ds.clean) == {"qd", "wrench"}

    r = run("data", "info", out)
    assert r.exit_code == 0, r.output
    for word in ("9 configurations x 5 frames", "sweaty-arm", "upper_arm.Izz", "forearm.m", "qd_clean", "fz", "seed 4"):
        assert word in r.output, word

    before = out.read_bytes()
    line = one_line_error(run("data", "generate", "--factorial", 3, "--n-frames", 5, "--out", out))
    assert line == f"Error: {out} exists; pass --overwrite to replace it" and out.read_bytes() == before
    r = run(
        "data", "generate", "sweaty-arm", "--n-configs", 4, "--pool", 2, "--n-frames", 3, "--out", out, "--overwrite"
    )
    assert r.exit_code == 0 and "4 configurations x 3 frames" in r.output

    csv = write_recording_csv(tmp_path / "rec.csv", ds, config=2)
    rec = tmp_path / "rec.h5"
    r = run("data", "import", csv, "--robot", "sweaty-arm", "--out", rec)
    assert r.exit_code == 0, r.output
    assert "5 frames" in r.output and np.array_equal(load_dataset(rec).wrench[0], ds.wrench[2])
    r = run("data", "info", rec)
    assert r.exit_code == 0 and "recording" in r.output and "upper_arm.Izz" not in r.output


def test_data_errors_are_one_line(run, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"garbage" * 100)
    assert "not a readable HDF5 file" in one_line_error(run("data", "info", bad))
    r = run("data", "generate", "--factorial", 2, "--noise", "force=-1", "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "KEY=STD" in r.output
    r = run("data", "generate", "--factorial", 2, "--n-configs", 3, "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "not both" in r.output
    assert not (tmp_path / "x.h5").exists()
    csv = tmp_path / "short.csv"
    csv.write_text("time,q1,qd1,qdd1,fx,fy,fz,mx,my,mz\n0,0,0,0,0,0,0,0,0,0\n")
    line = one_line_error(run("data", "import", csv, "--robot", "sweaty-arm", "--out", tmp_path / "r.h5"))
    assert "columns are for 1 joint" in line and not (tmp_path / "r.h5").exists()
    line = one_line_error(run("data", "generate", "--n-frames", 2, "--out", tmp_path / "nofolder" / "x.h5"), code=2)
    assert "does not exist; create it first" in line


# -- identification -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    import ineid
    from ineid.data import Combination, DatasetSpec, NoiseModel, write_dataset

    model = ineid.load_robot("sweaty-arm")
    path = tmp_path_factory.mktemp("id") / "d.h5"
    noise = NoiseModel.create(4, force=0.3, moment=0.03)
    write_dataset(model, DatasetSpec(Combination("random", n_configs=12), n_frames=30, seed=2, noise=noise), path)
    return path


def test_identifiability_command(run, tmp_path, small_data):
    r = run("identifiability", "sweaty-arm")
    assert r.exit_code == 0, r.output
    for text in (
        "structural rank 17",
        "17 identifiable combinations",
        "upper_arm.m + forearm.m",
        "forearm.Ixx - forearm.Izz",
        "individually identifiable (6)",
        "Null directions",
    ):
        assert text in r.output, text
    r = run("identifiability", "sweaty-arm", "--unknown-links", "forearm", "--n-frames", 1)
    assert r.exit_code == 0 and "these frames are not enough" in r.output and "use at least 2 frames" in r.output
    r = run("identifiability", "sweaty-arm", "--data", small_data, "--config", 3)
    assert r.exit_code == 0 and "30 frames of configuration 3" in r.output


def test_solve_and_export(run, tmp_path, small_data):
    out = tmp_path / "r.h5"
    r = run("solve", small_data, "--method", "linear", "--weights", "estimate", "--select", "0:6", "--out", out)
    assert r.exit_code == 0, r.output
    for text in (
        "6/6 configurations identified",
        "fitted 24 frames each, validated on 6",
        "held-out relative wrench error",
        "Relative error, standard parameters",
        "base parameters (what the data determine)",
        "no (prior)",
        "physically valid estimates",
    ):
        assert text in r.output, text
    before = out.read_bytes()
    assert (
        one_line_error(run("solve", small_data, "--out", out)) == f"Error: {out} exists; pass --overwrite to replace it"
    )
    assert out.read_bytes() == before
    r = run("results", "info", out)
    assert r.exit_code == 0, r.output
    assert f"dataset: {small_data}; fingerprint " in r.output and "6/6 configurations identified" in r.output
    out_c = tmp_path / "c.h5"
    r = run(
        "solve",
        small_data,
        "--method",
        "consistent",
        "--select",
        "2,5",
        "--fit-frames",
        30,
        "--workers",
        1,
        "--out",
        out_c,
    )
    assert (
        r.exit_code == 0
        and "2/2 configurations identified" in r.output
        and "physically valid estimates: 100.0%" in r.output
    )
    urdf = tmp_path / "arm.urdf"
    r = run("export-urdf", out_c, "--config", 5, "--out", urdf)
    assert r.exit_code == 0 and urdf.is_file(), r.output
    before = urdf.read_bytes()
    line = one_line_error(run("export-urdf", out_c, "--config", 2, "--out", urdf))
    assert line == f"Error: {urdf} exists; pass --overwrite to replace it" and urdf.read_bytes() == before
    r = run("robot", "show", urdf)
    assert r.exit_code == 0
    assert "not in the results" in one_line_error(
        run("export-urdf", out_c, "--config", 4, "--out", tmp_path / "x.urdf")
    )
    r = run("solve", small_data, "--select", "0:zz", "--out", tmp_path / "bad.h5")
    assert r.exit_code == 2 and "A:B[:STEP]" in r.output
    line = one_line_error(run("solve", small_data, "--fit-frames", 2, "--out", tmp_path / "few.h5"))
    assert "2 frames give 12 equations for 17 identifiable parameters; use at least 4 frames" in line
    assert not (tmp_path / "few.h5").exists()
    r = run("solve", small_data, "--weights", "noise", "--select", "0", "--out", tmp_path / "n.h5")
    assert r.exit_code == 0 and (tmp_path / "n.h5").exists()  # the file records its noise levels
    r = run("solve", small_data, "--sigma", 1, 1, 1, 1, 1, 1, "--out", tmp_path / "s.h5")
    assert r.exit_code == 2 and "--sigma goes with --weights noise" in r.output


def test_solve_recording_prints_estimates(run, tmp_path, small_data):
    from ineid.data import load_dataset, write_recording_csv

    csv = write_recording_csv(tmp_path / "rec.csv", load_dataset(small_data, configs=[4]))
    rec = tmp_path / "rec.h5"
    assert run("data", "import", csv, "--robot", "sweaty-arm", "--out", rec).exit_code == 0
    r = run("solve", rec, "--method", "consistent", "--out", tmp_path / "rr.h5")
    assert r.exit_code == 0, r.output
    for text in ("1/1 configurations identified", "Estimates of configuration 0", "prior (CAD)", "Base parameters"):
        assert text in r.output, text


def test_study_noise_command(run, tmp_path):
    r = run(
        "study",
        "noise",
        "--levels",
        "0,1",
        "--fit-frames",
        "10",
        "--n-configs",
        6,
        "--methods",
        "linear,consistent",
        "--workers",
        1,
        "--out",
        tmp_path / "study",
    )
    assert r.exit_code == 0, r.output
    assert (tmp_path / "study" / "noise_study.csv").is_file() and (tmp_path / "study" / "noise_study.png").is_file()
    assert "consistent" in r.output and "invalid" in r.output
    lines = (tmp_path / "study" / "noise_study.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * 1 * 2
    before = (tmp_path / "study" / "noise_study.csv").read_bytes()
    line = one_line_error(run("study", "noise", "--levels", "0", "--n-configs", 2, "--out", tmp_path / "study"))
    assert line == f"Error: {tmp_path / 'study' / 'noise_study.csv'} exists; pass --overwrite to replace it"
    assert (tmp_path / "study" / "noise_study.csv").read_bytes() == before


# -- learning --------------------------------------------------------------------------------


def test_train_evaluate_sweep(run, tmp_path):
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    data = tmp_path / "d.h5"
    write_dataset(
        ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=40), n_frames=6, seed=1), data
    )
    out = tmp_path / "run"
    r = run(
        "train",
        data,
        "--arch",
        "net1",
        "--sample-frames",
        3,
        "--siamese",
        "--loss",
        "physics",
        "--beta",
        2,
        "--epochs",
        3,
        "--batch",
        16,
        "--train-configs",
        24,
        "--val-configs",
        8,
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    for text in (
        "3 epochs in",
        "evaluated on 8 configurations (test split)",
        "floor (null space)",
        "linear LS",
        "upper_arm.m + forearm.m",
        "wrench residual of the predictions",
    ):
        assert text in r.output, text
    for name in (
        "config.json",
        "scalers.json",
        "model.msgpack",
        "checkpoint.msgpack",
        "metrics.jsonl",
        "evaluation.json",
    ):
        assert (out / name).is_file(), name
    assert "not empty; pass --overwrite" in one_line_error(run("train", data, "--epochs", 1, "--out", out))
    before = (out / "evaluation.json").read_bytes()
    r = run("evaluate", out, data, "--select", "0:5", "--no-linear")  # the run's own file: re-evaluated in place
    assert r.exit_code == 0 and "evaluated on 5 configurations" in r.output
    assert "(it replaces the run's previous evaluation)" in r.output
    assert (out / "evaluation.json").read_bytes() != before
    assert "not a finished training run" in one_line_error(run("evaluate", tmp_path, data))
    r = run("train", data, "--arch", "mlp", "--out", tmp_path / "x")
    assert r.exit_code == 2 and "depth >= 1 and width >= 1" in r.output
    sw = tmp_path / "sweep"
    r = run(
        "sweep",
        data,
        "--archs",
        "simple,funnel",
        "--sample-frames",
        "2",
        "--siamese",
        "both",
        "--epochs",
        2,
        "--batch",
        16,
        "--out",
        sw,
    )
    assert r.exit_code == 0, r.output
    assert (sw / "sweep.csv").is_file() and (sw / "sweep.png").is_file()
    assert len((sw / "sweep.csv").read_text().splitlines()) == 1 + 4
    before = (sw / "sweep.csv").read_bytes()
    line = one_line_error(run("sweep", data, "--archs", "simple", "--out", sw))
    assert line == f"Error: {sw / 'sweep.csv'} exists; pass --overwrite to replace it"
    assert (sw / "sweep.csv").read_bytes() == before


# -- the CLI's conventions ---------------------------------------------------------------------


def test_deprecated_spellings_still_work(run, tmp_path, small_data):
    out = tmp_path / "d.h5"
    r = run("data", "generate", "--robot", "sweaty-arm", "--configs", 3, "--frames", 4, "--out", out)
    assert r.exit_code == 0, r.output
    assert "3 configurations x 4 frames" in r.output
    for old, new in (("--robot", "the ROBOT argument"), ("--configs", "--n-configs"), ("--frames", "--n-frames")):
        assert f"ineid: {old} is deprecated; use {new}" in r.output
    r = run("solve", small_data, "--configs", "1,2", "--frames", 20, "--out", tmp_path / "r.h5")
    assert r.exit_code == 0, r.output
    assert "2/2 configurations identified" in r.output and "fitted 20 frames each" in r.output
    assert "--configs is deprecated; use --select" in r.output
    r = run("solve", small_data, "--configs", "1", "--select", "2", "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "give --select or --configs, not both" in r.output


def test_help_does_not_import_jax():
    import subprocess
    import sys

    code = (
        "import sys; from click.testing import CliRunner; from ineid.cli import main; "
        "r = CliRunner().invoke(main, ['--help']); assert r.exit_code == 0, r.output; "
        "print(sorted(m for m in ('jax', 'casadi', 'h5py', 'yourdfpy', 'sympy') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_verbose_logs_files_read(run, tmp_path, small_data):
    """-v logs each dataset read once (solve reads the header, then the data: one line)."""
    args = ("solve", small_data, "--method", "linear", "--weights", "estimate", "--select", "0:6")
    r = run("-v", *args, "--out", tmp_path / "v.h5")
    assert r.exit_code == 0, r.output
    lines = [line for line in r.output.splitlines() if line.startswith("ineid: read")]
    assert lines == [f"ineid: read {small_data}: synthetic dataset of sweaty-arm, 12 x 30 frames (6 x 30 selected)"]
    r = run(*args, "--out", tmp_path / "q.h5")
    assert "ineid: read" not in r.output


def test_sigterm_leaves_no_file(tmp_path):
    """A scheduler's SIGTERM during a long write: exit 143, one line, no output and no temporary file."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "big.h5"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ineid.cli",
            "-q",
            "data",
            "generate",
            "--n-configs",
            "200000",
            "--n-frames",
            "100",
            "--out",
            out,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not any(p.name.endswith(".tmp") for p in tmp_path.iterdir()):
        time.sleep(0.1)
    assert any(p.name.endswith(".tmp") for p in tmp_path.iterdir()), "the write never started"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert err.strip().splitlines()[-1] == "ineid: terminated (SIGTERM); no partial output file was left"
    assert list(tmp_path.iterdir()) == []
