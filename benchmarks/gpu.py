"""Throughput on the default JAX device (a GPU where there is one) against the same machine's CPU, one run.

Table 1, the evaluators: ``sweaty-arm`` (4 joints) and example-robot-data's Panda (7 joints, fingers
locked) on N random frames (q within the joint limits, qd and qdd within +-bounds, float64, seed 0),
``base_wrench`` (CAD parameters) and the full ``regressor``, on each device (the default one and the
CPU; one row set when they are the same):

* ``public``: ``model.base_wrench(q, qd, qdd)`` / ``model.regressor(q, qd, qdd)`` with ``q, qd, qdd``
  JAX arrays already on the device; the answer is a ``jax.Array`` there (waited for);
* ``raw``: the generated JAX function, ``jax.jit`` on the whole batch, the same device-resident arrays;
* ``NumPy``: the public call with NumPy arrays in and out (the host path, chunks streamed from one
  thread per core), once per table;
* ``Pinocchio`` (regressor, sweaty-arm): frame by frame from Python, on a slice of the frames
  (``benchmarks/compile.py`` has Pinocchio's per-frame times of 7-joint chains).

Every row's first frames are checked against ``model.regressor`` on NumPy (1e-10 relative); compile
time is excluded (each shape warmed first); the time is the best of ``--repeats``. The floors on a
GPU: device-resident ``base_wrench`` >= 100x and ``regressor`` >= 30x the same machine's CPU (the
public call on CPU arrays); ``model.regressor`` >= 10x Pinocchio (aim 20x).

Table 2, training: seconds per epoch of ``ineid.learn.train`` (the simple network, the paper's
dataset and split of ``ineid study networks``: 3,000 training configurations x 100 frames, batch
1024, SGD), as the difference of a 1- and a 3-epoch run after a warm-up run, against a bare loop:
the same-sized MLP (tanh, 18 inputs -> 20 -> 20 outputs), the same samples and batch, MSE and
Optax SGD with momentum, one jitted ``lax.scan`` per epoch over device-resident data. Floor: within 3x
the bare loop; on a GPU under 10 ms.

Table 3, ``ineid study networks --plan full`` (both seeds) estimated from measured trials: each of its
trials costs its epochs x the measured seconds per epoch of a representative network plus the fixed
cost of a run (its compile, split, scalers, evaluation); the representatives: the simple network
for itself, Network 6 for the single-frame networks of Table 1 and the funnel, Network 6 as a Siamese
network of K = 10 frames for the Siamese part. Floor: under 10 minutes on one H100/H200.

``--quick`` is a smoke test (a few thousand frames, sweaty-arm only, a tiny dataset): it runs on any
machine in seconds and its numbers mean nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import cpu_description  # benchmarks/machine.py
from public_api import best  # benchmarks/public_api.py
from regressor import PANDA_LOCKED, pinocchio_steps, sample  # benchmarks/regressor.py

import ineid  # float64 JAX before jax is used

FLOORS = {"base_wrench": 100.0, "regressor": 30.0}
"""Device-resident public call over the same machine's CPU public call, on a GPU."""


def machine_lines() -> list[str]:
    """What the run was measured on: JAX's devices and backend, the CPU, the cores this process may use."""
    import jax

    devices = ", ".join(f"{d.platform}:{d.device_kind}" for d in jax.devices())
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return [
        f"JAX {jax.__version__}, default backend {jax.default_backend()}; devices: {devices}",
        f"CPU: {cpu_description()} ({usable} usable); ineid {ineid.__version__}; float64",
    ]


def robots(quick: bool) -> list[tuple[str, object]]:
    """``(name, model)``: sweaty-arm, and the Panda unless ``quick``."""
    out = [("sweaty-arm", ineid.load_robot("sweaty-arm"))]
    if not quick:
        import importlib.metadata as md

        erd = md.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
        out.append(("panda", ineid.load_robot(erd / "panda_description/urdf/panda.urdf", locked_joints=PANDA_LOCKED)))
    return out


def check(label: str, y, ref: np.ndarray) -> None:
    """Fail loudly unless ``y`` matches ``ref`` (its first frames) to 1e-10 relative."""
    y = np.asarray(y)[: len(ref)]
    err = float(np.max(np.abs(y - ref)) / max(np.max(np.abs(ref)), 1e-300))
    if not err <= 1e-10:
        raise AssertionError(f"{label} differs from the NumPy evaluator by {err:.3g} (relative)")


