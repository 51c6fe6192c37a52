"""Cross-cutting: the fast paths give the reference paths' numbers.

* the public, chunked ``RobotModel.regressor`` / ``regressor_split`` / ``base_wrench``
  against the generated JAX function on the whole batch (no chunks, no padding);
* the fused linear identification (normal-equation blocks, one batched Cholesky) against a
  plain NumPy ``lstsq`` per configuration on stacks from the generated CasADi function (an
  independent evaluation), and against the QR route on the stacks (``fit_base``) for the
  weighted modes, the covariance and the residuals;
* ill-conditioned configurations going through the QR route;
* the persistent compilation cache, in fresh processes.

Speed is shown in ``benchmarks/``; nothing here is timed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, casadi_c, fit_base, fused, solve_dataset, stack
from ineid.identify.linear import NORMAL_MAX_COND, fit_base_blocks, standard_std
from ineid.identify.systems import stack_casadi
from ineid.robots import model as model_module

from .conftest import SEED, random_states, rel_err

NOISE = NoiseModel.create(4, force=0.5, moment=0.05, qd=0.01, qdd=0.1)


@pytest.fixture(scope="module")
def arm(model):
    return model  # conftest's sweaty-arm, under this file's name


@pytest.fixture(scope="module")
def noisy(arm):
    """300 configurations x 40 frames with noise (32 fitted, 8 held out): test_identify's, so
    a whole-suite run compiles the kernels of this shape once."""
    spec = DatasetSpec(Combination("random", n_configs=300), n_frames=40, seed=SEED, noise=NOISE)
    return generate_dataset(arm, spec)


def scaled_rel(a, b, scales) -> float:
    """Largest per-row ||a - b|| / ||b|| in scaled (unit-consistent) coordinates."""
    a, b = np.asarray(a) / scales, np.asarray(b) / scales
    return float(np.max(np.linalg.norm(a - b, axis=-1) / np.linalg.norm(b, axis=-1)))


# -- the public regressor -------------------------------------------------------------------

# Full chunks, a remainder padded to the small shape and one padded to a full chunk.
SIZES = [1, 63, model_module.CHUNK_FRAMES + model_module.SMALL_FRAMES // 2, 2 * model_module.CHUNK_FRAMES + 100]


@pytest.mark.parametrize("n", SIZES)
def test_chunked_regressor_equals_whole_batch(arm, rng, n):
    q, qd, qdd = random_states(arm, n, rng)
    # the generated CasADi function over the whole batch: no JAX, no chunks, no padding
    ref = np.array(arm.casadi_regressor.map(n)(q.T, qd.T, qdd.T)).reshape(6, n, 40).transpose(1, 0, 2)
    y = arm.regressor(q, qd, qdd)
    assert isinstance(y, np.ndarray) and y.dtype == np.float64 and y.shape == (n, 6, 40)
    assert rel_err(y, ref) < 1e-13
    y_u, y_k = arm.regressor_split(q, qd, qdd)
    assert np.array_equal(y_u, y[..., arm.unknown_index]) and np.array_equal(y_k, y[..., arm.known_index])
    assert rel_err(arm.base_wrench(q, qd, qdd), ref @ arm.theta_cad) < 1e-13
    if n > model_module.CHUNK_FRAMES:  # one parameter set per frame, over chunks
        theta = rng.normal(size=(n, 40))
        assert rel_err(arm.base_wrench(q, qd, qdd, theta), np.einsum("nij,nj->ni", ref, theta)) < 1e-13


def test_public_evaluators_take_jax_arrays_and_broadcast(arm, rng):
    import jax.numpy as jnp

    q, qd, qdd = (x.reshape(2, 3, 4) for x in random_states(arm, 6, rng))
    y = arm.regressor(jnp.asarray(q), qd, qdd[0])  # (2, 3, 4), (2, 3, 4), (3, 4)
    assert isinstance(y, np.ndarray) and y.shape == (2, 3, 6, 40)
    assert rel_err(y, np.asarray(arm.jax_regressor(q, qd, qdd[0], arm.gravity))) < 1e-13
    assert arm.regressor(q[0, 0], qd[0, 0], qdd[0, 0]).shape == (6, 40)
    theta = rng.normal(size=(2, 1, 40))  # one parameter set per row, broadcast over the frames
    w = arm.base_wrench(q, qd, qdd[0], theta)
    assert w.shape == (2, 3, 6)
    assert rel_err(w, np.einsum("abij,aj->abi", y, theta[:, 0])) < 1e-13
    assert arm.regressor(np.zeros((0, 4)), np.zeros((0, 4)), np.zeros((0, 4))).shape == (0, 6, 40)


def test_public_evaluators_refuse_tracers_and_bad_shapes(arm):
    import jax

    z = np.zeros(4)
    with pytest.raises(TypeError, match="inside jax.jit, grad or vmap use model.jax_regressor"):
        jax.jit(lambda q: arm.regressor(q, z, z))(z)
    with pytest.raises(ValueError, match="must broadcast to one leading shape"):
        arm.regressor(np.zeros((3, 4)), np.zeros((2, 4)), z)
    with pytest.raises(ValueError, match="does not broadcast|must broadcast"):
        arm.base_wrench(np.zeros((3, 4)), z, z, np.zeros((2, 40)))


# -- fused linear identification ------------------------------------------------------------


def test_fused_linear_equals_lstsq_per_configuration(arm, base, noisy):
    res = solve_dataset(noisy, SolveSettings(weights="none"), model=arm)
    n_fit = res.n_frames_fit
    assert (n_fit, res.n_frames_validation) == (32, 8)
    beta_ref, rms_fit, rms_val, rel_val = [], [], [], []
    for c in range(noisy.n_configs):
        frames = [a[c, :n_fit] for a in (noisy.q, noisy.qd, noisy.qdd, noisy.wrench)]
        w, y = stack_casadi(arm, *frames, noisy.theta_known)  # the generated CasADi code, not JAX
        beta, *_ = np.linalg.lstsq(w[:, base.base_index], y, rcond=None)
        beta_ref.append(beta)
        theta = arm.full_theta(res.theta_hat[c], noisy.theta_known)
        resid = noisy.wrench[c] - arm.base_wrench(noisy.q[c], noisy.qd[c], noisy.qdd[c], theta)
        rms_fit.append(np.sqrt(np.mean(resid[:n_fit] ** 2, axis=0)))
        rms_val.append(np.sqrt(np.mean(resid[n_fit:] ** 2, axis=0)))
        rel_val.append(np.linalg.norm(resid[n_fit:]) / np.linalg.norm(noisy.wrench[c, n_fit:]))
    assert np.all(res.success)
    assert scaled_rel(res.base_hat, np.array(beta_ref), base.scales[base.base_index]) < 1e-10
    assert rel_err(res.fit_rms, np.array(rms_fit)) < 1e-10
    assert rel_err(res.validation_rms, np.array(rms_val)) < 1e-10
    assert rel_err(res.validation_rel, np.array(rel_val)) < 1e-10


@pytest.mark.parametrize("weights", ["none", "noise", "estimate"])
def test_fused_fit_equals_qr_of_the_stacks(arm, base, noisy, weights):
    """Estimates, covariance and weights of the fused route against QR on the stacks."""
    sigma = NOISE.wrench if weights == "noise" else None
    res = solve_dataset(
        noisy, SolveSettings(weights=weights, axis_sigma=None if sigma is None else tuple(sigma)), model=arm
    )
    n_fit = res.n_frames_fit
    w, y = stack(arm, *(a[:, :n_fit] for a in (noisy.q, noisy.qd, noisy.qdd, noisy.wrench)), noisy.theta_known)
    ref = fit_base(w, y, base, weights, axis_sigma=sigma)
    s_b = base.scales[base.base_index]
    assert scaled_rel(res.base_hat, ref.beta, s_b) < 1e-10
    ident = base.identifiable
    assert rel_err(res.theta_std[:, ident], standard_std(ref.cov_beta, base)[:, ident]) < 1e-9
    assert rel_err(res.base_std, np.sqrt(np.diagonal(ref.cov_beta, axis1=1, axis2=2))) < 1e-9
    # the blocks alone give the same weights and factor (R^T R = A)
    blocks = fused.information_blocks(
        arm, base, *(a[:, :n_fit] for a in (noisy.q, noisy.qd, noisy.qdd, noisy.wrench)), noisy.theta_known
    )
    fit, refit = fit_base_blocks(blocks, base, weights, sigma)
    assert not refit.any()
    assert rel_err(fit.axis_weights, ref.axis_weights) < 1e-9
    assert rel_err(np.swapaxes(fit.R, 1, 2) @ fit.R, np.swapaxes(ref.R, 1, 2) @ ref.R) < 1e-9


def test_blocks_equal_the_stacks_over_frame_chunks(arm, base, noisy, monkeypatch):
    """Long configurations are reduced over masked frame chunks; the blocks are the stacks' products."""
    monkeypatch.setattr(fused, "MAX_FRAME_CHUNK", 16)  # 40 frames: two full chunks and a padded one
    monkeypatch.setattr(fused, "TARGET_FRAMES", 48)  # 3 configurations per call: 10 = 3 x 3 + 1
    sub = noisy.select(slice(0, 10))
    blocks = fused.information_blocks(arm, base, sub.q, sub.qd, sub.qdd, sub.wrench, sub.theta_known)
    w, y = stack(arm, sub.q, sub.qd, sub.qdd, sub.wrench, sub.theta_known)
    wb = w[:, :, base.base_index].reshape(sub.n_configs, sub.n_frames, 6, -1)
    yy = y.reshape(sub.n_configs, sub.n_frames, 6)
    assert rel_err(blocks.G, np.einsum("cfar,cfas->cars", wb, wb)) < 1e-13
    assert rel_err(blocks.h, np.einsum("cfar,cfa->car", wb, yy)) < 1e-13
    assert rel_err(blocks.e, np.einsum("cfa,cfa->ca", yy, yy)) < 1e-13


