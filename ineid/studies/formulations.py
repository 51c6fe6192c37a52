"""Formulations study: the base wrench against joint torques on an arm whose drives have friction.

The paper identifies from the base wrench and claims that this avoids modelling the joints'
friction and motors, which the classical formulation (joint torques, ``tau = Y theta``) must
model. This study measures the claim on MuJoCo data (:mod:`ineid.studies.mujoco_sim`, an engine
independent of ineid's): every configuration of the arm (its unknown links drawn around the CAD
values) follows its own smooth reference while its joints have viscous, Coulomb and Stribeck
friction and rotor inertia (armature); the base wrench and the joint torques are recorded with
sensor noise. Each formulation (:data:`FORMULATIONS`) identifies the same recordings with the
linear method, weights estimated per axis:

* ``wrench``: the base wrench alone (the paper);
* ``torque``: joint torques with no friction model (the rigid-body model of eq. 1-2);
* ``torque+friction``: joint torques with viscous and Coulomb friction and armature columns
  (the classical practice; the Stribeck term stays unmodelled, as on a real arm);
* ``both``: both channels stacked, with the friction model;
* ``two-step``: FloBaRoID's chain: the links from the wrench, then the friction from the torques.

Each is also run on the same motion with *ideal drives* (the recorded torques less MuJoCo's
friction and armature torques: the same states, so the same wrench), which says what the
friction costs each formulation. The first 80 % of each configuration's frames are fitted, the
rest held out. Errors are relative; "base" is each formulation's own base parameters (those that
involve a link parameter), so their errors compare formulations only loosely; the prediction
errors on the held-out frames compare them directly.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ineid._atomic import save_figure, write_csv
from ineid.channels import BaseWrench, ChannelSet, JointTorque
from ineid.data.dataset.meta import DatasetMeta, assemble_theta
from ineid.data.dataset.schema import Dataset
from ineid.data.synthesis.sampling import sample_link_parameters
from ineid.errors import RobotModelError
from ineid.identify.results import relative_error
from ineid.identify.solve import SolveSettings, solve_dataset
from ineid.studies.mujoco_sim import JointFriction, Reference, import_mujoco, simulate

FRICTION_MODEL = {"friction": ("viscous", "coulomb"), "armature": True}
FORMULATIONS = {
    "wrench": {"use": ("wrench",)},
    "torque": {"use": ("torque",)},
    "torque+friction": {"use": ("torque",), **FRICTION_MODEL},
    "both": {"use": ("wrench", "torque"), **FRICTION_MODEL},
    "two-step": {"use": ("wrench", "torque"), **FRICTION_MODEL, "two_step": True},
}
"""Each formulation's :class:`ineid.identify.SolveSettings` fields (the linear method, weights estimated)."""

WRENCH_NOISE = (0.5, 0.5, 0.5, 0.05, 0.05, 0.05)
"""Standard deviations of the base wrench's noise (N, N*m)."""
TORQUE_NOISE = 0.05
"""Standard deviation of each joint torque's noise (N*m; N for a prismatic joint)."""
FRICTION_SHARES = {"coulomb": 0.10, "viscous": 0.10, "armature": 0.05, "stribeck": 0.5, "stribeck_velocity": 0.1}
"""The simulated drives, sized per joint on the CAD arm's motion: Coulomb friction 10 % of the RMS torque,
viscous 10 % of it at the RMS speed, armature 5 % of it at the RMS acceleration; a Stribeck excess of 50 % of
the Coulomb friction, fading over 10 % of the RMS speed."""
TERMS = {"fv": "viscous", "fc": "coulomb", "Ia": "armature"}


@dataclass(frozen=True)
class StudySize:
    """How much is simulated: configurations, seconds of motion each, frames recorded per second."""

    n_configs: int
    duration: float
    rate: float


SIZES = {"quick": StudySize(2, 6.0, 50.0), "full": StudySize(10, 30.0, 100.0)}


