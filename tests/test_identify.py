"""Identification: base parameters (checked with Pinocchio), linear, nonlinear, consistent, results."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import ineid
from ineid import IdentificationError
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import (
    NlpSolver,
    SolveSettings,
    analyze_frames,
    base_parameters,
    error_summary,
    export_urdf,
    fit_base,
    generic_frames,
    identify_frames,
    linear_estimate,
    load_results,
    nlp_estimate,
    relative_error,
    save_results,
    solve_dataset,
    stack,
    urdf_with_inertials,
)
from ineid.params import is_physical
from ineid.reference import pinocchio_base_regressor, pinocchio_model

from .conftest import SEED, rel_err

NOISE = NoiseModel.create(4, force=0.5, moment=0.05, qd=0.01, qdd=0.1)


@pytest.fixture(scope="module")
def clean(model):
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=60), n_frames=30, seed=SEED))


@pytest.fixture(scope="module")
def noisy(model):
    return generate_dataset(
        model, DatasetSpec(Combination("random", n_configs=300), n_frames=40, seed=SEED, noise=NOISE)
    )


@pytest.fixture(scope="module")
def pin_regressor(model):
    """Pinocchio's base regressor of 400 random frames, stacked: (2400, 40)."""
    q, qd, qdd = generic_frames(model, 400, seed=SEED)
    pm = pinocchio_model(model.urdf_path)
    return pinocchio_base_regressor(pm, q, qd, qdd).reshape(-1, 40), (q, qd, qdd)


# -- identifiability, against an independent engine ----------------------------------------


def test_rank_facts_with_pinocchio(model, base, pin_regressor):
    y, _ = pin_regressor
    cols = {name: slice(10 * i, 10 * i + 10) for i, name in enumerate(model.link_names)}
    rank = lambda a: np.linalg.matrix_rank(a * np.linalg.norm(a, axis=0, keepdims=True) ** -1, tol=1e-9)  # noqa: E731
    assert rank(y[:, cols["upper_arm"]]) == 10
    assert rank(y[:, cols["forearm"]]) == 10
    assert rank(y[:, 20:40]) == 17
    assert base.rank == 17 and base.null_basis.shape == (20, 3)
    # every null direction is invisible to Pinocchio's regressor, for any frames
    assert np.abs(y[:, 20:40] @ base.null_basis).max() < 1e-10 * np.abs(y[:, 20:40]).max()
    # and W theta == W_b (B theta) for any parameters
    theta = np.random.default_rng(SEED).normal(size=(20, 5))
    np.testing.assert_allclose(y[:, 20:40] @ theta, y[:, 20:40][:, base.base_index] @ (base.B @ theta), atol=1e-9)


def test_structural_groupings_are_named(base):
    assert base.names[0] == "upper_arm.m + forearm.m"
    assert "upper_arm.mz - 0.22*forearm.m" in base.names
    assert "forearm.Ixx - forearm.Izz" in base.names
    ident = [p for p, ok in zip(base.param_names, base.identifiable, strict=True) if ok]
    assert ident == ["forearm.mx", "forearm.mz", "forearm.Ixy", "forearm.Iyy", "forearm.Ixz", "forearm.Iyz"]
    assert all("+1 forearm" in d for d in base.null_directions())


def test_one_unknown_link_is_fully_identifiable():
    for link in ("upper_arm", "forearm"):
        b = base_parameters(ineid.load_robot("sweaty-arm", unknown_links=[link]))
        assert b.rank == 10 and b.identifiable.all()


def test_frame_analysis(model, base):
    q, qd, qdd = generic_frames(model, 60, seed=1)
    good = analyze_frames(model, q, qd, qdd)
    assert good.ok and good.problem() is None and good.rank == 17 and 3 <= good.min_frames <= 6
    assert np.isfinite(good.condition_number) and good.condition_number > 1
    rest = analyze_frames(model, q, 0 * qd, 0 * qdd)
    assert not rest.ok and rest.rank < 17 and "frames at rest show only gravity" in rest.problem()
    few = analyze_frames(model, q[:2], qd[:2], qdd[:2])
    assert "2 frames give 12 equations for 17 identifiable parameters; use at least 4 frames" in few.problem()
    three = analyze_frames(model, q[:3], qd[:3], qdd[:3])  # 18 equations, but the force rows give only 6
    assert three.rank == 15 and three.problem().startswith(
        "use at least 4 frames (more with noise): 3 generic frames give rank 15 of 17, since the fx, fy, fz rows "
        "span only 6 of the 17"
    )


