"""``make demo``: the main job on the built-in arm, end to end, in about a minute.

Run with ``python -m ineid.demo``. Loads ``sweaty-arm``, evaluates its generated
base-wrench regressor on random frames with JAX and CasADi, checks the two agree and that
the arm at rest loads the sensor with its weight; then makes a small noisy ground-truth
dataset, identifies links 3-4 with the linear, weighted and physically consistent
solvers, and prints how close each gets, for the standard and for the base parameters.
"""

from __future__ import annotations

import time

import numpy as np


def main(n_frames: int = 100_000, seed: int = 0) -> None:
    import jax

    from ineid.data.synthesis.sampling import model_uniform_states
    from ineid.robots.load import load_robot

    model = load_robot("sweaty-arm")
    q, qd, qdd = model_uniform_states(model, n_frames, np.random.default_rng(seed))

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
    print(f"regressor Psi(q, qd, qdd): 6 x {10 * model.n_links}, {model.op_count} operations in its generated program")
    print(f"JAX regressor: {n_frames:,} frames in {seconds * 1e3:.1f} ms = {n_frames / seconds / 1e6:.2f} M frames/s")
    print(f"JAX wrench Psi@theta (fused): {seconds_w * 1e3:.1f} ms = {n_frames / seconds_w / 1e6:.2f} M frames/s")
    print(f"CasADi vs JAX on {n_check} frames: max relative difference {agree:.1e}")
    print(f"at rest: F = {np.round(at_rest[:3], 6).tolist()} N, weight m_total*g = {np.round(weight, 6).tolist()} N")
    print("wrench of the first frames (N, N*m):")
    for k in range(3):
        print("  " + "  ".join(f"{v:9.3f}" for v in wrench[k]))
    identification(model, seed)


def identification(model, seed: int = 0, per_link: int = 12, n_frames: int = 100) -> None:
    """A noisy ground truth (per_link^2 configurations), identified three ways."""
    from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
    from ineid.identify import SolveSettings, base_parameters, relative_error, solve_dataset
    from ineid.params import all_links_physical

    noise = NoiseModel.create(model.n_dof, force=0.5, moment=0.05, qd=0.01, qdd=0.1)
    t0 = time.perf_counter()
    ds = generate_dataset(model, DatasetSpec(Combination("factorial", per_link=per_link), n_frames, seed, noise=noise))
    base = base_parameters(model)
    print(
        f"\ndataset: {ds.n_configs} configurations x {n_frames} frames, noise force 0.5 N, moment 0.05 N*m, "
        f"qd 0.01 rad/s, qdd 0.1 rad/s^2 ({time.perf_counter() - t0:.1f} s)"
    )
    print(
        f"identifiable: {base.rank} of {base.n_params} parameters (base parameters such as {base.names[0]!r}); "
        "the other directions come from the CAD prior"
    )
    print(f"{'method':28s} {'base err':>9s} {'std err':>9s} {'identifiable':>13s} {'physical':>9s} {'seconds':>8s}")
    for label, settings in (
        ("linear least squares", SolveSettings(weights="none")),
        ("weighted least squares", SolveSettings(weights="estimate")),
        ("consistent (log-Cholesky)", SolveSettings(method="consistent", weights="estimate")),
    ):
        t0 = time.perf_counter()
        res = solve_dataset(ds, settings, model=model)
        seconds = time.perf_counter() - t0
        ok = res.success
        base_err = np.median(relative_error(res.base_hat[ok], res.base_true[ok]))
        std_err = np.median(relative_error(res.theta_hat[ok], res.theta_true[ok]))
        ident_err = np.median(
            relative_error(res.theta_hat[ok][:, base.identifiable], res.theta_true[ok][:, base.identifiable])
        )
        physical = all_links_physical(res.theta_hat[ok]).mean()
        print(f"{label:28s} {base_err:9.4f} {std_err:9.4f} {ident_err:13.4f} {physical:9.0%} {seconds:8.2f}")
    print("(median relative errors over configurations and parameters; identifiable = the 6 standard parameters")
    print(" the data determine alone; physical = share of estimates that are rigid bodies)")


if __name__ == "__main__":
    main()
