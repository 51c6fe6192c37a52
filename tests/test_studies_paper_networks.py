"""The paper's network exploration (``ineid study networks``, :mod:`ineid.studies.paper_networks`): the plans
cover the paper's settings, the claim checker's verdicts and its spread rule, and the quick study end to end."""

from __future__ import annotations

import csv

import pytest

from ineid.learn.models import TABLE1
from ineid.learn.scalers import Scaler
from ineid.learn.train import OPTIMIZERS as TRAIN_OPTIMIZERS
from ineid.studies.paper_claims import (
    HELD,
    NOT_HELD,
    UNDECIDABLE,
    check_claims,
    classical_claim,
    compare,
    factor_claim,
    siamese_claim,
)
from ineid.studies.paper_claims import cells as claim_cells
from ineid.studies.paper_networks import (
    ACTIVATIONS,
    OPTIMIZERS,
    PAPER_BEST,
    SCALERS,
    SIZES,
    base_config,
    plan,
    read_rows,
)


def _configs(parts, size):
    return [(p, c) for p in parts for c in p.grid.configs(base_config(size, p, 0))]


# -- the plans --------------------------------------------------------------------------------


def test_full_plan_covers_the_papers_grid_at_its_scale():
    size = SIZES["paper"]
    assert (size.n_train, size.epochs, size.dataset.n_frames) == (3000, 100, 100)  # "three-thousand", "one-hundred"
    assert size.dataset.combination.per_link == 100 and len(size.seeds) >= 2  # 100 x 100 = 10,000 configurations
    cfgs = _configs(plan("full"), size)
    # the paper's named best settings, and every activation, scaler and optimizer of the grid, each one a real choice
    for key, best in PAPER_BEST.items():
        assert best in {"activation": ACTIVATIONS, "scaler": SCALERS, "optimizer": OPTIMIZERS}[key]
    assert set(ACTIVATIONS) >= {"tanh", "relu", "sigmoid"} and set(SCALERS) >= {"robust", "standard", "minmax"}
    assert set(OPTIMIZERS) >= {"sgd", "adam"} and set(OPTIMIZERS) <= set(TRAIN_OPTIMIZERS)
    single = {(c.model.arch, c.model.activation, c.scaler, c.optimizer) for p, c in cfgs if not c.model.siamese}
    siamese = {(c.model.arch, c.model.activation, c.scaler, c.optimizer) for p, c in cfgs if c.model.siamese}
    every = {(a, s, o) for a in ACTIVATIONS for s in SCALERS for o in OPTIMIZERS}
    for arch in ("simple", *TABLE1, "funnel"):
        assert {x[1:] for x in single if x[0] == arch} == every, arch
    for arch in TABLE1:  # Table 1's networks as Siamese networks, Network 6 (8 layers, width factor 8) among them
        assert {x[1:] for x in siamese if x[0] == arch} == every, arch
    assert TABLE1["net6"] == (8, 8)
    for _, c in cfgs:  # the paper's size, at least 100 epochs, never stopped early
        assert (c.n_train, c.epochs, c.patience) == (3000, 100, 0)
        assert c.model.frames == (10 if c.model.siamese else 1)


def test_decisive_plan_varies_one_factor_around_the_papers_best():
    size = SIZES["paper"]
    cfgs = [c for p, c in _configs(plan("decisive"), size) if not p.siamese_size]
    best = (PAPER_BEST["activation"], PAPER_BEST["scaler"], PAPER_BEST["optimizer"])
    got = {(c.model.activation, c.scaler, c.optimizer) for c in cfgs}
    want = (
        {best}
        | {(a, best[1], best[2]) for a in ACTIVATIONS}
        | {(best[0], s, best[2]) for s in SCALERS}
        | {(best[0], best[1], o) for o in OPTIMIZERS}
    )
    assert got == want and len(cfgs) == len(want)  # the centre once, no cell twice
    assert all((c.n_train, c.epochs, c.model.arch) == (3000, 100, "net1") for c in cfgs)
    claim = [c for p, c in _configs(plan("decisive"), size) if p.siamese_size]
    nets = {(c.model.arch, c.model.siamese) for c in claim}
    assert nets == {("net1", False), ("net6", False), ("net1", True), ("net6", True)}
    assert all(c.epochs == size.siamese_epochs for c in claim)


