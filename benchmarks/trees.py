"""Kinematic trees on a fixed base: derivation, evaluation against Pinocchio, and the first solve.

Robots (example-robot-data, fixed base): ``talos``, the Talos humanoid of ``talos_reduced.urdf`` held at its
waist (32 moving joints: two 6-joint legs, a 2-joint torso carrying a 2-joint head and two arms of 7 joints
and a gripper motor); ``baxter`` (15: the head and both 7-joint arms, the mimic gripper fingers locked).

Table 1, code generation, one fresh process per robot with an empty ``INEID_CACHE_DIR``: derive = seconds of
the SymPy derivation of the structured Newton-Euler program (wall, and CPU of that process); print = printing
its JAX and CasADi modules; ops = the program's operation count; named = its named values; load =
``ineid.load_robot`` afterwards on the empty cache (derive, print, write, import: what a user's first call
costs before any kernel is compiled).

Table 2, evaluation of the full 6 x 10n base-wrench regressor on N random frames (q uniform within the joint
limits, qd, qdd within +-bounds, seed 0), frames per second, best of ``--repeats`` passes: the generated JAX
function (``jax.jit(model.jax_regressor)`` on 2048-frame chunks, the chunk the public evaluators use, and on
256-frame chunks, whose output stays in the CPU's caches: Talos' 6 x 320 regressor is 31 MB per 2048 frames;
trace + lower and XLA compile seconds of the 2048-frame kernel stated separately, with JAX's persistent cache
off so the compile is a real one), the generated CasADi function (``Function.map`` over 2048-frame chunks,
serial, and "thread" x2), and Pinocchio from Python frame by frame (``computeJointTorqueRegressor`` of the
URDF on a free-flyer root held at identity, rows 0-5, negated, the same locks; only the call and the copy are
timed, its columns are mapped to ineid's joint order for the check). Each method's first chunk is checked
against Pinocchio on the first 20 frames (1e-10 relative) before it is timed.

Table 3, the first solve: ``ineid data generate`` of 3 configurations x 100 frames (uniform frames, noise
``force=0.5,moment=0.05`` as in ``make demo``) and ``ineid solve`` of it (the default ``linear``; with
``--consistent`` also ``--method consistent``), each command in its own process. "first" runs on an empty
cache folder (the derivation, and every XLA compilation, included); "warm" repeats it on that folder
(generated code and compiled kernels reused). Columns: wall seconds of the command, its CPU seconds, the
derivation's seconds (ineid's log), XLA compile seconds summed over the kernels JAX compiled or read from
its persistent cache (``JAX_LOG_COMPILES``; "k/h": kernels / cache hits), and the rest (start-up, I/O, the
solve itself).

The machine, the libraries and the load average (before and after) are printed: the machine is often shared.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["INEID_XLA_CACHE"] = "0"  # table 2's compile is a real one (table 3's processes get the default)

import numpy as np
from machine import cpu_description
from regressor import sample  # the arms' frames: the same sampling

import ineid  # turns on JAX's float64 mode before jax is used

CHUNK = 2048
SMALL_CHUNK = 256
ERD = md.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
ROBOTS = {
    "talos": ("talos_data/robots/talos_reduced.urdf", {}),
    "baxter": (
        "baxter_description/urdf/baxter.urdf",
        {f"{s}_gripper_{f}_finger_joint": 0.0 for s in "lr" for f in "lr"},
    ),
}
NOISE = "force=0.5,moment=0.05"


def robot_path(name: str) -> tuple[Path, dict]:
    """URDF path and locked joints of a robot of :data:`ROBOTS`."""
    rel, locked = ROBOTS[name]
    return Path(ERD) / rel, locked


def derive_child(name: str) -> None:
    """Table 1's row for ``name``, printed as one JSON line (run in a fresh process, empty cache)."""
    from ineid.robots.urdf import load_chain
    from ineid.symbolic.emit import emit_modules
    from ineid.symbolic.newton_euler import derive_base_wrench_regressor

    path, locked = robot_path(name)
    chain = load_chain(path, locked_joints=locked or None)
    c0, t0 = time.process_time(), time.perf_counter()
    sym = derive_base_wrench_regressor(chain)
    c1, t1 = time.process_time(), time.perf_counter()
    emitted = emit_modules(sym, name)
    c2, t2 = time.process_time(), time.perf_counter()
    ineid.load_robot(path, locked_joints=locked or None)
    t3 = time.perf_counter()
    row = {"dof": chain.n_dof, "derive": t1 - t0, "derive_cpu": c1 - c0, "print": t2 - t1, "print_cpu": c2 - c1}
    row |= {"ops": emitted.op_count, "named": emitted.n_lines, "load": t3 - t2}
    print(json.dumps(row))


