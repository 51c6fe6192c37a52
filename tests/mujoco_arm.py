"""An independent engine for recordings: MuJoCo simulates an arm the way a lab records it.

The arm (an ineid :class:`~ineid.robots.Chain`, rebuilt as MJCF body by body) stands on a
6-axis force/torque sensor: the root body is welded to the world, and MuJoCo's ``force``
and ``torque`` sensors at a site on the root body read the interaction between the root
and the world, in the site's frame, moment about the site's origin. The site is the
sensor pose under test. The arm follows a smooth reference by a PD law evaluated inside
the dynamics (MuJoCo's control callback, so RK4 integrates a continuous right-hand side),
with joint damping and dry friction on. A lab's recording is taken from it: the sensor
wrench plus a constant bias, and the joint angles only, at ``rate`` Hz.

MuJoCo computes the sensor from its own recursive Newton-Euler (``mj_rnePostConstraint``),
not from ineid's regressor: :func:`simulate` also returns the exact states
``(q, qd, qdd)`` so that the tests can check ineid's ``base_wrench`` against it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.params import inertial_from_theta
from ineid.sensor import SensorPose


def _quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    import mujoco  # noqa: PLC0415

    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=np.float64).ravel())
    return q


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _inertial(theta: np.ndarray) -> str:
    m, c, ic = inertial_from_theta(theta)
    full = [ic[0, 0], ic[1, 1], ic[2, 2], ic[0, 1], ic[0, 2], ic[1, 2]]
    return f'<inertial pos="{_fmt(c)}" mass="{float(m)!r}" fullinertia="{_fmt(full)}"/>'


def arm_mjcf(chain, theta: np.ndarray, root_theta: np.ndarray, sensor: SensorPose, timestep: float,
             damping: float, frictionloss: float) -> str:
    """MJCF of ``chain`` with link parameters ``theta`` (10 n_links) on a sensor at ``sensor``.

    Body frames are the URDF link frames: body ``i`` sits at the joint origin in its parent
    (``parent_R_joint, parent_p_joint``), its hinge at the body origin about ``axis``, so
    MuJoCo's ``qpos`` is ineid's ``q``. Inertials are given about the centre of mass
    (``fullinertia``), the values ineid's ``theta`` stands for.
    """
    theta = np.asarray(theta, dtype=np.float64).reshape(-1, 10)
    body = (f'<body name="{chain.root_link}">{_inertial(root_theta)}'
            f'<site name="ft" pos="{_fmt(sensor.base_p_sensor)}" quat="{_fmt(_quat(sensor.base_R_sensor))}"/>')
    close = "</body>"
    for j, th in zip(chain.joints, theta, strict=True):
        kind = "hinge" if j.type == "revolute" else "slide"
        body += (f'<body name="{j.link}" pos="{_fmt(j.parent_p_joint)}" quat="{_fmt(_quat(j.parent_R_joint))}">'
                 f'<joint name="{j.name}" type="{kind}" axis="{_fmt(j.axis)}" damping="{damping!r}" '
                 f'frictionloss="{frictionloss!r}"/>{_inertial(th)}')
        close += "</body>"
    motors = "".join(f'<motor joint="{j.name}" gear="1"/>' for j in chain.joints)
    return (
        '<mujoco model="ineid-fixture">'
        f'<option timestep="{timestep!r}" gravity="0 0 -9.81" integrator="RK4"/>'
        f"<worldbody>{body}{close}</worldbody>"
        f"<actuator>{motors}</actuator>"
        '<sensor><force site="ft"/><torque site="ft"/></sensor>'
        "</mujoco>"
    )


@dataclass(frozen=True)
class Reference:
    """A smooth joint reference: ``q(t) = q0 + sum_l a_l sin(w l t + phi_l)`` per joint."""

    q0: np.ndarray
    amplitude: np.ndarray  # (n_dof, harmonics)
    phase: np.ndarray
    base_frequency: float

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, qd, qdd)`` of the reference at time ``t``."""
        w = 2 * np.pi * self.base_frequency * np.arange(1, self.amplitude.shape[1] + 1)
        arg = w * t + self.phase
        q = self.q0 + np.sum(self.amplitude * np.sin(arg), axis=1)
        qd = np.sum(self.amplitude * w * np.cos(arg), axis=1)
        qdd = -np.sum(self.amplitude * w**2 * np.sin(arg), axis=1)
        return q, qd, qdd

    @classmethod
    def random(cls, model, rng: np.random.Generator, base_frequency: float, harmonics: int) -> Reference:
        """Within 80 % of the joint range, accelerations well inside the model's bounds."""
        lo, hi = model.q_lower, model.q_upper
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        reach = 0.8 * np.minimum(half, 1.2)
        a = rng.uniform(0.3, 1.0, (model.n_dof, harmonics)) / np.arange(1, harmonics + 1)
        a *= (reach / a.sum(axis=1))[:, None]
        return cls(mid, a, rng.uniform(0, 2 * np.pi, a.shape), base_frequency)


