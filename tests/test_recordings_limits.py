"""Recordings read safely, in bounded time and memory (:mod:`ineid.data.recordings.limits`): CSV files
(:mod:`ineid.data.recordings.csv_import`, :mod:`ineid.data.recordings.csv_rows`), ROS bags' files and metadata
(:mod:`ineid.data.recordings.bag_metadata`), values beyond any sensor, the import's rate and cut-off against the
recording, and ``--plot`` formats checked before any work."""

from __future__ import annotations

import os
import shutil
import threading
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from ineid.data.recordings import csv_rows
from ineid.data.recordings.csv_import import read_csv_streams
from ineid.data.recordings.pipeline import recording_dataset
from ineid.errors import DatasetError, InputFileError

from .bag_files import write_bag
from .test_faults import one_line, run

HEADER = "time,q1,q2,q3,q4,fx,fy,fz,mx,my,mz"
RATE = 500.0


def signals(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(time, q, wrench)`` of a smooth recording of sweaty-arm at :data:`RATE`."""
    t = np.arange(n) / RATE
    q = 0.5 * np.sin(np.pi * t[:, None] + np.arange(4))
    w = np.column_stack([np.sin(t), np.cos(t), 10 + np.sin(3 * t), 0.1 * np.sin(t), 0.2 * np.cos(t), 0.01 * t])
    return t, q, w


def csv_lines(n: int) -> list[str]:
    t, q, w = signals(n)
    return [HEADER] + [",".join(f"{v:.17g}" for v in row) for row in np.column_stack([t, q, w])]


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> Path:
    """A good 4 s recording CSV (2,000 rows)."""
    return write(tmp_path_factory.mktemp("rec") / "rec.csv", csv_lines(2000))


@pytest.fixture(scope="module")
def bag2(tmp_path_factory, model) -> Path:
    """A good ROS 2 bag folder (sqlite3, 300 joint states and wrenches)."""
    t, q, w = signals(300)
    return write_bag(tmp_path_factory.mktemp("bag") / "bag", "sqlite3", model.joint_names, t, q, t, w)


def imported(tmp_path: Path, path: Path, *args, code=1) -> str:
    """The one error line of ``ineid data import PATH``; nothing written."""
    out = tmp_path / "out.h5"
    line = one_line(run("data", "import", path, "--robot", "sweaty-arm", *args, "--out", out), code)
    assert not out.exists()
    return line


def returns_within(seconds: float, call, fifo: Path):
    """``call()``'s result, failing (not hanging) when it blocks on ``fifo``: a writer opened there frees it."""
    box = {}
    worker = threading.Thread(target=lambda: box.setdefault("result", call()), daemon=True)
    worker.start()
    worker.join(seconds)
    if worker.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # the blocked reader gets an end of file
        os.close(fd)
        worker.join(seconds)
        pytest.fail(f"blocked on the FIFO {fifo}")
    return box["result"]


# -- what is not a regular file ------------------------------------------------------------------


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_as_the_csv_or_a_file_of_a_bag_is_refused_unopened(tmp_path, bag2):
    fifo = tmp_path / "rec.csv"
    os.mkfifo(fifo)
    line = returns_within(10, lambda: imported(tmp_path, fifo), fifo)
    assert f"the CSV recording {fifo} is a FIFO (named pipe), not a regular file" in line
    for kind in ("db3", "yaml"):  # sqlite opening a FIFO never returns, not even on SIGTERM
        bag = shutil.copytree(bag2, tmp_path / f"fifo-{kind}")
        inner = next(bag.glob(f"*.{kind}"))
        inner.unlink()
        os.mkfifo(inner)
        line = returns_within(10, lambda b=bag: imported(tmp_path, b), inner)
        assert f"{inner} is a FIFO (named pipe), not a regular file" in line
    with pytest.raises(InputFileError, match="is a character device"):
        read_csv_streams("/dev/null", None)


# -- sizes: columns, lines, rows, memory -----------------------------------------------------------


def test_a_header_of_100000_columns_is_refused_at_once(tmp_path, model):
    wide = write(tmp_path / "wide.csv", [HEADER + "".join(f",c{k}" for k in range(100_000)), "0" + ",1" * 100_010])
    t0 = time.perf_counter()
    with pytest.raises(DatasetError, match="names 100,011 columns, more than the 10,000 ineid reads"):
        read_csv_streams(wide, model)
    assert time.perf_counter() - t0 < 1.0
    assert "MAX_COLUMNS" in imported(tmp_path, wide)
    # at the limit the header is read in linear time: a repeated name found at once, else the rows read
    names = [f"c{k}" for k in range(csv_rows.MAX_COLUMNS - 11)]
    twice = write(tmp_path / "twice.csv", [",".join([HEADER, *names[:-1], "c0"])])
    t0 = time.perf_counter()
    with pytest.raises(DatasetError, match="column 'c0' appears more than once in the header"):
        read_csv_streams(twice, model)
    lines = csv_lines(50)
    body = [row + ",0" * len(names) for row in lines[1:]]
    at_limit = write(tmp_path / "limit.csv", [",".join([lines[0], *names]), *body])
    assert len(read_csv_streams(at_limit, model).joint_time) == 50
    assert time.perf_counter() - t0 < 2.0


def test_long_lines_and_many_rows_are_refused_before_they_are_read(tmp_path, model, monkeypatch):
    endless = tmp_path / "endless.csv"
    endless.write_text(HEADER + "\n" + "1" * (csv_rows.MAX_LINE_CHARS + 1))  # no line end: not read whole
    with pytest.raises(DatasetError, match="line 2 is longer than 1,048,576 characters"):
        read_csv_streams(endless, model)
    lines = csv_lines(2000)
    long = write(tmp_path / "long.csv", lines[:5] + ["2" * (csv_rows.MAX_LINE_CHARS + 1)] + lines[5:])
    with pytest.raises(DatasetError, match="line 6 is longer than"):
        read_csv_streams(long, model)
    monkeypatch.setattr(csv_rows, "MAX_ROWS", 1500)
    rec = write(tmp_path / "rec.csv", lines)
    assert "about 2,000 rows, more than the 1,500 ineid reads" in imported(tmp_path, rec)
    # long first rows make the estimate low: the rows are counted too (and the arrays grow past it)
    monkeypatch.setattr(csv_rows, "BLOCK_CHARS", 8192)
    padded = write(
        tmp_path / "padded.csv",
        [lines[0] + ",note"] + [r + "," + "x" * 3000 * (k < 3) for k, r in enumerate(lines[1:])],
    )
    with pytest.raises(DatasetError, match="1,501 rows, more than the 1,500"):
        read_csv_streams(padded, model)
    monkeypatch.setattr(csv_rows, "MAX_ROWS", 10**8)
    assert np.array_equal(read_csv_streams(padded, model).q, read_csv_streams(rec, model).q)
    monkeypatch.setattr("ineid._faults.available_memory", lambda: 1000)
    line = imported(tmp_path, rec)
    assert "reading about 1,9" in line and "more than the 1000 bytes available; import a shorter part" in line


def test_peak_memory_is_a_small_multiple_of_the_arrays(tmp_path, model):
    t, q, w = signals(50_000)
    path = tmp_path / "long.csv"
    np.savetxt(path, np.column_stack([t, q, w]), delimiter=",", header=HEADER, comments="", fmt="%.17g")
    tracemalloc.start()
    try:
        streams = read_csv_streams(path, model)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    arrays = 50_000 * 11 * 8
    assert len(streams.joint_time) == 50_000 and np.array_equal(streams.wrench, w)
    # rows kept as Python lists of strings take about 12 x the arrays
    assert peak < 2 * arrays + 16 * 2**20, (peak, arrays)


# -- the two parsers ------------------------------------------------------------------------------


def test_numpy_and_row_by_row_parsing_agree(tmp_path, model, monkeypatch):
    """Two clocks in one file (empty cells), comments, blank lines, CRLF, a byte-order mark, spaces, several blocks."""
    rng = np.random.default_rng(3)
    t, q, w = signals(3000)
    out = ["# logged by the lab", HEADER + ",note"]
    for k in range(len(t)):
        joint = ",".join(f"{v:.17g}" for v in q[k]) if rng.random() < 0.7 else ",,,"
        wrench = ",".join(f"{v:.17g}" for v in w[k]) if joint == ",,," or rng.random() < 0.6 else ",,,,,"
        out.append(f"{t[k]:.17g},{joint},{wrench}," + ("" if k % 7 else " ok"))
        if k % 500 == 250:
            out += ["", "  # a comment", "   "]
    path = tmp_path / "merged.csv"
    path.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(out).encode() + b"\r\n")
    slow = []
    parse_rows = csv_rows._parse_rows
    monkeypatch.setattr(csv_rows, "_parse_rows", lambda *a: slow.append(len(a[1])) or parse_rows(*a))
    fast = read_csv_streams(path, model)
    assert slow == []  # every block by NumPy: empty cells, spaces and CRLF included
    monkeypatch.setattr(csv_rows, "BLOCK_CHARS", 5000)
    blocks = read_csv_streams(path, model)
    monkeypatch.setattr(csv_rows, "_parse_fast", lambda lines, layout: None)
    rows = read_csv_streams(path, model)
    for other in (blocks, rows):
        for key in ("joint_time", "q", "wrench_time", "wrench"):
            assert np.array_equal(getattr(fast, key), getattr(other, key)), key
    assert 1800 < len(fast.joint_time) < 2400 and 1800 < len(fast.wrench_time) < 2500
    out[1000] = out[998]  # time goes back: both parsers name the same physical line
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(DatasetError, match="time does not increase at line 1001 "):
        read_csv_streams(path, model)
    monkeypatch.undo()
    with pytest.raises(DatasetError, match="time does not increase at line 1001 "):
        read_csv_streams(path, model)


