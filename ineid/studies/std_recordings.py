"""Is the std of a fit on a filtered recording honest? Simulated recordings, imported and solved, against the truth.

MuJoCo simulates ``sweaty-arm`` on a turned force/torque sensor with offsets (:mod:`ineid.studies.mujoco_sim`),
optionally with joint torques and viscous and Coulomb friction; the recording is what a lab brings (joint angles
only, the untared wrench, the joint torques), with independent noise drawn per sample at ``rate`` Hz. Each draw is
imported through :func:`ineid.data.recordings.pipeline.recording_dataset` (low-pass at ``cutoff``, the angles
differentiated) and solved with ``bias="estimate"``; ``z = (estimate - truth) / std`` per parameter group: the base
parameters of the links, the friction coefficients (their truth: what ineid's friction model fits MuJoCo's friction
torque with on the exact states, :func:`model_friction`), the sensor offsets. An honest std gives an RMS z near 1.

The ``before`` figures are the same fits' std counting every frame as an independent draw (the dataset's import
record left out: :func:`ineid.identify.time_correlation.filtered_frames` then sees independent frames).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ineid.channels.pose import SensorPose, wrench_in_sensor
from ineid.studies.mujoco_sim import JointFriction, Simulation, simulate

POSE = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
"""The sensor: 3-5 cm off the base origin, turned nearly upside down."""
POSE_TEXT = "0.03,-0.02,-0.05,3.1,0.2,0.7"
OFFSETS = np.array([1.5, -2.0, 3.0, 0.1, -0.2, 0.05])
"""The sensor's own offsets (N, N*m, sensor frame), on top of the root body's weight."""
FRICTION = JointFriction(viscous=0.05, coulomb=0.3)
"""The joints' friction of the torque scenario: ``fv`` 0.05 N*m*s/rad, ``fc`` 0.3 N*m."""
WRENCH_NOISE = np.array([0.3, 0.3, 0.3, 0.02, 0.02, 0.02])
"""White noise per sample of the sensor's axes (N, N*m)."""
ANGLE_NOISE = 2e-5
"""White noise per sample of the joint angles (rad)."""
TORQUE_NOISE = 0.02
"""White noise per sample of the joint torques (N*m)."""
FRICTION_TERMS = ("fv", "fc")


@dataclass
class Scenario:
    """A simulated recording and its truth.

    Attributes:
        model: ``sweaty-arm`` (CAD values as prior); theta: (10 n_links,) the simulated parameters;
        sim: the :class:`Simulation`; reading: (F, 6) the untared sensor's reading; bias: (6,) its offsets
        with the root body's weight; torque: joint torques recorded (with ``FRICTION`` in the joints).
    """

    model: object
    theta: np.ndarray
    sim: Simulation
    reading: np.ndarray
    bias: np.ndarray
    torque: bool

    @property
    def theta_unknown(self) -> np.ndarray:
        return self.theta[self.model.unknown_index]


LAW_ZONE = 0.05
"""rad/s: the smooth Coulomb zone of the friction law :func:`with_friction_law` puts in the joints."""


def scenario(
    torque: bool = False, duration: float = 10.0, seed: int = 11, links: dict[str, np.ndarray] | None = None
) -> Scenario:
    """Simulate ``sweaty-arm`` for ``duration`` s at 1 kHz, its unknown links' parameters drawn around CAD
    (``links``: those named given instead, ``{link: (10,) theta}``)."""
    from ineid.data.synthesis.sampling import sample_link_parameters
    from ineid.robots.load import load_robot

    model = load_robot("sweaty-arm")
    rng = np.random.default_rng(seed)
    theta = model.theta_cad.copy()
    for link in model.unknown_links:
        i = model.link_names.index(link)
        idx = np.arange(10 * i, 10 * i + 10)
        theta[idx] = sample_link_parameters(model.theta_cad[idx], 1, rng)[0]
    for link, value in (links or {}).items():
        i = model.link_names.index(link)
        theta[10 * i : 10 * i + 10] = value
    friction = FRICTION if torque else JointFriction()
    sim = simulate(model, theta, POSE, duration, friction=friction)
    x = POSE.transform()
    rt, g = sim.root_theta, model.gravity
    root = x @ np.concatenate([rt[0] * g, np.cross(rt[1:4], g)])
    bias = root + OFFSETS
    return Scenario(model, theta, sim, sim.wrench_sensor - root + bias, bias, torque)


