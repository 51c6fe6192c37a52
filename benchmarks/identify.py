"""How fast ineid identifies: the paper's dataset with every method, against a Pinocchio peer.

``sweaty-arm``, links ``upper_arm`` and ``forearm`` unknown (20 parameters, 17 base
parameters). The dataset is the paper's (10,000 configurations x 100 frames, factorial
100 x 100) with wrench noise (0.5 N, 0.05 N*m) so every solver has real work, generated in
memory first (not timed). Rows:

* linear, batched (JAX regressors, QR per configuration, the null-space rule), all
  configurations, 80 frames fitted and 20 held out, as ``ineid solve`` does it;
* the same through CasADi (the generated CasADi function, CasADi's QR), per configuration;
* the peer: the regressor from Pinocchio (``computeJointTorqueRegressor`` with a free-flyer
  base, frame by frame) and ``numpy.linalg.lstsq`` on the 20 columns, per configuration,
  what a lab would write with Pinocchio alone;
* the paper's ``lsqlin`` and ``lsqnonlin`` (:mod:`ineid.identify.classical`), all configurations, and
  ``lsqnonlin``'s trust region alone on the subset, batched against scipy's own loop;
* nonlinear and consistent (IPOPT) on a subset, one process and all cores;
* ``--backend casadi-c``: the same normal-equation blocks from the generated CasADi function
  printed as C and compiled (the compiler's seconds are paid once and cached), and the IPOPT
  problems compiled by CasADi's jit (paid per process, included in the row);
* the whole command, ``ineid solve DATA.h5 --method linear``, as a user runs it: two fresh
  processes on the dataset saved to a file, the first with an empty cache folder (it compiles
  the kernels), the second loading them from the persistent compilation cache.

Each row reports configurations per second; the error columns show the median relative
error of the 17 base parameters, the same for every method on the same data.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset, save_dataset
from ineid.identify import SolveSettings, relative_error, solve_dataset
from ineid.identify.casadi_c import c_compiler


def whole_command(ds, runs: int = 2) -> list[float]:
    """Wall seconds of ``ineid solve DATA.h5 --method linear`` in fresh processes, one cache folder."""
    times = []
    with tempfile.TemporaryDirectory(prefix="ineid-bench-") as tmp:
        data = save_dataset(ds, Path(tmp) / "paper.h5")
        env = dict(os.environ, INEID_CACHE_DIR=str(Path(tmp) / "cache"))
        cli = [
            sys.executable,
            "-m",
            "ineid.cli",
            "-q",
            "solve",
            str(data),
            "--method",
            "linear",
            "--out",
            str(Path(tmp) / "results.h5"),
            "--overwrite",
        ]
        for _ in range(runs):
            t0 = time.perf_counter()
            subprocess.run(cli, check=True, env=env, stdout=subprocess.DEVNULL)
            times.append(time.perf_counter() - t0)
    return times


def pinocchio_peer(model, ds, n_fit: int) -> tuple[np.ndarray, float]:
    """Base-parameter estimates by Pinocchio's regressor + lstsq; (C, 17), seconds."""
    import pinocchio as pin

    from ineid.identify import base_parameters

    base = base_parameters(model)
    urdf = str(model.urdf_path)
    pm = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    data = pm.createData()
    unknown = model.unknown_index
    known = model.known_index
    nv = pm.nv
    out = np.empty((ds.n_configs, base.rank))
    t0 = time.perf_counter()
    q_ff = np.zeros(pm.nq)
    q_ff[6] = 1.0  # identity quaternion of the free-flyer
    v = np.zeros(nv)
    a = np.zeros(nv)  # the base is fixed: zero free-flyer velocity and acceleration; gravity from the model
    for c in range(ds.n_configs):
        rows, rhs = [], []
        for f in range(n_fit):
            q_ff[7:] = ds.q[c, f]
            v[6:] = ds.qd[c, f]
            a[6:] = ds.qdd[c, f]
            y = -pin.computeJointTorqueRegressor(pm, data, q_ff, v, a)[:6, 10:]
            rows.append(y[:, unknown])
            rhs.append(ds.wrench[c, f] - y[:, known] @ ds.theta_known)
        w = np.vstack(rows)
        b = np.concatenate(rhs)
        beta, *_ = np.linalg.lstsq(w[:, base.base_index], b, rcond=None)
        out[c] = beta
    return out, time.perf_counter() - t0


