"""Training throughput: an ``ineid train`` epoch against a bare Optax loop, populations against runs one after
another, the network study's full plan, and float32 against float64.

Every epoch time is wall-clock between two epochs' ends as the public path reports them (its ``progress``
callback, after the epoch's metrics and checkpoint are written), the median over the epochs after the first
(which compiles). Rows:

1. **epoch vs bare loop**: ``ineid.learn.train`` (split, scalers, the cached physics term, validation,
   checkpoint every epoch) against a bare loop of the same Flax network on the same samples: the training
   features and targets standardized up front on the device, SGD, one jitted ``lax.scan`` over the epoch's
   steps, no validation, nothing written. Target on the CPU: within 2x (the physics loss within 2x of the MSE).
2. **a population of 16 vs 16 runs**: 16 trials of one network (4 seeds x 4 learning rates) trained by one
   ``train_population`` call against 16 ``train`` calls one after another (each whole: setup, compilation
   from the persistent cache, epochs, writing). Target on the CPU: at least 5x.
3. **the full plan** (``ineid study networks --plan full``: 576 trials x 100 epochs on 3,000 x 100 frames):
   each of its 16 networks measured on ``--plan-scale`` of the paper's split, as the study groups it (a
   population of 6: 3 scalers x 2 seeds), scaled to the paper's size by the ratio of training steps; each
   network's 3 activations x 2 optimizers taken at the cost of tanh + SGD. Beside it, the same trials one after
   another (one run's epoch x 18). Target on 2 CPU cores: under 3 hours a seed.
4. **float32 vs float64** (``--dtype``): how well float32 resolves the physics term's residual at the true
   parameters (clean and noisy data), the final metrics of the same run in both, and the epoch time.

Rows that need populations print ``n/a`` on a version without them (the script runs on either, for a
before/after comparison in one session). GPU figures (epoch within 3x of the bare loop, under 10 ms; the full
plan under 10 minutes) cannot be measured on a CPU.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from machine import cpu_description  # benchmarks/machine.py

import ineid
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.learn import ModelSpec, TrainConfig, split_configs, train
from ineid.learn.data import frame_features

try:
    from ineid.learn.train import Trial, train_population
except ImportError:  # a version without populations
    Trial = train_population = None

PAPER_TRAIN, PAPER_VAL, PAPER_FRAMES, PAPER_EPOCHS = 3000, 500, 100, 100


class Clock:
    """``progress`` callbacks that stamp when each epoch of any trial ended; :meth:`epoch` the median epoch."""

    def __init__(self) -> None:
        self.ends: dict[int, float] = {}

    def __call__(self, epoch, _epochs, _record) -> None:
        self.ends[epoch] = time.perf_counter()  # the last trial's end of this epoch

    def epoch(self) -> float:
        t = [self.ends[e] for e in sorted(self.ends)]
        return float(np.median(np.diff(t))) if len(t) > 1 else float("nan")


def train_epoch(ds, model, cfg: TrainConfig, run_dir: Path) -> float:
    """Seconds an epoch of ``train`` (median after the first)."""
    clock = Clock()
    train(ds, cfg, run_dir, overwrite=True, model=model, progress=clock)
    return clock.epoch()


def population_epoch(ds, model, cfgs: list[TrainConfig], out: Path) -> tuple[float, float]:
    """``(seconds of the whole call, seconds an epoch of every trial)`` of ``train_population``: the trials that
    trained together (their epochs interleaved) count their epoch once; programs that ran one after another
    (a population split by :func:`ineid.learn.population.population_limit`) add up."""
    clocks = [Clock() for _ in cfgs]
    trials = [Trial(c, out / f"t{i}", overwrite=True, progress=clocks[i]) for i, c in enumerate(cfgs)]
    t0 = time.perf_counter()
    for r in train_population(ds, trials, model=model):
        if isinstance(r, Exception):
            raise r
    spans = sorted((min(c.ends.values()), max(c.ends.values()), c.epoch()) for c in clocks)
    total, last_end, group = 0.0, -np.inf, 0.0
    for start, end, epoch in spans:
        if start > last_end:  # a program after the last one
            total, group = total + group, 0.0
        group, last_end = max(group, epoch), max(last_end, end)
    return time.perf_counter() - t0, total + group


def bare_epoch(ds, cfg: TrainConfig, split, epochs: int = 6) -> float:
    """Seconds an epoch of the bare loop (see the module doc): the same network, samples, batch and steps."""
    import optax

    feats = frame_features(ds.select(split.train)).reshape(-1, 18)
    theta = np.repeat(ds.theta_unknown[split.train], ds.n_frames, axis=0)
    x = jnp.asarray((feats - feats.mean(0)) / feats.std(0))
    z = jnp.asarray((theta - theta.mean(0)) / np.where(theta.std(0) > 0, theta.std(0), 1.0))
    net = cfg.model.build(z.shape[1])
    params = net.init(jax.random.key(cfg.seed), x[:1, None])
    opt = optax.sgd(cfg.lr, momentum=cfg.momentum)
    b = min(cfg.batch, len(x))
    steps = len(x) // b

    @jax.jit
    def epoch(params, opt_state, idx):
        def step(carry, i):
            p, s = carry
            loss, g = jax.value_and_grad(lambda p: jnp.mean((net.apply(p, x[i][:, None]) - z[i]) ** 2))(p)
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), loss

        (p, s), losses = jax.lax.scan(step, (params, opt_state), idx)
        return p, s, losses.mean()

    rng = np.random.default_rng(0)
    state, times = opt.init(params), []
    for _ in range(epochs):
        idx = jnp.asarray(rng.permutation(len(x))[: steps * b].reshape(steps, b))
        t0 = time.perf_counter()
        params, state, loss = epoch(params, state, idx)
        jax.block_until_ready(loss)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def section_bare(ds, model, split, tmp: Path, epochs: int) -> None:
    print("\n1. an `ineid train` epoch against the bare Optax loop of the same network (SGD, tanh, robust scaler)")
    head = f"{'network':28s} {'batch':>6s} {'bare ms':>8s} {'train mse ms':>13s} {'x bare':>7s} {'physics ms':>11s} "
    head += f"{'x mse':>6s}"
    print(head + "\n" + "-" * len(head))
    for arch, batch in (("simple", 256), ("net1", 1024)):
        cfg = TrainConfig(
            model=ModelSpec(arch), optimizer="sgd", scaler="robust", batch=batch, epochs=epochs, patience=0
        )
        bare = bare_epoch(ds, cfg, split)
        mse = train_epoch(ds, model, cfg, tmp / "run")
        phys = train_epoch(ds, model, dataclasses.replace(cfg, loss="physics"), tmp / "run")
        print(
            f"{arch:28s} {batch:6d} {bare * 1e3:8.1f} {mse * 1e3:13.1f} {mse / bare:6.2f}x {phys * 1e3:11.1f} "
            f"{phys / mse:5.2f}x"
        )
    print("target (CPU): the train epoch within 2x of the bare loop; the physics epoch within 2x of the MSE epoch")


def section_population(ds, model, tmp: Path, epochs: int) -> None:
    print("\n2. a population of 16 trials (simple network, SGD, batch 256; 4 seeds x 4 learning rates) against")
    print(f"   16 `train` runs one after another; {epochs} epochs each, whole calls (setup, compilation, writing)")
    base = TrainConfig(model=ModelSpec("simple"), optimizer="sgd", batch=256, epochs=epochs, patience=0)
    cfgs = [dataclasses.replace(base, seed=s, lr=lr) for s in range(4) for lr in (1e-3, 3e-3, 1e-2, 3e-2)]
    train(ds, dataclasses.replace(base, epochs=1), tmp / "warm", overwrite=True, model=model)  # the cache filled
    t0, solo_epochs = time.perf_counter(), []
    for i, cfg in enumerate(cfgs):
        clock = Clock()
        train(ds, cfg, tmp / f"solo{i}", overwrite=True, model=model, progress=clock)
        solo_epochs.append(clock.epoch())
    solo = time.perf_counter() - t0
    head = f"{'how':36s} {'seconds':>8s} {'s/epoch (all 16)':>17s} {'speed-up':>9s}"
    print(head + "\n" + "-" * len(head))
    print(f"{'16 runs one after another':36s} {solo:8.2f} {sum(solo_epochs):17.3f} {1:8.2f}x")
    if train_population is None:
        print(f"{'one population of 16':36s} {'n/a':>8s}")
        return
    pop, pop_epoch = population_epoch(ds, model, cfgs, tmp / "pop")
    print(f"{'one population of 16':36s} {pop:8.2f} {pop_epoch:17.3f} {solo / pop:8.2f}x")
    print(f"target (CPU): >= 5x (whole calls: {solo / pop:.1f}x; epochs: {sum(solo_epochs) / pop_epoch:.1f}x)")


def section_plan(ds, model, tmp: Path, scale: float, nets: list[str] | None) -> None:
    from ineid.studies.paper_networks import SIZES, base_config, plan

    size = SIZES["paper"]
    n_train, n_val = round(PAPER_TRAIN * scale), round(PAPER_VAL * scale)
    print(f"\n3. the full plan, per seed: each network on {n_train} / {n_val} configurations x 100 frames, scaled")
    print("   to 3,000 / 500 by the training steps; x 3 activations x 2 optimizers (at tanh + SGD's cost) x 100 epochs")
    head = (
        f"{'network':26s} {'steps':>6s} {'x':>6s} {'pop(6) s/ep':>12s} {'solo s/ep':>10s} {'pop h':>7s} {'solo h':>7s}"
    )
    print(head + "\n" + "-" * len(head))
    total_pop = total_solo = 0.0
    for part in plan("full"):
        for cfg0 in part.grid.configs(base_config(size, part, 0)):
            m = cfg0.model
            if m.activation != "tanh" or cfg0.scaler != "robust" or cfg0.optimizer != "sgd":
                continue
            label = f"{m.arch}" + (f" Siamese K={m.frames}" if m.siamese else "")
            if nets and m.arch not in nets:
                continue
            cfg = dataclasses.replace(cfg0, n_train=n_train, n_val=n_val, n_test=None, epochs=3)
            k = m.frames
            steps = n_train * (PAPER_FRAMES // k) // cfg.batch
            factor = (PAPER_TRAIN * (PAPER_FRAMES // k) // cfg.batch) / max(steps, 1)
            solo = train_epoch(ds, model, cfg, tmp / "plan-solo")
            solo_h = solo * factor * PAPER_EPOCHS * 18 / 3600
            total_solo += solo_h
            if train_population is None:
                print(f"{label:26s} {steps:6d} {factor:6.1f} {'n/a':>12s} {solo:10.3f} {'n/a':>7s} {solo_h:7.2f}")
                continue
            cfgs = [
                dataclasses.replace(cfg, scaler=sc, seed=s) for sc in ("robust", "standard", "minmax") for s in (0, 1)
            ]
            _, pop = population_epoch(ds, model, cfgs, tmp / "plan-pop")
            pop_h = pop * factor * PAPER_EPOCHS * 6 / 2 / 3600  # 6 populations a network, each of two seeds
            total_pop += pop_h
            print(f"{label:26s} {steps:6d} {factor:6.1f} {pop:12.3f} {solo:10.3f} {pop_h:7.2f} {solo_h:7.2f}")
    pop_text = f"{total_pop:.1f} h" if train_population is not None else "n/a"
    print(f"full plan, one seed: populations {pop_text}; one run after another {total_solo:.1f} h")
    print("target (2 CPU cores): under 3 hours a seed")


def section_float32(ds, noisy, model, tmp: Path, epochs: int) -> None:
    print(f"\n4. --dtype float32 against float64: the physics loss (simple network, SGD, batch 256, {epochs} epochs)")
    if not hasattr(TrainConfig(), "dtype"):
        print("n/a (no --dtype)")
        return
    from ineid.learn.shared import float32_resolution

    for name, d in (("clean", ds), ("noisy (0.3 N, 0.03 N*m)", noisy)):
        split = split_configs(d.n_configs, None, None, None, 0)
        ws = d.measured().reshape(-1, 6)[: len(split.train) * d.n_frames].std(0)
        residual, rounding = float32_resolution(d, model, split.train, ws)
        print(
            f"{name}: wrench residual at the true parameters (normalized RMS) {residual:.2g}; float32 changes it "
            f"by {rounding:.2g} (relative {rounding / residual:.1e})"
        )
    base = TrainConfig(model=ModelSpec("simple"), optimizer="sgd", batch=256, epochs=epochs, patience=0, loss="physics")
    head = f"{'dataset':24s} {'dtype':8s} {'s/epoch':>8s} {'val_mse':>12s} {'val_phys':>12s} {'rel. diff':>20s}"
    print(head + "\n" + "-" * len(head))
    import json

    for name, d in (("clean", ds), ("noisy", noisy)):
        got = {}
        for dtype in ("float64", "float32"):
            sec = train_epoch(d, model, dataclasses.replace(base, dtype=dtype), tmp / dtype)
            last = json.loads((tmp / dtype / "metrics.jsonl").read_text().splitlines()[-1])
            got[dtype] = (sec, last["val_mse"], last["val_phys"])
        (s64, m64, p64), (s32, m32, p32) = got["float64"], got["float32"]
        diff = f"{abs(m32 - m64) / m64:.1e} / {abs(p32 - p64) / p64:.1e}"
        print(f"{name:24s} {'float64':8s} {s64:8.3f} {m64:12.6g} {p64:12.6g}")
        print(f"{name:24s} {'float32':8s} {s32:8.3f} {m32:12.6g} {p32:12.6g} {diff:>20s}  ({s64 / s32:.2f}x faster)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", type=int, default=600, help="configurations x 100 frames of the dataset")
    ap.add_argument("--epochs", type=int, default=5, help="epochs of each timed run")
    ap.add_argument("--plan-scale", type=float, default=0.05, help="the paper's split measured for the full plan")
    ap.add_argument("--plan-nets", nargs="*", help="only these networks of the full plan (default: all 16)")
    ap.add_argument("--skip", nargs="*", default=[], choices=["bare", "population", "plan", "float32"])
    args = ap.parse_args()
    model = ineid.load_robot("sweaty-arm")
    spec = DatasetSpec(Combination("random", n_configs=args.configs), n_frames=PAPER_FRAMES, seed=0)
    ds = generate_dataset(model, spec)
    split = split_configs(ds.n_configs, None, None, None, 0)
    print(f"machine: {cpu_description()}; jax {jax.__version__} on {jax.default_backend()}; ineid {ineid.__version__}")
    print(f"dataset: {args.configs} random configurations x 100 frames (training: {len(split.train)}), float64")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if "bare" not in args.skip:
            section_bare(ds, model, split, tmp, args.epochs)
        if "population" not in args.skip:
            section_population(ds, model, tmp, args.epochs)
        if "plan" not in args.skip:
            section_plan(ds, model, tmp, args.plan_scale, args.plan_nets)
        if "float32" not in args.skip:
            noise = NoiseModel.create(model.n_dof, force=0.3, moment=0.03)
            noisy = generate_dataset(model, dataclasses.replace(spec, noise=noise))
            section_float32(ds, noisy, model, tmp, args.epochs)


if __name__ == "__main__":
    main()
