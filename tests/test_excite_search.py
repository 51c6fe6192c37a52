"""The excitation search: CasADi rows and pull-back, random feasible candidates, never worse than the best of them,
the starts' records, and the progress lines on a stderr that is not a terminal."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import ineid
from ineid.excite import ExcitationSettings, design_excitation
from ineid.excite.criterion import design_base, design_noise, design_rows
from ineid.excite.trajectory import DesignProblem, design_bounds

FAST = {"duration": 5.0, "harmonics": 3, "starts": 2, "candidates": 8, "seed": 5, "max_iter": 30}


@pytest.fixture(scope="module")
def arm():
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="module")
def design(arm):
    return design_excitation(arm, ExcitationSettings(**FAST, floor=0.0))


def _states(arm, n=40, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1.5, 1.5, (n, arm.n_dof)) for _ in range(3)]


def test_design_rows_are_the_regressor_columns(arm):
    """The CasADi rows the criterion uses equal the generated JAX regressor (checked against Pinocchio elsewhere)."""
    base = design_base(arm)
    q, qd, qdd = _states(arm)
    rows = design_rows(arm, base).rows(q, qd, qdd)
    np.testing.assert_allclose(rows, arm.regressor(q, qd, qdd)[..., base.columns - 6], rtol=0, atol=1e-12)


def test_pullback_is_the_exact_vector_jacobian_product(arm):
    base = design_base(arm)
    rows = design_rows(arm, base)
    q, qd, qdd = _states(arm, 5, 1)
    g = np.random.default_rng(2).standard_normal((5, 6, base.rank))
    pulled = rows.pullback(q, qd, qdd, g)  # (5, 3 n)
    h = 1e-6
    for d in range(3 * arm.n_dof):
        x = [q.copy(), qd.copy(), qdd.copy()]
        up, down = [a.copy() for a in x], [a.copy() for a in x]
        k, j = divmod(d, arm.n_dof)
        up[k][:, j] += h
        down[k][:, j] -= h
        fd = np.sum(g * (rows.rows(*up) - rows.rows(*down)), axis=(1, 2)) / (2 * h)
        np.testing.assert_allclose(pulled[:, d], fd, rtol=1e-6, atol=1e-8)


def test_batched_values_equal_one_at_a_time(arm):
    base = design_base(arm)
    prob = DesignProblem(arm, base, design_noise(), "d-opt", design_bounds(arm), 0.2, 3, 96, 48)
    rng = np.random.default_rng(3)
    xs = np.array([prob.random_start(rng) for _ in range(4)])
    np.testing.assert_allclose(prob.values(xs), [prob.value(x) for x in xs], rtol=1e-12)


def test_random_starts_keep_the_joint_bounds_about_a_given_pose(arm):
    prob = DesignProblem(arm, design_base(arm), design_noise(), "d-opt", design_bounds(arm), 0.2, 3, 96, 48)
    rng = np.random.default_rng(4)
    pose = prob.q_lo + 0.2 * (prob.q_hi - prob.q_lo)
    x = prob.random_start(rng, pose)
    traj = prob.trajectory(x, 5.0, arm.joint_names)
    np.testing.assert_allclose(traj.q0, pose, atol=1e-12)  # the mean pose is the one given
    _, q, qd, qdd = traj.sample(2000.0)
    b = design_bounds(arm)
    assert b.violation(q, qd, qdd) == 0.0


def test_design_beats_the_best_random_candidate(design):
    """The answer is never worse than the best of the random feasible candidates it was compared with."""
    assert design.n_candidates == FAST["candidates"]
    assert design.answer == "optimized"
    assert design.optimized.d_opt < design.best_random.d_opt <= design.random.d_opt
    assert np.median(design.best_random.std / design.optimized.std) > 1.0
    record = design.to_dict()
    assert record["answer"] == "optimized" and record["n_candidates"] == FAST["candidates"]
    assert record["best_random"]["d_opt"] == design.best_random.d_opt
    assert record["feasibility"]["feasible"] >= 1 and len(record["starts"]) == FAST["starts"]
    for start in design.starts:
        assert start.final_value <= start.start_value  # a start keeps its best feasible point
        assert isinstance(start.converged, bool) and isinstance(start.settled, bool)
    assert design.safety["samples"]["min_clearance"] >= 0 and design.safety["dense"]["min_clearance"] >= 0


def test_a_design_that_does_not_beat_the_best_candidate_is_not_returned(arm):
    """With no iteration, no start can beat the best candidate (it is the first start): that candidate is the answer."""
    res = design_excitation(arm, ExcitationSettings(**{**FAST, "max_iter": 0}))
    assert res.answer == "best random"
    np.testing.assert_array_equal(res.trajectory.a, res.best_random_trajectory.a)
    assert res.optimized.d_opt == res.best_random.d_opt


def _run(*args):
    from ineid.cli import main

    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_cli_says_the_comparison_the_starts_and_progress_on_a_non_terminal(tmp_path, monkeypatch):
    import ineid.cli.output as output

    monkeypatch.setattr(output, "STATUS_SECONDS", 0.0)  # every status line (the runner's stderr is no terminal)
    out = tmp_path / "t.csv"
    args = ["excite", "sweaty-arm", "--duration", 5, "--harmonics", 3, "--starts", 2, "--candidates", 8]
    r = _run(*args, "--floor", 0, "--workers", 1, "--out", out)
    assert r.exit_code == 0, r.output
    assert "ineid: checking the bounds on a sample of the joint space" in r.stderr
    assert "ineid: start 1 of 2:" in r.stderr and "ineid: start 2 of 2:" in r.stderr and "evaluations" in r.stderr
    assert "worker process" not in r.stderr
    assert "the design beats the best of 8 random feasible trajectories" in r.stdout
    assert "starts: 2 IPOPT runs from the best candidates:" in r.stdout
    assert "feasibility, checked before the design:" in r.stdout and "sampled poses keep" in r.stdout
    quiet = _run("-q", *args, "--max-iter", 0, "--out", tmp_path / "q.csv")
    assert quiet.exit_code == 0 and "ineid: start" not in quiet.stderr
    assert "no start beat the best of 8 random feasible trajectories" in quiet.stdout  # 0 iterations: the candidate


def test_starts_in_worker_processes_give_the_same_design(arm, design):
    """Two processes (a worker solving the first start, :mod:`ineid.excite.lanes`) give the design of one, start for
    start and bit for bit; the status says what runs where."""
    lines = []
    res = design_excitation(arm, ExcitationSettings(**FAST, floor=0.0), status=lines.append, workers=2)
    one = design_excitation(arm, ExcitationSettings(**FAST, floor=0.0), workers=1)
    assert [vars(r) | {"seconds": 0} for r in res.starts] == [vars(r) | {"seconds": 0} for r in one.starts]
    assert res.value == one.value and res.answer == one.answer
    np.testing.assert_array_equal(res.trajectory.a, one.trajectory.a)
    np.testing.assert_array_equal(res.trajectory.b, one.trajectory.b)
    assert any(line.startswith("start 2 of 2 (1 more in a worker process)") for line in lines)
    assert not any(line.startswith("start 1 of 2") for line in lines)  # the worker's start prints nothing


def test_a_worker_that_fails_is_named_and_stopped():
    """A worker process whose problem cannot be built answers its start with the error; the caller raises it in
    one line and no worker is left running."""
    from ineid.errors import ExcitationError
    from ineid.excite.lanes import Lanes

    with pytest.raises(ExcitationError, match=r"worker process failed on start 1: .*Error.*--workers 1"):
        with Lanes(_broken_problem, ("not a model",), 1) as lanes:
            procs = [lane[0] for lane in lanes._lanes]
            lanes.submit(0, np.zeros(3), np.ones(6))
            lanes.collect(timeout=60.0)
    assert all(p.poll() is not None for p in procs)


def test_workers_must_be_positive(arm):
    from ineid.errors import ExcitationError

    with pytest.raises(ExcitationError, match="workers must be at least 1"):
        design_excitation(arm, ExcitationSettings(**FAST), workers=0)


def _broken_problem(model):
    """A worker's problem that cannot be built (module level: sent to the worker by name)."""
    return model.nothing


