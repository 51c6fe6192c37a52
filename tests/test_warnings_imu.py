"""Link IMUs in a recording are used only when named: a CSV's ``imu_<NAME>_...`` columns by ``--imu``, a bag's
Imu topics by ``--imu-topic``; otherwise the import says in one line which it found and how to use them."""

from __future__ import annotations

from ineid.data.recordings.imus import unused_imu_lines

from .test_recordings_imus import FOREARM_POSE, rec, write_csv, write_imu_bag  # noqa: F401  (rec: the fixture)


def _import(run, path, out, *extra):
    return run("data", "import", path, "--robot", "sweaty-arm", "--cutoff", "20", *extra, "--out", out)


def test_imu_columns_without_imu_are_named_not_used(rec, run, tmp_path):  # noqa: F811
    from ineid.data.dataset.read import load_dataset

    path, out = write_csv(tmp_path / "rec.csv", rec), tmp_path / "rec.h5"
    r = _import(run, path, out)
    assert r.exit_code == 0, r.output
    notes = [line.strip() for line in r.output.splitlines() if "IMU columns" in line]
    assert notes == [
        "IMU columns not used: imu_forearm_* (gyro, accel, alpha), imu_upper_arm_* (gyro); to fuse an IMU with the "
        "joints name it: --imu NAME (on the link or URDF frame NAME) or --imu NAME=LINK[:x,y,z,roll,pitch,yaw]"
    ]
    origin = load_dataset(out).meta.origin
    assert "imu" not in origin and origin["imu_unused"] == {
        "columns": {"forearm": ["gyro", "accel", "alpha"], "upper_arm": ["gyro"]}
    }


def test_imu_columns_named_are_used_the_others_noted(rec, run, tmp_path):  # noqa: F811
    from ineid.data.dataset.read import load_dataset

    path, out = write_csv(tmp_path / "rec.csv", rec), tmp_path / "rec.h5"
    r = _import(run, path, out, "--imu", f"forearm:{FOREARM_POSE}")
    assert r.exit_code == 0, r.output
    assert "IMU 'forearm' on 'forearm'" in r.output and "IMU 'upper_arm'" not in r.output
    assert "IMU columns not used: imu_upper_arm_* (gyro);" in r.output
    origin = load_dataset(out).meta.origin
    assert [m["name"] for m in origin["imu"]["mounts"]] == ["forearm"]
    # an --imu with no columns: one line naming the IMUs the file has
    r = _import(run, path, tmp_path / "x.h5", "--imu", "hand")
    assert r.exit_code != 0 and "--imu 'hand' has no readings in the recording (its IMUs: forearm, upper_arm)" in (
        r.output
    )


def test_imu_topics_not_named_are_noted(model, rec, run, tmp_path):  # noqa: F811
    from ineid.data.dataset.read import load_dataset

    bag, out = write_imu_bag(tmp_path / "rec.bag", "ros1", model, rec), tmp_path / "rec.h5"
    r = _import(run, bag, out)
    assert r.exit_code == 0, r.output
    assert "Imu topics not used: /imu/forearm, /imu/upper_arm; to fuse one with the joints name it: --imu-topic" in (
        r.output
    )
    assert "imu" not in load_dataset(out).meta.origin


def test_unused_imu_topics_line():
    (line,) = unused_imu_lines({"imu_unused": {"topics": ["/imu/forearm", "/imu/upper_arm"]}})
    assert line.startswith("Imu topics not used: /imu/forearm, /imu/upper_arm; to fuse one with the joints name it:")
    assert unused_imu_lines({}) == ()