@dataclass
class Simulation:
    """What MuJoCo computed, at the recording instants.

    Attributes:
        time: (F,) s.
        q, qd, qdd: (F, n_dof) MuJoCo's exact states (``qpos, qvel, qacc``).
        wrench_sensor: (F, 6) the sensor's reading, no bias: the load on the sensor, in
            the sensor frame, moment about its origin (MuJoCo's sign flipped: MuJoCo gives
            the force the world exerts on the root).
        theta: (10 n_links,) the simulated links' parameters.
        root_theta: (10,) the root body's (its weight is part of what the sensor reads).
    """

    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    wrench_sensor: np.ndarray
    theta: np.ndarray
    root_theta: np.ndarray
    tau: np.ndarray | None = None
    """(F, n_dof) the actuators' torques (MuJoCo's ``qfrc_actuator``: the computed-torque law's output)."""


def simulate(model, theta: np.ndarray, sensor: SensorPose, duration: float, rate: float = 1000.0,
             steps_per_sample: int = 2, damping: float = 0.05, frictionloss: float = 0.02,
             reference: Reference | None = None, seed: int = 0) -> Simulation:
    """Simulate ``model`` with parameters ``theta`` following a reference for ``duration`` s.

    Forward dynamics by MuJoCo (RK4, ``steps_per_sample`` steps per recorded sample). The
    computed-torque law ``tau = M(q) (qdd_ref + Kp e + Kd de) + c(q, qd)`` (``e = q_ref - q``,
    5 Hz critically damped) runs in MuJoCo's control callback, so the torque is a continuous
    function of time and state; joint damping and dry friction are not compensated.
    """
    import mujoco  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    ref = reference or Reference.random(model, rng, base_frequency=0.2, harmonics=4)
    root_theta = _root_theta(model)
    xml = arm_mjcf(model.chain, theta, root_theta, sensor, 1.0 / (rate * steps_per_sample), damping, frictionloss)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], _ = ref(0.0)
    mass = np.empty((m.nv, m.nv))
    wn = 2 * np.pi * 5.0

    def control(mm, dd):
        q_ref, qd_ref, qdd_ref = ref(dd.time)
        mujoco.mj_fullM(mm, dd, mass)
        dd.ctrl[:] = mass @ (qdd_ref + wn**2 * (q_ref - dd.qpos) + 2 * wn * (qd_ref - dd.qvel)) + dd.qfrc_bias

    n = int(round(duration * rate)) + 1
    out = {k: np.empty((n, m.nv)) for k in ("q", "qd", "qdd")}
    wrench = np.empty((n, 6))
    tau = np.empty((n, m.nv))
    time = np.empty(n)
    mujoco.set_mjcb_control(control)
    try:
        for k in range(n):
            mujoco.mj_forward(m, d)
            time[k] = d.time
            out["q"][k], out["qd"][k], out["qdd"][k] = d.qpos, d.qvel, d.qacc
            wrench[k] = -d.sensordata[:6]
            tau[k] = d.qfrc_actuator
            for _ in range(steps_per_sample):
                mujoco.mj_step(m, d)
    finally:
        mujoco.set_mjcb_control(None)
    return Simulation(time, out["q"], out["qd"], out["qdd"], wrench, np.asarray(theta, dtype=np.float64), root_theta,
                      tau)


