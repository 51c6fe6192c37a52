"""Learning: models, the physics loss against NumPy, gradients, training, resume, evaluation."""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import ineid
from ineid.data import Combination, DatasetSpec, FrameSampling, generate_dataset
from ineid.learn import (
    ModelSpec,
    Scaler,
    TrainConfig,
    TrainingError,
    evaluate,
    floor_estimator,
    hidden_widths,
    load_run,
    make_loss,
    split_configs,
    train,
)
from ineid.learn.train import prepare

from .conftest import SEED


@pytest.fixture(scope="module")
def data(model):
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=120), n_frames=12, seed=SEED))


@pytest.fixture(scope="module")
def quasi_static(model):
    """Slow motions: the wrench is mostly gravity, so masses and first moments are learnable."""
    frames = FrameSampling(velocity_scale=0.02, acceleration_scale=0.02)
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=500), n_frames=8, seed=3, frames=frames))


# -- models ------------------------------------------------------------------------------------


def test_architectures_follow_table_1():
    assert hidden_widths("simple", 20) == (20,)
    assert hidden_widths("net1", 20) == (20,) * 8 and hidden_widths("net2", 20) == (40,) * 8
    assert hidden_widths("net3", 20) == (20,) * 12 and hidden_widths("net4", 20) == (20,) * 16
    assert [hidden_widths(f"net{i}", 20)[0] for i in (5, 6, 7)] == [80, 160, 320]
    assert hidden_widths("funnel", 20) == (64, 32, 16, 8, 4, 2)
    assert hidden_widths("mlp", 20, depth=3, width=7) == (7, 7, 7)
    with pytest.raises(ValueError, match="depth >= 1 and width >= 1"):
        ModelSpec("mlp")
    with pytest.raises(ValueError, match="activation must be one of"):
        ModelSpec(activation="swish2")


@pytest.mark.parametrize("arch", ["simple", "net3", "funnel"])
@pytest.mark.parametrize("siamese", [False, True])
def test_shapes(arch, siamese):
    k = 4
    net = ModelSpec(arch, frames=k, siamese=siamese).build(20)
    x = jnp.ones((3, k, 18))
    params = net.init(jax.random.key(0), x)
    assert net.apply(params, x).shape == (3, 20)
    kernels = [p for p in jax.tree_util.tree_leaves(params) if p.ndim == 2]
    first = kernels[0] if not siamese else params["params"]["encoder"]["hidden_0"]["kernel"]
    assert first.shape[0] == (18 if siamese else 18 * k)
    assert all(p.dtype == jnp.float64 for p in jax.tree_util.tree_leaves(params))


def test_siamese_shares_weights():
    spec = ModelSpec("net1", frames=5, siamese=True)
    net = spec.build(20)
    rng = np.random.default_rng(SEED)
    x = jnp.asarray(rng.normal(size=(2, 5, 18)))
    params = net.init(jax.random.key(1), x)
    # one encoder, whatever the number of frames: the parameter count does not grow with K
    count = sum(p.size for p in jax.tree_util.tree_leaves(params))
    params7 = net.init(jax.random.key(1), jnp.ones((2, 7, 18)))
    assert count == sum(p.size for p in jax.tree_util.tree_leaves(params7))
    assert set(params["params"]) == {"encoder", "head_hidden", "out"}
    # the same weights act on every frame: order does not matter, any K works
    perm = jnp.asarray(rng.permutation(5))
    np.testing.assert_allclose(net.apply(params, x), net.apply(params, x[:, perm]), rtol=1e-12)
    assert net.apply(params, jnp.asarray(rng.normal(size=(2, 9, 18)))).shape == (2, 20)
    # frames that are identical give the embedding of one frame
    one = x[:, :1]
    np.testing.assert_allclose(net.apply(params, jnp.repeat(one, 5, axis=1)), net.apply(params, one), rtol=1e-12)


# -- the physics loss ----------------------------------------------------------------------------


def _physics(model, data, mode, split):
    cfg = TrainConfig(model=ModelSpec("simple", frames=3), loss="physics")
    rows = np.union1d(split.train, split.val)
    return prepare(data, cfg, rows, model, fit_rows=split.train, physics_mode=mode)