def test_ill_conditioned_configurations_take_the_qr_route(arm, base):
    """Frames that barely move give a poorly conditioned regressor: flagged, refitted by QR."""
    spec = DatasetSpec(Combination("random", n_configs=6), n_frames=40, seed=SEED, noise=NOISE)
    ds = generate_dataset(arm, spec)
    slow = 3  # this configuration's frames: small velocities and accelerations, rank kept
    ds.qd[slow] *= 1e-3
    ds.qdd[slow] *= 1e-3
    ds.wrench[slow] = arm.base_wrench(
        ds.q[slow], ds.qd[slow], ds.qdd[slow], arm.full_theta(ds.theta_unknown[slow], ds.theta_known)
    )
    fitted = [a[:, :32] for a in (ds.q, ds.qd, ds.qdd, ds.wrench)]
    blocks = fused.information_blocks(arm, base, *fitted, ds.theta_known)
    fit, refit = fit_base_blocks(blocks, base, "none")  # unweighted: the slow frames' scale shows
    assert refit.tolist() == [i == slow for i in range(6)]
    assert not np.isfinite(fit.cond[slow]) or fit.cond[slow] > NORMAL_MAX_COND
    res = solve_dataset(ds, SolveSettings(weights="none"), model=arm)
    assert res.n_frames_fit == 32
    # a refit of this few frames stacks through CasADi (SMALL_JOB_FRAMES: no kernel compiled for it)
    assert 32 <= model_module.SMALL_JOB_FRAMES
    w, y = stack_casadi(arm, *(a[slow] for a in fitted), ds.theta_known)
    ref = fit_base(w[None], y[None], base, "none")
    assert res.success[slow] == ref.full_rank[0]
    np.testing.assert_allclose(res.base_hat[slow], ref.beta[0], rtol=1e-12)  # the same QR
    w, y = stack(arm, *fitted, ds.theta_known)  # the JAX stacks: the same to round-off, amplified by cond
    np.testing.assert_allclose(res.base_hat[slow], fit_base(w, y, base, "none").beta[slow], rtol=1e-9)


