"""Time stamps audited at import (:mod:`ineid.data.recordings.timing`), on CSV logs written the way a lab's
controller writes them: a 1 kHz log whose steps jitter from 0.7 to 8.8 ms and whose logger writes a held value
again under a new time stamp in 6 % of its rows, its two halves, time going backwards, a long gap.

The truth is an arm (``sweaty-arm``) moving along a smooth analytic trajectory, its base wrench ineid's model
at the very instants the log stamps (printed to 10 microseconds, as the lab's logs are)."""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid import DatasetError
from ineid.data import load_dataset
from ineid.data.recordings.pipeline import import_recording
from ineid.data.recordings.plausibility import check_dataset
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.timing import TimingReport, clean_interval, held_rows, nominal_interval

H = 1e-3
"""s, the log's nominal step (1 kHz)."""
AMPLITUDE = np.array([0.8, 0.5, 0.7, 0.6])
FREQUENCY = np.array([0.31, 0.47, 0.23, 0.39])
PHASE = np.array([0.3, 1.1, -0.4, 0.9])
OFFSET = np.array([0.0, 1.2, 0.0, -1.2])


def truth(model, t: np.ndarray):
    """``(q, qd, qdd, wrench)`` of the arm at times ``t`` (N,): each joint a sinusoid about a mid pose."""
    w = 2 * np.pi * FREQUENCY
    arg = w * t[:, None] + PHASE
    q = OFFSET + AMPLITUDE * np.sin(arg)
    qd = AMPLITUDE * w * np.cos(arg)
    qdd = -AMPLITUDE * w**2 * np.sin(arg)
    return q, qd, qdd, np.asarray(model.base_wrench(q, qd, qdd, model.theta_cad))


def lab_stamps(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) time stamps of a 1 kHz controller's log, in s, printed to 10 microseconds.

    Its first half on a clock the driver keeps slewing (each step 0.98 ms, every 16th 1.30 ms: a median step
    of 0.98 ms, 1020.41 Hz), its second half with its loop's wake-up jitter (steps 0.7 to 1.3 ms); cycles it
    missed in runs of 3 to 8 (steps up to about 9 ms).
    """
    k = np.arange(n + 200)
    late = np.where(k < n // 2, 0.3e-3 - 0.02e-3 * (k % 16), rng.uniform(0.0, 0.3e-3, len(k)))
    missed = np.zeros(len(k), dtype=bool)
    for start in rng.choice(np.arange(100, n - 100), 12, replace=False):
        missed[start : start + rng.integers(3, 9)] = True
    t = (k * H + late)[~missed][:n]
    return np.round(t - t[0], 5)


def write_log(path, t: np.ndarray, q: np.ndarray, wrench: np.ndarray) -> None:
    """A lab's CSV: time to 10 microseconds, angles and wrench to 17 digits, one row per controller cycle."""
    header = "time,q1,q2,q3,q4,fx,fy,fz,mx,my,mz"
    table = np.column_stack([t, q, wrench])
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=["%.5f"] + ["%.17g"] * 10)


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="module")
def jittery_log(arm, tmp_path_factory):
    """``(path, t, held, q, wrench)``: 10 s of the jittery log, 6 % of its rows holding the previous row's
    values (``q``, ``wrench``: as logged)."""
    rng = np.random.default_rng(20261128)
    t = lab_stamps(10_000, rng)
    q, _, _, wrench = truth(arm, t)
    held = np.zeros(len(t), dtype=bool)
    held[rng.choice(np.arange(1, len(t) - 1), int(0.06 * len(t)), replace=False)] = True
    held[1:] &= ~held[:-1]  # single held rows (a run holds the same value: the first one's predecessor)
    held[-1] = False
    for k in np.flatnonzero(held):
        q[k], wrench[k] = q[k - 1], wrench[k - 1]
    path = tmp_path_factory.mktemp("timing") / "jittery.csv"
    write_log(path, t, q, wrench)
    return path, t, held, q, wrench


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def test_the_nominal_rate_is_the_logs_not_its_jitters(arm, jittery_log, tmp_path):
    """Both halves of the jittery log, and the whole, give 1000 Hz; the median step of the first half is 0.98 ms
    (1020.41 Hz, what a median gives), of the second 1 ms."""
    path, t = jittery_log[:2]
    dt = np.diff(t)
    assert dt.min() < 0.75e-3 and dt.max() > 8.5e-3  # steps jitter from 0.7 to about 9 ms
    half = len(t) // 2
    assert np.isclose(np.median(np.diff(t[:half])), 0.98e-3) and np.isclose(np.median(np.diff(t[half:])), 1e-3)
    rows = path.read_text().splitlines()
    for name, part in (("first", rows[: half + 1]), ("second", [rows[0], *rows[half + 1 :]]), ("whole", rows)):
        log = tmp_path / f"{name}.csv"
        log.write_text("\n".join(part) + "\n")
        ds, summary = import_recording(log, arm, ImportSettings())
        assert summary.rate == 1000.0 and ds.time[0][1] - ds.time[0][0] == pytest.approx(1e-3, rel=1e-12)
        for s in summary.timing.streams:
            assert s.rate == 1000.0 and s.how == "snapped" and abs(s.estimate - 1000) < 0.1, (name, s)
        assert "1000 Hz nominal (" in "\n".join(summary.lines())
    h, how, estimate = nominal_interval(t)
    assert (h, how) == (1e-3, "snapped") and abs(estimate - 1e-3) < 1e-7
    # uniform stamps keep their own median step, whatever it is; a clean value needs the data within 1 %
    uniform = np.arange(100) * 0.0010203
    assert nominal_interval(uniform) == (np.median(np.diff(uniform)), "uniform", np.median(np.diff(uniform)))
    assert clean_interval(1 / 1023.0) == 1 / 1024 and clean_interval(1.07e-3) is None
    assert clean_interval(1 / 3000.5) == pytest.approx(1 / 3000) and clean_interval(3.01e-3) == 3e-3


