"""What a new arm costs before its first answer: derivation, compilation, first call, against the joints.

For synthetic serial chains of 4, 5, 6, 7 and 12 revolute joints (:func:`synthetic_urdf`:
axes cycling z, y, x, -z; generic offsets and rpy, some quarter turns; physical random
inertias; seeded) the table gives, per chain:

- derive, print: seconds of the SymPy derivation of the structured Newton-Euler program and
  of printing its JAX and CasADi modules (``ineid.symbolic``), and its operation count;
- load: ``ineid.load_robot`` on an empty code cache (derive, print, write, import);
- for the JAX regressor ``jax.jit(model.jax_regressor)`` and base wrench
  ``jax.jit(model.jax_base_wrench)`` on one chunk of 2048 frames (the chunk the public
  evaluators and the solvers compile): trace + lower seconds, XLA compile seconds, the first
  call of the compiled executable, and the warm time per frame (best of 5 calls);
- CasADi (no compilation): building the ``SX`` functions from the generated module, and the
  time per frame of the regressor through ``Function.map`` (serial) over 2048 frames;
- Pinocchio (the peer, needs no compilation): time per frame from Python, frame by frame,
  of ``computeJointTorqueRegressor`` (the n x 10n joint-torque regressor), ``rnea`` and
  ineid.reference's base regressor (``jointBodyRegressor`` blocks), best of 3 passes of 300.

Compile and derivation times are also given in CPU seconds of this process (the steadier
figure on a shared machine). JAX's persistent compilation cache is off, so every compile is
a real one. Every result is
checked against Pinocchio's base regressor on 20 frames (1e-12 relative) before it is timed.
The load average (``os.getloadavg``) is printed before and after: the machine is often shared.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import math
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ["INEID_XLA_CACHE"] = "0"  # every compile a real one: no executable from a previous run

import numpy as np
from machine import cpu_description

import ineid  # turns on JAX's float64 mode before jax is used

CHUNK = 2048
JOINTS = (4, 5, 6, 7, 12)


def synthetic_urdf(n: int, folder: Path, seed: int = 7) -> Path:
    """A serial chain of ``n`` revolute joints, written to ``folder/chain{n}.urdf``.

    Axes cycle z, y, x, -z; joint origins are generic (0.15 m up, +-0.1 m), every third
    joint turned a quarter about x, every fourth by a random angle about y; each link a
    random physical inertia (positive mass, triangle inequality) about a tilted frame.
    """
    rng = np.random.default_rng(seed)
    axes = ["0 0 1", "0 1 0", "1 0 0", "0 0 -1"]
    parts = [f'<robot name="chain{n}">', '<link name="base"/>']
    prev = "base"
    for i in range(n):
        m = rng.uniform(0.5, 3.0)
        c = rng.uniform(-0.05, 0.05, 3)
        d = rng.uniform(0.002, 0.02, 3)
        ixx, iyy, izz = d[1] + d[2], d[0] + d[2], d[0] + d[1]
        xyz = rng.uniform(-0.1, 0.1, 3) + np.array([0, 0, 0.15])
        rpy = [math.pi / 2 if i % 3 == 1 else 0.0, rng.uniform(-0.3, 0.3) if i % 4 == 2 else 0.0, 0.0]
        parts.append(
            f'<link name="l{i}"><inertial><origin xyz="{c[0]} {c[1]} {c[2]}" rpy="0.1 0.2 0.3"/>'
            f'<mass value="{m}"/><inertia ixx="{ixx}" ixy="0.0001" ixz="-0.0002" iyy="{iyy}" iyz="0.0003" '
            f'izz="{izz}"/></inertial></link>'
        )
        parts.append(
            f'<joint name="j{i}" type="revolute"><parent link="{prev}"/><child link="l{i}"/>'
            f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>'
            f'<axis xyz="{axes[i % 4]}"/><limit lower="-2.5" upper="2.5" velocity="2" effort="10"/></joint>'
        )
        prev = f"l{i}"
    parts.append("</robot>")
    path = folder / f"chain{n}.urdf"
    path.write_text("\n".join(parts))
    return path


def aot(fn, args) -> tuple[float, float, float, float, float, object]:
    """(trace + lower s, compile s, compile CPU s, first call s, warm s per call) of ``jax.jit(fn)``
    on ``args``, and the result."""
    import jax

    t0 = time.perf_counter()
    lowered = jax.jit(fn).trace(*args).lower()
    t1 = time.perf_counter()
    cpu = time.process_time()
    compiled = lowered.compile()
    cpu = time.process_time() - cpu
    t2 = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    t3 = time.perf_counter()
    warm = []
    for _ in range(5):
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        warm.append(time.perf_counter() - t)
    return t1 - t0, t2 - t1, cpu, t3 - t2, min(warm), out


def per_frame(fn, n: int, passes: int = 3) -> float:
    """Best seconds per frame of ``fn(n)`` (which runs ``n`` frames)."""
    best = math.inf
    for _ in range(passes):
        t = time.perf_counter()
        fn(n)
        best = min(best, (time.perf_counter() - t) / n)
    return best


def pinocchio_row(path: Path, q, qd, qdd, check) -> tuple[float, float, float]:
    """Pinocchio's seconds per frame (joint-torque regressor, rnea, base regressor), after checking ``check``."""
    import pinocchio as pin

    from ineid.reference import pinocchio_base_regressor, pinocchio_model, pinocchio_q

    model = pinocchio_model(path, (0.0, 0.0, -9.81))
    data = model.createData()
    ref = pinocchio_base_regressor(model, q[:20], qd[:20], qdd[:20], data)
    err = np.abs(check - ref).max() / np.abs(ref).max()
    if err > 1e-12:
        raise SystemExit(f"{path.name}: ineid's regressor differs from Pinocchio's by {err:.1e} (relative)")
    pq = np.stack([pinocchio_q(model, x) for x in q[:300]])

    def jtr(n):
        for k in range(n):
            pin.computeJointTorqueRegressor(model, data, pq[k], qd[k], qdd[k])

    def rnea(n):
        for k in range(n):
            pin.rnea(model, data, pq[k], qd[k], qdd[k])

    def base(n):
        pinocchio_base_regressor(model, q[:n], qd[:n], qdd[:n], data)

    return per_frame(jtr, 300), per_frame(rnea, 300), per_frame(base, 300)