# -- values --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "cell, message",
    [
        (
            "1e308",
            "line 100, column 'fz' is 1e308, beyond 1e+09 in magnitude, more than any sensor or clock gives "
            "(ineid.data.recordings.streams.VALUE_LIMIT)",
        ),
        ("-1e309", "line 100, column 'fz' is -1e309, beyond the range of a float64"),
        ("inf", "line 100, column 'fz' is inf; values must be finite"),
    ],
)
def test_a_cell_beyond_any_sensor_is_one_line(tmp_path, cell, message):
    lines = csv_lines(300)
    cells = lines[99].split(",")
    cells[7] = cell
    lines[99] = ",".join(cells)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning from NumPy
        line = imported(tmp_path, write(tmp_path / "rec.csv", lines))
    assert message in line


def test_values_beyond_any_sensor_from_a_bag_or_the_library(tmp_path, model, rec):
    t, q, w = signals(300)
    w[120, 2] = 1e308
    bag = write_bag(tmp_path / "spike.bag", "ros1", model.joint_names, t, q, t, w)
    assert "message 120 on /ft_sensor/wrench: its wrench values hold 1e+308, beyond 1e+09" in imported(tmp_path, bag)
    streams = read_csv_streams(rec, model)
    streams.q[7, 1] = -2e9
    with pytest.raises(DatasetError, match="the joint stream's q holds -2e\\+09 at sample 7, beyond 1e\\+09"):
        recording_dataset(streams, model)