def paper_rows(model, ds, sub, n_fit: int, row) -> None:
    """The paper's lsqlin and lsqnonlin on every configuration, and lsqnonlin's trust region alone on ``sub``:
    batched (:func:`ineid.identify.classical.trf`) against scipy's own loop."""
    for method in ("lsqlin", "lsqnonlin"):  # the paper's solvers (ineid.identify.classical), all configurations
        t0 = time.perf_counter()
        res = solve_dataset(ds, SolveSettings(method=method, weights="none"), model=model)
        row(
            f"{method} (the paper's; batched), all configurations, {res.success.mean():.0%} ok",
            ds.n_configs,
            time.perf_counter() - t0,
            np.nanmedian(relative_error(res.base_hat, res.base_true)),
        )
    from ineid.identify import base_parameters
    from ineid.identify.classical import lsqnonlin_theta
    from ineid.identify.fused import information_blocks
    from ineid.identify.linear import fit_base_blocks

    base = base_parameters(model)
    blocks = information_blocks(
        model, base, sub.q[:, :n_fit], sub.qd[:, :n_fit], sub.qdd[:, :n_fit], sub.wrench[:, :n_fit], sub.theta_known
    )
    fit, _ = fit_base_blocks(blocks, base, "none", None, None)
    for engine in ("batched", "scipy"):
        t0 = time.perf_counter()
        lsqnonlin_theta(fit, base, model.theta_cad[model.unknown_index], engine=engine)
        row(f"  lsqnonlin's trust region alone, {engine}", sub.n_configs, time.perf_counter() - t0, float("nan"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs-per-link", type=int, default=100, help="factorial size (100 -> 10,000 configurations)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--subset", type=int, default=400, help="configurations for the per-configuration rows")
    ap.add_argument("--no-cli", dest="cli", action="store_false", help="skip the whole-command timing")
    ap.add_argument("--paper-only", action="store_true", help="only the paper's lsqlin and lsqnonlin rows")
    args = ap.parse_args()

    model = ineid.load_robot("sweaty-arm")
    noise = NoiseModel.create(model.n_dof, force=0.5, moment=0.05)
    spec = DatasetSpec(
        Combination("factorial", per_link=args.configs_per_link), n_frames=args.frames, seed=0, noise=noise
    )
    ds = generate_dataset(model, spec)
    n_fit = args.frames - int(0.2 * args.frames)
    sub = ds.select(slice(0, min(args.subset, ds.n_configs)))
    for warm in (SolveSettings(), SolveSettings(weights="none")):  # compile the chunk shapes of both kernels
        solve_dataset(ds.select(slice(0, 8)), warm, model=model)
    print(f"machine: {cpu_description()}; ineid {ineid.__version__}")
    print(
        f"sweaty-arm, upper_arm + forearm unknown (20 parameters, 17 base); {ds.n_configs:,} configurations x "
        f"{args.frames} frames, wrench noise 0.5 N / 0.05 N*m; {n_fit} frames fitted per configuration"
    )
    header = f"{'method':58s} {'configs':>8s} {'seconds':>9s} {'configs/s':>10s} {'base err (median)':>18s}"
    print(header)
    print("-" * len(header))

    def row(name, n, seconds, err):
        print(f"{name:58s} {n:8,d} {seconds:9.2f} {n / seconds:10,.0f} {err:18.4g}")

    if args.paper_only:
        paper_rows(model, ds, sub, n_fit, row)
        return
    t0 = time.perf_counter()
    res = solve_dataset(ds, SolveSettings(), model=model)
    linear_seconds = time.perf_counter() - t0
    row(
        "linear, batched (JAX + NumPy QR), all configurations",
        ds.n_configs,
        linear_seconds,
        np.median(relative_error(res.base_hat, res.base_true)),
    )
    t0 = time.perf_counter()
    res = solve_dataset(ds, SolveSettings(weights="estimate"), model=model)
    row(
        "linear, weighted (noise per axis estimated, 3 rounds)",
        ds.n_configs,
        time.perf_counter() - t0,
        np.median(relative_error(res.base_hat, res.base_true)),
    )
    t0 = time.perf_counter()
    res = solve_dataset(sub, SolveSettings(backend="casadi"), model=model)
    row(
        "linear through CasADi, per configuration",
        sub.n_configs,
        time.perf_counter() - t0,
        np.median(relative_error(res.base_hat, res.base_true)),
    )
    beta, seconds = pinocchio_peer(model, sub, n_fit)
    peer_rate = sub.n_configs / seconds
    row(
        "peer: Pinocchio regressor per frame + numpy lstsq",
        sub.n_configs,
        seconds,
        np.median(relative_error(beta, res.base_true)),
    )
    ratio = ds.n_configs / linear_seconds / peer_rate
    print(
        f"{'  -> linear, batched against the peer: ' + f'{ratio:.1f}x':58s} (target 10x: "
        f"{'MET' if ratio >= 10 else 'MISSED'})"
    )
    compiled = c_compiler() is not None
    if compiled:
        t0 = time.perf_counter()
        res = solve_dataset(ds, SolveSettings(backend="casadi-c"), model=model)
        row(
            "linear, casadi-c (compiled C blocks), all configurations",
            ds.n_configs,
            time.perf_counter() - t0,
            np.median(relative_error(res.base_hat, res.base_true)),
        )
    paper_rows(model, ds, sub, n_fit, row)
    for method in ("nonlinear", "consistent"):
        for workers in sorted({1, os.cpu_count() or 1}):
            t0 = time.perf_counter()
            res = solve_dataset(sub, SolveSettings(method=method, workers=workers), model=model)
            ok = f"{res.success.mean():.0%} ok"
            row(
                f"{method} (IPOPT), {workers} process{'es' if workers > 1 else ''}, {ok}",
                sub.n_configs,
                time.perf_counter() - t0,
                np.nanmedian(relative_error(res.base_hat, res.base_true)),
            )
        if compiled:
            t0 = time.perf_counter()
            res = solve_dataset(sub, SolveSettings(method=method, backend="casadi-c"), model=model)
            ok = f"{res.success.mean():.0%} ok"
            row(
                f"{method}, casadi-c (IPOPT jit, compile incl.), 1 process, {ok}",
                sub.n_configs,
                time.perf_counter() - t0,
                np.nanmedian(relative_error(res.base_hat, res.base_true)),
            )
    if args.cli:
        first, second = whole_command(ds)
        print()
        print(f"ineid solve DATA.h5 --method linear, {ds.n_configs:,} configurations, whole command (fresh process):")
        print(f"  first run (empty cache, compiles): {first:6.2f} s")
        print(
            f"  second run (compilation cache):     {second:6.2f} s  -> {ds.n_configs / second:,.0f} configs/s, "
            f"{ds.n_configs / second / peer_rate:,.0f}x the Pinocchio peer"
        )


if __name__ == "__main__":
    main()
