"""An independent engine for recordings: MuJoCo simulates an arm the way a lab records it.

The arm (an ineid :class:`~ineid.robots.Chain`, rebuilt as MJCF body by body) stands on a
6-axis force/torque sensor: the root body is welded to the world, and MuJoCo's ``force``
and ``torque`` sensors at a site on the root body read the interaction between the root
and the world, in the site's frame, moment about the site's origin. The site is the
sensor pose. The arm follows a smooth reference by a computed-torque law evaluated inside
the dynamics (MuJoCo's control callback, so RK4 integrates a continuous right-hand side).

The joints carry what a real drive adds (:class:`JointFriction`): viscous damping (MuJoCo's
``damping``), dry friction (``frictionloss``, a soft constraint: ``fc sign(qd)`` away from
rest), rotor inertia (``armature``) and a Stribeck term that ineid's joint-torque model lacks,
applied in the control callback through ``qfrc_applied``. What a joint torque sensor (or a
motor current times its torque constant) reads is what the actuator applies, ``qfrc_actuator``
(motors of gear 1): per frame ::

    tau = Y_tau(q, qd, qdd) theta + Ia qdd + f(qd)        (f: what the friction takes, MuJoCo's own)

MuJoCo computes the sensor from its own recursive Newton-Euler (``mj_rnePostConstraint``),
not from ineid's regressor, and the torques from its own dynamics: :func:`simulate` returns
the exact states ``(q, qd, qdd)`` so that both can be checked against ineid's.

MuJoCo is imported lazily: only the tests and ``ineid study formulations`` need it
(``pip install 'ineid[mujoco]'``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ineid.channels.pose import SensorPose
from ineid.params import inertial_from_theta
from ineid.robots.mjcf import INSTALL_HINT, import_mujoco, mujoco_warnings  # noqa: F401  (importable here too)


def _quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    mujoco = import_mujoco()
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=np.float64).ravel())
    return q


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _inertial(theta: np.ndarray) -> str:
    m, c, ic = inertial_from_theta(theta)
    full = [ic[0, 0], ic[1, 1], ic[2, 2], ic[0, 1], ic[0, 2], ic[1, 2]]
    return f'<inertial pos="{_fmt(c)}" mass="{float(m)!r}" fullinertia="{_fmt(full)}"/>'


@dataclass(frozen=True)
class JointFriction:
    """What the drives of the joints add, per joint (a number for every joint, or one per joint).

    Attributes:
        viscous: ``fv`` (N*m*s/rad; N*s/m prismatic): MuJoCo's ``damping``, torque ``-fv qd``.
        coulomb: ``fc`` (N*m; N): MuJoCo's ``frictionloss``, at most ``fc`` against the motion: a soft
            constraint, ``fc sign(qd)`` once ``|qd|`` is beyond about 0.01 s times the acceleration the
            arm would have without it (MuJoCo's default ``solreffriction``), smaller nearer rest.
        armature: ``Ia`` (kg*m^2; kg): rotor inertia reflected through the gear (MuJoCo's ``armature``).
        stribeck: ``fs - fc`` (N*m; N), the breakaway torque's excess over Coulomb friction, which
            fades with speed: ``-(fs - fc) exp(-(qd / vs)^2) tanh(qd / (0.2 vs))`` (a smooth sign, so
            RK4 integrates it). ineid's joint-torque model has no such term.
        stribeck_velocity: ``vs`` (rad/s; m/s) of each joint.
    """

    viscous: np.ndarray | float = 0.0
    coulomb: np.ndarray | float = 0.0
    armature: np.ndarray | float = 0.0
    stribeck: np.ndarray | float = 0.0
    stribeck_velocity: np.ndarray | float = 0.05

    def per_joint(self, n_dof: int) -> dict[str, np.ndarray]:
        """Every field as an (n_dof,) array (checked: finite, >= 0; ``vs`` > 0)."""
        out = {}
        for name in ("viscous", "coulomb", "armature", "stribeck", "stribeck_velocity"):
            v = np.broadcast_to(np.asarray(getattr(self, name), dtype=np.float64), (n_dof,)).copy()
            if not np.all(np.isfinite(v)) or np.any(v < 0) or (name == "stribeck_velocity" and np.any(v <= 0)):
                raise ValueError(f"joint friction {name} must be finite and >= 0 (vs > 0), got {v}")
            out[name] = v
        return out

    def stribeck_torque(self, qd: np.ndarray) -> np.ndarray:
        """(..., n_dof) the Stribeck term's torque *against* the motion (what the actuator must add)."""
        qd = np.asarray(qd, dtype=np.float64)
        p = self.per_joint(qd.shape[-1])
        vs = p["stribeck_velocity"]
        return p["stribeck"] * np.exp(-((qd / vs) ** 2)) * np.tanh(qd / (0.2 * vs))

    def model_torque(self, qd: np.ndarray) -> np.ndarray:
        """(..., n_dof) ``fv qd + fc sign(qd)``: ineid's viscous + Coulomb model with the true coefficients."""
        qd = np.asarray(qd, dtype=np.float64)
        p = self.per_joint(qd.shape[-1])
        return p["viscous"] * qd + p["coulomb"] * np.sign(qd)


NO_FRICTION = JointFriction()
"""A rigid arm with ideal drives."""


def arm_mjcf(
    chain,
    theta: np.ndarray,
    root_theta: np.ndarray,
    sensor: SensorPose | None,
    timestep: float,
    friction: JointFriction = NO_FRICTION,
) -> str:
    """MJCF of ``chain`` with link parameters ``theta`` (10 n_links) on a sensor at ``sensor`` (None: the root frame).

    Bodies nest as the chain's tree (:attr:`ineid.chain.Chain.parents`), each body's children in chain order,
    so MuJoCo's joint order is the chain's. Body frames are the URDF link frames: body ``i`` sits at the joint
    origin in its parent (``parent_R_joint, parent_p_joint``), its hinge (slide, prismatic) at the body origin
    about ``axis``, so MuJoCo's ``qpos`` is ineid's ``q``. Inertials are given about the centre of mass
    (``fullinertia``), the values ineid's ``theta`` stands for. The joints get ``friction``'s damping,
    frictionloss and armature (its Stribeck term is :func:`simulate`'s).
    """
    theta = np.asarray(theta, dtype=np.float64).reshape(-1, 10)
    sensor = sensor or SensorPose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    f = friction.per_joint(len(chain.joints))
    root = chain.root_link if chain.root_link != "world" else "ineid_root"  # MuJoCo's world body owns "world"
    if len(theta) != chain.n_dof:
        raise ValueError(f"theta holds {len(theta)} links' parameters, the chain has {chain.n_dof} moving links")

    def subtree(i: int) -> str:  # body i and, nested in it, its children's (depth first: MuJoCo's qpos is q)
        j, kind = chain.joints[i], "slide" if chain.joints[i].type == "prismatic" else "hinge"
        return (
            f'<body name="{j.link}" pos="{_fmt(j.parent_p_joint)}" quat="{_fmt(_quat(j.parent_R_joint))}">'
            f'<joint name="{j.name}" type="{kind}" axis="{_fmt(j.axis)}" damping="{float(f["viscous"][i])!r}" '
            f'frictionloss="{float(f["coulomb"][i])!r}" armature="{float(f["armature"][i])!r}"/>{_inertial(theta[i])}'
            + "".join(subtree(c) for c in chain.children(i))
            + "</body>"
        )

    body = (
        f'<body name="{root}">{_inertial(root_theta)}'
        f'<site name="ft" pos="{_fmt(sensor.base_p_sensor)}" quat="{_fmt(_quat(sensor.base_R_sensor))}"/>'
        + "".join(subtree(c) for c in chain.children(-1))
    )
    close = "</body>"
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
        """Within 80 % of the joint range (at most 1.2 rad or m either side of its middle)."""
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
        tau: (F, n_dof) what each joint's actuator applies (``qfrc_actuator``; N*m, N prismatic):
            a joint torque sensor's (or a motor current's) reading, noise-free.
        friction: (F, n_dof) the part of ``tau`` that overcomes the joints' friction (MuJoCo's damping,
            frictionloss and the Stribeck term, sign flipped: ``-(qfrc_passive + qfrc_constraint +
            qfrc_applied)``), so ``tau = Y_tau theta + Ia qdd + friction``.
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
    friction: np.ndarray | None = None


