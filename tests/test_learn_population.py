"""Populations: trials trained together equal the same trials trained alone; splitting, memory, float32, grouping."""

from __future__ import annotations

import dataclasses
import json
import logging

import jax
import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset, write_dataset
from ineid.learn import ModelSpec, TrainConfig, load_run, train
from ineid.learn.train import Trial, train_population
from ineid.learn.trials import populations

from .conftest import SEED

BASE = TrainConfig(model=ModelSpec("simple"), optimizer="sgd", lr=1e-2, batch=32, epochs=3, patience=0)


@pytest.fixture(scope="module")
def data(model):
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=40), n_frames=8, seed=SEED))


def _metrics(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]


def _assert_same_run(a, b) -> None:
    """Two run folders hold the same run: the best parameters and every epoch's numbers, to round-off."""
    pa, pb = load_run(a).params, load_run(b).params
    for x, y in zip(jax.tree_util.tree_leaves(pa), jax.tree_util.tree_leaves(pb), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-13)
    ma, mb = _metrics(a), _metrics(b)
    assert [m["epoch"] for m in ma] == [m["epoch"] for m in mb]
    for ra, rb in zip(ma, mb, strict=True):
        for k in ("train_loss", "train_mse", "train_phys", "val_mse", "val_phys"):
            assert ra[k] == pytest.approx(rb[k], rel=1e-12, abs=1e-14), k
        assert ra["best_epoch"] == rb["best_epoch"]


def test_population_trials_equal_their_solo_runs(model, data, tmp_path):
    """Seeds, learning rates, scalers, patience (one trial stops early: masked, the others go on) in one program;
    another width (another program: split off, not refused); each as trained alone."""
    cfgs = [
        BASE,
        dataclasses.replace(BASE, seed=3, lr=3e-2),
        dataclasses.replace(BASE, scaler="minmax", seed=5),
        dataclasses.replace(BASE, patience=1, lr=0.5),  # stops early
        dataclasses.replace(BASE, model=ModelSpec("mlp", depth=1, width=8)),
    ]
    assert [len(g) for g in populations(cfgs)] == [4, 1]
    got = train_population(data, [Trial(c, tmp_path / f"pop{i}") for i, c in enumerate(cfgs)], model=model)
    assert [r.stopped_early for r in got] == [False, False, False, True, False]
    assert got[3].epochs_run < 3 and all(r.epochs_run == 3 for i, r in enumerate(got) if i != 3)
    for i, cfg in enumerate(cfgs):
        alone = train(data, cfg, tmp_path / f"solo{i}", model=model)
        assert (alone.epochs_run, alone.best_epoch, alone.stopped_early) == (
            got[i].epochs_run,
            got[i].best_epoch,
            got[i].stopped_early,
        )
        assert alone.best_val_mse == pytest.approx(got[i].best_val_mse, rel=1e-12)
        _assert_same_run(tmp_path / f"pop{i}", tmp_path / f"solo{i}")


def test_population_resumes_each_trial_where_it_stopped(model, data, tmp_path):
    """An interrupted population (its trials at different epochs) resumed together ends as the runs trained
    alone, uninterrupted; a failing trial (a folder holding another run) fails alone."""
    cfgs = [dataclasses.replace(BASE, seed=s, loss="physics") for s in (1, 2)]

    def stop_at(epoch):
        def progress(e, _n, _m):
            if e == epoch:
                raise KeyboardInterrupt

        return progress

    trials = [Trial(cfgs[0], tmp_path / "a"), Trial(cfgs[1], tmp_path / "b", progress=stop_at(2))]
    with pytest.raises(KeyboardInterrupt):
        train_population(data, trials, model=model)
    assert [m["epoch"] for m in _metrics(tmp_path / "a")] == [1, 2]
    assert [m["epoch"] for m in _metrics(tmp_path / "b")] == [1, 2]
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "config.json").write_text("{}")  # not a run of these settings
    again = [Trial(c, tmp_path / n, resume=True) for c, n in zip(cfgs, "ab", strict=True)]
    got = train_population(data, [*again, Trial(BASE, tmp_path / "c")], model=model)
    assert [r.epochs_run for r in got[:2]] == [3, 3] and isinstance(got[2], Exception)
    for cfg, name in zip(cfgs, "ab", strict=True):
        train(data, cfg, tmp_path / f"solo-{name}", model=model)
        _assert_same_run(tmp_path / name, tmp_path / f"solo-{name}")


