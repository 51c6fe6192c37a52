"""Excitation design: designed vs random Fourier trajectories vs independent uniform states.

For the built-in arm (``upper_arm``, ``forearm`` unknown), the Panda (fingers locked, every
moving link unknown) and the Unitree Z1 (every moving link unknown), ``ineid excite``'s
defaults (10 s, one period, 5 harmonics, d-optimality, 4 starts, 100 Hz), five seeds each.
Rows:

* ``designed``: the optimized trajectory;
* ``random Fourier``: a random Fourier trajectory of the same period, harmonics and bounds
  (the design's random start with the median criterion: what ``--frame-mode fourier``
  gives, scaled to the same bounds on the same grid);
* ``uniform states``: as many independent states, uniform within the model's bounds
  (no trajectory can pass through them; the reference the issue names).

Columns, medians over the seeds: the scaled condition number of the 1001 samples, the
median expected relative standard deviation of the base parameters (wrench noise 0.5 N,
0.05 N*m, the Cramer-Rao bound), and the identification error: the median relative error
of the base parameters, linear least squares on simulated data along the trajectory with
the noise study's reference noise (wrench 0.5 N, 0.05 N*m; qd 0.01 rad/s, qdd 0.1 rad/s^2),
20 random parameter configurations per seed. Design time: the median wall time of a design
with the regressor already compiled, and the compilation once per robot.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data import Combination, DatasetSpec, FrameSampling, NoiseModel, generate_dataset
from ineid.data.synthesis.sampling import model_uniform_states
from ineid.data.synthesis.trajectory import SampledTrajectory
from ineid.excite.design import design_base, design_excitation, design_noise, evaluate_design, regressor_and_derivatives
from ineid.excite.settings import ExcitationSettings
from ineid.identify import SolveSettings, relative_error, solve_dataset
from ineid.studies.noise import REFERENCE_NOISE

EXAMPLES = "cmeel.prefix/share/example-robot-data/robots"


def robots() -> dict[str, object]:
    import importlib.metadata

    root = importlib.metadata.distribution("example-robot-data").locate_file(EXAMPLES)
    return {
        "sweaty-arm": lambda: ineid.load_robot("sweaty-arm"),
        "panda": lambda: ineid.load_robot(
            str(root / "panda_description/urdf/panda.urdf"),
            locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0},
        ),
        "z1": lambda: ineid.load_robot(str(root / "z1_description/urdf/z1.urdf")),
    }


def identification_error(model, time_s, q, qd, qdd, seed: int, n_configs: int) -> float:
    """Median relative error of the base parameters, linear LS on noisy simulated data along the frames."""
    traj = SampledTrajectory(time_s, q, qd, qdd, source="benchmark")
    noise = NoiseModel.create(model.n_dof, **REFERENCE_NOISE)
    spec = DatasetSpec(
        Combination("random", n_configs=n_configs),
        n_frames=len(q),
        seed=seed,
        noise=noise,
        frames=FrameSampling("trajectory", trajectory=traj),
    )
    ds = generate_dataset(model, spec)
    res = solve_dataset(ds, SolveSettings(frames=len(q)), model=model)
    ok = res.success
    return float(np.median(relative_error(res.base_hat[ok], res.base_true[ok])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="sweaty-arm,panda,z1")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--starts", type=int, default=ExcitationSettings.starts)
    ap.add_argument("--configs", type=int, default=20, help="parameter configurations per identification")
    args = ap.parse_args()
    print(f"machine: {cpu_description()}")
    print(
        f"ineid excite defaults: {args.duration:g} s, 5 harmonics of {1 / args.duration:g} Hz, d-opt, "
        f"{args.starts} starts, 100 Hz; medians over {args.seeds} seeds\n"
    )
    makers = robots()
    for name in args.robots.split(","):
        model = makers[name]()
        base = design_base(model)  # through CasADi: no compilation
        t0 = time.perf_counter()
        zeros = np.zeros((1, model.n_dof))
        regressor_and_derivatives(model, zeros, zeros, zeros)  # compiles the regressor and its derivatives
        compile_s = time.perf_counter() - t0
        sigma = design_noise()
        rows = {"designed": [], "random Fourier": [], "uniform states": []}
        seconds = []
        for seed in range(args.seeds):
            res = design_excitation(model, ExcitationSettings(args.duration, starts=args.starts, seed=seed))
            seconds.append(res.seconds)
            for label, traj, ev in (
                ("designed", res.trajectory, res.optimized),
                ("random Fourier", res.random_trajectory, res.random),
            ):
                t, q, qd, qdd = traj.sample(res.rate)
                err = identification_error(model, t, q, qd, qdd, seed, args.configs)
                rows[label].append((ev.condition_number, np.median(ev.rel_std), err))
            n = res.optimized.n_samples
            q, qd, qdd = model_uniform_states(model, n, np.random.default_rng(seed))
            ev = evaluate_design(model, q, qd, qdd, base, sigma)
            err = identification_error(model, np.arange(n) / res.rate, q, qd, qdd, seed, args.configs)
            rows["uniform states"].append((ev.condition_number, np.median(ev.rel_std), err))
        print(
            f"{name}: {model.n_dof} joints, {len(model.unknown_links)} unknown links, {base.rank} base parameters; "
            f"compilation {compile_s:.1f} s; design {np.median(seconds):.1f} s (median; min {min(seconds):.1f}, "
            f"max {max(seconds):.1f})"
        )
        print(f"  {'frames':<16} {'scaled cond':>12} {'med rel std':>12} {'ident. error':>13}")
        for label, vals in rows.items():
            v = np.median(np.asarray(vals), axis=0)
            print(f"  {label:<16} {v[0]:>12.4g} {v[1]:>12.3g} {v[2]:>13.3g}")
        ratio = np.median([r[0] / d[0] for d, r in zip(rows["designed"], rows["random Fourier"], strict=True)])
        print(f"  random / designed condition number, median of the seeds' ratios: {ratio:.2f}x\n", flush=True)


if __name__ == "__main__":
    main()
