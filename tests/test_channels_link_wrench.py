"""The link-wrench channel (:mod:`ineid.channels.link_wrench`): an F/T sensor on a link, placed by a pose or a
URDF frame, and a sensor that reads nothing refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid.channels import BaseWrench, LinkWrench, sensor_channel, wrench_transform
from ineid.errors import DatasetError

from .conftest import FIXTURES, random_states, rel_err


@pytest.fixture(scope="module")
def frames(model):
    return random_states(model, 40, np.random.default_rng(11))


def test_sensor_pose_on_a_link(model, frames):
    q, qd, qdd = frames
    ch = sensor_channel("upper_arm:0.01,0,0.02,0,0,1.5", model)
    assert isinstance(ch, LinkWrench) and ch.link == "upper_arm" and ch.key == "wrench_upper_arm"
    x = wrench_transform(ch.sensor.base_R_sensor, ch.sensor.base_p_sensor)
    assert rel_err(ch.rows(model, q, qd, qdd), x @ model.link_wrench_regressor(q, qd, qdd, "upper_arm")) < 1e-15
    assert rel_err(ch.predict(model, q, qd, qdd, model.theta_cad), ch.rows(model, q, qd, qdd) @ model.theta_cad) < 1e-13
    assert sensor_channel("forearm", model) == LinkWrench(key="wrench_forearm", link="forearm")
    base = sensor_channel("0,0,0.1,0,0,0", model)
    assert isinstance(base, BaseWrench) and base.sensor.xyz == (0.0, 0.0, 0.1)
    with pytest.raises(DatasetError, match="'nowhere' is not a moving link of sweaty-arm"):
        sensor_channel("nowhere:0,0,0,0,0,0", model)


def test_sensor_frame_welded_to_a_link(tmp_path):
    """A URDF frame welded to a moving link places the sensor on it; a massive known link beyond is refused."""
    text = (
        (FIXTURES / "mixed_chain.urdf")
        .read_text()
        .replace(
            '<parent link="l3"/><child link="tool"/>',
            '<parent link="l3"/><child link="ft"/></joint><link name="ft"/>'
            '<joint name="ft_fixed" type="fixed"><parent link="ft"/><child link="tool"/>',
        )
    )
    path = tmp_path / "wrist.urdf"
    path.write_text(text)
    model = ineid.load_robot(path)
    ch = sensor_channel("tcp", model)
    assert isinstance(ch, LinkWrench) and ch.link == "l3" and ch.sensor.frame == "tcp"
    with pytest.raises(DatasetError, match="link 'tool' .* is welded beyond it .* name it in --unknown-links") as info:
        sensor_channel("ft", model)
    assert "\n" not in str(info.value)
    payload = ineid.load_robot(path, unknown_links=["tool"])
    ch = sensor_channel("ft", payload)
    assert ch.link == "l3" and ch.sensor is None  # the frame sits at l3's origin


def test_a_dataset_whose_wrist_sensor_sees_nothing_is_one_line(run, tmp_path):
    """A dataset measuring the wrench on the last link (zero at every frame) is refused by solve in one line, not a
    stack error deep in the fused kernels; data generate refuses to write one."""
    import h5py

    good = tmp_path / "upper.h5"
    assert (
        run(
            "-q",
            "data",
            "generate",
            "sweaty-arm",
            "--factorial",
            "2",
            "--n-frames",
            "10",
            "--sensor-pose",
            "upper_arm",
            "--out",
            good,
        ).exit_code
        == 0
    )
    r = run(
        "-q",
        "data",
        "generate",
        "sweaty-arm",
        "--factorial",
        "2",
        "--n-frames",
        "10",
        "--sensor-pose",
        "forearm",
        "--out",
        tmp_path / "x.h5",
    )
    assert r.exit_code == 1 and "a sensor on 'forearm' reads nothing" in r.output and not (tmp_path / "x.h5").exists()
    with h5py.File(good, "r+") as f:  # the same dataset, its channel moved to the last link
        f.attrs["channels"] = f.attrs["channels"].replace('"link": "upper_arm"', '"link": "forearm"')
    r = run("-q", "solve", good, "--out", tmp_path / "r.h5")
    assert r.exit_code == 1 and "a sensor on 'forearm' reads nothing" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "r.h5").exists()