def codegen_row(name: str) -> dict:
    """Run :func:`derive_child` in a fresh process on an empty cache folder."""
    with tempfile.TemporaryDirectory(prefix="ineid-bench-trees-") as cache:
        env = os.environ | {"INEID_CACHE_DIR": cache}
        out = subprocess.run(
            [sys.executable, __file__, "--derive-child", name], env=env, capture_output=True, text=True, check=True
        )
    return json.loads(out.stdout.strip().splitlines()[-1])


def best_of(step, n: int, repeats: int, chunk: int = CHUNK) -> float:
    """Best seconds over ``repeats`` passes of ``step(start, stop)`` over frames [0, n) in chunks."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for s in range(0, n, chunk):
            step(s, min(s + chunk, n))
        best = min(best, time.perf_counter() - t0)
    return best


def check(label: str, y, ref: np.ndarray) -> None:
    """Fail loudly unless ``y`` (frames, 6, 10n) matches ``ref`` to 1e-10 relative on ``ref``'s frames."""
    err = float(np.max(np.abs(np.asarray(y)[: len(ref)] - ref)) / np.max(np.abs(ref)))
    if not err <= 1e-10:
        raise AssertionError(f"{label}: regressor differs from Pinocchio's by {err:.3g} (relative)")


def pinocchio_free_flyer(model, path: Path, locked: dict, data, ref_frames: int = 20):
    """(step, reference): Pinocchio's base regressor frame by frame, and its first frames in ineid's order."""
    import pinocchio as pin

    from ineid.reference import pinocchio_model

    pm = pinocchio_model(path, model.gravity, locked, free_flyer=True)
    jids = [pm.getJointId(j) for j in model.joint_names]
    if any(pm.joints[j].nq != 1 for j in jids) or pm.nv != 6 + model.n_dof:
        raise AssertionError("the free-flyer route needs one-coordinate joints")
    iq, iv = [pm.joints[j].idx_q for j in jids], [pm.joints[j].idx_v for j in jids]
    # column block of ineid's link i: Pinocchio's body of joint jids[i]; the free flyer's own body is block 0
    cols = np.concatenate([np.arange(10 * (j - 2), 10 * (j - 1)) for j in jids])
    pd, reg, (q, qd, qdd) = pm.createData(), pin.computeJointTorqueRegressor, data
    buf = np.empty((CHUNK, 6, 10 * model.n_dof))

    def step(s, e):
        k, out = e - s, buf[: e - s]
        Q, V, A = np.tile(pin.neutral(pm), (k, 1)), np.zeros((k, pm.nv)), np.zeros((k, pm.nv))
        Q[:, iq], V[:, iv], A[:, iv] = q[s:e], qd[s:e], qdd[s:e]
        for i in range(k):  # rows 0..5: the wrench the fixture applies; columns 0..9: the free flyer's body
            out[i] = reg(pm, pd, Q[i], V[i], A[i])[:6, 10:]
        return np.negative(out, out=out)

    return step, step(0, ref_frames)[:, :, cols].copy()


def jax_method(model, data, chunk: int = CHUNK):
    """(lower s, compile s, compile CPU s, step) of the generated JAX regressor on ``chunk`` frames."""
    import jax

    q, qd, qdd = data
    g = jax.numpy.asarray(model.gravity)
    t0 = time.perf_counter()
    lowered = jax.jit(model.jax_regressor).trace(q[:chunk], qd[:chunk], qdd[:chunk], g).lower()
    t1, c1 = time.perf_counter(), time.process_time()
    compiled = lowered.compile()
    t2, c2 = time.perf_counter(), time.process_time()

    def step(s, e):
        return compiled(q[s:e], qd[s:e], qdd[s:e], g).block_until_ready()

    return t1 - t0, t2 - t1, c2 - c1, step