def measure(n: int, folder: Path) -> dict:
    """One row of the table for the ``n``-joint chain."""
    import casadi as ca
    import jax.numpy as jnp

    from ineid.robots.urdf import load_chain
    from ineid.symbolic.emit import emit_modules
    from ineid.symbolic.newton_euler import derive_base_wrench_regressor

    path = synthetic_urdf(n, folder)
    chain = load_chain(path)
    cpu = time.process_time()
    t0 = time.perf_counter()
    sym = derive_base_wrench_regressor(chain)
    t1 = time.perf_counter()
    emitted = emit_modules(sym, chain.name)
    t2 = time.perf_counter()
    cpu = time.process_time() - cpu
    model = ineid.load_robot(path, codegen_dir=folder / f"gen{n}")
    t3 = time.perf_counter()

    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-1.0, 1.0, (CHUNK, n)) for _ in range(3))
    g = jnp.asarray(model.gravity)
    reg = aot(model.jax_regressor, (q, qd, qdd, g))
    theta = jnp.asarray(model.theta_cad)
    wrench = aot(model.jax_base_wrench, (q, qd, qdd, g, theta))
    y = np.asarray(reg[-1])
    w_err = np.abs(np.asarray(wrench[-1]) - y @ model.theta_cad).max() / np.abs(y @ model.theta_cad).max()
    if w_err > 1e-12:
        raise SystemExit(f"chain{n}: base wrench differs from Psi theta by {w_err:.1e} (relative)")

    t4 = time.perf_counter()
    f = model.casadi_regressor
    t5 = time.perf_counter()
    mapped = f.map(CHUNK, "serial")
    y_ca = np.asarray(mapped(q.T, qd.T, qdd.T)).reshape(6, CHUNK, 10 * n).transpose(1, 0, 2)
    ca_err = np.abs(y_ca - y).max() / np.abs(y).max()
    if ca_err > 1e-12:
        raise SystemExit(f"chain{n}: CasADi differs from JAX by {ca_err:.1e} (relative)")
    ca_frame = per_frame(lambda k: mapped(q.T, qd.T, qdd.T), CHUNK)
    del ca

    pin_jtr, pin_rnea, pin_base = pinocchio_row(path, q, qd, qdd, y[:20])
    return {
        "n": n,
        "derive": t1 - t0,
        "print": t2 - t1,
        "ops": emitted.op_count,
        "cpu": cpu,
        "load": t3 - t2,
        "reg": reg[:5],
        "wrench": wrench[:5],
        "ca_build": t5 - t4,
        "ca_frame": ca_frame,
        "pin_jtr": pin_jtr,
        "pin_rnea": pin_rnea,
        "pin_base": pin_base,
    }