def with_friction_law(sc: Scenario, zone: float = LAW_ZONE) -> Scenario:
    """``sc`` with MuJoCo's joint friction replaced by the law ``fv qd + fc tanh(qd / zone)`` of ``FRICTION``'s
    coefficients, one that ineid's smooth Coulomb model represents exactly: the joint torques less MuJoCo's friction
    torque plus the law's, on the same motion (the base wrench does not see how a joint's torque splits between
    actuator and friction)."""
    sim = sc.sim
    law = FRICTION.viscous * sim.qd + FRICTION.coulomb * np.tanh(sim.qd / zone)
    return dataclasses.replace(sc, sim=dataclasses.replace(sim, tau=sim.tau - sim.friction + law, friction=law))


def noisy_streams(sc: Scenario, step: int, rng: np.random.Generator | None, scale: float = 1.0):
    """The recording every ``step``-th sample (``1000 / step`` Hz), with white noise (``scale`` times the defaults;
    ``rng`` None: none)."""
    from ineid.data.recordings.pipeline import Streams

    sl = slice(None, None, step)
    t, q, w = sc.sim.time[sl], sc.sim.q[sl], sc.reading[sl]
    tau = sc.sim.tau[sl] if sc.torque else None
    if rng is not None:
        q = q + scale * ANGLE_NOISE * rng.normal(size=q.shape)
        w = w + scale * WRENCH_NOISE * rng.normal(size=w.shape)
        tau = None if tau is None else tau + scale * TORQUE_NOISE * rng.normal(size=tau.shape)
    return Streams(t, q, None, None, t, w, "simulated", tau=tau)


def _groups(names) -> dict[str, np.ndarray]:
    friction = np.array([n.rsplit(".", 1)[-1] in FRICTION_TERMS for n in names])
    return {"links": ~friction, "friction": friction}


def model_friction(sim: Simulation, zone: float = 0.0) -> np.ndarray:
    """(n_dof, 2) ``(fv, fc)`` per joint that ineid's model ``fv qd + fc c(qd)`` fits MuJoCo's friction torque
    with, on the exact states: the friction the model can represent; ``c = sign``, or ``tanh(qd / zone)`` with a
    smooth ``zone`` (rad/s). MuJoCo's dry friction is a soft constraint, smaller near rest than ``fc sign(qd)``, so
    with ``sign`` these differ from the simulated ``FRICTION`` (``fc`` 0.21-0.27 against 0.3 on the study's arm)."""
    out = np.empty((sim.qd.shape[1], 2))
    for j in range(sim.qd.shape[1]):
        qd = sim.qd[:, j]
        columns = np.stack([qd, np.tanh(qd / zone) if zone > 0 else np.sign(qd)], axis=1)
        out[j] = np.linalg.lstsq(columns, sim.friction[:, j], rcond=None)[0]
    return out


def friction_zone(sim: Simulation) -> float:
    """The smooth Coulomb zone (rad/s) whose ``fv qd + fc tanh(qd / zone)`` fits MuJoCo's friction torque best on
    the exact states (every joint one zone; a log-spaced grid refined once)."""

    def rss(zone: float) -> float:
        fr = model_friction(sim, zone)
        pred = fr[:, 0] * sim.qd + fr[:, 1] * np.tanh(sim.qd / zone)
        return float(np.sum((sim.friction - pred) ** 2))

    grid = np.geomspace(1e-4, 1.0, 41)
    best = grid[int(np.argmin([rss(z) for z in grid]))]
    fine = best * np.geomspace(0.8, 1.25, 21)
    return float(fine[int(np.argmin([rss(z) for z in fine]))])


def _zone_used(res) -> float:
    """The Coulomb zone a solve ran at (its joint-torque channel's record; 0: ``sign``)."""
    for record in res.meta.get("channels", []):
        if "friction" in record:
            return float(record.get("coulomb_zone") or 0.0)
    return 0.0