def evaluator_rows(name: str, model, n: int, device, repeats: int) -> list[tuple]:
    """``(robot, what, device, frames, seconds)`` of the public and raw calls on device-resident arrays."""
    import jax

    states = sample(model, n)
    on = [jax.device_put(x, device) for x in states]
    g = jax.device_put(np.asarray(model.gravity), device)
    theta = jax.device_put(np.asarray(model.theta_cad), device)
    ref_states = [x[:50] for x in states]
    calls = {
        "base_wrench": (
            lambda: model.base_wrench(*on),
            jax.jit(lambda q, qd, qdd: model.jax_base_wrench(q, qd, qdd, g, theta)),
            model.base_wrench(*ref_states),
        ),
        "regressor": (
            lambda: model.regressor(*on),
            jax.jit(lambda q, qd, qdd: model.jax_regressor(q, qd, qdd, g)),
            model.regressor(*ref_states),
        ),
    }
    rows = []
    for what, (public, raw, ref) in calls.items():
        for label, fn in (("public", public), ("raw jit", lambda raw=raw: raw(*on))):
            check(f"{name} {what} {label} on {device.platform}", fn(), ref)  # also compiles every shape
            sec = best(lambda fn=fn: jax.block_until_ready(fn()), repeats)
            rows.append((name, what, label, device.platform, n, sec))
    return rows


def host_rows(name: str, model, n: int, peer_n: int, repeats: int) -> list[tuple]:
    """The NumPy path (NumPy in and out) and the Pinocchio peer (regressor) on the CPU."""
    states = sample(model, n)
    rows = []
    for what, fn in (("base_wrench", model.base_wrench), ("regressor", model.regressor)):
        fn(*(x[:5000] for x in states))
        rows.append((name, what, "NumPy in/out", "host", n, best(lambda fn=fn: fn(*states), repeats)))
    if model.n_dof != len(model.joint_names) or name != "sweaty-arm":
        return rows  # the Panda's locked fingers are not Pinocchio's model; benchmarks/compile.py has 7-joint peers
    m = min(peer_n, n)
    step = pinocchio_steps(model, states, "free-flyer")(m)
    check(f"{name} Pinocchio", step(0, 50).copy(), model.regressor(*(x[:50] for x in states)))
    rows.append((name, "regressor", "Pinocchio/frame", "host", m, best(lambda: step(0, m), repeats)))
    return rows


def evaluators_table(args) -> None:
    """Table 1 (see the module doc), with its floors."""
    import jax

    default = jax.devices()[0]
    cpu = jax.devices("cpu")[0]
    devices = [default] if default.platform == "cpu" else [default, cpu]
    rows = []
    for name, model in robots(args.quick):
        for device in devices:
            n = args.frames if device.platform != "cpu" else args.cpu_frames
            rows += evaluator_rows(name, model, n, device, args.repeats)
        rows += host_rows(name, model, args.cpu_frames, args.peer_frames, args.repeats)
    rate = {(r[0], r[1], r[2], r[3]): r[4] / r[5] for r in rows}
    head = f"{'robot':11s} {'call':12s} {'how':16s} {'device':7s} {'frames':>10s} {'M frames/s':>11s} {'vs CPU':>8s}"
    print(head)
    print("-" * len(head))
    for robot, what, how, platform, n, sec in rows:
        cpu_rate = rate.get((robot, what, "public", "cpu"))
        vs = f"{n / sec / cpu_rate:7.1f}x" if cpu_rate and platform != "host" else ""
        print(f"{robot:11s} {what:12s} {how:16s} {platform:7s} {n:10,d} {n / sec / 1e6:11.3f} {vs:>8s}")
    print()
    for robot in dict.fromkeys(r[0] for r in rows):
        if default.platform != "cpu":
            for what, floor in FLOORS.items():
                r = rate[(robot, what, "public", default.platform)] / rate[(robot, what, "public", "cpu")]
                print(
                    f"floor: {robot} {what} on {default.platform} >= {floor:.0f}x CPU: {r:.1f}x -> "
                    f"{'MET' if r >= floor else 'MISSED'}"
                )
        peer = rate.get((robot, "regressor", "Pinocchio/frame", "host"))
        if peer is not None:
            ratio = rate[(robot, "regressor", "NumPy in/out", "host")] / peer
            best_cpu = rate[(robot, "regressor", "public", "cpu")] / peer
            verdict = "MET" if max(ratio, best_cpu) >= 10 else "MISSED"
            print(
                f"floor: {robot} model.regressor >= 10x Pinocchio per frame: NumPy {ratio:.1f}x, CPU arrays "
                f"{best_cpu:.1f}x -> {verdict}; aim 20x {'met' if max(ratio, best_cpu) >= 20 else 'not met'}"
            )
    if default.platform == "cpu":
        print("no accelerator: the device rows are the CPU's; the GPU floors are not measured by this run")


