"""Excitation design as a lab runs it: ``ineid excite`` on six arms, its time and what the design gains.

For UR5, Panda (fingers locked), xArm7, Kinova (Jaco j2s6s200), SO-101 (gripper locked) from
example-robot-data and the built-in ``sweaty-arm``, every moving link unknown (sweaty-arm: its
default ``upper_arm``, ``forearm``), ``ineid excite ROBOT --duration 10 --floor F --workspace BOX
--out traj.csv`` with self-collision on (the default) and the command's other defaults, each arm's
floor and box in :data:`ARMS` (the floor at the mounting plane, a box a little larger than the reach:
what a lab would give). Each command runs in its own process (``python -m ineid.cli``), and the
figures are read from the ``traj.json`` it writes (its ``design`` record): what a user gets.

Table 1, design (one row per arm):

* ``first s``: wall time of the process with a new, empty ``INEID_CACHE_DIR``: deriving the robot's
  code, any compilation, the design and writing the files;
* ``warm s``: the same command again with that cache;
* ``converged``: starts that IPOPT solved (its ``converged`` flag; not at an iteration cap, not unsafe)
  of the starts run;
* ``answer``: what the command returned: the optimized design, or the best random candidate when
  the optimization did not beat it; ``candidates``: random feasible trajectories compared;
* ``std ratio med``, ``min``: over the base parameters, the expected standard deviation (Cramer-Rao,
  the design's wrench noise) of the best random candidate divided by the returned trajectory's: the
  median and the smallest; the target is a median of at least 2 on every arm (a line names each
  arm that misses it); ``typical``: the median of the same ratio against the typical random candidate
  (the one with the median criterion, the record's ``random_fourier``).

Table 2, the excitation bar (one block per arm), over the samples at 100 Hz of the 10 s:

* ``designed``: the returned trajectory (coefficients from ``traj.json``);
* ``random Fourier``: random Fourier trajectories of the same period, harmonics and joint bounds
  (:func:`random_fourier`: the median of each column over ``--random`` draws), their amplitudes scaled
  down about their mean pose until every frame origin stays above the floor and in the box at every
  sample (self-collision not checked: it leaves them more room than the design has; a draw that keeps
  neither after ``--tries`` is marked);

with the columns: the scaled condition number of the samples' regressor; the median expected relative
standard deviation of the base parameters; the expected workspace wrench-prediction error,
``sqrt(mean_k trace(Phi_k C Phi_k^T) / A)`` over ``--states`` independent uniform states within the
joint bounds (``model_uniform_states``), ``Phi_k`` the scaled regressor of :mod:`ineid.excite.criterion`
(each axis divided by its noise, so the figure is the predicted wrench's standard deviation in units of
the sensor noise) and ``C = (sum Phi^T Phi)^-1`` of the trajectory's samples; and the identification
error, the median relative error of the base parameters (CAD truth; those whose CAD value is zero left
out), linear least squares on simulated data along the trajectory with the noise study's reference
noise (wrench 0.5 N, 0.05 N*m; qd 0.01 rad/s, qdd 0.1 rad/s^2 in the regressor's states), over
``--draws`` noise draws. The regressors here are evaluated through CasADi (no compilation); the
designed row's condition number and median relative std are checked against the record's (the
largest relative difference is printed).
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data.synthesis.sampling import model_uniform_states
from ineid.data.synthesis.trajectory import FourierTrajectory, read_trajectory_json, state_matrices
from ineid.excite.criterion import design_base, design_noise, design_phi, scaled_regressor
from ineid.excite.settings import ExcitationSettings
from ineid.robots.kinematics import frame_points, welded_frames
from ineid.studies.noise import REFERENCE_NOISE

EXAMPLES = "cmeel.prefix/share/example-robot-data/robots"
BAR_ROWS = ("designed", "random")


@dataclass(frozen=True)
class Arm:
    """One arm: its URDF under example-robot-data (or a built-in name), locked joints, floor and box (m)."""

    robot: str
    floor: float
    workspace: tuple[float, float, float, float, float, float]
    locked: dict[str, float] = field(default_factory=dict)

    def path(self) -> str:
        if "/" not in self.robot:
            return self.robot
        return str(importlib.metadata.distribution("example-robot-data").locate_file(EXAMPLES) / self.robot)

    def cli_args(self) -> list[str]:
        args = [self.path()]
        for joint, value in self.locked.items():
            args += ["--lock", f"{joint}={value:g}"]
        box = ",".join(f"{v:g}" for v in self.workspace)
        return [*args, "--floor", f"{self.floor:g}", "--workspace", box]

    def load(self):
        return ineid.load_robot(self.path(), locked_joints=self.locked or None)


# The floor at each base's mounting plane (z = 0 of the base frame; sweaty-arm's first joint sits 0.4 m
# above it); the box the reach of 20,000 uniform states (every frame origin) plus about 0.1 m, the box's
# bottom below the floor (the floor bounds z).
ARMS = {
    "ur5": Arm("ur_description/urdf/ur5_robot.urdf", 0.0, (-1.05, 1.05, -1.05, 1.05, -0.1, 1.15)),
    "panda": Arm(
        "panda_description/urdf/panda.urdf",
        0.0,
        (-1.05, 1.05, -1.05, 1.05, -0.1, 1.4),
        {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0},
    ),
    "xarm7": Arm("xarm_description/urdf/xarm7.urdf", 0.0, (-0.9, 0.9, -0.9, 0.9, -0.1, 1.15)),
    "kinova": Arm("kinova_description/robots/kinova.urdf", 0.0, (-1.1, 1.1, -1.1, 1.1, -0.1, 1.4)),
    "so101": Arm("so_arm_description/urdf/so101.urdf", 0.0, (-0.45, 0.6, -0.55, 0.55, -0.1, 0.65), {"gripper": 0.0}),
    "sweaty-arm": Arm("sweaty-arm", 0.0, (-0.65, 0.65, -0.25, 0.85, -0.25, 1.05)),
}


def run_excite(arm: Arm, out: Path, cache: Path, extra: list[str]) -> tuple[float, str | None]:
    """Wall seconds of ``ineid excite`` in a new process with ``cache`` as its cache, and its last line on failure."""
    cmd = [sys.executable, "-m", "ineid.cli", "excite", *arm.cli_args(), "--duration", "10", "--out", str(out)]
    env = dict(os.environ, INEID_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    proc = subprocess.run([*cmd, *extra, "--overwrite"], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    out.with_suffix(".log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
        return seconds, lines[-1] if lines else f"exit {proc.returncode}"
    return seconds, None


def converged(start: dict) -> bool:
    """The record's flag; where a record has none, IPOPT's status says it solved."""
    if "converged" in start:
        return bool(start["converged"])
    return start["status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def design_figures(design: dict) -> dict:
    """Answer, candidates, converged starts, and the best random candidate's std over the answer's (median, min)."""
    best = design.get("best_random") or design["random_fourier"]  # a record without candidates: the median start
    returned = design["optimized"]  # the returned trajectory's evaluation, whichever the answer
    ratio = np.asarray(best["std"]) / np.asarray(returned["std"])
    typical = np.asarray(design["random_fourier"]["std"]) / np.asarray(returned["std"])
    starts = design["starts"]
    return {
        "answer": design.get("answer", "optimized"),
        "candidates": design.get("n_candidates", len(starts)),
        "converged": sum(converged(s) for s in starts),
        "starts": len(starts),
        "ratio_median": float(np.median(ratio)),
        "ratio_min": float(np.min(ratio)),
        "typical_median": float(np.median(typical)),
    }


# -- the excitation bar ---------------------------------------------------------------------------------


def scaled_phi(model, base, sigma, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
    """``(Psi, Phi)``: the base-wrench regressor (F, 6, 10 n_links) through CasADi and its scaled columns (F, 6, r)."""
    n = len(q)
    psi = np.array(model.casadi_regressor.map(n)(q.T, qd.T, qdd.T)).reshape(6, n, -1).transpose(1, 0, 2)
    return psi, scaled_regressor(psi, base, sigma)


def random_fourier(model, arm: Arm, design: FourierTrajectory, rng, tries: int, rate: float):
    """A random Fourier trajectory of ``design``'s period, harmonics and duration within the joint bounds less the
    margin, at rest at both ends, each joint scaled to its tightest bound on a grid 4x the rate, its mean drawn
    where its swing fits; where a frame origin leaves the floor or box at a sample, its amplitudes are scaled
    by 0.85 about the mean (at most 16 times), else drawn again (at most ``tries`` draws).

    Returns:
        ``(trajectory, kept)``: ``kept`` False when no draw kept the floor and box (the last draw, unscaled).
    """
    margin = ExcitationSettings.margin
    lo, hi = np.asarray(model.q_lower, float), np.asarray(model.q_upper, float)
    lo, hi = lo + margin * (hi - lo), hi - margin * (hi - lo)
    h, f0 = design.harmonics, design.base_frequency
    orders = np.arange(1, h + 1)
    grid = np.arange(int(4 * rate / f0)) * (1.0 / (4 * rate))
    pq, pqd, pqdd = state_matrices(grid, f0, h)
    welded = welded_frames(model.urdf_text, model.chain, model.locked_joints)
    box = np.asarray(arm.workspace).reshape(3, 2)

    def keeps(traj: FourierTrajectory) -> bool:
        pts = frame_points(model.chain, traj.sample(rate)[1], welded)
        return bool(pts[..., 2].min() >= arm.floor and np.all((pts >= box[:, 0]) & (pts <= box[:, 1])))

    for _ in range(tries):
        a = rng.uniform(-1, 1, (model.n_dof, h))
        b = rng.uniform(-1, 1, (model.n_dof, h))
        a -= a.mean(1, keepdims=True)  # qd(0) = sum a = 0
        b -= np.outer(b @ orders, orders) / (orders @ orders)  # qdd(0) ~ sum l b_l = 0
        c = np.concatenate([a, b], axis=1).T
        e, v, acc = pq @ c, pqd @ c, pqdd @ c
        swing = e.max(0) - e.min(0)
        s = np.minimum.reduce(
            [model.qd_max / np.abs(v).max(0), model.qdd_max / np.abs(acc).max(0), (hi - lo) / swing]
        ) * (1 - 1e-9)
        q_lo, q_hi = lo - s * e.min(0), hi - s * e.max(0)
        q0 = q_lo + (q_hi - q_lo) * rng.random(model.n_dof)
        first = FourierTrajectory(f0, q0, a * s[:, None], b * s[:, None], design.duration, design.joint_names)
        for k in range(17):  # scaled about the mean pose, within the joint bounds still
            traj = FourierTrajectory(f0, q0, first.a * 0.85**k, first.b * 0.85**k, first.duration, first.joint_names)
            if keeps(traj):
                return traj, True
    return first, False


def identification_error(model, base, sigma, q, qd, qdd, psi, rng, draws: int) -> float:
    """Median relative error of the base parameters (CAD truth), least squares on noisy data along the states."""
    theta = model.theta_cad
    wrench = psi @ theta
    known = np.asarray(model.known_index, dtype=int)
    noise_w = np.array([REFERENCE_NOISE["force"]] * 3 + [REFERENCE_NOISE["moment"]] * 3)
    nonzero = np.abs(base.cad) > 1e-12 * base.scales  # a relative error of a zero is undefined
    errors = []
    for _ in range(draws):
        y = wrench + noise_w * rng.standard_normal(wrench.shape)
        qd_n = qd + REFERENCE_NOISE["qd"] * rng.standard_normal(qd.shape)
        qdd_n = qdd + REFERENCE_NOISE["qdd"] * rng.standard_normal(qdd.shape)
        psi_n, phi_n = scaled_phi(model, base, sigma, q, qd_n, qdd_n)
        y = (y - psi_n[..., known] @ theta[known]) / sigma
        x = np.linalg.lstsq(phi_n.reshape(-1, base.rank), y.ravel(), rcond=None)[0]
        errors.append(np.abs(x * base.scales - base.cad)[nonzero] / np.abs(base.cad[nonzero]))
    return float(np.median(errors))


def wrench_prediction_error(phi_states: np.ndarray, cov: np.ndarray) -> float:
    """``sqrt(mean_k trace(Phi_k C Phi_k^T) / A)``: the RMS over states and axes of the predicted wrench's std
    (units of the noise) under the parameter covariance ``C`` (r, r); ``phi_states`` (K, A, r)."""
    chol = np.linalg.cholesky(cov)
    return float(np.sqrt(np.mean(np.sum((phi_states @ chol) ** 2, axis=(1, 2)) / phi_states.shape[1])))


def bar_row(model, base, sigma, traj: FourierTrajectory, phi_states: np.ndarray, rng, rate: float, draws: int):
    """(scaled cond, median rel std, wrench-prediction error, identification error) of ``traj``'s samples."""
    _, q, qd, qdd = traj.sample(rate)
    psi, phi = scaled_phi(model, base, sigma, q, qd, qdd)
    a = phi.reshape(-1, base.rank)
    sv = np.linalg.svd(a, compute_uv=False)
    cov = np.linalg.inv(a.T @ a)
    wrench = wrench_prediction_error(phi_states, cov)
    ident = identification_error(model, base, sigma, q, qd, qdd, psi, rng, draws)
    return np.array([sv[0] / sv[-1], np.median(np.sqrt(np.diag(cov))), wrench, ident])


