"""``make demo``: the main job on the built-in arm, end to end, in under a minute.

Run with ``python -m ineid.demo``. Loads ``sweaty-arm``, evaluates its generated
base-wrench regressor on random frames with JAX and CasADi, checks the two agree and that
the arm at rest loads the sensor with its weight, and prints what it measured.
"""

from __future__ import annotations

import time

import numpy as np


def main(n_frames: int = 100_000, seed: int = 0) -> None:
    import jax  # noqa: PLC0415

    import ineid  # noqa: PLC0415

    model = ineid.load_robot("sweaty-arm")
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.q_lower, model.q_upper, (n_frames, model.n_dof))
    qd = rng.uniform(-model.qd_max, model.qd_max, (n_frames, model.n_dof))
    qdd = rng.uniform(-model.qdd_max, model.qdd_max, (n_frames, model.n_dof))

    f = jax.jit(model.jax_regressor)
    f(q, qd, qdd, model.gravity).block_until_ready()  # compile for this shape
    t0 = time.perf_counter()
    y = f(q, qd, qdd, model.gravity).block_until_ready()
    seconds = time.perf_counter() - t0
    w = jax.jit(model.jax_base_wrench)
    w(q, qd, qdd, model.gravity, model.theta_cad).block_until_ready()
    t0 = time.perf_counter()
    wrench = np.asarray(w(q, qd, qdd, model.gravity, model.theta_cad).block_until_ready())
    seconds_w = time.perf_counter() - t0
    assert np.allclose(wrench, np.asarray(y) @ model.theta_cad, rtol=1e-12, atol=1e-9)

    n_check = 200
    y_ca = np.array(model.casadi_regressor.map(n_check)(q[:n_check].T, qd[:n_check].T, qdd[:n_check].T))
    y_ca = y_ca.reshape(6, n_check, -1).transpose(1, 0, 2)
    agree = float(np.max(np.abs(y_ca - np.asarray(y[:n_check]))) / np.max(np.abs(y_ca)))

    zeros = np.zeros(model.n_dof)
    at_rest = np.asarray(model.base_wrench(q[0], zeros, zeros))
    weight = model.theta_cad[::10].sum() * model.gravity

    print(f"\n{model!r}")
    print(f"unknown links {', '.join(model.unknown_links)} -> {len(model.unknown_index)} parameters to identify")
    print(f"regressor Psi(q, qd, qdd): 6 x {10 * model.n_links}, {model.op_count} operations after CSE")
    print(f"JAX regressor: {n_frames:,} frames in {seconds * 1e3:.1f} ms = {n_frames / seconds / 1e6:.2f} M frames/s")
    print(f"JAX wrench Psi@theta (fused): {seconds_w * 1e3:.1f} ms = {n_frames / seconds_w / 1e6:.2f} M frames/s")
    print(f"CasADi vs JAX on {n_check} frames: max relative difference {agree:.1e}")
    print(f"at rest: F = {np.round(at_rest[:3], 6).tolist()} N, weight m_total*g = {np.round(weight, 6).tolist()} N")
    print("wrench of the first frames (N, N*m):")
    for k in range(3):
        print("  " + "  ".join(f"{v:9.3f}" for v in wrench[k]))


if __name__ == "__main__":
    main()
