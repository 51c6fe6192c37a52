"""The sweeps behind docs/learning.md "What to expect": the paper's networks, and the wls network.

Run::

    python benchmarks/paper_sweep.py OUT_DIR              # the paper's networks (about 25 minutes on 2 cores)
    python benchmarks/paper_sweep.py OUT_DIR --wls          # the wls rows (about 6 minutes on 2 cores)
    python benchmarks/paper_sweep.py OUT_DIR --wls --quick  # a reduced mode (about 4 minutes; see below)

**The paper's networks** train on the paper's dataset and split; each run trains into
``OUT_DIR/<name>_<loss>`` and appends one JSON line with its test errors, the null-space
floor and the linear least squares to ``OUT_DIR/results.jsonl``.

**The wls rows** train ``--arch wls`` (K = 10 frames per sample, Adam) on three
datasets of ``sweaty-arm`` and compare it, on the same held-out configurations and frames,
with the classical estimators: least squares (unweighted, as ``ineid evaluate`` reports
it), least squares weighted by per-axis noise estimated from its residuals, and the
Gaussian-prior estimate (prior and noise model fitted on the training truth); and with
the floor. Datasets:

* ``paper``: the paper's clean data (10,000 configurations x 100 frames; 3,000 training,
  500 validation, 500 test configurations, as the networks above);
* ``noisy``: the noise study's level-1 noise (force 0.5 N, moment 0.05 N*m, qd 0.01 rad/s,
  qdd 0.1 rad/s^2), 10 frames per configuration, 12,000 random configurations (a
  sanity check of the wls layer), 70 / 10 / 20 % split, up to 100 epochs with patience 20;
* ``glitch``: the same with 2 % of frames given 20x force noise.

``--quick`` uses 4,000 noisy configurations, 30 epochs and 3 on the paper's data: a
check that the script runs, not the measurement (at that size the noisy row ends at the
Gaussian-prior estimate's level rather than below it).

Printed: test median relative error of the standard and base parameters, the 95th
percentile of the base error, the largest relative base error over the test set (the
1e-8 target on clean data), and training seconds (compilation included). The rows are
also written to ``OUT_DIR/wls.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, base_parameters, solve_dataset
from ineid.identify.results import relative_error
from ineid.learn import ModelSpec, TrainConfig, evaluate, load_run, predict, train
from ineid.learn.evaluate import gaussian_prior_estimates

LEVEL1 = {"force": 0.5, "moment": 0.05, "qd": 0.01, "qdd": 0.1}


def paper_networks(out: Path, m) -> None:
    ds = generate_dataset(m, DatasetSpec(seed=0))  # the paper's 10,000 configurations x 100 frames
    results = open(str(out / "results.jsonl"), "a")
    s = dict(batch=1024, lr=1e-3)
    runs = [
        ("simple", ModelSpec("simple"), "mse", dict(epochs=100, patience=15, batch=256, lr=1e-3)),
        ("simple", ModelSpec("simple"), "physics", dict(epochs=100, patience=15, batch=256, lr=1e-3, beta=50.0)),
        ("net1", ModelSpec("net1"), "mse", dict(epochs=30, patience=8, **s)),
        ("net2", ModelSpec("net2"), "mse", dict(epochs=30, patience=8, **s)),
        ("net3", ModelSpec("net3"), "mse", dict(epochs=30, patience=8, **s)),
        ("net4", ModelSpec("net4"), "mse", dict(epochs=30, patience=8, **s)),
        ("net5", ModelSpec("net5"), "mse", dict(epochs=30, patience=8, **s)),
        ("funnel", ModelSpec("funnel"), "mse", dict(epochs=30, patience=8, **s)),
        ("multi net2 K10", ModelSpec("net2", frames=10), "mse", dict(epochs=100, patience=15, batch=64, lr=1e-3)),
        ("multi net5 K10", ModelSpec("net5", frames=10), "mse", dict(epochs=100, patience=15, batch=64, lr=1e-3)),
        (
            "multi net2 K10",
            ModelSpec("net2", frames=10),
            "physics",
            dict(epochs=100, patience=15, batch=64, lr=1e-3, beta=50.0),
        ),
        (
            "siamese net2 K10",
            ModelSpec("net2", frames=10, siamese=True),
            "mse",
            dict(epochs=100, patience=15, batch=64, lr=1e-3),
        ),
        (
            "siamese net2 K10",
            ModelSpec("net2", frames=10, siamese=True),
            "physics",
            dict(epochs=100, patience=15, batch=64, lr=1e-3, beta=50.0),
        ),
        ("net6", ModelSpec("net6"), "mse", dict(epochs=10, patience=5, **s)),
        (
            "siamese net6 K10",
            ModelSpec("net6", frames=10, siamese=True),
            "mse",
            dict(epochs=40, patience=10, batch=64, lr=1e-3),
        ),
        ("net7", ModelSpec("net7"), "mse", dict(epochs=5, patience=5, **s)),
    ]
    for name, spec, loss, kw in runs:
        cfg = TrainConfig(
            model=spec, loss=loss, scaler="robust", optimizer="adam", n_train=3000, n_val=500, n_test=500, seed=0, **kw
        )
        t = time.perf_counter()
        d = str(out / f"{name.replace(' ', '_')}_{loss}")
        r = train(ds, cfg, d, overwrite=True, model=m)
        ev = evaluate(load_run(d), ds, model=m)
        rec = dict(
            name=name,
            loss=loss,
            epochs=r.epochs_run,
            best_epoch=r.best_epoch,
            stopped=r.stopped_early,
            seconds=time.perf_counter() - t,
            standard=ev.network["overall_median"],
            base=ev.network_base["overall_median"],
            floor=ev.floor["overall_median"],
            linear_standard=ev.linear["overall_median"],
            linear_base=ev.linear_base["overall_median"],
            physical=ev.physical_share,
            linear_physical=ev.linear_physical_share,
            per_sample=ev.per_sample_median,
            mass_r2=ev.network_base["r2"][0],
            frames=ev.frames_used,
        )
        results.write(json.dumps(rec) + "\n")
        results.flush()
        print(rec, flush=True)


def _errors(est_theta, truth, base) -> tuple[float, float, float, float]:
    """Median standard error, median / 95th percentile / max base error (relative)."""
    eb = relative_error(est_theta @ base.B.T, truth @ base.B.T)
    return (
        float(np.nanmedian(relative_error(est_theta, truth))),
        float(np.nanmedian(eb)),
        float(np.nanpercentile(eb, 95)),
        float(np.nanmax(eb)),
    )


def wls_rows(out: Path, m, quick: bool) -> list[dict]:
    base = base_parameters(m)
    n_noisy = 4_000 if quick else 12_000
    noise = NoiseModel.create(m.n_dof, **LEVEL1)
    glitch = NoiseModel.create(m.n_dof, **LEVEL1, glitch_rate=0.02, glitch_scale=20.0)
    cases = [  # name, dataset spec, split (train, val, test), epochs, lr
        ("paper", DatasetSpec(seed=0), (3000, 500, 500), 3 if quick else 20, 1e-3),
        (
            "noisy",
            DatasetSpec(Combination("random", n_configs=n_noisy), n_frames=10, seed=1, noise=noise),
            (int(0.7 * n_noisy), n_noisy // 10, n_noisy // 5),
            30 if quick else 100,
            3e-3,
        ),
        (
            "glitch",
            DatasetSpec(Combination("random", n_configs=n_noisy), n_frames=10, seed=2, noise=glitch),
            (int(0.7 * n_noisy), n_noisy // 10, n_noisy // 5),
            30 if quick else 100,
            3e-3,
        ),
    ]
    rows = []
    for name, spec, (n_train, n_val, n_test), epochs, lr in cases:
        ds = generate_dataset(m, spec)
        cfg = TrainConfig(
            model=ModelSpec("wls", frames=10),
            epochs=epochs,
            batch=256,
            lr=lr,
            patience=max(10, epochs // 5),
            n_train=n_train,
            n_val=n_val,
            n_test=n_test,
            seed=0,
        )
        run_dir = out / f"wls_{name}"
        t = time.perf_counter()
        result = train(ds, cfg, run_dir, overwrite=True, model=m)
        seconds = time.perf_counter() - t
        run = load_run(run_dir)
        test = run.split.test
        truth = ds.theta_unknown[test]
        ev = evaluate(run, ds, model=m, linear=False)  # the floor; the classical estimates follow
        theta_net, _, frames = predict(run, ds, test, model=m)
        sub = ds.select(test, slice(0, frames))
        ls = solve_dataset(sub, SolveSettings(frames=frames), model=m)
        wls = solve_dataset(sub, SolveSettings(frames=frames, weights="estimate"), model=m)
        gp_theta, _ = gaussian_prior_estimates(run, ds, test, frames, m, True)
        floor = ev.floor["overall_median"]
        for label, est, secs in (
            ("least squares", ls.theta_hat, None),
            ("least squares, weights estimated", wls.theta_hat, None),
            ("Gaussian prior (training truth)", gp_theta, None),
            (f"wls network ({result.epochs_run} epochs)", theta_net, seconds),
        ):
            std, b_med, b_p95, b_max = _errors(est, truth, base)
            rows.append(
                dict(
                    data=name,
                    estimator=label,
                    standard=std,
                    base=b_med,
                    base_p95=b_p95,
                    base_max=b_max,
                    floor=floor,
                    seconds=secs,
                    configs=ds.n_configs,
                    frames=frames,
                    test=len(test),
                )
            )
    with open(out / "wls.jsonl", "a") as fh:
        for r in rows:
            fh.write(json.dumps(r) + "\n")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", default="paper_sweep", help="output folder")
    parser.add_argument("--wls", action="store_true", help="only the wls rows")
    parser.add_argument("--quick", action="store_true", help="the wls rows reduced (4,000 noisy configurations)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    m = ineid.load_robot("sweaty-arm")
    if not args.wls:
        paper_networks(out, m)
    print(
        f"machine: {cpu_description()}; ineid {ineid.__version__}; float64; "
        f"{'--quick: 4,000 noisy configurations' if args.quick else '12,000 noisy configurations'}"
    )
    rows = wls_rows(out, m, args.quick)
    head = (
        f"{'data':7s} {'estimator':34s} {'standard':>9s} {'base':>9s} {'base p95':>9s} {'base max':>9s} "
        f"{'floor':>7s} {'train s':>8s}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        secs = "-" if r["seconds"] is None else f"{r['seconds']:.0f}"
        print(
            f"{r['data']:7s} {r['estimator']:34s} {r['standard']:9.3g} {r['base']:9.3g} {r['base_p95']:9.3g} "
            f"{r['base_max']:9.2g} {r['floor']:7.3g} {secs:>8s}"
        )
    print(
        "data: paper = 10,000 x 100 clean frames (3,000 / 500 / 500); noisy, glitch = level-1 noise, 10 frames "
        "(glitch: 2 % of frames with 20x force noise); errors on the test configurations, K = 10 frames per sample"
    )


if __name__ == "__main__":
    main()