@dataclass(frozen=True)
class FormulationRow:
    """One formulation over the configurations: medians over configurations (and parameters or axes).

    ``base_error``/``base_error_ideal``: relative error of the base parameters that involve a link
    parameter, with friction / ideal drives. ``wrench_error``, ``torque_error``: relative RMS error
    of the prediction on the held-out frames against what a noise-free sensor reads (per axis, RMS
    over axes; the torques predicted with the formulation's own friction estimates, none if it has none).
    ``link_torque_error``: the same for the links alone against the true rigid-body torques
    (``Y_tau (theta_hat - theta)``, no noise, no friction). ``friction_error``: per term
    (``fv``, ``fc``, ``Ia``) the relative error of the identified coefficients (NaN: not modelled).
    """

    robot: str
    formulation: str
    n_params: int
    rank: int
    base_error: float
    base_error_ideal: float
    wrench_error: float
    torque_error: float
    link_torque_error: float
    fv_error: float
    fc_error: float
    ia_error: float
    failed_share: float
    seconds: float


@dataclass
class StudyData:
    """The simulated recordings of one arm: the dataset with friction, the one with ideal drives, the truth."""

    real: Dataset
    ideal: Dataset
    friction: JointFriction


def typical_friction(model, reference: Reference, duration: float) -> JointFriction:
    """Drives sized on the CAD arm's torques along ``reference`` (:data:`FRICTION_SHARES`)."""
    t = np.linspace(0.0, duration, 400)
    q, qd, qdd = (np.stack(x) for x in zip(*(reference(ti) for ti in t), strict=True))
    tau = np.sqrt(np.mean(model.joint_torques(q, qd, qdd, model.theta_cad) ** 2, axis=0))
    speed, accel = (np.sqrt(np.mean(x**2, axis=0)) for x in (qd, qdd))
    s = FRICTION_SHARES
    return JointFriction(
        viscous=s["viscous"] * tau / speed,
        coulomb=s["coulomb"] * tau,
        armature=s["armature"] * tau / accel,
        stribeck=s["stribeck"] * s["coulomb"] * tau,
        stribeck_velocity=s["stribeck_velocity"] * speed,
    )


def _reference(model, duration: float, rng: np.random.Generator) -> Reference:
    # one period over the whole recording, so the held-out frames are motion the fit has not seen
    return Reference.random(model, rng, base_frequency=1.0 / duration, harmonics=max(4, int(round(0.8 * duration))))


def simulate_study(model, size: StudySize, seed: int = 0, progress=None) -> StudyData:
    """Simulate ``size.n_configs`` configurations of ``model`` in MuJoCo (base frame sensor) and make datasets.

    Raises:
        OptionalDependencyError: MuJoCo is not installed.
        RobotModelError: a payload among the unknown links (the simulation builds moving bodies only).
    """
    import_mujoco("ineid study formulations")
    if model.payloads:
        names = ", ".join(p.link for p in model.payloads)
        raise RobotModelError(
            f"ineid study formulations simulates moving links, and {names} is a payload: "
            "choose --unknown-links among the moving links"
        )
    rng = np.random.default_rng(seed)
    friction = typical_friction(model, _reference(model, size.duration, np.random.default_rng(seed)), size.duration)
    root = np.array([1.0, 0, 0, 0, 0.01, 0, 0.01, 0, 0, 0.01])  # any body: its weight is tared away
    f = friction.per_joint(model.n_dof)
    sims, thetas = _simulate_configs(model, size, friction, root, rng, progress)
    states = {k: np.stack([getattr(s, k) for s in sims]) for k in ("q", "qd", "qdd", "time")}
    weight = np.concatenate([root[0] * model.gravity, np.cross(root[1:4], model.gravity)])
    wrench = np.stack([s.wrench_sensor for s in sims]) - weight
    tau = np.stack([s.tau for s in sims])
    ideal_tau = tau - np.stack([s.friction for s in sims]) - f["armature"] * states["qdd"]
    noise_w = rng.normal(size=wrench.shape) * np.asarray(WRENCH_NOISE)
    noise_t = rng.normal(size=tau.shape) * TORQUE_NOISE
    rec = _Recordings(int(seed), size, states, wrench, noise_w, noise_t, thetas)
    ideal = {k: np.zeros_like(v) if k != "stribeck_velocity" else v for k, v in f.items()}
    return StudyData(_dataset(model, rec, tau, f), _dataset(model, rec, ideal_tau, ideal), friction)