def test_grid_scalers_are_the_libraries():
    for kind in SCALERS:  # each the grid names is a scaler ineid fits
        assert Scaler.fit(kind, [[0.0, 1.0], [2.0, 5.0], [4.0, 9.0]]).kind == kind


# -- the claim checker ------------------------------------------------------------------------


def _row(
    value,
    seed,
    arch="net1",
    activation="tanh",
    scaler="robust",
    optimizer="sgd",
    siamese=False,
    linear=0.05,
    status="ok",
):
    return dict(
        arch=arch,
        frames=10 if siamese else 1,
        siamese=siamese,
        activation=activation,
        scaler=scaler,
        optimizer=optimizer,
        loss="mse",
        epochs=100,
        n_train=3000,
        seed=seed,
        status=status,
        name=f"{arch}-{activation}-{scaler}-{optimizer}-{seed}",
        test_standard_median=value,
        test_base_median=value,
        linear_standard_median=linear,
        linear_base_median=linear,
    )


def _activation_verdict(rows):
    return factor_claim(claim_cells(rows), "activation", "tanh", "tanh best")


def test_compare_counts_a_difference_only_beyond_the_seed_spread():
    assert compare([0.30, 0.31], [0.35, 0.36]) == "better"
    assert compare([0.35, 0.36], [0.30, 0.31]) == "worse"
    assert compare([0.30, 0.34], [0.33, 0.35]) == "within spread"  # 0.02 apart, spread 0.04
    assert compare([0.30], [0.40, 0.41]) == "too few seeds"


def test_factor_claim_held_not_held_and_not_decidable():
    held = [
        _row(0.30, 0),
        _row(0.31, 1),
        _row(0.36, 0, activation="relu"),
        _row(0.37, 1, activation="relu"),
        _row(0.40, 0, activation="sigmoid"),
        _row(0.41, 1, activation="sigmoid"),
    ]
    v = _activation_verdict(held)
    assert v.verdict == HELD and "relu" in v.why and "sigmoid" in v.why
    beaten = [*held[:2], _row(0.25, 0, activation="relu"), _row(0.26, 1, activation="relu")]
    assert _activation_verdict(beaten).verdict == NOT_HELD
    within = [_row(0.30, 0), _row(0.36, 1), _row(0.32, 0, activation="relu"), _row(0.35, 1, activation="relu")]
    v = _activation_verdict(within)
    assert v.verdict == UNDECIDABLE and "within spread" in v.why
    one_seed = [_row(0.30, 0), _row(0.40, 0, activation="relu")]  # ten times the gap, but one seed
    v = _activation_verdict(one_seed)
    assert v.verdict == UNDECIDABLE and "too few seeds" in v.why
    # one alternative decidably worse, another within spread: not decidable
    mixed = [*held[:4], _row(0.30, 0, activation="sigmoid"), _row(0.315, 1, activation="sigmoid")]
    assert _activation_verdict(mixed).verdict == UNDECIDABLE
    # failed trials do not count as seeds
    failed = [*held[:2], _row(0.36, 0, activation="relu"), _row(float("nan"), 1, activation="relu", status="failed: x")]
    assert _activation_verdict(failed).verdict == UNDECIDABLE
    assert _activation_verdict([_row(0.3, 0), _row(0.3, 1)]).verdict == UNDECIDABLE  # nothing to compare with


def test_factor_claim_over_contexts():
    """Held in one context and contradicted in another: not held; cells differing in two factors never compared."""
    good = [_row(0.30, 0), _row(0.31, 1), _row(0.36, 0, activation="relu"), _row(0.37, 1, activation="relu")]
    bad = [_row(0.40, s, scaler="minmax") for s in (0, 1)] + [
        _row(0.20 + s / 100, s, activation="relu", scaler="minmax") for s in (0, 1)
    ]
    v = _activation_verdict(good + bad)
    assert v.verdict == NOT_HELD and "1 held, 1 not held" in v.why
    # relu with minmax beats tanh with robust, but they differ in the scaler too: no context, not decidable
    cross = [_row(0.30, 0), _row(0.31, 1), *bad[2:]]
    assert _activation_verdict(cross).verdict == UNDECIDABLE