# -- linear -------------------------------------------------------------------------------


def test_linear_exact_on_clean_data(model, base, clean):
    w, y = stack(model, clean.q, clean.qd, clean.qdd, clean.wrench, clean.theta_known)
    prior = model.theta_cad[model.unknown_index]
    est = linear_estimate(fit_base(w, y, base), base, prior)
    truth = clean.theta_unknown
    assert rel_err(est.beta, truth @ base.B.T) < 1e-10
    assert rel_err(est.theta[:, base.identifiable], truth[:, base.identifiable]) < 1e-10
    # the rest follows the documented rule: reproduce beta, closest to the prior (scaled)
    phi = (est.theta - prior) / base.scales
    null = base.null_basis / base.scales[:, None]
    assert np.abs(phi @ np.linalg.qr(null)[0]).max() < 1e-9
    assert np.all(np.isnan(est.theta_std[:, ~base.identifiable]))
    assert np.all(np.isfinite(est.theta_std[:, base.identifiable]))


def test_linear_uncertainty_is_calibrated(model, base, noisy):
    w, y = stack(model, noisy.q, noisy.qd, noisy.qdd, noisy.wrench, noisy.theta_known)
    for weights in ("estimate", "noise"):
        fit = fit_base(w, y, base, weights, axis_sigma=NOISE.wrench)
        z = (fit.beta - noisy.theta_unknown @ base.B.T) / np.sqrt(np.diagonal(fit.cov_beta, axis1=1, axis2=2))
        assert 0.8 < z.std() < 1.25, (weights, z.std())
    fit = fit_base(w, y, base, "estimate")
    # the estimated per-axis noise includes the kinematic noise's effect, so it is >= the wrench noise
    sigma = 1 / fit.axis_weights
    assert np.all(np.median(sigma, axis=0) > 0.9 * NOISE.wrench)
    assert np.all(np.median(sigma, axis=0) < 3 * NOISE.wrench)


def test_weighting_helps_with_unequal_noise(model, base):
    noise = NoiseModel.create(4, force=[0.2, 0.2, 3.0], moment=0.02)
    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=200), n_frames=40, seed=3, noise=noise))
    truth = ds.theta_unknown @ base.B.T
    w, y = stack(model, ds.q, ds.qd, ds.qdd, ds.wrench, ds.theta_known)
    errs = {m: np.median(relative_error(fit_base(w, y, base, m).beta, truth)) for m in ("none", "estimate")}
    assert errs["estimate"] < 0.7 * errs["none"]


def test_casadi_route_equals_jax(model, clean):
    sub = clean.select(slice(0, 4))
    a = solve_dataset(sub, SolveSettings(backend="casadi"), model=model)
    b = solve_dataset(sub, SolveSettings(), model=model)
    np.testing.assert_allclose(a.theta_hat, b.theta_hat, rtol=1e-9, atol=1e-12)


def test_too_few_frames_and_rank_deficiency(model, clean):
    with pytest.raises(IdentificationError, match="use at least 4 frames") as e:
        solve_dataset(clean.select(frames=slice(0, 2)), SolveSettings(frames=2), model=model)
    assert e.value.status == "too_few_frames"
    still = clean.select(slice(0, 3))
    still.qd[1] = 0.0
    still.qdd[1] = 0.0  # configuration 1 at rest: gravity only
    still.wrench[1] = np.asarray(model.base_wrench(still.q[1], still.qd[1], still.qdd[1], still.theta()[1]))
    res = solve_dataset(still, SolveSettings(frames=30), model=model)
    assert res.success.tolist() == [True, False, True] and res.status[1].startswith("rank_deficient")
    assert np.all(np.isnan(res.theta_hat[1]))
    with pytest.raises(IdentificationError, match="frames at rest show only gravity"):
        identify_frames(model, still.q[1], still.qd[1], still.qdd[1], still.wrench[1])