def excitation_bar(name: str, arm: Arm, traj: FourierTrajectory, design: dict, args) -> dict:
    """The designed trajectory's row and the random Fourier ones' medians (and how many draws missed the limits)."""
    model = arm.load()
    base, sigma = design_base(model), design_noise()
    rng = np.random.default_rng(args.seed)
    q, qd, qdd = model_uniform_states(model, args.states, rng)
    phi_states = design_phi(model, base, sigma, q, qd, qdd)
    rate = float(design["rate"])
    designed = bar_row(model, base, sigma, traj, phi_states, rng, rate, args.draws)
    opt = design["optimized"]
    check = max(
        abs(designed[0] / opt["condition_number"] - 1),
        abs(designed[1] / np.median(opt["rel_std"]) - 1),
    )
    rows, missed = [], 0
    for _ in range(args.random):
        rnd, kept = random_fourier(model, arm, traj, rng, args.tries, rate)
        missed += not kept
        rows.append(bar_row(model, base, sigma, rnd, phi_states, rng, rate, args.draws))
    return {"designed": designed, "random": np.median(rows, axis=0), "missed": missed, "check": check}


# -- the run -----------------------------------------------------------------------------------------------


def run_arm(name: str, arm: Arm, folder: Path, args) -> dict:
    """The cold and warm commands, the design's figures and the bar of one arm."""
    cache = Path(tempfile.mkdtemp(prefix=f"cache-{name}-", dir=folder))
    out = folder / f"{name}.csv"
    extra = args.excite.split() if args.excite else []
    first, failed = run_excite(arm, out, cache, extra)
    row = {"first": first, "failed": failed}
    if failed:
        return row
    warm, failed = run_excite(arm, folder / f"{name}-warm.csv", cache, extra)
    row.update(warm=warm, failed=failed)
    traj, record = read_trajectory_json(out.with_suffix(".json"))
    design = record["design"]
    row.update(design_figures(design), base=len(design["base_parameters"]))
    row["bar"] = excitation_bar(name, arm, traj, design, args)
    return row