@pytest.mark.parametrize("mode", ["cached", "inline"])
def test_physics_loss_equals_numpy_and_vanishes_at_the_truth(model, data, mode):
    split = split_configs(data.n_configs, 80, 20, 20, SEED)
    prep = _physics(model, data, mode, split)
    rows = prep.local(split.train[:6])
    frames = np.tile(np.arange(3), (6, 1)) + 2
    from ineid.learn.train import gather_samples

    x, z, inputs = gather_samples(prep.arrays, prep.physics.mode, rows, frames)
    theta_true = data.theta_unknown[split.train[:6]]
    rng = np.random.default_rng(SEED)
    theta_hat = theta_true * (1 + 0.1 * rng.normal(size=theta_true.shape))
    z_hat = prep.y_scaler.transform(theta_hat)
    got = float(prep.physics.term(jnp.asarray(z_hat), inputs))
    # direct NumPy: full parameter vectors, the model's regressor frame by frame
    full = np.empty((6, 40))
    full[:, model.unknown_index] = theta_hat
    full[:, model.known_index] = data.theta_known
    c = split.train[:6]
    y = np.asarray(model.regressor(data.q[c][:, 2:5], data.qd[c][:, 2:5], data.qdd[c][:, 2:5]))
    resid = data.wrench[c][:, 2:5] - np.einsum("ckij,cj->cki", y, full)
    expected = np.mean((resid / prep.physics.wrench_scale) ** 2)
    assert abs(got - expected) <= 1e-12 * expected
    at_truth = float(prep.physics.term(jnp.asarray(prep.y_scaler.transform(theta_true)), inputs))
    assert at_truth < 1e-24


def test_physics_modes_agree(model, data):
    split = split_configs(data.n_configs, 80, 20, 20, SEED)
    a, b = _physics(model, data, "cached", split), _physics(model, data, "inline", split)
    from ineid.learn.train import gather_samples

    rows, frames = a.local(split.val[:4]), np.tile(np.arange(3), (4, 1))
    z = jnp.asarray(np.random.default_rng(1).normal(size=(4, 20)))
    va = a.physics.term(z, gather_samples(a.arrays, "cached", rows, frames)[2])
    vb = b.physics.term(z, gather_samples(b.arrays, "inline", rows, frames)[2])
    np.testing.assert_allclose(float(va), float(vb), rtol=1e-12)


def test_compact_cache_equals_the_full_regressor(model, data, rng):
    """The compact rows (base columns, entries never zero, axes grouped by their columns) give
    ``(y - Psi_u theta) / s``: on the arm (forces use 6 base columns, moments all 17: 75
    numbers a frame) and on a made-up regressor whose groups interleave the axes."""
    from types import SimpleNamespace

    from ineid.learn.losses import CompactRegressor

    split = split_configs(data.n_configs, 80, 20, 20, SEED)
    prep = _physics(model, data, "cached", split)
    compact = prep.physics.compact
    assert [(len(c), a) for c, a in compact.groups] == [(6, (0, 1, 2)), (17, (3, 4, 5))]
    assert compact.width == 75 and prep.arrays["compact"].shape[-1] == 75
    with pytest.raises(ValueError, match="compact cached regressor"):
        prep.physics.system((None, None))

    r, p = 5, 8
    b = np.hstack([np.eye(r), rng.normal(size=(r, p - r))])
    psi_b = rng.normal(size=(40, 6, r))
    psi_b[:, [0, 2, 5], 3:] = 0.0  # axes 0, 2, 5 use columns 0-2 only: groups (1, 3, 4) and (0, 2, 5)
    psi_u, y = psi_b @ b, rng.normal(size=(40, 6))
    scale = rng.uniform(0.5, 2.0, size=6)
    made_up, rows = CompactRegressor.from_frames(psi_u, y, SimpleNamespace(base_index=np.arange(r), B=b, rank=r), scale)
    assert [a for _, a in made_up.groups] == [(0, 2, 5), (1, 3, 4)]
    theta = rng.normal(size=(40, p))
    got = made_up.residual(jnp.asarray(theta), (jnp.asarray(rows[:, None, 6:]), jnp.asarray(rows[:, None, :6])))
    want = (y - np.einsum("fap,fp->fa", psi_u, theta)) / scale
    np.testing.assert_allclose(np.asarray(got)[:, 0], want, rtol=1e-12, atol=1e-12)