DEFAULT_FRICTION = JointFriction(viscous=0.05, coulomb=0.02)
"""What :func:`simulate` puts in the joints unless told: a little damping and dry friction."""


def simulate(
    model,
    theta: np.ndarray,
    sensor: SensorPose | None,
    duration: float,
    rate: float = 1000.0,
    steps_per_sample: int = 2,
    friction: JointFriction = DEFAULT_FRICTION,
    reference: Reference | None = None,
    seed: int = 0,
    root_theta: np.ndarray | None = None,
) -> Simulation:
    """Simulate ``model`` with parameters ``theta`` following a reference for ``duration`` s.

    Forward dynamics by MuJoCo (RK4, ``steps_per_sample`` steps per recorded sample). The
    computed-torque law ``tau = M(q) (qdd_ref + Kp e + Kd de) + c(q, qd)`` (``e = q_ref - q``,
    5 Hz critically damped; ``M`` with the armature) runs in MuJoCo's control callback, so the
    torque is a continuous function of time and state; the joints' friction is not compensated.

    Args:
        model: the :class:`ineid.RobotModel` (its chain and joint ranges).
        theta: (10 n_links,) the links' parameters simulated.
        sensor: the F/T sensor's pose in the root frame (None: the root frame itself).
        duration: s; ``round(duration * rate) + 1`` samples are recorded.
        friction: the joints' friction and armature (:class:`JointFriction`).
        reference: the joint reference (default: :meth:`Reference.random` from ``seed``, 0.2 Hz, 4 harmonics).
        root_theta: (10,) the root body's parameters (default: the URDF's, :func:`root_link_theta`).

    Raises:
        OptionalDependencyError: MuJoCo is not installed.
    """
    mujoco = import_mujoco()
    rng = np.random.default_rng(seed)
    ref = reference or Reference.random(model, rng, base_frequency=0.2, harmonics=4)
    root_theta = root_link_theta(model) if root_theta is None else np.asarray(root_theta, dtype=np.float64)
    xml = arm_mjcf(model.chain, theta, root_theta, sensor, 1.0 / (rate * steps_per_sample), friction)
    with mujoco_warnings(mujoco):  # not MuJoCo's default handler, which writes MUJOCO_LOG.TXT into the working folder
        m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], _ = ref(0.0)
    control = _computed_torque(mujoco, ref, friction, m.nv)
    n = int(round(duration * rate)) + 1
    out = {k: np.empty((n, m.nv)) for k in ("q", "qd", "qdd", "tau", "friction")}
    wrench = np.empty((n, 6))
    time = np.empty(n)
    mujoco.set_mjcb_control(control)
    try:
        with mujoco_warnings(mujoco) as warnings:  # an unstable step warns: said here, not in MUJOCO_LOG.TXT
            for k in range(n):
                mujoco.mj_forward(m, d)
                time[k] = d.time
                out["q"][k], out["qd"][k], out["qdd"][k] = d.qpos, d.qvel, d.qacc
                out["tau"][k] = d.qfrc_actuator
                out["friction"][k] = -(d.qfrc_passive + d.qfrc_constraint + d.qfrc_applied)
                wrench[k] = -d.sensordata[:6]
                for _ in range(steps_per_sample):
                    mujoco.mj_step(m, d)
    finally:
        mujoco.set_mjcb_control(None)
    for message in dict.fromkeys(" ".join(w.split()) for w in warnings):
        logging.getLogger(__name__).warning("MuJoCo: %s", message)
    return Simulation(
        time,
        out["q"],
        out["qd"],
        out["qdd"],
        wrench,
        np.asarray(theta, dtype=np.float64),
        root_theta,
        out["tau"],
        out["friction"],
    )