def _simulate_configs(model, size: StudySize, friction: JointFriction, root: np.ndarray, rng, progress):
    """``size.n_configs`` MuJoCo recordings of ``model``, each with its unknown links' parameters drawn about the
    CAD values and its own random reference, the drives' ``friction`` and the base body ``root``.

    Returns:
        ``(recordings, thetas)``: one simulation each, and its unknown parameters (n_unknown,).
    """
    sims, thetas = [], []
    for k in range(size.n_configs):
        theta = model.theta_cad.copy()
        for link in model.unknown_links:
            i = model.link_names.index(link)
            theta[10 * i : 10 * i + 10] = sample_link_parameters(model.theta_cad[10 * i : 10 * i + 10], 1, rng)[0]
        ref = _reference(model, size.duration, rng)
        sims.append(
            simulate(
                model,
                theta,
                None,
                size.duration,
                rate=size.rate,
                steps_per_sample=max(1, int(round(1000.0 / size.rate))),
                friction=friction,
                reference=ref,
                root_theta=root,
            )
        )
        thetas.append(theta[model.unknown_index])
        if progress is not None:
            progress(k + 1, size.n_configs)
    return sims, thetas


@dataclass
class _Recordings:
    """What the study's two datasets share: the seed and size, the joint states and times (C, F, ...), the sensor
    wrench less the root body's weight (C, F, 6) and the noise drawn for it and for the torques, and the unknown
    parameters of each configuration."""

    seed: int
    size: StudySize
    states: dict[str, np.ndarray]
    wrench: np.ndarray
    noise_wrench: np.ndarray
    noise_tau: np.ndarray
    thetas: list[np.ndarray]


def _dataset(model, rec: _Recordings, t: np.ndarray, drives: dict[str, np.ndarray]) -> Dataset:
    """The recordings as a dataset of base wrench and joint torques ``t`` (C, F, n_dof) of drives with the
    per-joint terms ``drives`` (the friction model's columns should find them: the ``extra_truth``)."""
    truth = {  # Stribeck is nobody's column
        f"{j}.{term}": float(drives[field][i]) for i, j in enumerate(model.joint_names) for term, field in TERMS.items()
    }
    meta = DatasetMeta.for_model(
        model,
        source="synthetic",
        seed=rec.seed,
        noise={"wrench": list(WRENCH_NOISE), "tau": [TORQUE_NOISE] * model.n_dof},
        extra_truth=truth,
        channels=ChannelSet.of(BaseWrench(), JointTorque()),
        sampling={"study": "formulations", **asdict(rec.size)},
        origin={"simulator": "mujoco", **{k: v.tolist() for k, v in drives.items()}},
    )
    states = rec.states
    return Dataset(
        meta=meta,
        q=states["q"],
        qd=states["qd"],
        qdd=states["qdd"],
        wrench=rec.wrench + rec.noise_wrench,
        theta_known=model.theta_cad[model.known_index],
        theta_unknown=np.stack(rec.thetas),
        clean={"wrench": rec.wrench, "tau": t},
        time=states["time"],
        channel_values={"tau": t + rec.noise_tau},
    )


def _base_error(res) -> float:
    """Median relative error of the base parameters that involve a link parameter (``B theta_true``: the
    dataset's ``extra_truth`` for the friction terms)."""
    ok = res.success
    if not ok.any():
        return np.nan
    b = res.base.B
    links = np.any(np.abs(b[:, : res.base.n_link_params]) > 1e-12 * np.abs(b).max(), axis=1)
    return float(np.nanmedian(relative_error(res.base_hat[ok][:, links], res.base_true[ok][:, links])))


