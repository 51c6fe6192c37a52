"""Frames per second of the base-wrench regressor, and the cost of generating it.

Table 1: the full 6 x 40 regressor of ``sweaty-arm`` on N random frames (q uniform within
the joint limits, qd and qdd uniform within +-bounds, float64, seed 0), evaluated by
(1) the generated JAX function, ``jax.jit``, batched over chunks of frames, XLA defaults,
and again with XLA's fusion pass off for that executable (a diagnostic: one kernel per op,
no subexpression copied into several fusions); (2) the generated CasADi function,
``Function.map`` over chunks, "serial" or "thread" x2, n x chunk DM inputs, DM output;
(3) SymPy ``lambdify`` (NumPy, ``cse=True``) vectorised over the frames of a chunk;
(4) Pinocchio from Python, frame by frame: the faster of a free-flyer root held at identity
(first 6 rows of ``computeJointTorqueRegressor``, negated) and ineid.reference's
``jointBodyRegressor`` route. Each method's first chunk is checked against
``model.regressor`` (1e-10 relative); every shape is warmed up (compile time excluded);
each chunk is waited for (``block_until_ready``) and dropped, so at most one chunk's
output is held. Chunk size (and map mode, Pinocchio route) are picked by one probe pass
over <= 100k frames; the time is the best of ``--repeats`` passes.

Table 2: seconds to derive the structured Newton-Euler program (SymPy) and to print its JAX
and CasADi modules, its operation count and named values, for sweaty-arm and the 7-DOF Panda of
example-robot-data (fingers locked). ``benchmarks/compile.py`` has the compile times.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import os
import platform
import time

import numpy as np
from machine import cpu_description

import ineid  # turns on JAX's float64 mode before jax is used

PROBE_FRAMES = 100_000
SLOW_BUDGET_S = 60.0
PANDA_LOCKED = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}


def header() -> str:
    """CPU model, core count, library versions."""
    versions = ", ".join(
        f"{p} {md.version(d)}"
        for p, d in (("jax", "jax"), ("casadi", "casadi"), ("sympy", "sympy"), ("pinocchio", "pin"))
    )
    flags = os.environ.get("XLA_FLAGS", "")
    return f"CPU: {cpu_description()}; {versions}; Python {platform.python_version()}" + (
        f"; XLA_FLAGS={flags!r}" if flags else ""
    )


def sample(model, n: int, seed: int = 0):
    """(q, qd, qdd), each (n, n_dof): uniform within joint limits and +-velocity/acceleration bounds."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.q_lower, model.q_upper, (n, model.n_dof))
    qd = rng.uniform(-model.qd_max, model.qd_max, (n, model.n_dof))
    qdd = rng.uniform(-model.qdd_max, model.qdd_max, (n, model.n_dof))
    return q, qd, qdd


def run(step, n: int, chunk: int) -> float:
    """Seconds for ``step(start, stop)`` over frames [0, n) in chunks."""
    t0 = time.perf_counter()
    for s in range(0, n, chunk):
        step(s, min(s + chunk, n))
    return time.perf_counter() - t0


def check(label: str, y, ref: np.ndarray) -> None:
    """Fail loudly unless ``y`` (frames, 6, 10n) matches ``ref`` to 1e-10 relative."""
    err = float(np.max(np.abs(np.asarray(y)[: len(ref)] - ref)) / np.max(np.abs(ref)))
    if not err <= 1e-10:
        raise AssertionError(f"{label}: regressor differs from model.regressor by {err:.3g} (relative)")


def jax_steps(model, data, fusion: bool):
    """Step factory: the generated JAX function, jit-compiled (optionally with XLA fusion off)."""
    import jax

    opts = None if fusion else {"xla_disable_hlo_passes": "fusion"}
    f = jax.jit(model.jax_regressor, compiler_options=opts)
    g = jax.numpy.asarray(model.gravity)
    q, qd, qdd = data
    return lambda chunk: lambda s, e: f(q[s:e], qd[s:e], qdd[s:e], g).block_until_ready()


