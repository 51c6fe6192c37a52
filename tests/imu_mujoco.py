"""MuJoCo as the independent source of IMU readings: the test arm's MJCF with a site, a gyro and
an accelerometer per IMU, and its body angular acceleration (``mj_objectAcceleration``)."""

from __future__ import annotations

import re

import numpy as np

from ineid.channels.pose import SensorPose
from ineid.studies.mujoco_sim import Reference, arm_mjcf, root_link_theta


def _quat(r: np.ndarray) -> np.ndarray:
    import mujoco

    out = np.empty(4)
    mujoco.mju_mat2Quat(out, np.ascontiguousarray(r, dtype=np.float64).ravel())
    return out


def root_theta(model) -> np.ndarray:
    """The root body's own parameters (10,), from the URDF: its weight is part of what the F/T sensor reads."""
    return root_link_theta(model)


def imu_mjcf(model, mounts, theta, root_theta, timestep: float = 1e-3) -> str:
    """The arm with a site per IMU (its pose in its link) and MuJoCo's ``gyro`` and ``accelerometer``
    at each, after the F/T sensor's ``force`` and ``torque`` (sensordata 0:6)."""
    xml = arm_mjcf(model.chain, theta, root_theta, SensorPose(), timestep)
    sensors = ""
    for m in mounts:
        site = (
            f'<site name="imu_{m.name}" pos="{" ".join(repr(float(v)) for v in m.link_p_sensor)}" '
            f'quat="{" ".join(repr(float(v)) for v in _quat(m.link_R_sensor))}"/>'
        )
        body = rf'(<body name="{re.escape(m.link)}"[^>]*>)'
        xml, n = re.subn(body, lambda mt, site=site: mt.group(1) + site, xml, count=1)
        assert n == 1, m.link
        sensors += f'<gyro site="imu_{m.name}"/><accelerometer site="imu_{m.name}"/>'
    return xml.replace("</sensor>", sensors + "</sensor>")


def mujoco_imu(m, d, mounts) -> dict[str, dict[str, np.ndarray]]:
    """MuJoCo's readings now: its gyro and accelerometer, and the site's angular acceleration."""
    import mujoco

    mujoco.mj_rnePostConstraint(m, d)
    out = {}
    acc = np.empty(6)
    for k, mount in enumerate(mounts):
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"imu_{mount.name}")
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_SITE, site, acc, 1)
        out[mount.name] = {
            "gyro": d.sensordata[6 + 6 * k : 9 + 6 * k].copy(),
            "accel": d.sensordata[9 + 6 * k : 12 + 6 * k].copy(),
            "alpha": acc[:3].copy(),
        }
    return out


def simulate_imus(
    model,
    mounts,
    theta,
    root_theta,
    duration: float,
    rate: float,
    seed: int = 0,
    speed: float = 1.0,
    steps_per_sample: int = 2,
):
    """MuJoCo's forward dynamics (RK4) of the arm tracking a smooth reference (computed torque), no
    friction: per recorded sample the exact ``q, qd, qdd``, the wrench at the root (base frame, about the
    base origin, the load on the fixture: the root's weight included) and every IMU's readings."""
    import mujoco

    rng = np.random.default_rng(seed)
    ref = Reference.random(model, rng, base_frequency=0.2 * speed, harmonics=4)
    xml = imu_mjcf(model, mounts, theta, root_theta, 1.0 / (rate * steps_per_sample))
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], _ = ref(0.0)
    mass = np.empty((m.nv, m.nv))
    wn = 2 * np.pi * 5.0

    def control(mm, dd):
        q_ref, qd_ref, qdd_ref = ref(dd.time)
        mujoco.mj_fullM(mm, dd, mass)
        dd.ctrl[:] = mass @ (qdd_ref + wn**2 * (q_ref - dd.qpos) + 2 * wn * (qd_ref - dd.qvel)) + dd.qfrc_bias

    n = round(duration * rate) + 1
    q, qd, qdd, wrench, time = (
        np.empty((n, m.nv)),
        np.empty((n, m.nv)),
        np.empty((n, m.nv)),
        np.empty((n, 6)),
        np.empty(n),
    )
    readings = {mt.name: {k: np.empty((n, 3)) for k in ("gyro", "accel", "alpha")} for mt in mounts}
    mujoco.set_mjcb_control(control)
    try:
        for k in range(n):
            mujoco.mj_forward(m, d)
            time[k], q[k], qd[k], qdd[k], wrench[k] = d.time, d.qpos, d.qvel, d.qacc, -d.sensordata[:6]
            for name, kinds in mujoco_imu(m, d, mounts).items():
                for kind, v in kinds.items():
                    readings[name][kind][k] = v
            for _ in range(steps_per_sample):
                mujoco.mj_step(m, d)
    finally:
        mujoco.set_mjcb_control(None)
    return time, q, qd, qdd, wrench, readings
