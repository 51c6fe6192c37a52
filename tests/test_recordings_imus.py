"""Link IMUs as data (:mod:`ineid.data.recordings.imus`): CSV and bag round trips, each stream on its own
clock; the rehearsal (``data generate --imu``); every bad input one line, no file written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.bag_files import _time

DURATION = 3.0
JOINT_RATE = 200.0
IMU_RATE = 250.0
FOREARM_POSE = "0.05,0.01,-0.1,0.3,-0.2,0.5"


def trajectory(t: np.ndarray):
    """``(q, qd, qdd)`` of a smooth motion of sweaty-arm's four joints (sums of sines), exact."""
    amp = np.array([0.5, 0.4, 0.6, 0.7])
    w = 2 * np.pi * np.array([0.6, 0.8, 0.5, 0.7])
    s, c = np.sin(w * t[:, None] + 0.3), np.cos(w * t[:, None] + 0.3)
    return amp * s, amp * w * c, -amp * w**2 * s


@pytest.fixture(scope="module")
def rec(model):
    """The arm's recording: joints and wrench at 200 Hz, a forearm IMU (all kinds, at a pose) at 250 Hz
    stamped 1.3 ms after the joints, an upper-arm gyro at 250 Hz on a clock of its own (2.1 ms later)."""
    from ineid.channels.pose import parse_sensor_pose
    from ineid.data.imu.readings import ImuMount, imu_readings

    tq = np.arange(0.0, DURATION, 1 / JOINT_RATE)
    q, qd, qdd = trajectory(tq)
    wrench = model.base_wrench(q, qd, qdd)
    mounts = [ImuMount("forearm", parse_sensor_pose(FOREARM_POSE)), ImuMount("upper_arm", kinds=("gyro",))]
    imus = {}
    for mount, offset in zip(mounts, (0.0013, 0.0021), strict=True):
        ti = offset + np.arange(0.0, DURATION - 0.01, 1 / IMU_RATE)
        imus[mount.name] = (ti, imu_readings(model, [mount], *trajectory(ti))[mount.name])
    return {"tq": tq, "q": q, "wrench": wrench, "imus": imus, "mounts": mounts}


def write_csv(path: Path, rec, columns=None, shift: float = 0.0) -> Path:
    """One CSV of three clocks: joint+wrench rows, then each IMU's rows (cells of the others empty), by time."""
    from ineid.data.recordings.imus import IMU_AXES

    n = rec["q"].shape[1]
    imu_cols = [
        (name, kind, f"imu_{name}_{a}") for name, (_, r) in rec["imus"].items() for kind in r for a in IMU_AXES[kind]
    ]
    header = [
        "time",
        *(f"q{i}" for i in range(1, n + 1)),
        "fx",
        "fy",
        "fz",
        "mx",
        "my",
        "mz",
        *(c for _, _, c in imu_cols),
    ]
    rows = [(t, [*q, *w, *[""] * len(imu_cols)]) for t, q, w in zip(rec["tq"], rec["q"], rec["wrench"], strict=True)]
    for name, (ti, r) in rec["imus"].items():
        for k, t in enumerate(ti):
            cells = [
                r[kind][k, IMU_AXES[kind].index(c.rsplit("_", 1)[1])] if nm == name else "" for nm, kind, c in imu_cols
            ]
            rows.append((t + shift, [""] * (n + 6) + cells))
    rows.sort(key=lambda r: r[0])
    keep = [i for i, h in enumerate(header) if columns is None or h in columns or not h.startswith("imu_")]
    with open(path, "w") as fh:
        fh.write(",".join(header[i] for i in keep) + "\n")
        for t, cells in rows:
            line = [repr(float(t)), *(c if c == "" else repr(float(c)) for c in cells)]
            if all(line[i] == "" for i in keep[1:]):
                continue
            fh.write(",".join(line[i] for i in keep) + "\n")
    return Path(path)


