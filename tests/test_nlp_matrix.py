"""The IPOPT problem's data term as a matrix graph (:mod:`ineid.identify.nlp_matrix`) against the scalar graph
with ``R`` as r^2 symbols, built here: objective, gradient, the hand-formed Hessian of the Lagrangian and the
std's derivatives equal CasADi's derivatives of the scalar form to 1e-10 on sweaty-arm, both methods."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from ineid.identify import NlpSolver
from ineid.identify.nlp import entropic_divergence, null_basis_scaled, scaled_pseudo_inertia
from ineid.identify.nlp_matrix import data_parameters


def scalar_problem(solver, method):
    """``(x, p, f, g)``: the problem with ``R`` as r^2 SX symbols and the same terms."""
    base, prior = solver.base, solver.theta_prior
    n, r = base.n_params, base.rank
    x = ca.SX.sym("x", n)
    theta = solver.theta_fn(x)
    rp, zp, inv_s2 = ca.SX.sym("R", r, r), ca.SX.sym("z", r), ca.SX.sym("w")
    f = ca.sumsqr(ca.mtimes(rp, ca.mtimes(ca.DM(base.B), theta)) - zp) * inv_s2 / r
    nb = null_basis_scaled(base)
    null_part = ca.mtimes(ca.DM(nb.T), theta / ca.DM(base.scales) - ca.DM(prior / base.scales))
    g = ca.SX.zeros(0, 1)
    if method == "nonlinear":
        g = null_part
    else:
        f += solver.pull * ca.sumsqr(null_part)
        jp_inv = [np.linalg.inv(j) for j in scaled_pseudo_inertia(prior, base.scales)]
        f += solver.entropic * entropic_divergence(x, jp_inv)
    return x, ca.vertcat(ca.vec(rp), zp, inv_s2), f, g, theta, zp


@pytest.mark.parametrize("method", ["consistent", "nonlinear"])
def test_matrix_problem_equals_scalar_form(model, base, method):
    rng = np.random.default_rng(3)
    prior = model.theta_cad[model.unknown_index]
    solver = NlpSolver.build(method, base, prior)
    n, r = base.n_params, base.rank
    x0 = solver.start(prior) + 0.05 * rng.standard_normal(n)
    r_factor = np.triu(rng.standard_normal((r, r))) + 3 * np.eye(r)
    beta_hat = base.B @ prior * (1 + 0.1 * rng.standard_normal(r))
    inv_s2 = 7.0
    xs, ps, fs, gs, theta_s, zs = scalar_problem(solver, method)
    p_old = np.concatenate([r_factor.ravel(order="F"), r_factor @ beta_hat, [inv_s2]])
    lam_f, lam_g = 0.7, rng.standard_normal(gs.numel())
    grad_s = ca.gradient(fs, xs)
    lag = lam_f * fs + ca.dot(ca.DM(lam_g), gs) if gs.numel() else lam_f * fs
    outs = [fs, grad_s, ca.hessian(lag, xs)[0], ca.jacobian(grad_s, xs), ca.jacobian(grad_s, zs)]
    ref = [np.array(v) for v in ca.Function("ref", [xs, ps], outs + [ca.jacobian(theta_s, xs)])(x0, p_old)]

    x, p, f = solver.expressions[:3]
    p_new = data_parameters(r_factor, beta_hat, inv_s2, base.B)
    got_f, got_grad = (np.array(v) for v in ca.Function("new", [x, p], [f, ca.gradient(f, x)])(x0, p_new))
    hess_lag = solver.solver.solver.get_function("nlp_hess_l")
    got_h = np.array(hess_lag(x0, p_new, lam_f, lam_g))

    def close(a, b):
        assert np.max(np.abs(a - b)) <= 1e-10 * max(np.max(np.abs(b)), 1.0)

    close(got_f, ref[0])
    close(got_grad, ref[1])
    close(got_h, np.triu(ref[2]))
    if method == "consistent":  # the std's derivatives (estimator_gain)
        h, h_xz, jac = solver.derivatives(x0, r_factor, beta_hat, inv_s2)
        close(h, ref[3])
        close(h_xz, ref[4])
        close(jac, ref[5])