def test_out_of_memory_trains_smaller_populations(model, data, tmp_path, monkeypatch, caplog):
    """The device's RESOURCE_EXHAUSTED on a population of 4: two populations of 2, one line saying so."""
    import ineid.learn.population as population

    build = population.build_epoch

    def small_device(spec, physics):
        epoch = build(spec, physics)

        def run(state, *args):
            if args[-2].shape[0] > 2:  # the trials' batches (P, S, B)
                raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 1.00GiB.")
            return epoch(state, *args)

        return run

    monkeypatch.setattr(population, "build_epoch", small_device)
    cfgs = [dataclasses.replace(BASE, seed=s, epochs=2) for s in range(4)]
    with caplog.at_level(logging.WARNING, logger="ineid"):
        got = train_population(data, [Trial(c, tmp_path / f"t{i}") for i, c in enumerate(cfgs)], model=model)
    assert [r.epochs_run for r in got] == [2, 2, 2, 2]
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert lines == [
        "a population of 4 trials does not fit in the device's memory; training it as populations of 2 and 2"
    ]
    monkeypatch.setattr(population, "build_epoch", build)
    train(data, cfgs[3], tmp_path / "solo", model=model)
    _assert_same_run(tmp_path / "t3", tmp_path / "solo")


def test_float32_trains_and_says_when_it_cannot_resolve_the_residual(model, data, tmp_path, caplog, run):
    from ineid.learn.shared import float32_resolution

    cfg = dataclasses.replace(BASE, loss="physics", dtype="float32", epochs=2)
    with caplog.at_level(logging.WARNING, logger="ineid"):
        r32 = train(data, cfg, tmp_path / "f32", model=model)
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1 and lines[0].startswith("float32 cannot resolve this dataset's wrench residual")
    r64 = train(data, dataclasses.replace(cfg, dtype="float64"), tmp_path / "f64", model=model)
    assert r32.best_val_mse == pytest.approx(r64.best_val_mse, rel=1e-3)
    loaded = load_run(tmp_path / "f32")
    assert loaded.config.dtype == "float32"
    assert all(p.dtype == np.float32 for p in jax.tree_util.tree_leaves(loaded.params))
    # noisy data: a residual float32 resolves (no line)
    noisy = DatasetSpec(
        Combination("random", n_configs=20), n_frames=8, seed=SEED, noise=NoiseModel.create(4, force=0.3, moment=0.03)
    )
    path = tmp_path / "noisy.h5"
    write_dataset(model, noisy, path)
    residual, rounding = float32_resolution(generate_dataset(model, noisy), model, np.arange(14), np.ones(6))
    assert residual > 1e3 * rounding
    # the command: the one line on stderr, and the run trains
    out = run("train", path, "--out", tmp_path / "cli", "--epochs", 1, "--batch", 32, "--dtype", "float32")
    assert out.exit_code == 0, out.output
    out = run("train", path, "--out", tmp_path / "bad", "--epochs", 1, "--dtype", "float16")
    assert out.exit_code == 2 and "float16" in out.output
    with pytest.raises(ValueError, match="the wls network solves least squares inside"):
        TrainConfig(model=ModelSpec("wls", frames=4), dtype="float32")


def test_study_and_sweep_group_their_trials():
    """How many programs a plan trains: trials that differ in seed and scaler share one; the network, activation,
    optimizer, frames set it apart."""
    from ineid.learn.sweep import Grid
    from ineid.studies.paper_networks import SIZES, base_config, plan

    def grouped(name, size):
        cfgs = [c for p in plan(name) for s in size.seeds for c in p.grid.configs(base_config(size, p, s))]
        return len(cfgs), [len(g) for g in populations(cfgs)]

    n, sizes = grouped("full", SIZES["paper"])
    assert n == 576 and len(sizes) == 96 and set(sizes) == {6}  # 16 networks x 3 activations x 2 optimizers
    n, sizes = grouped("quick", SIZES["quick"])
    assert n == 8 and sizes == [2, 2, 2, 2]
    grid = Grid(archs=("simple", "net1"), scalers=("robust", "standard", "minmax"), losses=("mse", "physics"))
    cfgs = grid.configs(BASE)
    assert len(cfgs) == 12 and [len(g) for g in populations(cfgs)] == [3, 3, 3, 3]
    assert [len(g) for g in populations(cfgs, max_size=2)] == [2, 1] * 4


@pytest.mark.parametrize(
    ("arch", "frames", "batch", "cpu"), [("simple", 1, 256, 64), ("net6", 1, 1024, 1), ("net1", 10, 256, 1)]
)
def test_a_large_step_trains_one_trial_a_program_on_the_cpu(arch, frames, batch, cpu):
    """On the CPU the trials' stacked products cost more than one at a time: only small steps share a program."""
    from types import SimpleNamespace

    from ineid.learn.population import MAX_POPULATION, population_limit

    cfg = TrainConfig(model=ModelSpec(arch, frames=frames, siamese=frames > 1), batch=batch)
    params = cfg.model.build(20).init(jax.random.key(0), np.zeros((1, frames, 18)))
    run = SimpleNamespace(state={"params": params}, batch=batch, trial=SimpleNamespace(cfg=cfg))
    assert population_limit(run, "cpu") == cpu
    assert population_limit(run, "gpu") == MAX_POPULATION
