"""Cross-cutting: the small stumbles of a first-time user, each pinned by the user's own commands (CliRunner)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def one_line_error(result, code=1):
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    return [line for line in result.output.splitlines() if line.strip()][-1]


def readme_block(heading: str) -> list[list[str]]:
    """The ``ineid`` commands of the first ``sh`` block under ``## heading`` of the README, as argv lists."""
    text = README.read_text()
    section = text[text.index(f"## {heading}") :]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    lines = block.replace("\\\n", " ").splitlines()
    return [shlex.split(line.split("#")[0])[1:] for line in lines if line.startswith("ineid ")]


# -- I: the README's train, then evaluate ------------------------------------------------------


@pytest.mark.slow  # three trainings' compilations of net6 with the physics loss: a minute, more on a busy machine
def test_readme_train_then_evaluate_sequence(run, tmp_path, monkeypatch):
    """The Learning section's commands, in order, in a fresh folder: each succeeds (evaluate used to
    refuse the evaluation.json that train had just written). Sizes are scaled down; nothing else changes.
    Then: a failed re-evaluation keeps the run's evaluation.json (atomic), and an --out file of the
    user's still needs --overwrite. (The default suite's train-then-evaluate is test_cli.py's
    test_train_evaluate_sweep.)"""
    import ineid.learn

    monkeypatch.chdir(tmp_path)
    paper = next(c for c in readme_block("Datasets") if c[-1] == "paper.h5")
    scale = {"--factorial": "5", "--n-frames": "10"}  # 25 configurations of 10 frames, not 10,000 x 100
    assert run(*[scale.get(a, a) if i and paper[i - 1] in scale else a for i, a in enumerate(paper)]).exit_code == 0
    commands = readme_block("Learning")
    assert [c[0] for c in commands] == ["train", "train", "evaluate", "sweep"], commands
    train = [("15" if a == "3000" else a) for a in commands[0]] + ["--epochs", "1", "--batch", "8"]
    assert commands[1][2] == "..." and commands[1][-1] == "--resume"
    resume = [*train, "--resume"]  # the "..." are the first line's settings
    for argv in (train, resume, commands[2]):
        r = run(*argv)
        assert r.exit_code == 0, (argv, r.output)
    own = Path("runs/s/evaluation.json")
    assert f"wrote {own}" in r.output and own.is_file()
    # the sweep line is test_cli.py's test_train_evaluate_sweep (twelve trainings: too slow here)

    before = own.read_bytes()
    evaluate = ineid.learn.evaluate

    def broken(*a, **k):
        raise RuntimeError("evaluation failed half-way")

    monkeypatch.setattr(ineid.learn, "evaluate", broken)
    with pytest.raises(RuntimeError):
        run("evaluate", "runs/s", "paper.h5")
    assert own.read_bytes() == before
    monkeypatch.setattr(ineid.learn, "evaluate", evaluate)
    r = run("evaluate", "runs/s", "paper.h5", "--select", "0:5", "--no-linear")
    assert r.exit_code == 0 and "evaluated on 5 configurations" in r.output
    assert own.read_bytes() != before
    mine = tmp_path / "mine.json"
    mine.write_text("{}")
    line = one_line_error(run("evaluate", "runs/s", "paper.h5", "--no-linear", "--out", mine))
    assert line == f"Error: {mine} exists; pass --overwrite to replace it"
    assert mine.read_text() == "{}"
    assert run("evaluate", "runs/s", "paper.h5", "--no-linear", "--out", mine, "--overwrite").exit_code == 0
    assert mine.read_text() != "{}"