def print_design(rows: dict) -> None:
    print(
        f"{'arm':<11} {'base':>4} {'first s':>8} {'warm s':>7} {'converged':>10} {'answer':>12} "
        f"{'candidates':>10} {'std ratio med':>13} {'min':>6} {'typical':>8}"
    )
    for name, r in rows.items():
        if r.get("failed") and "answer" not in r:
            print(f"{name:<11} failed after {r['first']:.1f} s: {r['failed']}")
            continue
        warm = f"{r['warm']:.1f}" if r.get("warm") is not None else "-"
        print(
            f"{name:<11} {r['base']:>4} {r['first']:>8.1f} {warm:>7} {r['converged']:>6}/{r['starts']:<3} "
            f"{r['answer']:>12} {r['candidates']:>10} {r['ratio_median']:>12.2f}x {r['ratio_min']:>5.2f}x "
            f"{r['typical_median']:>7.2f}x"
        )
        if r.get("failed"):
            print(f"{'':<11} the warm run failed: {r['failed']}")
    ran = [n for n, r in rows.items() if "ratio_median" in r]
    short = [n for n in ran if rows[n]["ratio_median"] < 2]
    failed = [n for n in rows if n not in ran]
    print(f"median std ratio below 2x on: {', '.join(short) or 'none'} (of {', '.join(ran) or 'none'})")
    if failed:
        print(f"no design on: {', '.join(failed)}")