def test_held_rows_are_dropped_and_the_frames_match_the_arm(arm, jittery_log, tmp_path, run):
    """The 6 % of rows that hold the previous sample are found (exactly those) and left out: the frames are the
    arm's to 1e-6 (qd, qdd) where kept as data they are 1e-3 to 1e-1 off; each is said and stored."""
    path, t, held = jittery_log[:3]
    ds, summary = import_recording(path, arm, ImportSettings())
    timing = summary.timing
    assert [s.held for s in timing.streams] == [int(held.sum())] * 2 and 0.05 < held.mean() < 0.07
    q, qd, qdd, w = truth(arm, ds.time[0])
    errors = rel(ds.q[0], q), rel(ds.qd[0], qd), rel(ds.qdd[0], qdd), rel(ds.wrench[0], w)
    # measured: q 9.6e-11, qd 1.0e-6, qdd 9.0e-7, wrench 7.6e-10
    assert max(errors) < 5e-6, errors
    kept, _ = import_recording(path, arm, ImportSettings(keep_repeats=True))
    q, qd, qdd, w = truth(arm, kept.time[0])
    assert rel(kept.qd[0], qd) > 1e-3 and rel(kept.qdd[0], qdd) > 1e-2  # measured 4.4e-3, 9.2e-2
    text = "\n".join(summary.lines())
    assert "joint and wrench time stamps: 1000 Hz nominal" in text and "held the previous sample: dropped" in text
    codes = [f.code for f in check_dataset(ds, arm)]
    assert codes.count("timing_jitter") == 1 and codes.count("timing_repeats") == 1  # one clock: said once
    # stored in the origin, read back, printed by data info
    ds.save(tmp_path / "jittery.h5")
    back = load_dataset(tmp_path / "jittery.h5").meta.origin["import"]["timing"]
    assert TimingReport.from_dict(back).streams == timing.streams
    r = run("data", "info", tmp_path / "jittery.h5")
    shown = " ".join(r.output.split())  # the console wraps long lines
    assert r.exit_code == 0 and "held the previous sample: dropped as missing" in shown
    assert "timing warning: 564 joint and wrench rows (5.6 %) repeat the previous sample" in shown