def test_base_parameters_from_casadi_equal_the_jax_stacks(arm, base):
    from ineid.identify.identifiability import base_parameters_from_regressor, generic_frames

    q, qd, qdd = generic_frames(arm)
    w, _ = stack(arm, q[None], qd[None], qdd[None], np.zeros((1, len(q), 6)), arm.theta_cad[arm.known_index])
    other = base_parameters_from_regressor(w[0], base.param_names, base.scales)
    assert np.array_equal(other.base_index, base.base_index)
    assert np.allclose(other.K, base.K, rtol=1e-9, atol=1e-12)


# -- compilation cache ---------------------------------------------------------------------

_CHILD = textwrap.dedent(
    """
    import logging, sys
    logging.basicConfig(level=logging.INFO, stream=sys.stdout, format="%(name)s %(message)s")
    import numpy as np, ineid
    model = ineid.load_robot("sweaty-arm")
    w = model.base_wrench(np.zeros(4), np.zeros(4), np.zeros(4))
    import jax
    print("DIR", jax.config.jax_compilation_cache_dir)
    """
)


def _child(env: dict) -> str:
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_second_process_loads_compiled_kernels(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION", "JAX_PERSISTENT", "INEID_XLA"))}
    env["INEID_CACHE_DIR"] = str(tmp_path)
    first = _child(env)
    assert f"DIR {tmp_path / 'xla'}" in first
    assert "cache hit" not in first
    assert any((tmp_path / "xla").iterdir())
    second = _child(env)
    assert "ineid.cache XLA compilation cache hit" in second
    env["INEID_XLA_CACHE"] = "0"
    assert "DIR None" in _child(env)


def test_second_solve_command_logs_its_cache_hits(arm, noisy, tmp_path):
    """``ineid -v solve`` twice in fresh processes: the second loads the fused kernels from the
    cache and says so, and parses the URDF from the cache (no yourdfpy import)."""
    data = noisy.select(slice(0, 12)).save(tmp_path / "d.h5")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION", "JAX_PERSISTENT", "INEID_XLA"))}
    env["INEID_CACHE_DIR"] = str(tmp_path / "cache")
    code = (
        "import sys; from ineid.cli import main\ntry:\n    main()\nfinally:\n"
        "    print('YOURDFPY', 'yourdfpy' in sys.modules)"
    )

    def solve() -> str:
        argv = ["-v", "solve", str(data), "--out", str(tmp_path / "r.h5"), "--overwrite"]
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, env=env, timeout=300)
        assert out.returncode == 0, out.stderr
        return out.stdout + out.stderr

    first, second = solve(), solve()
    assert "cache hit" not in first and "YOURDFPY True" in first
    # one kernel, the blocks: this small job's residuals come from CasADi (SMALL_JOB_FRAMES)
    assert second.count("ineid: XLA compilation cache hit") == 1 and "YOURDFPY False" in second