# -- training ----------------------------------------------------------------------------------------


def bare_epoch_seconds(n_samples: int, batch: int, repeats: int) -> float:
    """Seconds per epoch of the bare Optax loop (see the module doc) on JAX's default device."""
    import jax
    import jax.numpy as jnp
    import optax

    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(n_samples, 18)))
    y = jnp.asarray(rng.normal(size=(n_samples, 20)))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    params = {
        "w1": jax.random.normal(keys[0], (18, 20)) * 0.2,
        "b1": jnp.zeros(20),
        "w2": jax.random.normal(keys[1], (20, 20)) * 0.2,
        "b2": jnp.zeros(20),
    }
    opt = optax.sgd(1e-3, momentum=0.9)
    n_steps = n_samples // batch

    def loss(p, xb, yb):
        h = jnp.tanh(xb @ p["w1"] + p["b1"])
        return jnp.mean((h @ p["w2"] + p["b2"] - yb) ** 2)

    @jax.jit
    def epoch(p, s, key):
        order = jax.random.permutation(key, n_samples)[: n_steps * batch].reshape(n_steps, batch)

        def step(carry, idx):
            p, s = carry
            value, grads = jax.value_and_grad(loss)(p, x[idx], y[idx])
            updates, s = opt.update(grads, s, p)
            return (optax.apply_updates(p, updates), s), value

        (p, s), values = jax.lax.scan(step, (p, s), order)
        return p, s, values.mean()

    state = opt.init(params)
    jax.block_until_ready(epoch(params, state, keys[2]))
    return best(lambda: jax.block_until_ready(epoch(params, state, keys[3])), repeats)


def train_epoch_seconds(ds, model, cfg, folder: Path) -> tuple[float, float]:
    """``(seconds per epoch, fixed seconds of a run)`` of ``ineid.learn.train`` at ``cfg``: runs of 1 and 3
    epochs after a warm-up run (compilation cache filled); best of two each."""
    from ineid.learn import train

    train(ds, dataclasses.replace(cfg, epochs=1), folder, overwrite=True, model=model)
    t = {}
    for epochs in (1, 3):
        run = dataclasses.replace(cfg, epochs=epochs)
        t[epochs] = best(lambda run=run: train(ds, run, folder, overwrite=True, model=model), 2)
    per_epoch = max((t[3] - t[1]) / 2, 1e-9)
    return per_epoch, max(t[1] - per_epoch, 0.0)


def study_size(quick: bool):
    """The network study's size (:data:`ineid.studies.paper_networks.SIZES`), ``quick`` or ``paper``."""
    from ineid.studies.paper_networks import SIZES

    return SIZES["quick" if quick else "paper"]


def study_trials(quick: bool) -> list[tuple[str, object]]:
    """Every trial of ``ineid study networks --plan full`` (both seeds; ``quick``: the quick plan):
    ``(representative, TrainConfig)``, the representative network whose epochs stand for the trial's."""
    from ineid.studies.paper_networks import base_config, plan

    size = study_size(quick)
    out = []
    for part in plan("quick" if quick else "full"):
        for seed in size.seeds:
            for cfg in part.grid.configs(base_config(size, part, seed)):
                spec = cfg.model
                rep = "siamese" if spec.siamese else ("simple" if spec.arch == "simple" else "net6")
                out.append((rep, cfg))
    return out