def test_a_bags_stamps_are_audited_the_same(arm, jittery_log, tmp_path):
    """The jittery log's first 3 s as a ROS 1 bag (nanosecond stamps): 1000 Hz, the same held rows dropped, the
    frames the arm's."""
    from tests.bag_files import write_bag

    _, t, held, q, wrench = jittery_log
    n = 3000
    path = write_bag(tmp_path / "jittery.bag", "ros1", arm.joint_names, t[:n], q[:n], t[:n], wrench[:n])
    ds, summary = import_recording(path, arm, ImportSettings(sensor_pose="0,0,0,0,0,0"))
    assert summary.rate == 1000.0 and [s.held for s in summary.timing.streams] == [int(held[:n].sum())] * 2
    q_true, qd, qdd, w = truth(arm, ds.time[0])
    errors = rel(ds.q[0], q_true), rel(ds.qd[0], qd), rel(ds.qdd[0], qdd), rel(ds.wrench[0], w)
    assert max(errors) < 5e-6, errors


def test_held_values_are_told_from_a_resting_arm_and_a_coarse_encoder():
    """Equal rows are held values only where the stream leaves them by more than its resolution allows."""
    t = np.arange(2000) * 1e-3
    moving = np.column_stack([np.sin(2 * t), np.cos(3 * t)])
    held = moving.copy()
    held[[500, 900, 901]] = held[[499, 899, 899]]  # one held row, then two
    assert np.flatnonzero(held_rows(held)).tolist() == [500, 900, 901]
    count = 2 * np.pi / 2**12  # a 12-bit encoder, on slow motion: plateaus left by one count
    coarse = np.round(0.05 * np.column_stack([np.sin(t), np.sin(0.7 * t)]) / count) * count
    assert (np.diff(coarse, axis=0) == 0).all(axis=1).sum() > 1000 and not held_rows(coarse).any()
    resting = np.vstack([np.zeros((500, 2)), 1e-3 * (t[:1500, None] ** 3) * [1.0, 2.0]])  # at rest, then moving
    assert not held_rows(resting).any()


def test_time_going_backwards_is_one_line_naming_the_row(arm, tmp_path, run):
    t = np.arange(400) * 1e-3
    q, _, _, w = truth(arm, t)
    t[200] = t[198] - 2e-3  # the clock jumps back at row 200 (line 202: the header is line 1)
    write_log(tmp_path / "back.csv", t, q, w)
    with pytest.raises(
        DatasetError, match=r"time does not increase at line 202 \(joint samples: 0.196 s after 0.199 s"
    ):
        import_recording(tmp_path / "back.csv", arm, ImportSettings())
    r = run("-q", "data", "import", tmp_path / "back.csv", "--robot", "sweaty-arm", "--out", tmp_path / "b.h5")
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and "time goes back 0.003 s" in lines[0], r.output
    # streams from a bag name the sample
    from ineid.data.recordings.pipeline import Streams, recording_dataset

    streams = Streams(t, q, None, None, None, None, "arrays", tau=w[:, :4])
    with pytest.raises(DatasetError, match="time does not increase at sample 200"):
        recording_dataset(streams, arm, ImportSettings())


def test_a_gap_longer_than_the_filters_support_is_an_error_unless_allowed(arm, tmp_path, run):
    t = np.arange(3000) * 1e-3
    t = np.concatenate([t[:1500], t[1545:]])  # 45 ms missing: longer than 3 periods of the 100 Hz cut-off
    q, qd, qdd, w = truth(arm, t)
    write_log(tmp_path / "gap.csv", t, q, w)
    with pytest.raises(DatasetError, match=r"the joint stream has a gap of 46 ms ending at t = 1.545 s, longer than"):
        import_recording(tmp_path / "gap.csv", arm, ImportSettings())
    out = tmp_path / "gap.h5"
    r = run("-q", "data", "import", tmp_path / "gap.csv", "--robot", "sweaty-arm", "--out", out)
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and "--allow-gaps" in lines[0] and not out.exists(), r.output
    r = run("data", "import", tmp_path / "gap.csv", "--robot", "sweaty-arm", "--allow-gaps", "--out", out)
    assert r.exit_code == 0 and "the largest 46 ms at 1.545 s" in r.output, r.output
    assert "ineid: warning: the joint and wrench streams have 1 gap in their samples, the largest 46 ms" in r.output
    # a cut-off whose filter spans the gap imports it; --rate overrides the nominal rate and says so
    ds, summary = import_recording(tmp_path / "gap.csv", arm, ImportSettings(cutoff=50.0, rate=500.0))
    assert summary.rate == 500.0 and "frames at 500 Hz given by --rate (nominal: joint and wrench 1000 Hz" in "\n".join(
        summary.lines()
    )
    assert "--allow-gaps" in run("data", "import", "--help").output