def test_user_cache_setting_wins(tmp_path, monkeypatch):
    import jax

    from ineid.cache import enable_compilation_cache

    before = jax.config.jax_compilation_cache_dir
    try:
        jax.config.update("jax_compilation_cache_dir", str(tmp_path / "mine"))
        monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "ineid"))
        assert enable_compilation_cache() == tmp_path / "mine"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "mine")
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


# -- the CasADi route compiled to C ---------------------------------------------------------

needs_cc = pytest.mark.skipif(casadi_c.c_compiler() is None, reason="no C compiler (cc, gcc, clang) on PATH")


@needs_cc
def test_compiled_casadi_blocks_equal_the_jax_blocks(arm, base, noisy):
    """70 configurations: a full call of CONFIGS_PER_CALL and a padded one; then the whole solve."""
    sub = noisy.select(slice(0, casadi_c.CONFIGS_PER_CALL + 6))
    frames = [a[:, :32] for a in (sub.q, sub.qd, sub.qdd, sub.wrench)]
    ref = fused.information_blocks(arm, base, *frames, sub.theta_known)
    got = casadi_c.information_blocks_c(arm, base, *frames, sub.theta_known)
    for name in ("G", "h", "e"):
        assert rel_err(getattr(got, name), getattr(ref, name)) < 1e-13
    libraries = list((casadi_c.cache_dir() / "casadi-c").glob("*.so"))
    assert len(libraries) == 1  # compiled once, in ineid's cache
    a = solve_dataset(sub, SolveSettings(), model=arm)
    b = solve_dataset(sub, SolveSettings(backend="casadi-c"), model=arm)
    assert scaled_rel(b.base_hat, a.base_hat, base.scales[base.base_index]) < 1e-10
    assert rel_err(b.validation_rms, a.validation_rms) < 1e-10


