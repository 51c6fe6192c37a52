"""Calibration of the constrained fits' standard deviations (:mod:`ineid.identify.constrained_std`).

On ``sweaty-arm`` (links ``upper_arm`` and ``forearm`` unknown, 17 base parameters), one simulated dataset
(``--configs`` configurations of 30 random frames each, Gaussian noise on the base wrench: ``--noise`` N on
the forces, a tenth of it in N m on the moments), re-synthesized for each truth:

- ``inside``: the CAD-sampled links, positive definite pseudo-inertias (the boundary binds only through
  noise);
- ``rod``: the forearm a thin rod along its -z axis (two zero principal moments: on the boundary);
- ``point``: the forearm a point mass (three zero eigenvalues);
- ``points``: both links point masses.

Per truth, noise and method (``consistent``, ``nonlinear``) the table gives the configurations whose std
differs from the linear fit's (``active``), and over the base parameters the mean, least and largest RMS
of ``(beta_hat - beta) / std`` over the configurations: with the method's std (``z``) and with the linear
fit's std for the same estimates (``z lin``), and the RMS ``z`` over the active and the other
configurations apart. With ``n`` configurations a calibrated parameter's RMS z lies within about
``1 +/- 2 / sqrt(2 n)`` (0.86..1.14 at 100).

Run: ``python benchmarks/std_constrained.py [--configs 100] [--noise 0.2 1 3]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import numpy as np

import ineid
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, base_parameters, solve_dataset


def thin_rod(mass: float, length: float) -> np.ndarray:
    i = mass * length**2 / 3
    return np.array([mass, 0.0, 0.0, -mass * length / 2, i, 0.0, i, 0.0, 0.0, 0.0])


def point_mass(mass: float, c) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    s = mass * np.outer(c, c)
    i = np.trace(s) * np.eye(3) - s
    return np.array([mass, *(mass * c), i[0, 0], i[0, 1], i[1, 1], i[0, 2], i[1, 2], i[2, 2]])


def truths(cad: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "inside": cad,
        "rod": np.concatenate([cad[:10], thin_rod(1.2, 0.3)]),
        "point": np.concatenate([cad[:10], point_mass(1.2, [0.0, 0.0, -0.15])]),
        "points": np.concatenate([point_mass(1.3, [0.0, 0.0, -0.13]), point_mass(1.2, [0.0, 0.0, -0.15])]),
    }


def rms(z: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(z**2, axis=0)) if len(z) else np.full(z.shape[1], np.nan)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=100)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.2, 1.0, 3.0])
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    model = ineid.load_robot("sweaty-arm")
    base = base_parameters(model)
    print(f"load average {os.getloadavg()[0]:.1f}; sweaty-arm, {base.rank} base parameters, {args.configs} configs")
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=args.configs),
            n_frames=30,
            seed=args.seed,
            noise=NoiseModel.create(4, force=1.0, moment=0.1),
        ),
    )
    unit_noise = ds.wrench - ds.clean["wrench"]
    rows_u, rows_k = model.regressor_split(ds.q, ds.qd, ds.qdd)
    known = np.einsum("cfap,p->cfa", rows_k, ds.theta_known)
    head = f"{'truth':7s} {'noise':>5s} {'method':10s} {'active':>6s}  {'z mean [min, max]':20s}  "
    print(head + f"{'z lin mean [min, max]':22s} {'z active':>8s} {'z other':>8s} {'s':>5s}")
    for name, theta in truths(ds.theta_unknown[0]).items():
        truth = theta @ base.B.T
        for noise in args.noise:
            wrench = np.einsum("cfap,p->cfa", rows_u, theta) + known + noise * unit_noise
            case = dataclasses.replace(ds, wrench=wrench, theta_unknown=np.broadcast_to(theta, (ds.n_configs, 20)))
            lin = solve_dataset(case, SolveSettings(frames=30), model=model)
            for method in ("consistent", "nonlinear"):
                t0 = time.perf_counter()
                res = solve_dataset(case, SolveSettings(frames=30, method=method), model=model)
                sec = time.perf_counter() - t0
                ok = res.success
                act = np.any(res.base_std != lin.base_std, axis=1) & ok
                err = res.base_hat - truth
                z, z0 = rms((err / res.base_std)[ok]), rms((err / lin.base_std)[ok])
                za, zo = rms((err / res.base_std)[act]), rms((err / res.base_std)[ok & ~act])
                print(
                    f"{name:7s} {noise:5.1f} {method:10s} {act.sum():3d}/{ok.sum():<3d} "
                    f"{z.mean():5.2f} [{z.min():.2f}, {z.max():.2f}]     "
                    f"{z0.mean():5.2f} [{z0.min():.2f}, {z0.max():.2f}]      "
                    f"{np.mean(za):8.2f} {np.mean(zo):8.2f} {sec:5.1f}"
                )
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