# -- nonlinear and consistent ------------------------------------------------------------------


def test_nonlinear_matches_linear(model, noisy, clean):
    sub = noisy.select(slice(0, 30))
    lin = solve_dataset(sub, SolveSettings(weights="estimate"), model=model)
    nl = solve_dataset(sub, SolveSettings(method="nonlinear", weights="estimate"), model=model)
    assert nl.success.all()
    np.testing.assert_allclose(nl.theta_hat, lin.theta_hat, atol=1e-5 * lin.base.scales.max())
    exact = solve_dataset(clean.select(slice(0, 10)), SolveSettings(method="nonlinear"), model=model)
    assert exact.success.all() and rel_err(exact.base_hat, exact.base_true) < 1e-6
    exact_lin = solve_dataset(clean.select(slice(0, 10)), model=model)
    np.testing.assert_allclose(exact.theta_hat, exact_lin.theta_hat, atol=1e-6 * lin.base.scales.min())


def test_consistent_is_always_physical(model, base):
    heavy = NoiseModel.create(4, force=2.0, moment=0.2, qd=0.04, qdd=0.4)
    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=40), n_frames=12, seed=5, noise=heavy))
    lin = solve_dataset(ds, SolveSettings(weights="estimate"), model=model)
    con = solve_dataset(ds, SolveSettings(method="consistent", weights="estimate"), model=model)
    assert con.success.all()
    assert is_physical(con.theta_hat.reshape(-1, 10)).all()
    assert not is_physical(lin.theta_hat.reshape(-1, 2, 10)).all(axis=-1).all()  # why the method exists
    assert np.median(relative_error(con.base_hat, con.base_true)) <= 1.1 * np.median(
        relative_error(lin.base_hat, lin.base_true)
    )


def test_linear_start_is_used_and_physical(model, base, clean):
    from ineid.identify.solve import physical_start

    sub = clean.select(slice(0, 20))
    lin = solve_dataset(sub, model=model)
    prior = model.theta_cad[model.unknown_index]
    start = physical_start(lin.theta_hat, prior, base.scales)
    assert is_physical(start.reshape(-1, 10)).all()
    moved = ~np.all(start == prior, axis=1)
    assert moved.mean() > 0.5  # most starts are (part of the way to) the linear estimate


def test_consistent_on_clean_data(model, clean):
    for start in ("prior", "linear"):
        res = solve_dataset(clean.select(slice(0, 12)), SolveSettings(method="consistent", start=start), model=model)
        assert res.success.all(), res.status
        assert np.median(relative_error(res.base_hat, res.base_true)) < 1e-4
        assert is_physical(res.theta_hat.reshape(-1, 10)).all()


def test_ipopt_failure_is_reported_never_silent(model, base, clean):
    w, y = stack(model, clean.q[:3], clean.qd[:3], clean.qdd[:3], clean.wrench[:3], clean.theta_known)
    fit = fit_base(w, y, base)
    solver = NlpSolver.build("consistent", base, model.theta_cad[model.unknown_index], ipopt_options={"max_iter": 1})
    est = nlp_estimate(fit, solver, np.sqrt(np.mean(y**2, axis=1)))
    assert not est.success.any() and set(est.status) == {"Maximum_Iterations_Exceeded"}
    assert np.all(np.isnan(est.theta))


def test_identify_frames_single_recording(model, clean):
    res = identify_frames(model, clean.q[0], clean.qd[0], clean.qdd[0], clean.wrench[0], method="consistent")
    assert res.n == 1 and res.success[0] and res.theta_true is None
    assert rel_err(res.base_hat[0], clean.theta_unknown[0] @ res.base.B.T) < 1e-4
    with pytest.raises(ValueError, match=r"qd must have shape \(n_frames, 4\)"):
        identify_frames(model, clean.q[0], clean.qd[0, :, :3], clean.qdd[0], clean.wrench[0])
    bad = clean.wrench[0].copy()
    bad[3, 1] = np.nan
    with pytest.raises(IdentificationError, match="wrench holds NaN"):
        identify_frames(model, clean.q[0], clean.qd[0], clean.qdd[0], bad)


