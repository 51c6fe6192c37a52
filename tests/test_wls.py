"""The wls network (:mod:`ineid.learn.wls`): exact least squares inside, gradients through the solve, training on
glitchy data, amortized solving, glitch noise, and sweeps on a local Ray cluster."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner
from jax.test_util import check_grads

import ineid
from ineid.channels.pose import SensorPose
from ineid.cli import main
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, fit_base, load_results, stack
from ineid.learn import Grid, ModelSpec, TrainConfig, evaluate, load_run, predict, sweep, train
from ineid.learn.wls import WLS, fit_context, prior_estimate, residual_sigma, wls_solve
from ineid.workflow import solve_dataset

from .conftest import SEED

LEVEL1 = {"force": 0.5, "moment": 0.05, "qd": 0.01, "qdd": 0.1}


def _data(model, n_configs, n_frames, seed, glitch=0.0, noise=True):
    nm = NoiseModel.create(model.n_dof, **LEVEL1, glitch_rate=glitch) if noise else None
    return generate_dataset(
        model, DatasetSpec(Combination("random", n_configs=n_configs), n_frames=n_frames, seed=seed, noise=nm)
    )


def _layer_inputs(model, ds, base):
    w, y = stack(model, ds.q, ds.qd, ds.qdd, ds.wrench, ds.theta_known)
    sigma = residual_sigma(w, y, ds.theta_unknown, ds.wrench.reshape(-1, 6).std(axis=0))
    ctx = fit_context(ds.theta_unknown, sigma, base, np.zeros(20), np.ones(20))  # the identity target scaler
    c, f = ds.n_configs, ds.n_frames
    x = np.random.default_rng(SEED).standard_normal((c, f, 18))  # the features only feed the encoder
    return ctx, w, y, (x, w.reshape(c, f, 6, -1), y.reshape(c, f, 6))


# -- the layer ------------------------------------------------------------------------------------


@pytest.mark.parametrize("noise", [False, True], ids=["clean", "noisy"])
def test_layer_is_weighted_least_squares_with_the_noise_weights_and_no_prior(model, base, noise):
    ds = _data(model, 60, 5, SEED, noise=noise)
    ctx, w, y, inputs = _layer_inputs(model, ds, base)
    net = WLS(hidden=(16, 16), context=ctx, prior=False)
    params = net.init(jax.random.key(0), *(a[:1] for a in inputs))  # untrained: weights = 1 / sigma
    theta = np.asarray(jax.jit(net.apply)(params, *inputs))
    ref = fit_base(w, y, base, weights="noise", axis_sigma=ctx.sigma)  # identify's QR route
    scale = base.scales[base.base_index]
    np.testing.assert_allclose(theta @ base.B.T / scale, ref.beta / scale, rtol=0, atol=1e-9)
    # the null-space rule is the floor's: B theta = beta exactly, the rest from the training correlation
    np.testing.assert_allclose(
        theta,
        ctx.identifiable_part(np.asarray(ref.beta) @ np.linalg.pinv(base.B).T),
        rtol=0,
        atol=1e-9 * np.abs(theta).max(),
    )
    if not noise:  # clean data: the identifiable combinations exactly
        truth = ds.theta_unknown @ base.B.T
        assert np.max(np.abs(theta @ base.B.T - truth) / scale) < 1e-10
        # and whatever weights and prior a network learns: the data rows outweigh any prior
        net = WLS(hidden=(16, 16), context=ctx)
        params = _perturbed(net.init(jax.random.key(4), *(a[:1] for a in inputs)), 1.0, jax.random.key(5))
        theta = np.asarray(jax.jit(net.apply)(params, *inputs))
        assert np.max(np.abs(theta @ base.B.T - truth) / np.abs(truth)) < 1e-8


def _perturbed(params, std, key):
    """Every weight moved off its start by N(0, std^2) (the last layers start at zero)."""
    leaves, tree = jax.tree_util.tree_flatten(params)
    keys = jax.random.split(key, len(leaves))
    return jax.tree_util.tree_unflatten(
        tree, [w + std * jax.random.normal(k, w.shape, w.dtype) for w, k in zip(leaves, keys, strict=True)]
    )


def test_untrained_layer_is_the_gaussian_prior_estimate(model, base):
    ds = _data(model, 60, 5, SEED)
    ctx, w, y, inputs = _layer_inputs(model, ds, base)
    net = WLS(hidden=(16,), context=ctx)
    params = net.init(jax.random.key(1), *(a[:1] for a in inputs))
    theta = np.asarray(jax.jit(net.apply)(params, *inputs))
    theta_ref, beta_ref = prior_estimate(ctx, w, y)  # NumPy QR of the stacked rows and prior
    scale = base.scales[base.base_index]
    np.testing.assert_allclose(theta @ base.B.T / scale, beta_ref / scale, rtol=0, atol=1e-10)
    np.testing.assert_allclose(theta, theta_ref, rtol=0, atol=1e-10 * np.abs(theta).max())
    # 5 frames of level-1 noise: the prior helps, so the estimate beats plain least squares
    truth = ds.theta_unknown @ base.B.T
    ls = fit_base(w, y, base).beta
    assert np.median(np.abs(beta_ref - truth) / np.abs(truth)) < 0.7 * np.median(np.abs(ls - truth) / np.abs(truth))


def test_solve_gradients_match_finite_differences():
    rng = np.random.default_rng(SEED)
    n, r = 18, 4
    a, e = rng.standard_normal((2, n, r)), rng.standard_normal((2, n))
    d, g = rng.uniform(0.5, 2.0, (2, n)), rng.uniform(0.5, 2.0, (2, r))
    p, m = np.eye(r) + 0.1 * rng.standard_normal((r, r)), rng.standard_normal((2, r))
    u = wls_solve(a, e, d, p, g, m)
    # the normal equations hold
    for i in range(2):
        wd, wg = d[i] ** 2, g[i] ** 2
        lhs = a[i].T @ (wd[:, None] * a[i]) + p.T @ (wg[:, None] * p)
        np.testing.assert_allclose(lhs @ u[i], a[i].T @ (wd * e[i]) + p.T @ (wg * m[i]), rtol=1e-12)
    check_grads(jax.jit(wls_solve), (a, e, d, p, g, m), order=1, modes=("fwd", "rev"), eps=1e-6)


@pytest.mark.slow
def test_model_gradients_match_finite_differences(model, base):
    ds = _data(model, 30, 4, SEED + 2, glitch=0.1)
    ctx, _, _, inputs = _layer_inputs(model, ds, base)
    net = WLS(hidden=(4,), context=ctx)
    params = net.init(jax.random.key(2), *(a[:1] for a in inputs))
    params = _perturbed(params, 0.05, jax.random.key(3))  # so that every path carries a gradient
    x, psi, y = (jnp.asarray(a[:2]) for a in inputs)
    check_grads(
        jax.jit(lambda prm: jnp.sum(net.apply(prm, x, psi, y) ** 2)), (params,), order=1, modes=("rev",), eps=1e-6
    )


# -- glitches -------------------------------------------------------------------------------------


def test_glitches_scale_the_force_noise_of_some_frames(model):
    plain = _data(model, 200, 10, SEED)
    glitchy = _data(model, 200, 10, SEED, glitch=0.05)
    for k in ("q", "qd", "qdd"):  # the same draws otherwise
        np.testing.assert_array_equal(getattr(plain, k), getattr(glitchy, k))
    np.testing.assert_array_equal(plain.wrench[..., 3:], glitchy.wrench[..., 3:])
    noise_plain = plain.wrench[..., :3] - plain.clean["wrench"][..., :3]
    noise_glitch = glitchy.wrench[..., :3] - glitchy.clean["wrench"][..., :3]
    hit = ~np.all(noise_plain == noise_glitch, axis=-1)
    np.testing.assert_allclose(noise_glitch[hit], 20.0 * noise_plain[hit], rtol=1e-12)
    assert 0.03 < hit.mean() < 0.07
    assert glitchy.meta.noise["glitch_rate"] == 0.05 and "glitch_rate" not in plain.meta.noise
    assert NoiseModel.from_dict(glitchy.meta.noise, model.n_dof).to_dict() == glitchy.meta.noise
    with pytest.raises(ValueError, match="glitch_rate must be in"):
        NoiseModel.create(4, force=0.5, glitch_rate=1.5)
    with pytest.raises(ValueError, match="give a force noise"):
        NoiseModel.create(4, moment=0.05, glitch_rate=0.1)


# -- training -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def glitch_run(model, tmp_path_factory):
    ds = _data(model, 1000, 10, SEED + 3, glitch=0.02)
    cfg = TrainConfig(
        model=ModelSpec("wls", frames=10), epochs=8, batch=128, lr=3e-3, patience=0, n_train=600, n_val=150, n_test=250
    )
    run_dir = tmp_path_factory.mktemp("wls") / "run"
    train(ds, cfg, run_dir, model=model)
    return ds, run_dir


def test_short_training_beats_least_squares_on_glitchy_data(model, glitch_run):
    ds, run_dir = glitch_run
    run = load_run(run_dir)
    ev = evaluate(run, ds, model=model)
    net, ls, gp = (
        ev.network_base["overall_median"],
        ev.linear_base["overall_median"],
        ev.gaussian_base["overall_median"],
    )
    assert net < ls / 1.5
    assert net <= gp * 1.02  # it starts as the Gaussian-prior estimate and training keeps it there or better
    metrics = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert metrics[-1]["train_mse"] < metrics[0]["train_mse"]  # it learned something
    assert run.config.model.name == "wls-tanh-k10" and "wls" in run.meta


# -- amortized solving ------------------------------------------------------------------------------


def test_solve_with_a_run_dataset_and_recording(model, glitch_run, tmp_path):
    from ineid.data import read_recording_csv, write_recording_csv

    ds, run_dir = glitch_run
    run = load_run(run_dir)
    test = run.split.test[:40]
    sub = ds.select(test)
    res = solve_dataset(sub, SolveSettings(method="network", run=str(run_dir)), model=model)
    expected, _, _ = predict(run, sub, np.arange(len(test)), model=model)
    np.testing.assert_allclose(res.theta_hat, expected, rtol=1e-12)
    assert res.n_frames_fit == 10 and res.n_frames_validation == 0 and res.success.all()
    assert np.isnan(res.theta_std).all() and np.isfinite(res.fit_rms).all()
    np.testing.assert_allclose(res.base_hat, res.theta_hat @ res.base.B.T)
    rec = read_recording_csv(write_recording_csv(tmp_path / "r.csv", ds, int(test[0])), model)
    one = solve_dataset(rec, SolveSettings(method="network", run=str(run_dir)), model=model)
    assert one.theta_true is None
    np.testing.assert_allclose(one.theta_hat[0], expected[0], rtol=1e-9)
    np.testing.assert_allclose(one.fit_rms[0], res.fit_rms[0], rtol=1e-9)
    tilted = dataclasses.replace(
        rec, meta=dataclasses.replace(rec.meta, sensor=SensorPose(rpy=(np.pi, 0.0, 0.0)).to_dict())
    )
    with pytest.raises(ineid.IneidError, match="this recording's wrench is in a sensor frame"):
        solve_dataset(tilted, SolveSettings(method="network", run=str(run_dir)), model=model)
    with pytest.raises(ValueError, match="needs run"):
        SolveSettings(method="network")
    with pytest.raises(ineid.IneidError, match="frames per sample"):
        solve_dataset(ds.select(test[:2], slice(0, 6)), SolveSettings(method="network", run=str(run_dir)), model=model)


def test_cli_solve_network_round_trip(model, tmp_path):
    runner = CliRunner()

    def run(*args):
        return runner.invoke(main, [str(a) for a in args], catch_exceptions=False)

    data, out = tmp_path / "d.h5", tmp_path / "run"
    noise = "force=0.5,moment=0.05,qd=0.01,qdd=0.1,glitch=0.05,glitch_scale=10"
    assert run("data", "generate", "--n-configs", 80, "--n-frames", 8, "--noise", noise, "--out", data).exit_code == 0
    r = run("-q", "train", data, "--arch", "wls", "--sample-frames", 4, "--epochs", 2, "--batch", 32, "--out", out)
    assert r.exit_code == 0, r.output
    assert "Gaussian prior" in r.output
    r = run("-q", "solve", data, "--method", "network", "--run", out, "--select", "0:10", "--out", tmp_path / "r.h5")
    assert r.exit_code == 0, r.output
    assert "network on sweaty-arm: 10/10 configurations identified" in r.output and "validated on 4" in r.output
    res = load_results(tmp_path / "r.h5")
    assert res.settings.method == "network" and res.settings.run == str(out) and res.n == 10
    r = run("solve", data, "--method", "network", "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "needs --run" in r.output
    r = run("solve", data, "--method", "network", "--run", out, "--fit-frames", 6, "--out", tmp_path / "x.h5")
    assert r.exit_code == 1 and "multiple of the run's 4 frames" in r.output
    r = run("data", "generate", "--n-configs", 5, "--noise", "force=0.5,glitch=2", "--out", tmp_path / "g.h5")
    assert r.exit_code == 2 and "glitch_rate must be in [0, 1)" in r.output


# -- sweeps -----------------------------------------------------------------------------------------


def test_grid_runs_wls_once():
    cfgs = Grid(archs=("wls", "simple"), frames=(1, 4), siamese=(False, True)).configs(TrainConfig())
    names = [c.model.name for c in cfgs]
    assert names.count("wls-tanh-k4") == 1 and names.count("wls-tanh-k1") == 1 and "simple-tanh-siamese4" in names
    with pytest.raises(ValueError, match="drop siamese"):
        ModelSpec("wls", frames=4, siamese=True)


def test_ray_engine_runs_a_sweep_and_reports_a_failed_trial(model, tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install 'ineid[ray]'); the ray engine needs it")
    ds = _data(model, 60, 4, SEED + 4, noise=False)
    base = TrainConfig(epochs=1, batch=16, n_train=30, n_val=10, n_test=20)
    # two trials: K = 2 trains; K = 8 fails in its worker (the dataset has 4 frames per configuration)
    rows = sweep(
        ds,
        Grid(archs=("simple",), frames=(2, 8)),
        base,
        tmp_path / "sw",
        model=model,
        engine="ray",
        cpus_per_trial=1,
        ray_init={"num_cpus": 2},
    )
    assert [r.frames for r in rows] == [2, 8]
    assert rows[0].status == "ok" and np.isfinite(rows[0].test_base_median) and rows[0].epochs_run == 1
    assert rows[1].status == "failed: DatasetError: 8 frames per sample but the dataset has 4 frames per configuration"
    ok_dir = tmp_path / "sw" / rows[0].name
    assert load_run(ok_dir).config.model.frames == 2 and (ok_dir / "evaluation.json").is_file()
    assert not (tmp_path / "sw" / rows[1].name).exists()
    csv = (tmp_path / "sw" / "sweep.csv").read_text().splitlines()
    assert len(csv) == 3 and csv[0].endswith(",status") and "failed: DatasetError" in csv[2]
    assert (tmp_path / "sw" / "sweep.png").is_file()
    import ray

    assert not ray.is_initialized()  # the local cluster was stopped


def test_ray_engine_writes_only_run_files_a_worker_sends(tmp_path, monkeypatch):
    """File names from a worker are joined onto the run folder: only the plain run files are taken."""
    import sys
    import types

    from ineid.learn import ray_engine
    from ineid.learn.runs import MODEL, RUN_FILES
    from ineid.learn.sweep import SweepRow, run_name

    cfgs = [TrainConfig(model=ModelSpec("simple", frames=k)) for k in (1, 2, 3, 4)]
    sent = iter(
        [
            {MODEL: b"weights", "config.json": b"{}"},
            {"../../escaped": b"x"},
            {MODEL + "/../../x": b"y"},
            {MODEL: "not bytes"},
        ]
    )

    class Ref:  # a task trains a population: a row and the files of each of its trials
        def __init__(self, cfgs):
            self.value = [(dataclasses.replace(SweepRow.failed(cfg, ""), status="ok"), next(sent)) for cfg in cfgs]

    class Task:
        def options(self, **_):
            return self

        def remote(self, ds, cfgs, *_):
            return Ref(cfgs)

    fake = types.SimpleNamespace(
        is_initialized=lambda: True,
        remote=lambda fn: Task(),
        put=lambda x: x,
        wait=lambda refs, num_returns: ([refs[0]], refs[1:]),
        get=lambda ref: ref.value,
        exceptions=types.SimpleNamespace(RayError=RuntimeError),
    )
    monkeypatch.setitem(sys.modules, "ray", fake)
    out = tmp_path / "a" / "b" / "sweep"
    rows = ray_engine.ray_trials(None, cfgs, out)
    assert rows[0].status == "ok"
    assert sorted(p.name for p in (out / run_name(cfgs[0])).iterdir()) == ["config.json", MODEL]
    for row, bad in zip(rows[1:], ("'../../escaped'", f"'{MODEL}/../../x'", "str instead of the bytes"), strict=True):
        assert row.status.startswith("failed: the worker sent back") and bad in row.status, row.status
        assert "nothing of this trial was written" in row.status and not (out / row.name).exists()
    assert sorted(p.name for p in tmp_path.rglob("*")) == sorted(
        ["a", "b", "sweep", run_name(cfgs[0]), "config.json", MODEL]
    )
    with pytest.raises(ineid.errors.TrainingError, match="refusing to write a file named '../x'"):
        ray_engine._write_run(tmp_path / "run", {"../x": b""})
    assert ray_engine.files_problem(dict.fromkeys(RUN_FILES, b"")) is None


def test_ray_engine_says_how_to_install_ray(model, tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as if it were not installed
    ds = _data(model, 30, 2, SEED, noise=False)
    with pytest.raises(ineid.errors.OptionalDependencyError, match=r"pip install 'ineid\[ray\]'"):
        sweep(ds, Grid(archs=("simple",)), TrainConfig(epochs=1), tmp_path / "sw", model=model, engine="ray")
    data = tmp_path / "d.h5"
    ds.save(data)
    r = CliRunner().invoke(main, ["sweep", str(data), "--engine", "ray", "--out", str(tmp_path / "o")])
    assert r.exit_code == 1 and "pip install 'ineid[ray]'" in r.output
    r = CliRunner().invoke(main, ["sweep", str(data), "--cpus-per-trial", "2", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "go with --engine ray" in r.output