def _axis_rel(pred: np.ndarray, ref: np.ndarray) -> float:
    """Relative RMS error per axis of (F, A) arrays, RMS over the axes."""
    rel = np.sqrt(np.mean((pred - ref) ** 2, axis=0)) / np.sqrt(np.mean(ref**2, axis=0))
    return float(np.sqrt(np.mean(rel**2)))


def _extra_torques(names, x: np.ndarray, joints, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """(F, n_dof) ``E x`` of the extra parameters ``names`` (``<joint>.fv|fc|Ia``)."""
    out = np.zeros_like(qd)
    for name, value in zip(names, x, strict=True):
        joint, term = name.rsplit(".", 1)
        j = joints.index(joint)
        out[:, j] += value * {"fv": qd[:, j], "fc": np.sign(qd[:, j]), "Ia": qdd[:, j]}[term]
    return out


def _predictions(res, data: StudyData, model) -> tuple[float, float, float]:
    """Median over configurations of the held-out wrench, torque and link-torque errors."""
    ds, held = data.real, slice(res.n_frames_fit, None)
    n_link = res.base.n_link_params
    errs = []
    for c in np.flatnonzero(res.success):
        q, qd, qdd = ds.q[c, held], ds.qd[c, held], ds.qdd[c, held]
        theta = assemble_theta(ds.meta, res.theta_hat[c, :n_link], ds.theta_known)
        truth = assemble_theta(ds.meta, ds.theta_unknown[c], ds.theta_known)
        tau_links = model.joint_torques(q, qd, qdd, theta)
        tau = tau_links + _extra_torques(
            res.param_names[n_link:], res.theta_hat[c, n_link:], model.joint_names, qd, qdd
        )
        errs.append(
            (
                _axis_rel(model.base_wrench(q, qd, qdd, theta), ds.clean["wrench"][c, held]),
                _axis_rel(tau, ds.clean["tau"][c, held]),
                _axis_rel(tau_links, model.joint_torques(q, qd, qdd, truth)),
            )
        )
    if not errs:
        return np.nan, np.nan, np.nan
    return tuple(float(v) for v in np.median(np.asarray(errs), axis=0))


def _friction_errors(res, model, friction: dict) -> dict[str, float]:
    n_link = res.base.n_link_params
    out = {}
    for term, field in TERMS.items():
        cols = [i for i, n in enumerate(res.param_names[n_link:]) if n.rsplit(".", 1)[1] == term]
        if not cols or not res.success.any():
            out[term] = np.nan
            continue
        truth = np.array(
            [friction[field][model.joint_names.index(res.param_names[n_link + i].rsplit(".", 1)[0])] for i in cols]
        )
        est = res.theta_hat[res.success][:, [n_link + i for i in cols]]
        out[term] = float(np.nanmedian(relative_error(est, truth)))
    return out


def formulations_study(
    model, size: StudySize = SIZES["quick"], seed: int = 0, formulations=tuple(FORMULATIONS), progress=None
) -> tuple[list[FormulationRow], StudyData, dict]:
    """Simulate (:func:`simulate_study`) and identify by each formulation (:func:`identify_formulations`).

    Returns:
        One :class:`FormulationRow` per formulation, the simulated data, and per formulation the
        :class:`ineid.identify.SolveResults` with friction.
    """
    total = size.n_configs + len(formulations)
    data = simulate_study(model, size, seed, None if progress is None else lambda done, _: progress(done, total))
    step = None if progress is None else lambda done, _: progress(size.n_configs + done, total)
    rows, results = identify_formulations(model, data, formulations, step)
    return rows, data, results


def identify_formulations(
    model, data: StudyData, formulations=tuple(FORMULATIONS), progress=None
) -> tuple[list[FormulationRow], dict]:
    """Identify ``data`` (with friction, then with ideal drives) by each formulation of :data:`FORMULATIONS`."""
    friction = data.friction.per_joint(model.n_dof)
    rows, results = [], {}
    for k, name in enumerate(formulations):
        settings = SolveSettings(method="linear", weights="estimate", **FORMULATIONS[name])
        t0 = time.perf_counter()
        res = solve_dataset(data.real, settings, model=model)
        seconds = time.perf_counter() - t0
        ideal = solve_dataset(data.ideal, settings, model=model)
        wrench_err, torque_err, link_err = _predictions(res, data, model)
        fr = _friction_errors(res, model, friction)
        rows.append(
            FormulationRow(
                robot=model.name,
                formulation=name,
                n_params=res.base.n_params,
                rank=res.base.rank,
                base_error=_base_error(res),
                base_error_ideal=_base_error(ideal),
                wrench_error=wrench_err,
                torque_error=torque_err,
                link_torque_error=link_err,
                fv_error=fr["fv"],
                fc_error=fr["fc"],
                ia_error=fr["Ia"],
                failed_share=float(1.0 - res.success.mean()),
                seconds=seconds,
            )
        )
        results[name] = res
        if progress is not None:
            progress(k + 1, len(formulations))
    return rows, results


def write_rows(rows: list[FormulationRow], path) -> None:
    """The study's table as CSV (atomically), one row per formulation."""
    write_csv(path, list(asdict(rows[0])), [asdict(r) for r in rows])


def plot(rows: list[FormulationRow], results: dict, data: StudyData, model, path) -> None:
    """Base-parameter errors (ideal drives, friction), held-out prediction errors, identified friction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r.formulation for r in rows]
    x = np.arange(len(rows))
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), constrained_layout=True)
    for ax, pairs, title in (
        (
            axes[0],
            (("ideal drives", "base_error_ideal"), ("friction", "base_error")),
            "base parameters: median rel. error",
        ),
        (
            axes[1],
            (
                ("wrench", "wrench_error"),
                ("joint torques", "torque_error"),
                ("links' torques vs truth", "link_torque_error"),
            ),
            "held-out prediction: rel. RMS error",
        ),
    ):
        width = 0.8 / len(pairs)
        for i, (label, attr) in enumerate(pairs):
            ax.bar(x + (i - (len(pairs) - 1) / 2) * width, [getattr(r, attr) for r in rows], width, label=label)
        ax.set_xticks(x)
        _literal(ax.set_xticklabels(names, rotation=20))
        ax.set_yscale("log")
        ax.set_title(title)
        ax.legend(fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
    friction = data.friction.per_joint(model.n_dof)
    ax = axes[2]
    with_extra = {name: res for name, res in results.items() if res.base.n_extra}
    for i, (name, res) in enumerate(with_extra.items()):
        n_link = res.base.n_link_params
        extra = res.param_names[n_link:]
        truth = np.array(
            [friction[TERMS[n.rsplit(".", 1)[1]]][model.joint_names.index(n.rsplit(".", 1)[0])] for n in extra]
        )
        ratio = res.theta_hat[res.success][:, n_link:] / truth
        pos = np.arange(len(extra)) + 0.2 * (i - (len(with_extra) - 1) / 2)
        ax.plot(
            np.broadcast_to(pos, ratio.shape).ravel(),
            ratio.ravel(),
            "o",
            ms=3,
            color=f"C{names.index(name)}",
            label=name,
        )
        ax.set_xticks(np.arange(len(extra)))
        _literal(ax.set_xticklabels(extra, rotation=60, fontsize=7))
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_title("identified / simulated friction and armature")
    if with_extra:
        ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    _literal([fig.suptitle(f"{model.name}: {data.real.n_configs} MuJoCo configurations with joint friction")])
    save_figure(fig, path)
    plt.close(fig)


def _literal(texts) -> None:
    """Joint, link and robot names are shown as written, never as mathtext."""
    for t in texts:
        t.set_parse_math(False)
