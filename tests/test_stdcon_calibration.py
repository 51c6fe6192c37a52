"""Standard deviations of the constrained fits (:mod:`ineid.identify.constrained_std`): the linear fit's where no
constraint is active, the constrained estimate's sandwich where one is, calibrated on 30 simulated configurations
(one trajectory and one noise draw each) of a truth inside the physical set and of one on its boundary."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, solve_dataset

N_CONFIGS = 30
FORCE_NOISE = 3.0
"""N (moments a tenth, N m): noisy enough that the physical set's boundary bites (sweaty-arm's wrench is ~30 N);
the quiet case ``inside`` has a twentieth of it."""


def thin_rod(mass: float, length: float) -> np.ndarray:
    """A thin rod along the link's -z axis from its origin: two zero principal moments, on the boundary."""
    i = mass * length**2 / 3
    return np.array([mass, 0.0, 0.0, -mass * length / 2, i, 0.0, i, 0.0, 0.0, 0.0])


def with_truth(ds, noise, rows, theta):
    """A copy of ``ds`` whose unknown links are ``theta`` (n,) in every configuration, with ``noise`` added."""
    rows_u, rows_k = rows
    wrench = np.einsum("cfap,p->cfa", rows_u, theta) + np.einsum("cfap,p->cfa", rows_k, ds.theta_known) + noise
    return dataclasses.replace(
        ds, wrench=wrench, theta_unknown=np.broadcast_to(theta, (ds.n_configs, len(theta))).copy()
    )


def simulated(model, n_configs: int, seed: int = 7):
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=n_configs),
            n_frames=30,
            seed=seed,
            noise=NoiseModel.create(4, force=FORCE_NOISE, moment=FORCE_NOISE / 10),
        ),
    )
    noise = ds.wrench - ds.clean["wrench"]
    rows = model.regressor_split(ds.q, ds.qd, ds.qdd)
    inside = ds.theta_unknown[0]
    rod = np.concatenate([inside[:10], thin_rod(1.2, 0.3)])
    truths = (("inside", inside, 0.05), ("inside, noisy", inside, 1.0), ("rod", rod, 1.0))
    return {name: with_truth(ds, scale * noise, rows, th) for name, th, scale in truths}


@pytest.fixture(scope="module")
def cases(model):
    return simulated(model, N_CONFIGS)


def rms_z(res, base, ds, std=None) -> np.ndarray:
    """(r,) RMS over the successful configurations of each base parameter's error / std."""
    z = (res.base_hat - ds.theta_unknown @ base.B.T) / (res.base_std if std is None else std)
    return np.sqrt(np.mean(z[res.success] ** 2, axis=0))


def test_std_is_the_linear_one_where_nothing_is_active_and_changes_where_a_constraint_is(model, cases):
    inside, rod = cases["inside"], cases["rod"]
    lin = solve_dataset(inside, SolveSettings(frames=30), model=model)
    non = solve_dataset(inside, SolveSettings(frames=30, method="nonlinear"), model=model)
    np.testing.assert_array_equal(non.base_std, lin.base_std)  # its mass bounds never bind: the linear std, exactly
    con = solve_dataset(inside, SolveSettings(frames=30, method="consistent"), model=model)
    same = np.all(con.base_std == lin.base_std, axis=1)
    assert con.success.all() and same.sum() >= N_CONFIGS - 3, same.sum()  # inside: the constraints hardly bind
    np.testing.assert_array_equal(con.theta_std[same], lin.theta_std[same])
    lin_r = solve_dataset(rod, SolveSettings(frames=30), model=model)
    con_r = solve_dataset(rod, SolveSettings(frames=30, method="consistent"), model=model)
    changed = np.any(con_r.base_std != lin_r.base_std, axis=1)
    assert changed.all()  # the rod's linear estimates leave the physical set: the boundary is active everywhere
    assert np.nanmin(con_r.base_std / lin_r.base_std) < 0.5  # what the constraint tells is in the std
    assert np.all(con_r.base_std <= lin_r.base_std * (1 + 1e-3))  # a constraint only adds information


def test_consistent_std_is_calibrated_on_30_configurations(model, base, cases):
    """RMS of error / std per base parameter near 1 inside and on the boundary; the linear std, used for the
    consistent estimate on the boundary, is too large where the constraint informs (z far below 1)."""
    for name, ds in cases.items():
        lin = solve_dataset(ds, SolveSettings(frames=30), model=model)
        con = solve_dataset(ds, SolveSettings(frames=30, method="consistent"), model=model)
        z = rms_z(con, base, ds)
        assert con.success.all(), name
        assert 0.85 < z.mean() < 1.15 and np.all((z > 0.6) & (z < 1.5)), (name, z.round(2))
        if name == "rod":
            assert rms_z(con, base, ds, lin.base_std).min() < 0.55  # the linear std: overstated here


