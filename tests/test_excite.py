"""Excitation design: bounds at every instant, rest at both ends, exact derivatives, exact gradients."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import ineid
from ineid.data.synthesis.trajectory import (
    FourierTrajectory,
    load_trajectory,
    read_trajectory_csv,
    read_trajectory_json,
)
from ineid.errors import ExcitationError
from ineid.excite.design import design_base, design_bounds, design_excitation, design_noise, evaluate_design
from ineid.excite.settings import ExcitationSettings
from ineid.excite.trajectory import DesignProblem

from .conftest import SEED

DURATION = 10.0


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="module")
def design(arm):
    return design_excitation(arm, ExcitationSettings(DURATION, starts=2, seed=SEED % 1000))


def test_design_keeps_every_bound_on_a_dense_grid(arm, design):
    traj = design.trajectory
    t = np.linspace(0.0, traj.duration, 200_001)  # 2,500 points per constraint-grid interval (16 H = 80)
    q, qd, qdd = traj.evaluate(t)
    assert design.bounds.violation(q, qd, qdd) == 0.0
    assert np.all(q >= arm.q_lower) and np.all(q <= arm.q_upper)
    assert np.all(np.abs(qd) <= arm.qd_max) and np.all(np.abs(qdd) <= arm.qdd_max)
    # the design uses its room: some bound is nearly active (else the criterion could still improve)
    span = design.bounds.q_upper - design.bounds.q_lower
    slack = min(
        np.min((design.bounds.q_upper - q) / span),
        np.min((q - design.bounds.q_lower) / span),
        np.min(1 - np.abs(qd) / design.bounds.qd_max),
        np.min(1 - np.abs(qdd) / design.bounds.qdd_max),
    )
    assert slack < 0.05


def test_design_starts_and_ends_at_rest(design):
    traj = design.trajectory
    _, qd, qdd = traj.evaluate(np.array([0.0, traj.duration]))
    assert np.max(np.abs(qd)) < 1e-12 * np.max(np.abs(traj.amplitude_bounds()[1]))
    assert np.max(np.abs(qdd)) < 1e-12 * np.max(np.abs(traj.amplitude_bounds()[2]))
    q_ends = traj.evaluate(np.array([0.0, traj.duration]))[0]
    np.testing.assert_allclose(q_ends[0], q_ends[1], atol=1e-12)


def test_optimized_beats_random_starts(design):
    for start in design.starts:
        assert start.final_value < start.start_value - 1.0  # d-opt: -log det, at least e times more information
    assert design.value <= min(s.final_value for s in design.starts)
    assert design.optimized.d_opt < design.random.d_opt
    assert design.optimized.condition_number < design.random.condition_number
    assert np.median(design.optimized.rel_std) < np.median(design.random.rel_std)


def test_expected_std_is_the_spread_of_least_squares_estimates(arm, design):
    """The reported std is the Cramer-Rao bound: Monte-Carlo least squares on the design's frames matches it."""
    _, q, qd, qdd = design.trajectory.sample(design.rate)
    base = design.base
    psi = arm.regressor(q, qd, qdd)  # pinocchio-checked elsewhere; independent of the design's CasADi rows
    wb = psi[..., base.columns - 6].reshape(-1, base.rank)  # no bias columns in this design
    rng = np.random.default_rng(SEED)
    sigma = np.tile(design.sigma, len(q))
    beta = np.linalg.lstsq(
        wb / sigma[:, None], (rng.standard_normal((len(sigma), 400)) * sigma[:, None]) / sigma[:, None], rcond=None
    )[0]
    np.testing.assert_allclose(beta.std(axis=1), design.optimized.std, rtol=0.2)


@pytest.mark.parametrize(("criterion", "bias"), [("d-opt", False), ("cond", False), ("d-opt", True)])
def test_gradient_matches_finite_differences(arm, criterion, bias):
    base = design_base(arm, bias=bias)
    problem = DesignProblem(arm, base, design_noise(), criterion, design_bounds(arm), 1 / DURATION, 4, 160, 128)
    x = problem.random_start(np.random.default_rng(SEED))
    f, g = problem.gradient(x)
    assert np.isfinite(f)
    h = 1e-5  # central differences: truncation ~h^2, rounding ~1e-16 |f| / h
    fd = np.array([(problem.value(x + h * e) - problem.value(x - h * e)) / (2 * h) for e in np.eye(len(x))])
    np.testing.assert_allclose(g, fd, atol=1e-5 * np.max(np.abs(fd)))