def test_siamese_claim():
    cell = {
        "net6s": dict(arch="net6", siamese=True),
        "net1s": dict(arch="net1", siamese=True),
        "net6": dict(arch="net6"),
        "net1": dict(arch="net1"),
    }

    def rows(values):
        return [_row(values[k] + s / 1000, s, **cell[k]) for k in values for s in (0, 1)]

    v = siamese_claim(claim_cells(rows({"net6s": 0.30, "net1s": 0.34, "net6": 0.36, "net1": 0.37})))
    assert v.verdict == HELD and "net1 Siamese K10" in v.why
    assert siamese_claim(claim_cells(rows({"net6s": 0.30, "net1s": 0.28, "net6": 0.36}))).verdict == NOT_HELD
    assert siamese_claim(claim_cells(rows({"net6s": 0.30, "net1s": 0.3005}))).verdict == UNDECIDABLE
    assert siamese_claim(claim_cells(rows({"net1s": 0.3, "net6": 0.4}))).verdict == UNDECIDABLE  # no Siamese net6


def test_classical_claim_and_all_claims():
    rows = [_row(0.30, 0, linear=0.05), _row(0.35, 1, linear=0.05)]
    assert classical_claim(rows).verdict == HELD
    assert classical_claim([*rows, _row(0.04, 2, linear=0.05)]).verdict == NOT_HELD
    assert classical_claim([]).verdict == UNDECIDABLE
    verdicts = check_claims(rows)
    assert len(verdicts) == 10 and {v.claim.rsplit("[", 1)[1] for v in verdicts} == {
        "standard parameters]",
        "base parameters]",
    }


# -- the study end to end ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    from click.testing import CliRunner

    from ineid.cli import main

    out = tmp_path_factory.mktemp("networks") / "study"
    r = CliRunner().invoke(main, ["-q", "study", "networks", "--quick", "--out", str(out)], catch_exceptions=False)
    return out, r


def test_quick_study_through_the_cli(quick_study):
    out, r = quick_study
    assert r.exit_code == 0, r.output
    rows = read_rows(out / "networks.csv")
    assert len(rows) == 8 and all(r.status == "ok" for r in rows)
    assert {(r.activation, r.scaler, r.optimizer) for r in rows} == {
        (a, s, o) for a in ACTIVATIONS[:2] for s in SCALERS[:2] for o in OPTIMIZERS
    }
    assert all(r.epochs == 2 and r.epochs_run == 2 and r.n_train == 12 and r.seed == 0 for r in rows)
    assert all(0 < r.test_standard_median < 10 and r.linear_base_median < 1e-6 for r in rows)
    assert all((out / "grid" / "seed-0" / r.name / "evaluation.json").is_file() for r in rows)
    with open(out / "claims.csv", newline="") as fh:
        claims = list(csv.DictReader(fh))
    verdicts = {c["claim"]: c["verdict"] for c in claims}
    assert len(claims) == 10 and set(verdicts.values()) <= {HELD, NOT_HELD, UNDECIDABLE}
    # one seed: no factor claim is decidable; least squares beats 2-epoch networks by far
    factor = [c for c in claims if "most promising results" in c["claim"]]
    assert len(factor) == 6 and all(c["verdict"] == UNDECIDABLE and "too few seeds" in c["why"] for c in factor)
    assert [c["verdict"] for c in claims if "struggled" in c["claim"]] == [HELD, HELD]
    assert "wrote" in r.output and "not decidable" in r.output


def test_quick_study_refuses_then_resumes(quick_study, run):
    out, first = quick_study

    def errors():
        return {
            r.name: (r.test_standard_median, r.test_base_median, r.epochs_run) for r in read_rows(out / "networks.csv")
        }

    before = errors()
    r = run("study", "networks", "--quick", "--out", out)
    assert r.exit_code != 0 and "--resume" in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    again = run("-q", "study", "networks", "--quick", "--out", out, "--resume")  # every trial finished: kept
    assert again.exit_code == 0, again.output
    assert errors() == before  # read back, not trained again
    bad = run("study", "networks", "--quick", "--out", out, "--resume", "--epochs", "3")
    assert bad.exit_code != 0 and "different run settings" in bad.output and "Traceback" not in bad.output


def test_study_usage_errors(run, tmp_path):
    r = run("study", "networks", "--quick", "--address", "auto", "--out", tmp_path / "s")
    assert r.exit_code == 2 and "--address and --cpus-per-trial go with --engine ray" in r.output
    r = run("study", "networks", "--quick", "--resume", "--overwrite", "--out", tmp_path / "s")
    assert r.exit_code == 2 and "not both" in r.output
    assert not (tmp_path / "s").exists()
