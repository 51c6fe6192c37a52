"""The paper's classical solvers (``lsqlin``, ``lsqnonlin``, :mod:`ineid.identify.classical`) and the fewest
frames (:mod:`ineid.identify.frame_minimum`).

On clean data both solvers must fit the frames exactly and land, in the standard parameters, somewhere
along the regressor's null space: their difference from the truth is a null-space vector, checked against
the null space of the raw stacked regressor (CasADi, an independent route, not the base-parameter
analysis). ``lsqlin``'s minimum norm is checked against NumPy's ``lstsq`` on the raw frames, and the
batched ``lsqnonlin`` against ``scipy.optimize.least_squares`` itself.
"""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid import IdentificationError
from ineid.data import Combination, DatasetSpec, generate_dataset, write_dataset
from ineid.identify import SolveSettings, load_results, save_results, solve_dataset
from ineid.identify.classical import cad_bounds, lsqnonlin_theta, theta_from_x, theta_jacobian, x_from_theta
from ineid.identify.identifiability import frame_minimum, generic_frames
from ineid.identify.systems import stack_casadi

FRAMES = 10
"""Frames fitted per configuration: few, so the casadi route (no compilation) is quick."""


@pytest.fixture(scope="module")
def clean(model):
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=8), n_frames=FRAMES, seed=5))


@pytest.fixture(scope="module")
def solved(model, clean):
    """``{method: SolveResults}`` of the clean data, every frame fitted, through CasADi (no kernel compiled)."""
    return {
        m: solve_dataset(clean, SolveSettings(method=m, frames=FRAMES, weights="none", backend="casadi"), model=model)
        for m in ("lsqlin", "lsqnonlin", "linear")
    }


def _stacks(model, ds):
    return [
        stack_casadi(model, ds.q[c], ds.qd[c], ds.qdd[c], ds.wrench[c], ds.theta_known) for c in range(ds.n_configs)
    ]


@pytest.mark.parametrize("method", ["lsqlin", "lsqnonlin"])
def test_exact_fit_and_null_directions_only(model, clean, solved, method):
    res = solved[method]
    assert res.success.all() and list(res.status) == ["ok"] * clean.n_configs
    signal = np.sqrt(np.mean(clean.wrench**2, axis=(1, 2)))
    assert np.max(np.linalg.norm(res.fit_rms, axis=1) / signal) < 1e-11  # the wrench fitted to round-off
    base_err = np.abs(res.base_hat - res.base_true) / np.maximum(np.abs(res.base_true), 1e-3)
    assert base_err.max() < 1e-9  # every base parameter exact
    d = res.theta_hat - res.theta_true
    scale = res.base.scales
    assert np.max(np.abs(d) / scale) > 1e-2  # wrong standard parameters: the paper's observation
    for c, (w, _) in enumerate(_stacks(model, clean)):
        # the difference lies in the null space of the raw regressor of these frames: W d = 0 to round-off
        assert np.linalg.norm(w @ d[c]) <= 1e-10 * np.linalg.norm(w * scale, 2) * np.linalg.norm(d[c] / scale)
        _, sv, vt = np.linalg.svd(w * scale)
        assert sv[16] > 1e-6 * sv[0] and sv[17] < 1e-10 * sv[0]  # rank 17 of 20: three null directions
        null = vt[17:].T
        ds = d[c] / scale
        assert np.linalg.norm(ds - null @ (null.T @ ds)) < 1e-9 * np.linalg.norm(ds)
    # the identifiable standard parameters are the truth, whatever the solver did along the null space
    ident = res.base.identifiable
    assert np.max(np.abs(d[:, ident]) / scale[ident]) < 1e-9


def test_lsqlin_is_the_minimum_norm_least_squares_solution(model, clean, solved):
    """The unbounded lsqlin is ``pinv(W) y`` of the raw stacked frames (NumPy's ``lstsq``, SVD)."""
    theta = solved["lsqlin"].theta_hat
    for c, (w, y) in enumerate(_stacks(model, clean)):
        ref = np.linalg.lstsq(w, y, rcond=1e-10)[0]
        assert np.allclose(theta[c], ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())
    linear = solved["linear"].theta_hat  # the same data, ineid's prior rule: another point of the same set
    assert not np.allclose(theta, linear, rtol=1e-3)


def test_lsqlin_bounds_respected(model, clean):
    prior = model.theta_cad[model.unknown_index]
    for fraction in (0.5, 0.02):
        res = solve_dataset(
            clean,
            SolveSettings(method="lsqlin", frames=FRAMES, weights="none", backend="casadi", bounds=fraction),
            model=model,
        )
        lb, ub = cad_bounds(prior, res.base.scales, fraction)
        assert res.success.all()
        assert np.all(res.theta_hat >= lb - 1e-12) and np.all(res.theta_hat <= ub + 1e-12)
        rel = np.linalg.norm(res.fit_rms, axis=1) / np.sqrt(np.mean(clean.wrench**2, axis=(1, 2)))
        outside = np.any((res.theta_true < lb) | (res.theta_true > ub), axis=1)
        if fraction == 0.02:  # a box the truth leaves: the fit can no longer be exact
            assert outside.any() and np.all(rel[outside] > 1e-6)
    with pytest.raises(ValueError, match="bounds"):
        SolveSettings(method="linear", bounds=0.5)