def test_bounded_lsqlin_std_accounts_for_its_active_bounds(model, base, cases):
    """A box the truth sits on the edge of (the rod's Iyy as a lower bound): the bounded fit's std is the
    linear one where the bound is not active, smaller where it is, and calibrated (30 configurations)."""
    from ineid.identify import fused
    from ineid.identify.classical import lsqlin_theta
    from ineid.identify.constrained_std import constrained_cov
    from ineid.identify.linear import fit_base_blocks, prior_map

    ds = cases["rod"]
    blocks = fused.information_blocks(model, base, ds.q, ds.qd, ds.qdd, ds.wrench, ds.theta_known)
    fit, _ = fit_base_blocks(blocks, base)
    truth = ds.theta_unknown[0]
    lb, ub = np.full(base.n_params, -np.inf), np.full(base.n_params, np.inf)
    k = base.param_names.index("forearm.Iyy")
    lb[k] = truth[k]  # the truth on the bound: about half the configurations stop there
    theta, status = lsqlin_theta(fit, base, (lb, ub))
    ok = status == "ok"
    cov, n_active = constrained_cov(theta, ok, fit, base, null="free", psd=False, bounds=(lb, ub))
    active = n_active > 0
    assert 5 <= active.sum() <= 25, active.sum()
    np.testing.assert_array_equal(cov[~active], fit.cov_beta[~active])
    std = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    ratio = std[active] / np.sqrt(np.diagonal(fit.cov_beta[active], axis1=1, axis2=2))
    assert ratio.max() < 1 + 1e-3 and ratio.min() < 1e-6  # the bounded parameter: pinned (the rest: as linear)
    # an identifiable parameter's bound is a row of base parameters, j = e_k^T T: the projection in the information
    # metric, P = I - M^-1 j^T (j M^-1 j^T)^-1 j, cov = P V P^T
    j = prior_map(base)[k][None, :]
    for i in np.flatnonzero(active)[:3]:
        m_inv = np.linalg.inv(fit.R[i].T @ fit.R[i])
        p = np.eye(base.rank) - m_inv @ j.T @ np.linalg.solve(j @ m_inv @ j.T, j)
        np.testing.assert_allclose(cov[i], p @ fit.cov_beta[i] @ p.T, atol=1e-9 * np.abs(fit.cov_beta[i]).max())
    # nonlinear's form (the null-space part held at the prior's) binds the same identifiable bound the same way
    held, n_held = constrained_cov(theta, ok, fit, base, null="exact", psd=False, prior=truth, bounds=(lb, ub))
    np.testing.assert_array_equal(n_held, n_active)
    np.testing.assert_allclose(held, cov, rtol=1e-7, atol=1e-9 * np.abs(cov).max())  # lsqlin: a 1e-10 ridge
    err = theta @ base.B.T - truth @ base.B.T
    lin_std = np.sqrt(np.diagonal(fit.cov_beta, axis1=1, axis2=2))
    pinned = std < 1e-6 * lin_std  # the bound's own direction where it binds: the truth's value, to round-off
    assert np.all(np.abs(err[pinned]) < 1e-6 * lin_std[pinned])
    z = np.where(pinned, np.nan, err / np.where(pinned, 1.0, std))[ok]
    rms = np.sqrt(np.nanmean(z**2, axis=0))
    assert 0.8 < rms.mean() < 1.2 and np.all(rms < 1.5), rms.round(2)


def test_results_file_and_info_carry_the_constrained_std(model, cases, tmp_path, run):
    from ineid.identify import load_results, save_results

    ds = cases["rod"]
    con = solve_dataset(ds, SolveSettings(frames=30, method="consistent"), model=model)
    path = save_results(con, tmp_path / "c.h5")
    back = load_results(path)
    np.testing.assert_array_equal(back.base_std, con.base_std)
    np.testing.assert_array_equal(back.theta_std, con.theta_std)
    r = run("results", "info", path)
    assert r.exit_code == 0, r.output
    assert "std: the linear fit's covariance through the active constraints" in r.output


@pytest.mark.slow  # 200 configurations of three truths: ~1 min of IPOPT solves
def test_consistent_std_calibration_study(model, base):
    """The calibration of the fast test on 200 configurations: each base parameter's RMS z within 0.7..1.35 (at a
    tenth of the wrench in noise the linearization at the boundary leaves 0.73..1.29 on the rod)."""
    for name, ds in simulated(model, 200, seed=11).items():
        con = solve_dataset(ds, SolveSettings(frames=30, method="consistent"), model=model)
        z = rms_z(con, base, ds)
        assert 0.9 < z.mean() < 1.1 and np.all((z > 0.7) & (z < 1.35)), (name, z.round(2))