def main(argv=None) -> None:
    """Parse options, measure every chain, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--joints",
        default=",".join(map(str, JOINTS)),
        help=f"comma-separated chain lengths (default {','.join(map(str, JOINTS))})",
    )
    args = ap.parse_args(argv)
    joints = [int(x) for x in args.joints.split(",")]
    versions = ", ".join(f"{d} {md.version(d)}" for d in ("jax", "casadi", "sympy", "pin"))
    print(f"CPU: {cpu_description()}; {versions}; Python {platform.python_version()}")
    print("load average before: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    us = 1e6
    print(
        f"\nfirst run of a new chain: seconds, except the per-frame times (us); JAX on {CHUNK}-frame chunks, "
        "compile = XLA, first = first call of the compiled executable"
    )
    print(
        "(derive+print and compile also as CPU seconds, 'wall/cpu': the compiler uses one core, so on a shared "
        "machine its CPU seconds are the steadier figure; contention still inflates them)"
    )
    head = (
        f"{'joints':>6} {'derive':>7} {'print':>6} {'cpu':>5} {'ops':>6} {'load':>6} | {'reg lower':>9} "
        f"{'compile wall/cpu':>16} {'first':>6} {'us/fr':>6} | {'wrench compile':>14} {'us/fr':>6} | "
        f"{'CasADi build':>12} {'us/fr':>6} | "
        f"{'Pinocchio JTR':>13} {'rnea':>5} {'base':>5}"
    )
    print(head)
    with tempfile.TemporaryDirectory(prefix="ineid-bench-compile-") as tmp:
        for n in joints:
            r = measure(n, Path(tmp))
            lower, comp, comp_cpu, first, warm = r["reg"]
            _, w_comp, w_cpu, _, w_warm = r["wrench"]
            print(
                f"{n:>6} {r['derive']:>7.2f} {r['print']:>6.2f} {r['cpu']:>5.2f} {r['ops']:>6,} {r['load']:>6.2f} | "
                f"{lower:>9.2f} {f'{comp:.2f}/{comp_cpu:.2f}':>16} {first:>6.3f} {warm / CHUNK * us:>6.2f} | "
                f"{f'{w_comp:.2f}/{w_cpu:.2f}':>14} {w_warm / CHUNK * us:>6.2f} | "
                f"{r['ca_build']:>12.2f} {r['ca_frame'] * us:>6.2f} | {r['pin_jtr'] * us:>13.2f} "
                f"{r['pin_rnea'] * us:>5.2f} {r['pin_base'] * us:>5.2f}",
                flush=True,
            )
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