def jax_wrench_row(model, data, n: int, repeats: int, chunk: int = 10_000) -> tuple[str, int, float]:
    """The generated ``base_wrench`` (Psi @ theta contracted inside the fused loops, Psi never formed)."""
    import jax

    f = jax.jit(model.jax_base_wrench)
    g, theta, (q, qd, qdd) = jax.numpy.asarray(model.gravity), jax.numpy.asarray(model.theta_cad), data
    chunk = min(chunk, n)
    w_ref = np.asarray(model.regressor(q[:100], qd[:100], qdd[:100])) @ model.theta_cad
    err = float(np.max(np.abs(np.asarray(f(q[:100], qd[:100], qdd[:100], g, theta)) - w_ref)) / np.max(np.abs(w_ref)))
    if not err <= 1e-10:
        raise AssertionError(f"JAX base_wrench differs from regressor @ theta by {err:.3g} (relative)")

    def step(s, e):
        return f(q[s:e], qd[s:e], qdd[s:e], g, theta).block_until_ready()

    step(0, chunk)
    if n % chunk:
        step(n - n % chunk, n)
    return (
        f"JAX jit, chunk {chunk:,}: wrench Psi@theta fused (no Psi)",
        n,
        min(run(step, n, chunk) for _ in range(repeats)),
    )


def casadi_steps(model, data, mode: str):
    """Step factory: ``casadi_regressor.map(chunk, mode)``; returns frames as (k, 6, 10n) when checked."""
    import casadi as ca

    F, q, qd, qdd, maps = model.casadi_regressor, *data, {}

    def step(s, e):
        k = e - s
        if k not in maps:
            maps[k] = F.map(k, "thread", 2) if mode == "thread" else F.map(k, "serial")
        return maps[k](ca.DM(q[s:e].T), ca.DM(qd[s:e].T), ca.DM(qdd[s:e].T))

    return lambda chunk: step


def lambdify_steps(model, data):
    """Step factory: SymPy lambdify (NumPy, cse=True) on the flattened expressions."""
    import sympy as sp

    from ineid.symbolic.newton_euler import derive_base_wrench_regressor

    sym = derive_base_wrench_regressor(model.chain)
    # the derivation is a program of named lines: substitute them, so lambdify sees whole expressions
    inlined: dict = {}
    for lhs, rhs in sym.lines:
        inlined[lhs] = rhs.xreplace(inlined)
    flat = [sp.sympify(e).xreplace(inlined) for row in sym.Y for e in row]
    fn = sp.lambdify((sym.q, sym.qd, sym.qdd, sym.gravity), flat, modules="numpy", cse=True)
    g, (q, qd, qdd) = tuple(model.gravity), data

    def make(chunk):
        buf = np.empty((chunk, len(flat)))

        def step(s, e):
            out = buf[: e - s]
            vals = fn(tuple(q[s:e].T), tuple(qd[s:e].T), tuple(qdd[s:e].T), g)
            for k, v in enumerate(vals):
                out[:, k] = v  # constant (zero) entries broadcast
            return out.reshape(e - s, *sym.shape)

        return step

    return make


