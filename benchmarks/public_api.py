"""What a user's call costs: the public ``RobotModel`` evaluators on 10^6 frames, one call each.

``sweaty-arm``, N random frames (q uniform within the joint limits, qd and qdd within
+-bounds, float64, seed 0), NumPy arrays in, called as the README shows:

* ``model.regressor(q, qd, qdd)`` -> (N, 6, 40) NumPy; ``model.regressor_split`` -> the
  unknown links' columns and the known links' wrench; ``model.base_wrench(q, qd, qdd)`` and
  with one parameter set per frame ``base_wrench(q, qd, qdd, theta)`` (N, 40);
* before (ineid 0.1's ``model.regressor``): the generated JAX function called without
  ``jax.jit``, op by op, on a slice of the frames (the rate is per frame);
* the peer: Pinocchio from Python, frame by frame (``computeJointTorqueRegressor`` with the
  root on a free flyer held at identity, rows 0-5 negated), on a slice of the frames.

Every public call's first frames are checked against the generated CasADi function (1e-10
relative). Each public row is one call (the compilation of the chunk kernels is excluded:
warmed on a small call first; with the persistent cache it is loaded from disk anyway);
the time is the best of ``--repeats``. The floor: ``model.regressor`` at least
5x Pinocchio's frames/s, aim 10x.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from machine import cpu_description  # benchmarks/machine.py
from regressor import header, pinocchio_steps, sample  # benchmarks/regressor.py

import ineid


def best(fn, repeats: int) -> float:
    """Seconds of the fastest of ``repeats`` calls of ``fn`` (which waits for its result)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--peer-frames", type=int, default=20_000, help="frames for the per-frame peer and 'before'")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    model = ineid.load_robot("sweaty-arm")
    n = args.frames
    q, qd, qdd = sample(model, n)
    theta = np.random.default_rng(1).normal(size=(n, 10 * model.n_links))
    ref = np.array(model.casadi_regressor.map(100)(q[:100].T, qd[:100].T, qdd[:100].T)).reshape(6, 100, -1)
    ref = ref.transpose(1, 0, 2)

    def check(label, y):
        err = float(np.max(np.abs(y - ref)) / np.max(np.abs(ref)))
        if not err <= 1e-10:
            raise AssertionError(f"{label} differs from the CasADi function by {err:.3g} (relative)")

    # warm: compile (or load) the chunk kernels, check the numbers
    check("model.regressor", model.regressor(q[:100], qd[:100], qdd[:100]))
    y_u, w_k = model.regressor_split(q[:100], qd[:100], qdd[:100])
    check(
        "model.regressor_split",
        np.concatenate([y_u, ref[..., model.known_index]], axis=-1)[
            ..., np.argsort(np.concatenate([model.unknown_index, model.known_index]))
        ],
    )
    np.testing.assert_allclose(
        model.base_wrench(q[:100], qd[:100], qdd[:100]),
        ref @ model.theta_cad,
        rtol=1e-10,
        atol=1e-10 * np.max(np.abs(ref @ model.theta_cad)),
    )
    model.base_wrench(q[:5000], qd[:5000], qdd[:5000], theta[:5000])

    rows = []
    rows.append(
        ("model.regressor(q, qd, qdd) -> (N, 6, 40)", n, best(lambda: model.regressor(q, qd, qdd), args.repeats))
    )
    rows.append(("model.regressor_split(q, qd, qdd)", n, best(lambda: model.regressor_split(q, qd, qdd), args.repeats)))
    rows.append(
        ("model.base_wrench(q, qd, qdd) (CAD theta)", n, best(lambda: model.base_wrench(q, qd, qdd), args.repeats))
    )
    rows.append(
        (
            "model.base_wrench(q, qd, qdd, theta), theta per frame",
            n,
            best(lambda: model.base_wrench(q, qd, qdd, theta), args.repeats),
        )
    )
    m = min(args.peer_frames, n)
    g = model.gravity
    f = model.jax_regressor
    f(q[:m], qd[:m], qdd[:m], g)  # op-by-op dispatch warms its per-op caches
    rows.append(
        (
            "before: generated JAX function without jit (0.1)",
            m,
            best(lambda: np.asarray(f(q[:m], qd[:m], qdd[:m], g)), args.repeats),
        )
    )
    step = pinocchio_steps(model, (q, qd, qdd), "free-flyer")(m)
    check("Pinocchio", step(0, 100).copy())
    rows.append(("peer: Pinocchio per frame (free-flyer regressor)", m, best(lambda: step(0, m), args.repeats)))

    print(header())
    print(f"machine: {cpu_description()}; sweaty-arm, one call per row, NumPy in and out, best of {args.repeats}")
    head = f"{'call':58s} {'frames':>10s} {'seconds':>9s} {'M frames/s':>11s} {'vs Pinocchio':>13s}"
    print(head)
    print("-" * len(head))
    peer = rows[-1][1] / rows[-1][2]
    for label, k, sec in rows:
        print(f"{label:58s} {k:10,d} {sec:9.3f} {k / sec / 1e6:11.3f} {k / sec / peer:12.1f}x")
    ratio = rows[0][1] / rows[0][2] / peer
    print(
        f"floor: model.regressor >= 5x Pinocchio per frame: {ratio:.1f}x -> {'MET' if ratio >= 5 else 'MISSED'}"
        f"; aim 10x {'met' if ratio >= 10 else 'not met'}"
    )


if __name__ == "__main__":
    main()