def print_bar(rows: dict) -> None:
    print(f"{'arm':<11} {'frames':<15} {'scaled cond':>11} {'med rel std':>11} {'wrench err':>10} {'ident. error':>12}")
    for name, r in rows.items():
        bar = r.get("bar")
        if bar is None:
            continue
        marks = f" ({bar['missed']} draws break the floor or box)" if bar["missed"] else ""
        for label, v in (("designed", bar["designed"]), ("random Fourier", bar["random"])):
            print(f"{name:<11} {label:<15} {v[0]:>11.4g} {v[1]:>11.3g} {v[2]:>10.3g} {v[3]:>12.3g}")
        better = np.all(bar["designed"][:3] < bar["random"][:3])
        print(
            f"{'':<11} designed beats random Fourier on all three: {'yes' if better else 'NO'}{marks}; "
            f"record check {bar['check']:.1e}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default=",".join(ARMS), help=f"comma-separated, of {', '.join(ARMS)}")
    ap.add_argument("--excite", default="", help="more options of ineid excite, e.g. --excite='--starts 1'")
    ap.add_argument("--random", type=int, default=5, help="random Fourier trajectories per arm")
    ap.add_argument("--tries", type=int, default=200, help="draws per random Fourier trajectory to keep the limits")
    ap.add_argument("--states", type=int, default=2000, help="uniform states of the wrench-prediction error")
    ap.add_argument("--draws", type=int, default=10, help="noise draws of the identification error")
    ap.add_argument("--seed", type=int, default=0, help="of the random Fourier trajectories, states and noise")
    ap.add_argument("--keep", type=Path, default=None, help="folder of the files and logs (default: temp)")
    args = ap.parse_args()
    print(f"machine: {cpu_description()}; load average at start {os.getloadavg()[0]:.1f}")
    given = f" {args.excite}" if args.excite else ""
    print(f"ineid excite ROBOT --duration 10 --floor F --workspace BOX{given} (every other option its default)")
    from ineid.excite.lanes import default_workers

    print(f"workers by default here: {default_workers(3)} (one per usable CPU, at most one per start; 3 starts)")
    for name in args.arms.split(","):
        arm = ARMS[name]
        print(f"  {name}: {' '.join(arm.cli_args()[1:])}")
    folder = args.keep or Path(tempfile.mkdtemp(prefix="ineid-excite-bench-"))
    folder.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name in args.arms.split(","):
        rows[name] = run_arm(name, ARMS[name], folder, args)
        shown = {k: v for k, v in rows[name].items() if k != "bar"}
        if "bar" in rows[name]:
            shown.update({k: np.round(v, 6).tolist() for k, v in rows[name]["bar"].items() if k in BAR_ROWS})
        print(f"  {name} done ({json.dumps(shown)})", flush=True)
    print()
    print_design(rows)
    print()
    print_bar(rows)
    print(f"\nload average at end {os.getloadavg()[0]:.1f}; files in {folder}")


if __name__ == "__main__":
    main()