def test_a_problem_that_cannot_be_sent_runs_in_this_process(arm, design, caplog):
    """A model whose generated code ineid did not load itself does not pickle: the starts run here, with the same
    answer, and an INFO line says why."""
    import copy
    import logging
    import types

    odd = copy.copy(arm)
    odd._generated = (types.ModuleType("hand_made_jax"), types.ModuleType("hand_made_casadi"))
    with caplog.at_level(logging.INFO, logger="ineid.excite.design"):
        res = design_excitation(odd, ExcitationSettings(**FAST, floor=0.0), workers=2)
    assert res.value == design.value
    assert "every start in this process: the problem cannot be sent to a worker process" in caplog.text
    assert "is not generated code ineid loaded" in caplog.text


def test_a_worker_that_dies_is_named_with_its_last_words():
    """A worker process that dies (here: its problem's builder exits the interpreter) ends the design with one line
    saying so and what to do, not a hang or a traceback."""
    from ineid.errors import ExcitationError
    from ineid.excite.lanes import Lanes

    with pytest.raises(ExcitationError, match=r"worker process exited \(status 3: dying on purpose\).*--workers 1"):
        with Lanes(_dying_problem, (), 1) as lanes:
            lanes._lanes[0][0].wait(60)  # dead before it is given a start: the start goes nowhere, and that is said
            lanes.submit(0, np.zeros(3), np.ones(6))
            lanes.collect(timeout=60.0)


def _dying_problem():
    """A worker's problem builder that writes a last line and exits (module level: sent by name)."""
    import os
    import sys

    sys.stderr.write("dying on purpose\n")
    sys.stderr.flush()
    os._exit(3)