def pinocchio_steps(model, data, route: str):
    """Step factory: Pinocchio frame by frame, by ``route`` "free-flyer" or "body-regressor"."""
    import pinocchio as pin

    from ineid.reference import pinocchio_base_regressor, pinocchio_model

    (q, qd, qdd), n = data, model.n_dof
    if route == "free-flyer":  # root body on a free flyer held at identity, zero velocity/acceleration
        pm = pinocchio_model(model.urdf_path, free_flyer=True)
        if pm.nv != 6 + n or pm.nq != 7 + n:
            raise AssertionError("free-flyer route needs one-coordinate joints")
    else:
        pm = pinocchio_model(model.urdf_path)
    pm.gravity.linear = model.gravity
    pd, reg = pm.createData(), pin.computeJointTorqueRegressor

    def make(chunk):
        buf = np.empty((chunk, 6, 10 * n))

        def free_flyer(s, e):
            k, out = e - s, buf[: e - s]
            Q = np.zeros((k, pm.nq))
            Q[:, 6], Q[:, 7:] = 1.0, q[s:e]  # identity quaternion (x, y, z, w)
            V, A = np.zeros((k, pm.nv)), np.zeros((k, pm.nv))
            V[:, 6:], A[:, 6:] = qd[s:e], qdd[s:e]
            for i in range(k):  # rows 0..5: the wrench the fixture applies; columns 0..9: root body
                out[i] = reg(pm, pd, Q[i], V[i], A[i])[:6, 10:]
            return np.negative(out, out=out)

        def body_regressor(s, e):
            out = buf[: e - s]
            out[:] = pinocchio_base_regressor(pm, q[s:e], qd[s:e], qdd[s:e], pd)
            return out

        return free_flyer if route == "free-flyer" else body_regressor

    return make