def test_bias_design_is_for_the_offset_aware_base_parameters(arm):
    from ineid.identify import base_parameters

    plain, with_bias = design_base(arm), design_base(arm, bias=True)
    assert with_bias.names == base_parameters(arm, bias=True).names  # what ineid solve --bias estimate fits
    assert with_bias.rank <= plain.rank
    # centring the samples profiles the offsets out: the std equals that of [1 | Psi_b] least squares
    rng = np.random.default_rng(SEED)
    q, qd, qdd = (rng.uniform(-1, 1, (300, arm.n_dof)) for _ in range(3))
    ev = evaluate_design(arm, q, qd, qdd, with_bias, design_noise())
    from ineid.excite.design import scaled_regressor

    phi = scaled_regressor(arm.regressor(q, qd, qdd), with_bias, design_noise())
    ones = np.tile(np.eye(6) / design_noise()[:, None], (len(q), 1))
    a = np.concatenate([ones, phi.reshape(-1, with_bias.rank)], axis=1)
    rel = np.sqrt(np.diag(np.linalg.inv(a.T @ a)))[6:]
    np.testing.assert_allclose(ev.rel_std, rel, rtol=1e-8)


def test_trajectory_json_and_csv_agree(tmp_path, design):
    from ineid.data.synthesis.trajectory import write_trajectory_csv, write_trajectory_json

    t, q, qd, qdd = design.trajectory.sample(100.0)
    write_trajectory_csv(tmp_path / "t.csv", t, q, qd, qdd, ["joints: a, b, c, d"])
    write_trajectory_json(tmp_path / "t.json", design.trajectory, {"design": design.to_dict()})
    from_csv = load_trajectory(tmp_path / "t.csv")
    from_json = load_trajectory(tmp_path / "t.json")
    assert from_csv.joint_names == ("a", "b", "c", "d")
    for k in ("time", "q", "qd", "qdd"):
        np.testing.assert_array_equal(getattr(from_csv, k), getattr(from_json, k))
    traj, record = read_trajectory_json(tmp_path / "t.json")
    assert isinstance(traj, FourierTrajectory) and record["design"]["criterion"] == "d-opt"
    np.testing.assert_array_equal(traj.a, design.trajectory.a)
    # ineid excite names the joints as a JSON list: names with commas or newlines read back
    import json

    names = ["a,b", "c\n1,2,3", "[d]", "e"]
    write_trajectory_csv(tmp_path / "n.csv", t, q, qd, qdd, ["robot x\ny", f"joints: {json.dumps(names)}"])
    assert load_trajectory(tmp_path / "n.csv").joint_names == tuple(names)
    np.testing.assert_array_equal(load_trajectory(tmp_path / "n.csv").q, from_csv.q)  # the comments stayed comments


def test_failures_are_clear(arm):
    with pytest.raises(ExcitationError, match="too short for 5 harmonics") as e:
        design_excitation(arm, ExcitationSettings(0.08))
    assert e.value.reason == "duration"
    with pytest.raises(ExcitationError, match="not a whole number of periods"):
        design_excitation(arm, ExcitationSettings(10.0, base_frequency=0.25))
    with pytest.raises(ExcitationError, match="--harmonics 2 or more"):
        design_excitation(arm, ExcitationSettings(10.0, harmonics=1))
    with pytest.raises(ExcitationError, match="margin") as e:
        design_excitation(arm, ExcitationSettings(10.0, margin=0.5))
    assert e.value.reason == "infeasible_bounds"


def test_barely_moving_design_is_rank_deficient(arm):
    """A trajectory that cannot move (bounds 1e-9 of the model's) leaves base parameters undetermined."""
    with pytest.raises(ExcitationError, match="undetermined|determines only") as e:
        design_excitation(
            arm, ExcitationSettings(DURATION, starts=1, velocity_scale=1e-9, acceleration_scale=1e-9, max_iter=5)
        )
    assert e.value.reason == "rank_deficient"


def test_evaluate_design_counts_rank(arm):
    base = design_base(arm)
    q = np.tile(np.asarray(arm.q_lower, float), (50, 1))  # one pose, at rest: only gravity excites
    ev = evaluate_design(arm, q, 0 * q, 0 * q, base, design_noise())
    assert ev.rank < base.rank and not np.isfinite(ev.condition_number)


# -- the CLI -----------------------------------------------------------------------------------