def _root_theta(model) -> np.ndarray:
    """The root body's own parameters, from the URDF (the fixture models no links welded to it)."""
    import io  # noqa: PLC0415

    import yourdfpy  # noqa: PLC0415

    from ineid.robots.urdf import _link_theta  # noqa: PLC0415

    root = model.chain.root_link
    assert model.chain.merged_links.get(root, (root,)) == (root,), "links welded to the root are not modelled"
    robot = yourdfpy.URDF.load(io.BytesIO(model.urdf_text.encode()), build_scene_graph=False, load_meshes=False,
                               build_collision_scene_graph=False, load_collision_meshes=False).robot
    return _link_theta(next(link for link in robot.links if link.name == root), "urdf")


SENSOR_POSE = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
"""The test sensor: 3-5 cm off the base origin and turned nearly upside down (roll 3.1 rad)."""
OFFSETS = np.array([1.5, -2.0, 3.0, 0.1, -0.2, 0.05])
"""The test sensor's own offsets (N, N*m, sensor frame), on top of the root body's weight."""


class LabRecording:
    """A MuJoCo run of ``sweaty-arm`` recorded like a lab records it, and the files it makes.

    The simulated arm's unknown links (``upper_arm``, ``forearm``) carry parameters drawn
    around the CAD values (so the prior is not the truth).

    Attributes:
        model: the :class:`ineid.RobotModel` (CAD values as prior).
        theta: (10 n_links,) the simulated parameters; ``theta_unknown`` those of the unknown links.
        sim: the :class:`Simulation`.
        reading: (F, 6) what the untared sensor reads: the load in its frame plus the root
            body's weight plus :data:`OFFSETS`.
        tared: (F, 6) what a sensor tared before the arm was mounted reads: no offset.
        bias: (6,) ``reading - tared``, the offsets ``--bias estimate`` must find (up to the
            weight of mass that never moves, which it cannot tell from an offset).
    """

    def __init__(self, folder, duration: float = 10.0, seed: int = 11) -> None:
        import ineid  # noqa: PLC0415
        from ineid.data.sampling import sample_link_parameters  # noqa: PLC0415

        self.folder = folder
        self.model = ineid.load_robot("sweaty-arm")
        rng = np.random.default_rng(seed)
        theta = self.model.theta_cad.copy()
        for link in self.model.unknown_links:
            idx = _link_columns(self.model, link)
            theta[idx] = sample_link_parameters(self.model.theta_cad[idx], 1, rng)[0]
        self.theta = theta
        self.theta_unknown = theta[self.model.unknown_index]
        self.pose = SENSOR_POSE
        self.sim = simulate(self.model, theta, self.pose, duration)
        x = self.pose.transform()
        rt, g = self.sim.root_theta, self.model.gravity
        root = x @ np.concatenate([rt[0] * g, np.cross(rt[1:4], g)])
        self.tared = self.sim.wrench_sensor - root
        self.bias = root + OFFSETS
        self.reading = self.tared + self.bias
        self._files: dict[str, object] = {}

    def file(self, kind: str):
        """The recording as ``csv`` (angles only, untared), ``csv-tared``, ``ros1``, ``sqlite3``, ``mcap``
        (ROS 2 folders) or ``bare-mcap``; written once. Bags list the joints in reverse order with an
        extra joint ``head_pan``; the wrench's ``frame_id`` is ``ft_sensor``."""
        if kind in self._files:
            return self._files[kind]
        from tests.bag_files import write_angles_csv, write_bag  # noqa: PLC0415

        t, q = self.sim.time, self.sim.q
        if kind in ("csv", "csv-tared"):
            path = write_angles_csv(self.folder / f"{kind}.csv", t, q, self.reading if kind == "csv" else self.tared)
        elif kind == "bare-mcap":
            import shutil  # noqa: PLC0415

            folder = self.file("mcap")
            path = self.folder / "bare.mcap"
            shutil.copy(next(folder.glob("*.mcap")), path)
        else:
            names = [*reversed(self.model.joint_names), "head_pan"]
            q_msg = np.column_stack([q[:, ::-1], np.zeros(len(q))])
            path = self.folder / ("rec.bag" if kind == "ros1" else f"rec_{kind}")
            write_bag(path, kind, names, t, q_msg, t, self.reading)
        self._files[kind] = path
        return path


def _link_columns(model, link: str) -> np.ndarray:
    i = model.link_names.index(link)
    return np.arange(10 * i, 10 * i + 10)