def casadi_method(model, data, mode: str):
    """Step of the generated CasADi regressor mapped over CHUNK frames; frames as (k, 6, 10n)."""
    import casadi as ca

    F, (q, qd, qdd) = model.casadi_regressor, data
    mapped = F.map(CHUNK, "thread", 2) if mode == "thread" else F.map(CHUNK, "serial")
    cols = 10 * model.n_dof

    def step(s, e):
        y = mapped(ca.DM(q[s:e].T), ca.DM(qd[s:e].T), ca.DM(qdd[s:e].T))
        return y.full().reshape(6, -1, cols).transpose(1, 0, 2)

    return step


def evaluation_rows(name: str, n: int, repeats: int) -> tuple[list[tuple], tuple]:
    """Table 2's rows for ``name``: (method, frames/s); and the JAX (lower, compile, compile CPU) seconds."""
    path, locked = robot_path(name)
    with tempfile.TemporaryDirectory(prefix="ineid-bench-trees-") as gen:
        model = ineid.load_robot(path, locked_joints=locked or None, codegen_dir=gen)
        data = sample(model, n)
        pin_step, ref = pinocchio_free_flyer(model, path, locked, data)
        lower, comp, comp_cpu, jax_step = jax_method(model, data)
        methods = [
            ("JAX jit, 2048-frame chunks", jax_step, CHUNK),
            (f"JAX jit, {SMALL_CHUNK}-frame chunks", jax_method(model, data, SMALL_CHUNK)[-1], SMALL_CHUNK),
            ("CasADi map serial, 2048-frame chunks", casadi_method(model, data, "serial"), CHUNK),
            ("CasADi map thread x2, 2048-frame chunks", casadi_method(model, data, "thread"), CHUNK),
        ]
        rows = []
        for label, step, chunk in methods:
            check(f"{name} {label}", step(0, chunk), ref)
            rows.append((label, n / best_of(step, n, repeats, chunk)))
        rows.append(("Pinocchio per frame, free-flyer JTR rows 0-5", n / best_of(pin_step, n, repeats)))
    return rows, (lower, comp, comp_cpu)


COMPILE_RE = re.compile(r"Finished XLA compilation of .* in ([0-9.eE+-]+) sec")
DERIVE_RE = re.compile(r"finished for '.*' after ([0-9.]+) s")


def timed(cmd: list[str], cache: str) -> dict:
    """Run an ``ineid`` command in its own process; wall, CPU, derivation and XLA compile seconds."""
    env = {k: v for k, v in os.environ.items() if k != "INEID_XLA_CACHE"} | {
        "INEID_CACHE_DIR": cache,
        "JAX_LOG_COMPILES": "1",
    }
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "ineid.cli", "-v", *cmd], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode:
        raise SystemExit(f"ineid {' '.join(cmd[:2])} failed: {out.stderr.strip().splitlines()[-1]}")
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return {"wall": wall, "cpu": cpu, **read_log(out.stderr)}


def read_log(stderr: str) -> dict:
    """Derivation seconds, XLA compile seconds, kernels compiled and persistent-cache hits of a command's log."""
    compiles = [float(x) for x in COMPILE_RE.findall(stderr)]
    derive = sum(float(x) for x in DERIVE_RE.findall(stderr))
    hits = stderr.count("Persistent compilation cache hit")
    return {"derive": derive, "xla": sum(compiles), "kernels": len(compiles), "hits": hits}


def solve_rows(name: str, methods: list[str], folder: Path) -> list[tuple[str, str, dict]]:
    """Table 3's rows for ``name``: (step, first/warm, timings); each first run on an empty cache folder."""
    path, locked = robot_path(name)
    locks = [x for j, v in locked.items() for x in ("--lock", f"{j}={v}")]
    h5 = str(folder / f"{name}.h5")
    generate = ["data", "generate", str(path), *locks, "--n-configs", "3", "--n-frames", "100", "--seed", "1"]
    generate += ["--noise", NOISE, "--out", h5, "--overwrite"]
    steps = [("data generate", generate)]
    for method in methods:
        res = str(folder / f"{name}-{method}.h5")
        steps.append((f"solve --method {method}", ["solve", h5, "--method", method, "--out", res, "--overwrite"]))
    rows = []
    for k, (label, cmd) in enumerate(steps):
        cache = str(folder / f"cache-{k}")
        for run in ("first", "warm"):
            rows.append((label, run, timed(cmd, cache)))
    return rows