def representatives(trials) -> dict[str, object]:
    """The trial each representative network is measured on (tanh, robust scaler, SGD where the plan has them)."""
    reps: dict[str, object] = {}
    for rep, cfg in trials:
        if rep == "simple" or cfg.model.arch == "net6" or rep not in reps:
            preferred = (cfg.model.activation, cfg.scaler, cfg.optimizer) == ("tanh", "robust", "sgd")
            if rep not in reps or (preferred and cfg.model.arch in ("simple", "net6")):
                reps[rep] = cfg
    return reps


def learn_tables(args) -> None:
    """Tables 2 and 3 (see the module doc)."""
    from ineid.data import generate_dataset

    size = study_size(args.quick)
    model = ineid.load_robot("sweaty-arm")
    t0 = time.perf_counter()
    ds = generate_dataset(model, size.dataset)
    print(
        f"dataset: {ds.n_configs} configurations x {ds.n_frames} frames, generated in {time.perf_counter() - t0:.1f} s"
    )
    trials = study_trials(args.quick)
    reps = representatives(trials)
    measured = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rep, cfg in reps.items():
            if rep != "simple" and args.skip_study:
                continue
            measured[rep] = train_epoch_seconds(ds, model, cfg, Path(tmp) / rep)
    simple = reps["simple"]
    n_samples = (simple.n_train or ds.n_configs) * ds.n_frames
    bare = bare_epoch_seconds(n_samples, simple.batch, args.repeats)
    per_epoch, fixed = measured["simple"]
    head = f"{'training epoch (simple network)':44s} {'samples':>9s} {'batch':>6s} {'ms/epoch':>9s} {'vs bare':>8s}"
    print(head)
    print("-" * len(head))
    print(
        f"{'ineid.learn.train (3 - 1 epochs) / 2':44s} {n_samples:9,d} {simple.batch:6d} {per_epoch * 1e3:9.2f} "
        f"{per_epoch / bare:7.2f}x"
    )
    print(f"{'bare Optax loop (jit lax.scan epoch)':44s} {n_samples:9,d} {simple.batch:6d} {bare * 1e3:9.2f} {1:7.2f}x")
    print(f"fixed cost of a run (compile, split, scalers, evaluation): {fixed:.2f} s")
    ratio = per_epoch / bare
    print(
        f"floor: ineid train epoch <= 3x the bare loop: {ratio:.2f}x -> {'MET' if ratio <= 3 else 'MISSED'}; "
        f"under 10 ms (a GPU's floor): {per_epoch * 1e3:.1f} ms"
    )
    if args.skip_study:
        return
    print()
    head = f"{'study part (representative)':34s} {'trials':>7s} {'epochs':>8s} {'s/epoch':>9s} {'fixed s':>8s}"
    head += f" {'est. s':>9s}"
    print(head)
    print("-" * len(head))
    total = 0.0
    for rep in reps:
        mine = [cfg for r, cfg in trials if r == rep]
        epochs = sum(cfg.epochs for cfg in mine)
        sec_epoch, sec_fixed = measured[rep]
        est = epochs * sec_epoch + len(mine) * sec_fixed
        total += est
        print(f"{rep:34s} {len(mine):7d} {epochs:8,d} {sec_epoch:9.4f} {sec_fixed:8.2f} {est:9.1f}")
    plan = "quick" if args.quick else "full"
    print(
        f"estimate: ineid study networks --plan {plan} ({len(trials)} trials): {total / 60:.1f} min; "
        f"floor under 10 min on one H100/H200 -> {'MET' if total < 600 else 'MISSED'} on this machine"
    )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=4_000_000, help="frames on an accelerator")
    ap.add_argument("--cpu-frames", type=int, default=400_000, help="frames on the CPU")
    ap.add_argument("--peer-frames", type=int, default=5_000, help="frames for Pinocchio, frame by frame")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-study", action="store_true", help="time the simple network only (no study estimate)")
    ap.add_argument("--quick", action="store_true", help="smoke test: few frames, sweaty-arm, the quick study")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.cpu_frames, args.peer_frames, args.repeats = 50, 50, 50, 1
    t0 = time.perf_counter()
    print("\n".join(machine_lines()))
    print()
    evaluators_table(args)
    print(f"({time.perf_counter() - t0:.0f} s)\n")
    learn_tables(args)
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