# -- validation, results file, URDF export ---------------------------------------------------


def test_validation_on_held_out_frames(model, clean, noisy):
    res = solve_dataset(clean.select(slice(0, 5)), model=model)
    assert res.n_frames_fit == 24 and res.n_frames_validation == 6
    assert np.nanmax(res.validation_rel) < 1e-9
    res = solve_dataset(noisy.select(slice(0, 20)), SolveSettings(frames=20), model=model)
    assert res.n_frames_validation == 20 and 1e-3 < np.median(res.validation_rel) < 0.2
    with pytest.raises(IdentificationError, match="at most 40"):
        solve_dataset(noisy.select(slice(0, 2)), SolveSettings(frames=41), model=model)


def test_results_round_trip_and_summary(model, noisy, tmp_path):
    res = solve_dataset(noisy.select(np.arange(0, 300, 30)), SolveSettings(method="consistent"), model=model)
    path = save_results(res, tmp_path / "r.h5")
    back = load_results(path)
    for name in ("config_index", "theta_hat", "theta_std", "base_hat", "success", "validation_rel", "theta_true"):
        np.testing.assert_array_equal(getattr(back, name), getattr(res, name))
    assert back.base.names == res.base.names and back.settings == res.settings
    assert back.config_index.tolist() == list(range(0, 300, 30))
    rows = error_summary(back.base_hat, back.base_true, back.base.names, back.success)
    assert len(rows) == 17 and all(0 <= r.within_1 <= r.within_5 <= 1 for r in rows)
    with pytest.raises(ineid.OutputExistsError, match="exists; pass --overwrite to replace it"):
        save_results(res, path)
    noisy.select(slice(0, 2)).save(tmp_path / "d.h5")
    with pytest.raises(ineid.DatasetError, match="it is a dataset"):
        load_results(tmp_path / "d.h5")


def test_export_urdf_round_trip(model, clean, tmp_path):
    import pinocchio as pin

    res = solve_dataset(clean.select([7]), SolveSettings(method="consistent", frames=30), model=model)
    out = export_urdf(res, 7, tmp_path / "identified.urdf")
    text = out.read_text()
    assert "identified by ineid" in text and "inertial folded by ineid into the identified link" in text
    assert "'forearm'" not in text  # the comments hold no name (an XML comment cannot escape one)
    again = ineid.load_robot(out, unknown_links=["upper_arm", "forearm"])
    np.testing.assert_allclose(again.theta_cad[again.unknown_index], res.theta_hat[0], rtol=1e-13, atol=1e-16)
    np.testing.assert_array_equal(again.theta_cad[again.known_index], model.theta_cad[model.known_index])
    pm = pin.buildModelFromUrdf(str(out))
    got = np.concatenate([pm.inertias[i].toDynamicParameters() for i in (3, 4)])
    np.testing.assert_allclose(got, res.theta_hat[0], rtol=1e-12, atol=1e-15)
    with pytest.raises(ineid.OutputExistsError, match="exists; pass --overwrite to replace it"):
        export_urdf(res, 7, out)
    with pytest.raises(IdentificationError, match="configuration 3 is not in the results"):
        export_urdf(res, 3, tmp_path / "x.urdf")
    bad = res.theta_hat[0].copy()
    bad[0] = -1.0
    with pytest.raises(IdentificationError, match="not a rigid body"):
        urdf_with_inertials(res.meta["urdf"], {"upper_arm": bad[:10]})


def test_identify_never_imports_sympy():
    code = "import sys, ineid.identify; assert 'sympy' not in sys.modules, 'sympy imported'"
    subprocess.run([sys.executable, "-c", code], check=True)