def _run(*args):
    from ineid.cli import main

    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_cli_excite_writes_csv_json_and_summary(tmp_path):
    out = tmp_path / "traj.csv"
    r = _run(
        "-q", "excite", "sweaty-arm", "--duration", 5, "--harmonics", 3, "--starts", 1, "--rate", 200, "--out", out
    )
    assert r.exit_code == 0, r.output
    for text in ("scaled condition number", "random Fourier", "median expected relative std", "white Gaussian wrench"):
        assert text in r.output
    assert "gravity (0, 0, -9.81) m/s^2 (ineid's default; --gravity standard for 9.80665)" in r.output
    sampled = read_trajectory_csv(out)
    assert sampled.n_frames == 1001 and sampled.n_dof == 4
    # qd and qdd in the CSV are the derivatives of q (central differences, O(dt^2))
    dt = 1 / 200
    fd_qd = (sampled.q[2:] - sampled.q[:-2]) / (2 * dt)
    fd_qdd = (sampled.qd[2:] - sampled.qd[:-2]) / (2 * dt)
    assert np.max(np.abs(fd_qd - sampled.qd[1:-1])) < 1e-3 * np.max(np.abs(sampled.qd))
    assert np.max(np.abs(fd_qdd - sampled.qdd[1:-1])) < 1e-3 * np.max(np.abs(sampled.qdd))
    record = json.loads(out.with_suffix(".json").read_text())
    assert record["format"] == "ineid-fourier-trajectory" and len(record["a"]) == 4 and len(record["a"][0]) == 3
    assert record["design"]["optimized"]["condition_number"] < record["design"]["random_fourier"]["condition_number"]
    # never replaced without --overwrite, one line
    r = _run("excite", "sweaty-arm", "--duration", 5, "--out", out)
    assert r.exit_code == 1 and "exists; pass --overwrite" in r.output and "Traceback" not in r.output

    r = _run(
        "-q",
        "excite",
        "sweaty-arm",
        "--duration",
        5,
        "--harmonics",
        3,
        "--starts",
        1,
        "--bias",
        "estimate",
        "--out",
        tmp_path / "b.csv",
    )
    assert r.exit_code == 0 and "sensor offsets estimated" in r.output, r.output
    assert json.loads((tmp_path / "b.json").read_text())["design"]["bias"] is True

    # the designed trajectory drives a simulated dataset
    h5 = tmp_path / "d.h5"
    r = _run(
        "-q",
        "data",
        "generate",
        "--n-configs",
        3,
        "--frame-mode",
        "trajectory",
        "--trajectory",
        out,
        "--noise",
        "force=0.5,moment=0.05",
        "--out",
        h5,
    )
    assert r.exit_code == 0, r.output
    ds = ineid.data.load_dataset(h5)
    assert ds.q.shape == (3, 1001, 4)
    for c in range(3):
        np.testing.assert_array_equal(ds.q[c], sampled.q)
        np.testing.assert_array_equal(ds.time[c], sampled.time)
    assert ds.meta.sampling["frames"]["trajectory"]["source"] == "traj.csv"
    r = _run(
        "data",
        "generate",
        "--n-configs",
        3,
        "--n-frames",
        50,
        "--frame-mode",
        "trajectory",
        "--trajectory",
        out,
        "--out",
        tmp_path / "e.h5",
    )
    assert r.exit_code == 2 and "rows of a trajectory CSV are the frames" in r.output


def test_cli_help_lists_the_choices():
    for args in (("excite", "--help"), ("data", "generate", "--help")):
        r = _run(*args)
        assert r.exit_code == 0, r.output
    assert "d-opt|cond" in _run("excite", "--help").output
    assert "uniform|fourier|trajectory" in _run("data", "generate", "--help").output
    words = " ".join(_run("excite", "--help").output.split())
    assert "Default: the base wrench (excite reads no file)" in words and "the file has" not in words


def test_cli_excite_one_line_errors(tmp_path):
    r = _run("excite", "sweaty-arm", "--duration", 0.08, "--out", tmp_path / "t.csv")
    assert r.exit_code == 1 and "too short" in r.output.strip().splitlines()[-1] and "Traceback" not in r.output
    assert not (tmp_path / "t.csv").exists() and not (tmp_path / "t.json").exists()
    r = _run("data", "generate", "--frame-mode", "trajectory", "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "--trajectory" in r.output


def test_each_collision_pair_of_bodies_is_named_once(capsys):
    from types import SimpleNamespace

    from ineid.cli.excite_summary import print_limits

    model = ineid.load_robot("sweaty-arm")
    pairs = ["'hand' and 'base'"] * 4 + ["'forearm' and 'base'"]
    capsules = [{"body": b, "shape": "capsule", "radius": 0.05} for b in ("hand", "forearm", "base")]
    res = SimpleNamespace(
        settings={"velocity_scale": 1.0, "acceleration_scale": 1.0},
        bounds=SimpleNamespace(
            q_lower=model.q_lower, q_upper=model.q_upper, qd_max=model.qd_max, qdd_max=model.qdd_max
        ),
        safety={"floor": None, "workspace": None, "self_collision": {"pairs": pairs, "capsules": capsules}},
    )
    print_limits(res, model)
    words = " ".join(capsys.readouterr().out.split())
    assert "'hand' and 'base' (4 capsule pairs); 'forearm' and 'base';" in words
    assert words.count("'hand' and 'base'") == 1