def _computed_torque(mujoco, ref: Reference, friction: JointFriction, nv: int):
    """MuJoCo's control callback ``control(model, data)`` of :func:`simulate`: the computed-torque law towards
    ``ref`` (5 Hz, critically damped) into ``data.ctrl``, and the joints' Stribeck torque, against the motion, into
    ``data.qfrc_applied``."""
    mass = np.empty((nv, nv))
    wn = 2 * np.pi * 5.0
    drive = friction.per_joint(nv)
    excess, vs = drive["stribeck"], drive["stribeck_velocity"]
    stribeck = bool(np.any(excess > 0))

    def control(mm, dd):
        q_ref, qd_ref, qdd_ref = ref(dd.time)
        mujoco.mj_fullM(mm, dd, mass)
        dd.ctrl[:] = mass @ (qdd_ref + wn**2 * (q_ref - dd.qpos) + 2 * wn * (qd_ref - dd.qvel)) + dd.qfrc_bias
        if stribeck:  # JointFriction.stribeck_torque, against the motion
            dd.qfrc_applied[:] = -excess * np.exp(-((dd.qvel / vs) ** 2)) * np.tanh(dd.qvel / (0.2 * vs))

    return control


def root_link_theta(model) -> np.ndarray:
    """The root body's own parameters, from the URDF (ineid tares them away, MuJoCo needs them).

    Raises:
        ValueError: links are welded to the root (their inertia is not folded here): pass ``root_theta``.
    """
    import io

    import yourdfpy

    from ineid.robots.urdf import link_theta

    root = model.chain.root_link
    if model.chain.merged_links.get(root, (root,)) != (root,):
        raise ValueError(f"links are welded to the root {root!r}; give the root body's parameters (root_theta)")
    robot = yourdfpy.URDF.load(
        io.BytesIO(model.urdf_text.encode()),
        build_scene_graph=False,
        load_meshes=False,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    ).robot
    return link_theta(next(link for link in robot.links if link.name == root), "urdf")


def root_wrench(root_theta: np.ndarray, gravity: np.ndarray, sensor: SensorPose | None = None) -> np.ndarray:
    """(6,) the root body's weight as the sensor reads it (in its frame): what taring removes."""
    rt, g = np.asarray(root_theta, dtype=np.float64), np.asarray(gravity, dtype=np.float64)
    w = np.concatenate([rt[0] * g, np.cross(rt[1:4], g)])
    return w if sensor is None else sensor.transform() @ w