def _truth_extra(sc: Scenario, names, zone: float = 0.0) -> dict[str, float]:
    fr = model_friction(sc.sim, zone)
    joints = list(sc.model.joint_names)
    out = {}
    for n in names:
        joint, term = (n.rsplit(".", 1) + [""])[:2]
        if term in FRICTION_TERMS and joint in joints:
            out[n] = float(fr[joints.index(joint), FRICTION_TERMS.index(term)])
    return out


def z_scores(sc: Scenario, ds, res, row: int = 0) -> dict[str, np.ndarray]:
    """``(estimate - truth) / std`` per group (``links``, ``friction``, ``offsets``) of one solve's row ``row`` (a
    configuration: one noise draw of the same recording).

    The offsets' truth is the sensor's offsets plus the mean wrench of what the data cannot tell from them (the
    weight of mass that never moves), as the estimate split it: ``b + Wbar (I - T B)(theta - theta_hat)``, the
    quantity whose std :func:`ineid.identify.steps.bias_estimate` gives (``linear``: ``(I - T B) theta_hat`` is the
    prior's; the IPOPT methods take their own null-space part). The friction's truth is at the Coulomb zone the
    solve ran at (:func:`model_friction`)."""
    from ineid.identify.linear import prior_map

    base, model = res.base, sc.model
    extra = _truth_extra(sc, base.param_names[base.n_link_params :], _zone_used(res))
    theta_u = np.concatenate([sc.theta_unknown, [extra.get(n, 0.0) for n in base.param_names[base.n_link_params :]]])
    truth = base.B @ theta_u
    z = (res.base_hat[row] - truth) / res.base_std[row]
    names = base.names
    out = {k: z[m] for k, m in _groups(names).items() if m.any()}
    if res.bias_hat is not None:
        n_u = base.n_link_params
        hidden = (np.eye(len(theta_u)) - prior_map(base) @ base.B) @ (theta_u - res.theta_hat[row])
        fit = slice(0, res.n_frames_fit)
        theta = model.full_theta(hidden[:n_u], np.zeros_like(ds.theta_known))
        moved = wrench_in_sensor(
            POSE.transform(), np.asarray(model.base_wrench(ds.q[row, fit], ds.qd[row, fit], ds.qdd[row, fit], theta))
        )
        b_true = sc.bias + moved.mean(axis=0)
        out["offsets"] = (res.bias_hat[row, :6] - b_true) / res.bias_std[row, :6]
    return out


def solve_draw(
    sc: Scenario,
    step: int,
    cutoff: float,
    rng,
    scale: float = 1.0,
    method: str = "linear",
    zone: float | str = 0.0,
    two_step: bool = False,
) -> tuple[dict, dict]:
    """One noise draw imported at ``1000 / step`` Hz and ``cutoff`` Hz and solved by ``method``: the z-scores per
    group with the corrected std and with the std of independent frames. With torques, the Coulomb friction at
    ``zone`` (``SolveSettings.coulomb_zone``: 0 ``sign(qd)``, a zone in rad/s, or ``"identify"``); ``two_step``: the
    links from the wrench, then the friction from the torques (``SolveSettings.two_step``)."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.identify import SolveSettings, solve_dataset

    ds, _ = recording_dataset(
        noisy_streams(sc, step, rng, scale), sc.model, ImportSettings(sensor_pose=POSE_TEXT, cutoff=cutoff)
    )
    extra = {"friction": ("viscous", "coulomb"), "coulomb_zone": zone, "two_step": two_step} if sc.torque else {}
    settings = SolveSettings(method=method, bias="estimate", **extra)
    after = z_scores(sc, ds, solve_dataset(ds, settings, model=sc.model))
    origin = ds.meta.origin
    ds.meta = dataclasses.replace(ds.meta, origin={k: v for k, v in origin.items() if k != "import"})
    before = z_scores(sc, ds, solve_dataset(ds, settings, model=sc.model))
    ds.meta = dataclasses.replace(ds.meta, origin=origin)
    return before, after


def rms_z(draws: list[dict]) -> dict[str, float]:
    """RMS z per group over draws."""
    keys = draws[0].keys()
    return {k: float(np.sqrt(np.mean(np.concatenate([d[k] for d in draws]) ** 2))) for k in keys}