def test_loss_gradients(model, data):
    split = split_configs(data.n_configs, 80, 20, 20, SEED)
    prep = _physics(model, data, "cached", split)
    net = ModelSpec("mlp", depth=2, width=6, frames=3).build(20)
    from ineid.learn.train import gather_samples

    x, z, inputs = gather_samples(prep.arrays, "cached", prep.local(split.train[:4]), np.tile(np.arange(3), (4, 1)))
    params = net.init(jax.random.key(0), x)
    loss = make_loss(net.apply, 0.7, 2.0, prep.physics)
    check_grads(lambda p: loss(p, x, z, inputs)[0], (params,), order=2, modes=["rev"], eps=1e-6, atol=1e-6, rtol=1e-6)
    with pytest.raises(ValueError, match="physics loss needs"):
        make_loss(net.apply, 1.0, 1.0, None)


# -- scalers, splits, floor ---------------------------------------------------------------------


def test_scalers(rng):
    x = rng.normal(3.0, 2.0, size=(1000, 4))
    x[:, 3] = 5.0  # constant column
    for kind in ("standard", "robust", "minmax"):
        s = Scaler.fit(kind, x)
        back = Scaler.from_dict(json.loads(json.dumps(s.to_dict())))
        np.testing.assert_allclose(back.inverse(back.transform(x)), x, rtol=1e-12)
        assert np.all(np.isfinite(s.transform(x)))
    np.testing.assert_allclose(Scaler.fit("minmax", x).transform(x)[:, :3].min(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(Scaler.fit("standard", x).transform(x)[:, :3].std(axis=0), 1.0, rtol=1e-12)


def test_split_is_by_configuration_and_seeded():
    s = split_configs(100, 60, 20, 15, seed=4)
    assert len(s.train) == 60 and len(s.val) == 20 and len(s.test) == 15
    assert not (set(s.train) & set(s.val)) and not (set(s.train) & set(s.test)) and not (set(s.val) & set(s.test))
    assert np.array_equal(s.train, split_configs(100, 60, 20, 15, seed=4).train)
    with pytest.raises(ineid.DatasetError, match="cannot split 10 configurations"):
        split_configs(10, 9, 1, None, 0)


def test_floor_is_zero_where_identifiable(model, data):
    from ineid.identify import base_parameters

    base = base_parameters(model)
    est = floor_estimator(data.theta_unknown[:80], base.B)(data.theta_unknown[80:])
    truth = data.theta_unknown[80:]
    np.testing.assert_allclose(est[:, base.identifiable], truth[:, base.identifiable], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(est @ base.B.T, truth @ base.B.T, rtol=1e-8, atol=1e-12)
    assert np.abs(est[:, ~base.identifiable] - truth[:, ~base.identifiable]).max() > 0


# -- training ------------------------------------------------------------------------------------


def test_training_learns_below_the_mean(model, quasi_static, tmp_path):
    cfg = TrainConfig(
        model=ModelSpec("net2", frames=4, siamese=True),
        epochs=40,
        batch=64,
        lr=3e-3,
        patience=0,
        n_train=350,
        n_val=50,
        n_test=100,
    )
    train(quasi_static, cfg, tmp_path / "run", model=model)
    ev = evaluate(load_run(tmp_path / "run"), quasi_static, model=model, linear=False)
    test = load_run(tmp_path / "run").split.test
    mean_guess = np.broadcast_to(
        quasi_static.theta_unknown[load_run(tmp_path / "run").split.train].mean(axis=0), (len(test), 20)
    )
    from ineid.identify.results import relative_error

    mean_err = np.nanmedian(relative_error(mean_guess, quasi_static.theta_unknown[test]), axis=0)
    # the total mass and the first moments along the arm show in the static load
    total_mass = ev.network_base["names"].index("upper_arm.m + forearm.m")
    assert ev.network_base["r2"][total_mass] > 0.8
    assert ev.network_base["median"][total_mass] < 0.3 * np.nanmedian(
        relative_error(
            mean_guess[:, 0] + mean_guess[:, 10],
            quasi_static.theta_unknown[test][:, 0] + quasi_static.theta_unknown[test][:, 10],
        )
    )
    assert ev.network["overall_median"] < 0.8 * float(np.median(mean_err))


def test_resume_continues_the_same_run(model, data, tmp_path):
    cfg = TrainConfig(
        model=ModelSpec("net1", frames=3, siamese=True),
        loss="physics",
        epochs=4,
        batch=32,
        optimizer="sgd",
        lr=1e-2,
        schedule="cosine",
        patience=0,
    )
    train(data, cfg, tmp_path / "straight", model=model)

    def interrupt(epoch, total, rec):
        if epoch == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(data, cfg, tmp_path / "split", model=model, progress=interrupt)
    assert not (tmp_path / "split" / "model.msgpack").exists()
    with pytest.raises(TrainingError, match="not a finished training run: model.msgpack missing .*--resume"):
        load_run(tmp_path / "split")
    train(data, cfg, tmp_path / "split", model=model, resume=True)
    a, b = load_run(tmp_path / "straight"), load_run(tmp_path / "split")
    for pa, pb in zip(jax.tree_util.tree_leaves(a.params), jax.tree_util.tree_leaves(b.params), strict=True):
        np.testing.assert_array_equal(np.asarray(pa), np.asarray(pb))
    lines = (tmp_path / "split" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2, 3, 4]
    # every record but its wall-clock seconds is the uninterrupted run's, bit for bit
    timeless = lambda text: [{k: v for k, v in json.loads(x).items() if k != "seconds"} for x in text]  # noqa: E731
    assert timeless(lines) == timeless((tmp_path / "straight" / "metrics.jsonl").read_text().splitlines())
    # the scalers were saved and are reapplied, not refitted
    sc = json.loads((tmp_path / "split" / "scalers.json").read_text())
    assert b.x_scaler.to_dict() == sc["x"] and b.y_scaler.to_dict() == sc["y"]
    with pytest.raises(TrainingError, match="other settings"):
        train(data, TrainConfig(model=cfg.model, epochs=5), tmp_path / "split", model=model, resume=True)
    with pytest.raises(TrainingError, match="not empty; pass --overwrite"):
        train(data, cfg, tmp_path / "split", model=model)
    with pytest.raises(TrainingError, match="no checkpoint to resume"):
        train(data, cfg, tmp_path / "fresh", model=model, resume=True)


def test_learn_never_imports_sympy():
    code = "import sys, ineid.learn; assert 'sympy' not in sys.modules, 'sympy imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_resume_guards(model, data, tmp_path):
    cfg = TrainConfig(model=ModelSpec("net1", frames=2), epochs=30, batch=16, lr=0.05, patience=1)
    first = train(data, cfg, tmp_path / "run", model=model)
    assert first.stopped_early and first.epochs_run < 30
    n_lines = len((tmp_path / "run" / "metrics.jsonl").read_text().splitlines())
    again = train(data, cfg, tmp_path / "run", model=model, resume=True)  # a finished run stays finished
    assert again.stopped_early and len((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()) == n_lines
    other = generate_dataset(model, DatasetSpec(Combination("random", n_configs=120), n_frames=12, seed=SEED + 1))
    with pytest.raises(TrainingError, match="trained on another dataset"):
        train(other, cfg, tmp_path / "run", model=model, resume=True)
    with pytest.raises(ValueError, match="depth and width apply to the mlp"):
        ModelSpec("net1", depth=3)


def test_evaluate_on_another_dataset(model, data, tmp_path):
    cfg = TrainConfig(model=ModelSpec("simple"), epochs=2, batch=64)
    train(data, cfg, tmp_path / "run", model=model)
    run = load_run(tmp_path / "run")
    other = generate_dataset(model, DatasetSpec(Combination("random", n_configs=150), n_frames=6, seed=9))
    ev = evaluate(run, other, model=model)
    assert ev.n_configs == 150 and ev.extra == {"configs": "all", "same_dataset": False}
    assert np.isfinite(ev.floor["overall_median"]) and ev.floor["overall_median"] > 0.001  # out of fold, not fitted
    small = evaluate(run, other, configs=np.arange(5), model=model, linear=False)
    assert small.extra["configs"] == "given" and np.isnan(small.floor["overall_median"])


def test_training_refuses_a_recording(model, data, tmp_path):
    from ineid.data import read_recording_csv, write_recording_csv

    rec = read_recording_csv(write_recording_csv(tmp_path / "r.csv", data, 0), model)
    with pytest.raises(ineid.DatasetError, match="training needs the true parameters, and this dataset is a recording"):
        train(rec, TrainConfig(), tmp_path / "run", model=model)