def measure(candidates, n: int, repeats: int, ref: np.ndarray, frames=np.asarray):
    """Check and probe each ``(label, make, chunk)``, keep the fastest, time it best of ``repeats``.

    Returns ``(label, frames timed, seconds)``. A method whose full run would exceed about
    ``SLOW_BUDGET_S`` seconds is timed on a subset of >= ``PROBE_FRAMES`` frames.
    """
    best = None
    for label, make, chunk in candidates:
        chunk = min(chunk, n)
        step = make(chunk)
        check(label.format(chunk=chunk), frames(step(0, chunk)), ref)  # also warms up (compiles)
        if n % chunk:
            step(n - n % chunk, n)  # warm up the remainder's shape too
        probe = min(n, max(chunk, PROBE_FRAMES // chunk * chunk))
        fps = probe / run(step, probe, chunk)
        if best is None or fps > best[0]:
            best = (fps, label.format(chunk=chunk), step, chunk)
    fps, label, step, chunk = best
    n_timed = n
    if n * repeats / fps > SLOW_BUDGET_S:
        n_timed = min(n, max(PROBE_FRAMES, int(fps * SLOW_BUDGET_S / repeats) // chunk * chunk))
    return label, n_timed, min(run(step, n_timed, chunk) for _ in range(repeats))


def codegen_rows() -> list[tuple]:
    """(robot, dof, derive s, print s, ops, named values) for sweaty-arm and the Panda."""
    from ineid.robots.urdf import load_chain
    from ineid.symbolic.emit import emit_modules
    from ineid.symbolic.newton_euler import derive_base_wrench_regressor

    erd = md.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
    robots = [
        ("sweaty-arm", ineid.BUILTIN_ROBOTS["sweaty-arm"].urdf_path, None),
        ("panda", erd / "panda_description/urdf/panda.urdf", PANDA_LOCKED),
    ]
    rows = []
    for name, path, locked in robots:
        chain = load_chain(path, locked_joints=locked)
        t0 = time.perf_counter()
        sym = derive_base_wrench_regressor(chain)
        t1 = time.perf_counter()
        emitted = emit_modules(sym, name)
        t2 = time.perf_counter()
        rows.append((name, chain.n_dof, t1 - t0, t2 - t1, emitted.op_count, emitted.n_lines))
    return rows


def main(argv=None) -> None:
    """Parse options, run both tables, print them."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="random frames to evaluate (default 1e6)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes; the best is reported (default 3)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 20k frames, 1 repeat, one chunk size each")
    args = ap.parse_args(argv)
    n, repeats = (20_000, 1) if args.quick else (args.frames, args.repeats)
    few = (lambda xs: xs[:1]) if args.quick else (lambda xs: xs)
    print(header())
    model = ineid.load_robot("sweaty-arm")
    data = sample(model, n)
    ref = np.asarray(model.regressor(*(x[:100] for x in data)))
    cols = 10 * model.n_dof
    print(f"\nsweaty-arm: full 6x{cols} base-wrench regressor, float64, {n:,} random frames, best of {repeats}")

    jax_default, jax_nofusion = jax_steps(model, data, fusion=True), jax_steps(model, data, fusion=False)
    methods = [
        ("jax", [("JAX jit, chunk {chunk:,}, XLA defaults", jax_default, c) for c in few([2_000, 10_000, 100_000])]),
        (
            "jax-nofusion",
            [
                ("JAX jit, chunk {chunk:,}, XLA fusion pass off", jax_nofusion, c)
                for c in few([2_000, 1_000, 5_000, 10_000])
            ],
        ),
        (
            "casadi",
            [
                (
                    f"CasADi map {mode}{', 2 threads' if mode == 'thread' else ''}, chunk {{chunk:,}}",
                    casadi_steps(model, data, mode),
                    c,
                )
                for mode in ("serial", "thread")
                for c in few([1_000, 10_000])
            ],
        ),
        (
            "lambdify",
            [
                ("SymPy lambdify NumPy cse=True, chunk {chunk:,}", lambdify_steps(model, data), c)
                for c in few([1_000, 10_000])
            ],
        ),
        (
            "pinocchio",
            [
                (
                    "Pinocchio per frame, free-flyer computeJointTorqueRegressor",
                    pinocchio_steps(model, data, "free-flyer"),
                    10_000,
                ),
                (
                    "Pinocchio per frame, jointBodyRegressor (ineid.reference)",
                    pinocchio_steps(model, data, "body-regressor"),
                    10_000,
                ),
            ],
        ),
    ]
    casadi_frames = lambda y: y.full().reshape(6, -1, cols).transpose(1, 0, 2)  # noqa: E731
    results = {
        key: measure(cands, n, repeats, ref, casadi_frames if key == "casadi" else np.asarray) for key, cands in methods
    }

    pin_fps = results["pinocchio"][1] / results["pinocchio"][2]
    print(f"{'method':<62} {'frames timed':>13} {'seconds':>9} {'frames/s':>12} {'vs Pinocchio':>13}")
    for key in ("jax", "jax-nofusion", "casadi", "lambdify", "pinocchio"):
        label, n_timed, seconds = results[key]
        timed = f"{n_timed:,}" + ("" if n_timed == n else " (subset)")
        fps = n_timed / seconds
        print(f"{label:<62} {timed:>13} {seconds:>9.3f} {fps:>12,.0f} {fps / pin_fps:>12.2f}x")
    label, n_timed, seconds = jax_wrench_row(model, data, n, repeats)
    fps = n_timed / seconds
    print(f"{label:<62} {n_timed:>13,} {seconds:>9.3f} {fps:>12,.0f} {fps / pin_fps:>12.2f}x  (6 outputs, not 240)")
    for key, what in (("jax", "JAX path (XLA defaults)"), ("jax-nofusion", "JAX, XLA fusion pass off (diagnostic)")):
        ratio = results[key][1] / results[key][2] / pin_fps
        print(f"floor >= 5x Pinocchio frames/s: {what}: {ratio:.2f}x -> {'MET' if ratio >= 5 else 'NOT MET'}")

    print("\ncode generation: derive = SymPy Newton-Euler program; print = the JAX and CasADi modules")
    print(f"{'robot':<12} {'DOF':>4} {'derive s':>9} {'print s':>8} {'ops':>7} {'named values':>13}")
    for name, dof, t_derive, t_print, ops, lines in codegen_rows():
        print(f"{name:<12} {dof:>4} {t_derive:>9.2f} {t_print:>8.2f} {ops:>7,} {lines:>13,}")


if __name__ == "__main__":
    main()