def test_casadi_c_without_a_compiler_says_so(arm, noisy, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from ineid.cli import main
    from ineid.data import save_dataset

    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    monkeypatch.setattr(casadi_c, "_LOADED", {})
    path = save_dataset(noisy.select(slice(0, 3)), tmp_path / "d.h5")
    out = tmp_path / "r.h5"
    r = CliRunner().invoke(main, ["solve", str(path), "--backend", "casadi-c", "--out", str(out)])
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert (
        r.output.strip()
        .splitlines()[-1]
        .startswith(f"Error: the C compiler {str(tmp_path / 'no-such-cc')!r} cannot run (No such file or directory)")
    )
    assert not out.exists() and not list((tmp_path / "cache").rglob("*.so"))


@pytest.mark.slow
@needs_cc
def test_compiled_ipopt_problems_give_the_same_estimates(arm, noisy):
    """CasADi's jit for the nonlinear and consistent problems (seconds of compilation each)."""
    sub = noisy.select(slice(0, 8))
    for method in ("nonlinear", "consistent"):
        a = solve_dataset(sub, SolveSettings(method=method), model=arm)
        b = solve_dataset(sub, SolveSettings(method=method, backend="casadi-c"), model=arm)
        assert np.array_equal(a.success, b.success)
        assert rel_err(b.theta_hat, a.theta_hat) < 1e-8


def test_cache_command_shows_and_clears(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from ineid._trust import write_manifest
    from ineid.cache import private_folder
    from ineid.cli import main

    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path))
    (private_folder("xla") / f"jit_f-{'0' * 64}-cache").write_bytes(b"x" * 1000)  # named as JAX names its kernels
    generated = private_folder("generated", "abc")
    (generated / "m.py").write_text("# code\n")
    write_manifest(generated, {"m.py": b"# code\n"}, private=True)  # ineid's code: listed in its manifest
    runner = CliRunner()
    info = runner.invoke(main, ["cache", "info"])
    assert info.exit_code == 0 and "compiled XLA kernels" in info.output and "generated" in info.output
    r = runner.invoke(main, ["cache", "clear", "--xla-only"])
    assert r.exit_code == 0 and f"removed {tmp_path / 'xla'} (1 files" in r.output
    assert not (tmp_path / "xla").exists() and (tmp_path / "generated" / "abc" / "m.py").exists()
    assert runner.invoke(main, ["cache", "clear"]).exit_code == 0 and not tmp_path.exists()


def test_chunks_on_several_threads_equal_one_thread(arm, base, noisy, monkeypatch):
    """The configurations split among threads give the one-thread blocks bit for bit, and
    the progress counts every configuration once, in order."""
    frames = [a[:, :32] for a in (noisy.q, noisy.qd, noisy.qdd, noisy.wrench)]
    monkeypatch.setattr(fused, "WORKERS", 1)
    one = fused.information_blocks(arm, base, *frames, noisy.theta_known)
    monkeypatch.setattr(fused, "WORKERS", 3)  # 300 configurations, 64 a call: 5 chunks over 3 threads
    seen = []
    many = fused.information_blocks(arm, base, *frames, noisy.theta_known, progress=lambda d, n: seen.append((d, n)))
    for name in ("G", "h", "e"):
        assert np.array_equal(getattr(one, name), getattr(many, name)), name
    assert seen[-1] == (300, 300) and [d for d, _ in seen] == sorted(d for d, _ in seen) and len(seen) == 5


def test_blocks_summed_with_known_weights_equal_the_per_axis_sum(arm, base, noisy, rng):
    """Weights known in advance are applied in the kernel: ``G = sum_a d_a^2 G_a`` (and ``h``),
    the same normal equations as from per-axis blocks; the summed blocks refuse what needs the axes."""
    frames = [a[:, :32] for a in (noisy.q, noisy.qd, noisy.qdd, noisy.wrench)]
    d = rng.uniform(0.5, 3.0, size=(noisy.n_configs, 6))
    per_axis = fused.information_blocks(arm, base, *frames, noisy.theta_known)
    summed = fused.information_blocks(arm, base, *frames, noisy.theta_known, axis_weights=d)
    assert summed.G.shape == (noisy.n_configs, base.rank, base.rank)
    for got, want in zip(summed.weighted(d), per_axis.weighted(d), strict=True):
        assert rel_err(got, want) < 1e-13
    assert np.array_equal(summed.e, per_axis.e)
    with pytest.raises(ValueError, match="other row weights"):
        summed.weighted(np.ones_like(d))
    with pytest.raises(ValueError, match="needs per-axis blocks"):
        summed.axis_rss(np.zeros((noisy.n_configs, base.rank)))
    with pytest.raises(ValueError, match="per axis"):
        fused.information_blocks(arm, base, *frames, noisy.theta_known, sums=True, axis_weights=d)