def test_lsqnonlin_batched_is_scipys_iteration(model, clean, solved):
    """The batched trust region takes scipy's steps: the same estimates and function evaluations."""
    from ineid.identify.identifiability import base_parameters
    from ineid.identify.linear import fit_base

    base = base_parameters(model)
    pairs = _stacks(model, clean)
    fit = fit_base(np.stack([w for w, _ in pairs]), np.stack([y for _, y in pairs]), base, "none")
    start = model.theta_cad[model.unknown_index]
    tb, okb, _, nb = lsqnonlin_theta(fit, base, start)
    ts, oks, _, ns = lsqnonlin_theta(fit, base, start, engine="scipy")
    assert okb.all() and oks.all() and np.mean(nb == ns) >= 0.75
    assert np.max(np.abs(tb - ts) / base.scales) < 1e-9
    assert np.allclose(tb, solved["lsqnonlin"].theta_hat, rtol=1e-8, atol=1e-12)


def test_parameterization_and_its_jacobian(model, rng):
    """``theta(x)`` inverts ``x(theta)`` and its Jacobian matches central differences."""
    theta = model.theta_cad[model.unknown_index]
    x = x_from_theta(theta, 2)
    assert np.allclose(theta_from_x(x, 2), theta, rtol=1e-13, atol=1e-15)
    m, c, i_c = ineid.inertial_from_theta(theta[:10])
    assert (
        np.isclose(x[0], m)
        and np.allclose(x[1:4], c)
        and np.allclose(x[4:10], i_c[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]])
    )
    x = x + 0.01 * rng.standard_normal(x.shape)
    jac = theta_jacobian(x, 2)
    h = 1e-6
    num = np.stack([(theta_from_x(x + h * e, 2) - theta_from_x(x - h * e, 2)) / (2 * h) for e in np.eye(20)], axis=1)
    assert np.allclose(jac, num, rtol=1e-7, atol=1e-9)
    assert np.allclose(theta_jacobian(np.stack([x, x]), 2), jac)


def test_results_files_of_the_paper_methods(run, tmp_path, model, clean, solved):
    res = solved["lsqnonlin"]
    back = load_results(save_results(res, tmp_path / "r.h5"))
    assert back.settings.method == "lsqnonlin" and np.array_equal(back.theta_hat, res.theta_hat)
    data = tmp_path / "d.h5"
    write_dataset(model, DatasetSpec(Combination("random", n_configs=3), n_frames=FRAMES, seed=5), data)
    out = tmp_path / "lsqlin.h5"
    r = run(
        "solve",
        data,
        "--method",
        "lsqlin",
        "--bounds",
        0.5,
        "--fit-frames",
        FRAMES,
        "--backend",
        "casadi",
        "--weights",
        "none",
        "--out",
        out,
    )
    assert r.exit_code == 0 and "3/3 configurations identified" in r.output, r.output
    assert "no (solver)" in r.output and "no (prior)" not in r.output  # the data do not decide them, nor a prior
    r = run("results", "info", out)
    assert r.exit_code == 0 and "lsqlin" in r.output, r.output
    assert load_results(out).settings.bounds == 0.5
    r = run("solve", data, "--method", "linear", "--bounds", 0.5, "--out", tmp_path / "x.h5")
    assert r.exit_code == 2 and "go with method='lsqlin'" in r.output


def test_fewest_frames_found_from_the_structure(model, clean):
    """4 for sweaty-arm with links 3-4 unknown (counting says 3), and each robot / unknown set its own number."""
    fm = frame_minimum(model)
    assert (fm.frames, fm.by_counting, fm.rank) == (4, 3, 17) and fm.ranks[2] == 15
    assert (("fx", "fy", "fz"), 6) in fm.groups and "fx, fy, fz rows span only 6 of the 17" in fm.reason
    # independently of the analysis: the raw regressor of 3 random frames has rank 15, of 4 rank 17
    for seed in (1, 2):
        q, qd, qdd = generic_frames(model, 4, seed=seed)
        w, _ = stack_casadi(model, q, qd, qdd, np.zeros((4, 6)), model.theta_cad[model.known_index])
        scaled = w * fm_scales(model)
        assert [np.linalg.matrix_rank(scaled[: 6 * f], tol=1e-9 * np.linalg.norm(scaled, 2)) for f in (3, 4)] == [
            15,
            17,
        ]
    with pytest.raises(IdentificationError, match="use at least 4 frames .*3 generic frames give rank 15 of 17") as e:
        solve_dataset(clean.select(frames=slice(0, 3)), SolveSettings(frames=3, backend="casadi"), model=model)
    assert e.value.status == "too_few_frames"
    every = ineid.load_robot("sweaty-arm", unknown_links=list(model.link_names))
    fm_all = frame_minimum(every)
    assert (fm_all.frames, fm_all.by_counting) == (7, 5) and fm_all.reason and "use at least 7" in fm_all.message(6)
    one = frame_minimum(ineid.load_robot("sweaty-arm", unknown_links=["forearm"]))
    assert (one.frames, one.reason) == (2, None) and "use at least 2 frames" in one.message(1)
    assert frame_minimum(model, bias=True).frames == 5


def fm_scales(model):
    from ineid.identify.identifiability import base_parameters

    return base_parameters(model).scales
