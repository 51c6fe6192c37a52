"""Training steps per second: the plain MSE loss against the physics-informed loss.

The same network, batch and data for both losses; one step is gather + forward + loss +
gradient + Adam update, jit-compiled (``ineid.learn.train.build_functions``), timed after
compilation over ``--steps`` steps (best of 5), the way training runs them: 16 steps per
compiled call (a ``lax.scan``). The physics loss evaluates
``||R - Psi theta_hat||^2`` over every frame of every sample, ``Psi`` from the generated
JAX regressor, either cached per frame (the default) or evaluated inside the loss
(``inline``). Floor: the physics step costs at most 2x the plain step on the CPU; aim 1.3x.

Then whole runs, as a user trains: ``ineid.learn.train`` for a few epochs with each loss
(split, scalers, the cached regressor, every step, every epoch's validation, checkpoints,
test metrics), timed after a one-epoch run has filled the compilation cache. Target: a
physics run takes at most 1.3x the MSE run.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import jax
import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data import Combination, DatasetSpec, generate_dataset
from ineid.learn import ModelSpec, TrainConfig, split_configs
from ineid.learn.train import STEPS_PER_CALL, build_functions, epoch_groups, make_optimizer, prepare, train


def time_steps(ds, model, cfg: TrainConfig, split, physics_mode: str, n_steps: int) -> float:
    """Seconds per training step (best of 5 runs of n_steps, in calls of STEPS_PER_CALL steps)."""
    rows = np.union1d(split.train, split.val)
    prep = prepare(ds, cfg, rows, model, fit_rows=split.train, physics_mode=physics_mode)
    net = cfg.model.build(prep.n_out)
    k = cfg.model.frames
    params = net.init(jax.random.key(0), prep.arrays["x"][:1, :k])
    opt = make_optimizer(cfg, 100)
    state = opt.init(params)
    steps, _ = build_functions(net, cfg, prep, opt)
    pos, frames = epoch_groups(len(split.train), prep.n_frames, k, 0, 1)
    local = prep.local(split.train)[pos]
    b = cfg.batch
    n = STEPS_PER_CALL
    per_call = b * n
    n_calls = len(local) // per_call
    rows = [local[i * per_call : (i + 1) * per_call].reshape(n, b) for i in range(n_calls)]
    fr = [frames[i * per_call : (i + 1) * per_call].reshape(n, b, k) for i in range(n_calls)]
    p, s, out = steps(params, state, prep.arrays, rows[0], fr[0])  # compile
    jax.block_until_ready(out)
    best = np.inf
    calls = max(1, n_steps // n)
    for _ in range(5):
        t0 = time.perf_counter()
        for i in range(calls):
            p, s, out = steps(p, s, prep.arrays, rows[i % n_calls], fr[i % n_calls])
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - t0) / (calls * n))
    return best


def time_run(ds, model, cfg: TrainConfig, run_dir: Path) -> float:
    """Seconds of one whole :func:`ineid.learn.train` call (split, scalers, cached regressor,
    every epoch's steps and validation, checkpoints, the test metrics), after a one-epoch
    run of the same settings has filled the compilation cache (best of 3)."""
    train(ds, dataclasses.replace(cfg, epochs=1), run_dir, overwrite=True, model=model)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        train(ds, cfg, run_dir, overwrite=True, model=model)
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", type=int, default=600)
    ap.add_argument("--steps", type=int, default=480)
    ap.add_argument("--epochs", type=int, default=5, help="epochs of each whole run")
    args = ap.parse_args()
    model = ineid.load_robot("sweaty-arm")
    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=args.configs), n_frames=100, seed=0))
    split = split_configs(ds.n_configs, None, None, None, 0)
    cases = [
        ("simple, 1 frame, batch 256", ModelSpec("simple"), 256),
        ("net6 (8 x 160), 1 frame, batch 256", ModelSpec("net6"), 256),
        ("net2 (8 x 40), 10 frames concatenated, batch 64", ModelSpec("net2", frames=10), 64),
        ("net6 Siamese, 10 frames, batch 64", ModelSpec("net6", frames=10, siamese=True), 64),
    ]
    print(f"machine: {cpu_description()}; ineid {ineid.__version__}; float64")
    print(f"{len(split.train)} training configurations x 100 frames; Adam; {args.steps} steps timed, best of 5")
    head = f"{'network':48s} {'loss':16s} {'steps/s':>9s} {'samples/s':>10s} {'frames/s':>10s} {'vs MSE':>7s}"
    print(head)
    print("-" * len(head))
    worst = 0.0
    for label, spec, batch in cases:
        base = None
        for loss, mode in (("mse", "cached"), ("physics", "cached"), ("physics", "inline")):
            cfg = TrainConfig(model=spec, loss=loss, batch=batch)
            sec = time_steps(ds, model, cfg, split, mode, args.steps)
            base = sec if loss == "mse" else base
            ratio = sec / base
            if loss == "physics" and mode == "cached":
                worst = max(worst, ratio)
            name = "MSE" if loss == "mse" else f"physics ({mode})"
            print(
                f"{label:48s} {name:16s} {1 / sec:9,.0f} {batch / sec:10,.0f} {batch * spec.frames / sec:10,.0f} "
                f"{ratio:6.2f}x"
            )
    verdict = "MET" if worst <= 2.0 else "MISSED"
    aim = "met" if worst <= 1.3 else "not met"
    print(
        f"floor: physics step <= 2x the MSE step (cached, the default): worst {worst:.2f}x -> {verdict}; aim 1.3x {aim}"
    )

    print()
    print(f"whole runs: ineid.learn.train, {args.epochs} epochs (no early stop), best of 3 after a warm-up run")
    head = f"{'network':48s} {'loss':16s} {'seconds':>9s} {'s/epoch':>9s} {'vs MSE':>7s}"
    print(head)
    print("-" * len(head))
    worst_run = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for label, spec, batch in cases:
            base = None
            for loss in ("mse", "physics"):
                cfg = TrainConfig(model=spec, loss=loss, batch=batch, epochs=args.epochs, patience=0)
                sec = time_run(ds, model, cfg, Path(tmp) / "run")
                base = sec if loss == "mse" else base
                if loss == "physics":
                    worst_run = max(worst_run, sec / base)
                name = "MSE" if loss == "mse" else "physics (cached)"
                print(f"{label:48s} {name:16s} {sec:9.2f} {sec / args.epochs:9.3f} {sec / base:6.2f}x")
    print(f"whole runs: physics <= 1.3x MSE: worst {worst_run:.2f}x -> {'MET' if worst_run <= 1.3 else 'MISSED'}")


if __name__ == "__main__":
    main()