def print_tables(args) -> None:
    """Measure and print the three tables."""
    print("\n1. code generation: one fresh process per robot, empty INEID_CACHE_DIR; seconds (wall, CPU)")
    print(
        f"{'robot':<8} {'joints':>6} {'derive s':>9} {'cpu':>6} {'print s':>8} {'cpu':>6} {'ops':>8} "
        f"{'named':>7} {'load s':>7}"
    )
    for name in args.robots:
        r = codegen_row(name)
        print(
            f"{name:<8} {r['dof']:>6} {r['derive']:>9.2f} {r['derive_cpu']:>6.2f} {r['print']:>8.2f} "
            f"{r['print_cpu']:>6.2f} {r['ops']:>8,} {r['named']:>7,} {r['load']:>7.2f}",
            flush=True,
        )
    print(f"\n2. base-wrench regressor (6 x 10n), float64, {args.frames:,} random frames, best of {args.repeats}")
    print(f"{'robot':<8} {'method':<46} {'frames/s':>11} {'vs Pinocchio':>13}")
    compiles = []
    for name in args.robots:
        rows, compile_s = evaluation_rows(name, args.frames, args.repeats)
        compiles.append((name, *compile_s))
        pin_fps = rows[-1][1]
        for label, fps in rows:
            print(f"{name:<8} {label:<46} {fps:>11,.0f} {fps / pin_fps:>12.2f}x", flush=True)
    for name, lower, comp, comp_cpu in compiles:
        print(
            f"{name}: JAX regressor on {CHUNK} frames: trace + lower {lower:.2f} s, XLA compile {comp:.2f} s "
            f"({comp_cpu:.2f} s CPU)"
        )
    methods = ["linear", "consistent"] if args.consistent else ["linear"]
    print(f"\n3. first solve: data generate 3 x 100 frames (noise {NOISE}), solve; one process per command")
    print(
        f"{'robot':<8} {'command':<26} {'run':<6} {'wall s':>7} {'cpu s':>7} {'derive s':>9} "
        f"{'XLA s':>7} {'k/h':>6} {'rest s':>7}"
    )
    with tempfile.TemporaryDirectory(prefix="ineid-bench-trees-") as tmp:
        for name in args.robots:
            for label, run, r in solve_rows(name, methods, Path(tmp)):
                rest, kh = r["wall"] - r["derive"] - r["xla"], f"{r['kernels']}/{r['hits']}"
                print(
                    f"{name:<8} {label:<26} {run:<6} {r['wall']:>7.1f} {r['cpu']:>7.1f} {r['derive']:>9.1f} "
                    f"{r['xla']:>7.1f} {kh:>6} {rest:>7.1f}",
                    flush=True,
                )


def main(argv=None) -> None:
    """Parse options, print the machine, the tables and the load."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default=",".join(ROBOTS), help=f"comma-separated, of {', '.join(ROBOTS)}")
    ap.add_argument("--frames", type=int, default=20_480, help="random frames evaluated (default 20480)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes; the best is reported (default 3)")
    ap.add_argument("--consistent", action="store_true", help="also time `ineid solve --method consistent`")
    ap.add_argument("--quick", action="store_true", help="smoke run: 2048 frames, 1 repeat")
    ap.add_argument("--derive-child", metavar="ROBOT", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.derive_child:
        return derive_child(args.derive_child)
    if args.quick:
        args.frames, args.repeats = CHUNK, 1
    args.robots = args.robots.split(",")
    unknown = sorted(set(args.robots) - set(ROBOTS))
    if unknown:
        ap.error(f"unknown robot {unknown[0]!r}; choose from {', '.join(ROBOTS)}")
    versions = ", ".join(f"{d} {md.version(d)}" for d in ("jax", "casadi", "sympy", "pin"))
    print(f"CPU: {cpu_description()}; {versions}; Python {platform.python_version()}")
    print("load average before: " + " ".join(f"{x:.2f}" for x in os.getloadavg()), flush=True)
    print_tables(args)
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