def write_imu_bag(path: Path, kind: str, model, rec, frame_ids=None) -> Path:
    """A bag (``"ros1"`` or ``"mcap"``) of joint states, the wrench, and each IMU as ``sensor_msgs/Imu`` on
    ``/imu/<name>`` (its angular acceleration on ``/imu/<name>/angular_acceleration``), every topic
    stamped on its own clock."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    t = store.types
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    start = 1_700_000_000 * 10**9
    v3 = t["geometry_msgs/msg/Vector3"]

    def header(ns, frame, k):
        return t["std_msgs/msg/Header"](stamp=_time(store, ns), frame_id=frame, **({"seq": k} if ros1 else {}))

    events = []  # (ns, topic, msgtype, message factory)
    for k, s in enumerate(rec["tq"]):
        ns = start + round(s * 1e9)
        events.append(
            (
                ns,
                "/joint_states",
                "sensor_msgs/msg/JointState",
                lambda ns=ns, k=k: t["sensor_msgs/msg/JointState"](
                    header=header(ns, "", k),
                    name=list(model.joint_names),
                    position=np.ascontiguousarray(rec["q"][k]),
                    velocity=np.zeros(0),
                    effort=np.zeros(0),
                ),
            )
        )
        f, m = rec["wrench"][k, :3], rec["wrench"][k, 3:]
        events.append(
            (
                ns,
                "/ft/wrench",
                "geometry_msgs/msg/WrenchStamped",
                lambda ns=ns, k=k, f=f, m=m: t["geometry_msgs/msg/WrenchStamped"](
                    header=header(ns, "", k),
                    wrench=t["geometry_msgs/msg/Wrench"](
                        force=v3(x=f[0], y=f[1], z=f[2]), torque=v3(x=m[0], y=m[1], z=m[2])
                    ),
                ),
            )
        )
    cov_none = np.r_[-1.0, np.zeros(8)]
    for name, (ti, r) in rec["imus"].items():
        frame = (frame_ids or {}).get(name, name)
        for k, s in enumerate(ti):
            ns = start + round(s * 1e9)
            gyro = r.get("gyro", np.zeros((len(ti), 3)))[k]
            acc = r.get("accel", np.zeros((len(ti), 3)))[k]
            events.append(
                (
                    ns,
                    f"/imu/{name}",
                    "sensor_msgs/msg/Imu",
                    lambda ns=ns, k=k, g=gyro, a=acc, fr=frame, r=r: t["sensor_msgs/msg/Imu"](
                        header=header(ns, fr, k),
                        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                        orientation_covariance=cov_none,
                        angular_velocity=v3(x=g[0], y=g[1], z=g[2]),
                        angular_velocity_covariance=np.zeros(9) if "gyro" in r else cov_none,
                        linear_acceleration=v3(x=a[0], y=a[1], z=a[2]),
                        linear_acceleration_covariance=np.zeros(9) if "accel" in r else cov_none,
                    ),
                )
            )
            if "alpha" in r:
                al = r["alpha"][k]
                ns2 = ns + 400_000  # the angular-acceleration sensor on a clock of its own
                events.append(
                    (
                        ns2,
                        f"/imu/{name}/angular_acceleration",
                        "geometry_msgs/msg/Vector3Stamped",
                        lambda ns=ns2, k=k, al=al, fr=frame: t["geometry_msgs/msg/Vector3Stamped"](
                            header=header(ns, fr, k), vector=v3(x=al[0], y=al[1], z=al[2])
                        ),
                    )
                )
    events.sort(key=lambda e: e[0])
    with writer:
        conns = {}
        for ns, topic, msgtype, make in events:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], ns, serialize(make(), msgtype))
    return path


def check_fused(ds, tol: float = 2e-3) -> None:
    """The imported qd, qdd match the exact motion at the frames (the filter at 20 Hz barely touches a 1 Hz motion)."""
    _, qd, qdd = trajectory(ds.time[0])
    assert np.abs(ds.qd[0] - qd).max() < tol * np.abs(qd).max()
    assert np.abs(ds.qdd[0] - qdd).max() < 10 * tol * np.abs(qdd).max()


# -- round trips ---------------------------------------------------------------------------------


def test_csv_round_trip_three_clocks(model, rec, run, tmp_path):
    from ineid.data.dataset.read import load_dataset

    path = write_csv(tmp_path / "rec.csv", rec)
    out = tmp_path / "rec.h5"
    r = run(
        "data",
        "import",
        path,
        "--robot",
        "sweaty-arm",
        "--cutoff",
        "20",
        "--imu",
        f"forearm:{FOREARM_POSE}",
        "--imu",
        "upper_arm",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "IMU 'forearm' on 'forearm'" in r.output and "IMU 'upper_arm' on 'upper_arm'" in r.output
    assert "fused" in r.output and "gyro bias" in r.output
    ds = load_dataset(out)
    imu = ds.meta.origin["imu"]
    assert {m["name"]: m["kinds"] for m in imu["mounts"]} == {
        "forearm": ["gyro", "accel", "alpha"],
        "upper_arm": ["gyro"],
    }
    assert np.allclose(imu["mounts"][0]["sensor"]["xyz"], [0.05, 0.01, -0.1])
    assert "estimation" in imu and not any("imu" in k for k in ds.meta.channels.keys)
    check_fused(ds)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bag_round_trip_imu_topics(model, rec, run, tmp_path, kind):
    from ineid.data.dataset.read import load_dataset

    bag = write_imu_bag(
        tmp_path / ("rec.bag" if kind == "ros1" else "rec"), kind, model, rec, frame_ids={"forearm": "forearm_imu"}
    )
    out = tmp_path / "rec.h5"
    r = run(
        "data",
        "import",
        bag,
        "--robot",
        "sweaty-arm",
        "--imu-topic",
        "/imu/forearm",
        "--imu-topic",
        "/imu/upper_arm",
        "--imu",
        f"forearm_imu=forearm:{FOREARM_POSE}",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "low-pass at 20 Hz (the upper bound, 0.1 x the rate: angular-acceleration sensors measure qdd" in r.output
    ds = load_dataset(out)
    mounts = {m["name"]: m for m in ds.meta.origin["imu"]["mounts"]}
    assert mounts["forearm_imu"]["link"] == "forearm" and mounts["forearm_imu"]["kinds"] == ["gyro", "accel", "alpha"]
    assert mounts["upper_arm"]["kinds"] == ["gyro"]  # its accelerometer marked "not measured"
    assert ds.meta.origin["imu_topics"]["/imu/forearm/angular_acceleration"] == len(rec["imus"]["forearm"][0])
    check_fused(ds)


def test_generate_imu_rehearsal_round_trip(model, run, tmp_path):
    from ineid.data.dataset.read import load_dataset

    out = tmp_path / "g.h5"
    r = run(
        "data",
        "generate",
        "--n-configs",
        "1",
        "--n-frames",
        "400",
        "--frame-mode",
        "fourier",
        "--base-frequency",
        "0.25",
        "--imu",
        "upper_arm",
        "--imu",
        f"forearm:{FOREARM_POSE}",
        "--encoder-bits",
        "16",
        "--noise",
        "gyro=0.002,alpha=0.05,force=0.01",
        "--gyro-bias",
        "0.01",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    ds = load_dataset(out)
    assert set(ds.clean) >= {"q", "qd", "qdd", "wrench"}
    imu = ds.meta.sampling["imu"]
    assert imu["encoder_bits"] == 16 and [m["name"] for m in imu["mounts"]] == ["upper_arm", "forearm"]
    step = 2 * np.pi / 2**16
    assert np.abs(ds.q - ds.clean["q"]).max() < 2 * step  # quantized and filtered encoders
    rel = np.sqrt(np.mean((ds.qd - ds.clean["qd"]) ** 2) / np.mean(ds.clean["qd"] ** 2))
    assert rel < 0.02, rel


# -- bad input: one line each, no file ------------------------------------------------------------


def _one_line_no_file(r, out: Path, *words: str) -> None:
    assert r.exit_code != 0
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, r.output
    for w in words:
        assert w in lines[0], r.output
    assert not out.exists()


def test_bad_imu_inputs_are_one_line_and_write_nothing(model, rec, run, tmp_path):
    good = write_csv(tmp_path / "good.csv", rec)
    out = tmp_path / "x.h5"
    imp = ("-q", "data", "import")
    # an IMU on a link not in the model, named by --imu (columns no --imu names are not read: test_warnings_imu)
    _one_line_no_file(run(*imp, good, "--robot", "sweaty-arm", "--imu", "gripper", "--out", out), out, "gripper")
    # a missing axis column: _wy without _wx
    cols = {"imu_upper_arm_wy", "imu_upper_arm_wz"}
    _one_line_no_file(
        run(*imp, write_csv(tmp_path / "m.csv", rec, columns=cols), "--robot", "sweaty-arm", "--out", out),
        out,
        "imu_upper_arm_wx",
    )
    # a pose that does not parse
    _one_line_no_file(run(*imp, good, "--robot", "sweaty-arm", "--imu", "forearm:1,2", "--out", out), out, "forearm")
    # an IMU stream that does not overlap the joints in time
    _one_line_no_file(
        run(
            *imp,
            write_csv(tmp_path / "late.csv", rec, shift=100.0),
            "--robot",
            "sweaty-arm",
            "--imu",
            "upper_arm",
            "--out",
            out,
        ),
        out,
        "overlap",
    )
    # a gyro whose readings contradict the encoders: the forearm IMU declared at the link origin, unturned
    _one_line_no_file(
        run(*imp, good, "--robot", "sweaty-arm", "--cutoff", "20", "--imu", "forearm", "--out", out), out, "forearm"
    )
    # --imu-topic on a CSV, --imu-delay without IMUs
    _one_line_no_file(run(*imp, good, "--robot", "sweaty-arm", "--imu-topic", "/imu", "--out", out), out, "CSV")
    # the rehearsal on independent frames, IMU noise without --imu
    gen = ("data", "generate", "--n-configs", "1", "--n-frames", "50")
    r = run(*gen, "--imu", "forearm", "--out", out)
    assert r.exit_code == 2 and "fourier" in r.output and not out.exists()
    r = run(*gen, "--frame-mode", "fourier", "--noise", "gyro=0.01", "--out", out)
    assert r.exit_code == 2 and "--imu" in r.output and not out.exists()


def test_imu_delay_shifts_the_imu_clock(model, rec):
    """IMU stamps 4 ms late: --imu-delay 0.004 puts them back (the library call, no file)."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.data.recordings.streams import ImuStream, Streams

    imus = tuple(ImuStream(name, t + 0.004, r) for name, (t, r) in rec["imus"].items())
    streams = Streams(rec["tq"], rec["q"], None, None, rec["tq"], rec["wrench"], "arrays", imus=imus)
    settings = ImportSettings(cutoff=20.0, imus=(f"forearm:{FOREARM_POSE}",), imu_delay=0.004)
    ds, summary = recording_dataset(streams, model, settings)
    assert ds.meta.origin["imu"]["delay"] == 0.004 and any("0.004 s late" in line for line in summary.lines())
    check_fused(ds)