def test_evaluate_keeps_overwrite_for_the_users_files(run, tmp_path):
    """Before any work: an existing --out file is refused without --overwrite and left as it was;
    without --out the run's own evaluation.json is not refused, and a failure keeps it."""
    data = tmp_path / "d.h5"
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    own = run_dir / "evaluation.json"
    own.write_text('{"old": 1}')
    mine = tmp_path / "mine.json"
    mine.write_text("{}")
    line = one_line_error(run("evaluate", run_dir, data, "--out", mine))
    assert line == f"Error: {mine} exists; pass --overwrite to replace it"
    assert mine.read_text() == "{}"
    line = one_line_error(run("evaluate", run_dir, data))  # got past the output check, to the run itself
    assert "not a finished training run" in line and own.read_text() == '{"old": 1}'


# -- J: a recording given where a dataset is expected ----------------------------------------------


def test_recordings_and_text_given_to_solve_point_to_data_import(run, tmp_path):
    csv = tmp_path / "rec.csv"
    csv.write_text("time,q1,q2,q3,q4,fx,fy,fz,mx,my,mz\n0,0,0,0,0,1,2,3,4,5,6\n")
    bag = tmp_path / "run.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)))
    mcap = tmp_path / "run.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)))
    ros2 = tmp_path / "ros2bag"
    ros2.mkdir()
    (ros2 / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    bom = tmp_path / "excel.txt"
    bom.write_text("\ufefftime;q1\n0;1\n")  # no comma, not .csv: text, not a recording
    out = tmp_path / "r.h5"
    cases = {
        csv: f"{csv} is a CSV recording, not an ineid dataset (HDF5); import it first: ineid data import {csv} "
        "--robot ROBOT --out rec.h5",
        bag: f"{bag} is a ROS 1 bag, not an ineid dataset (HDF5); import it first",
        mcap: f"{mcap} is an MCAP recording, not an ineid dataset (HDF5); import it first",
        ros2: f"{ros2} is a ROS 2 bag folder, not an ineid dataset (HDF5); import it first",
        bom: f"{bom} is a text file, not an ineid dataset (HDF5); a recording is imported with `ineid data import`",
    }
    for path, message in cases.items():
        line = one_line_error(run("solve", path, "--out", out))
        assert line.startswith(f"Error: {message}"), line
        assert not out.exists()
    assert "is a CSV recording" in one_line_error(run("data", "info", csv))
    line = one_line_error(run("export-urdf", csv, "--config", 0, "--out", tmp_path / "x.urdf"))
    assert "is a CSV recording, not an ineid results file; import it first" in line and "then solve it" in line
    junk = tmp_path / "junk.h5"
    junk.write_bytes(bytes(range(256)) * 4)  # binary, not HDF5: damaged, as before
    assert "not a readable HDF5 file" in one_line_error(run("solve", junk, "--out", out))


# -- K: data import names its robot ---------------------------------------------------------------


def test_data_import_requires_robot(run, tmp_path):
    csv = tmp_path / "rec.csv"
    csv.write_text("time,q1,q2,q3,q4,fx,fy,fz,mx,my,mz\n0,0,0,0,0,1,2,3,4,5,6\n")
    r = run("data", "import", csv, "--out", tmp_path / "rec.h5")
    assert r.exit_code == 2 and "Missing option '--robot'" in r.output, r.output
    assert not (tmp_path / "rec.h5").exists()
    assert "--robot ROBOT" in run("data", "import", "--help").output


# -- L: what -v says ------------------------------------------------------------------------------


def test_cache_hit_logs_a_saving_only_when_there_is_one(caplog):
    """JAX reports the stored compile time less the load time: -0.0003 s used to print "-0.00 s saved"."""
    import logging

    from jax import monitoring

    from ineid import cache

    cache._listen()
    caplog.set_level(logging.INFO, logger="ineid.cache")
    for duration in (-0.0003, 0.0, 0.004, 2.5):
        monitoring.record_event_duration_secs("/jax/compilation_cache/compile_time_saved_sec", duration)
    hits = [r.getMessage() for r in caplog.records if "cache hit" in r.getMessage()]
    assert hits == ["XLA compilation cache hit: loaded a compiled kernel"] * 3 + [
        "XLA compilation cache hit: loaded a compiled kernel (2.50 s of compilation saved)"
    ]