# -- ROS 2 metadata ---------------------------------------------------------------------------------


def test_bag_metadata_faults_are_one_line_naming_the_line(tmp_path, bag2):
    pwned = tmp_path / "pwned"
    qos = bag2 / "metadata.yaml"
    good = qos.read_text()
    nested = good.replace("offered_qos_profiles: []", 'offered_qos_profiles: "- history: [\\n  a: {"', 1)
    cases = [
        (
            f'rosbag2_bagfile_information: !!python/object/apply:os.system ["touch {pwned}"]\n'.encode(),
            "line 1: could not determine a constructor for the tag",
        ),
        (b"rosbag2_bagfile_information:\n  version: [\n    a: {\n", "line 4: expected the node content"),
        (b"rosbag2_bagfile_information:\n  version: 9\x00\n", "line 2: unacceptable character #x0000"),
        (b"rosbag2_bagfile_information:\n  \xff\xfe\n", "line 2: not UTF-8 text"),
        (b"just words\n", "line 1: no rosbag2_bagfile_information mapping"),
        (
            nested.encode(),
            f"line {nested[: nested.index('- history')].count(chr(10)) + 1}: the offered_qos_profiles of "
            "topic 0 are not YAML (their line 2: expected the node content",
        ),
    ]
    for k, (text, message) in enumerate(cases):
        bag = shutil.copytree(bag2, tmp_path / f"bag{k}")
        (bag / "metadata.yaml").write_bytes(text)
        line = imported(tmp_path, bag)
        assert f"{bag / 'metadata.yaml'}, {message}" in line and "restore it" in line, line
    assert not pwned.exists()  # the safe loader refused the tag: nothing ran


# -- the import's settings against the recording ------------------------------------------------------


def test_rate_cutoff_and_factors_that_leave_nothing_are_one_line(tmp_path, rec):
    assert "--rate 1e-09 Hz gives 4e-09 frames over the 3.998 s both streams cover; use from 2.5 to 50000 Hz" in (
        imported(tmp_path, rec, "--rate", "1e-9")
    )
    line = imported(tmp_path, rec, "--cutoff", "1e-9")
    assert "--cutoff 1e-09 Hz drops 3e+09 s at each end" in line
    assert "use --cutoff above 1.5 Hz (and below 225 Hz)" in line
    assert "wrench_scale must be a factor from 1e-06 to 1e+06" in imported(tmp_path, rec, "--wrench-scale", "1e300")
    line = imported(tmp_path, rec, "--torque-constant", "1e-308", "--gear-ratio", "100", code=2)
    assert "expected comma-separated numbers of magnitude 1e-06 to 1e+06" in line


def test_an_unknown_plot_format_stops_before_any_work(tmp_path):
    data, out = tmp_path / "data.h5", tmp_path / "res.h5"
    data.write_bytes(b"")  # never read: the option fails as it is parsed
    line = one_line(run("solve", data, "--plot", tmp_path / "r.xyz", "--out", out), 2)
    assert "matplotlib writes no .xyz files here; end the name with one of" in line
    assert ".png" in line and ".svg" in line
    assert not out.exists()
    line = one_line(run("study", "sensors", "--quick", "--plot", tmp_path / "s.XYZ"), 2)
    assert "no .xyz files" in line
