"""The IPOPT problem of :class:`ineid.identify.nlp.NlpSolver` with many base parameters: the data term as a
matrix graph.

The data term ``||R B theta(x) - z||^2 s^-2 / r`` with the factor ``R`` as r^2 scalar symbols makes the
problem's derivatives a graph of about ``r^2 n`` operations (Talos: 221 base parameters, 320 unknowns, 19 s
to build). Here ``R`` is one matrix symbol (CasADi ``MX``) applied to the scalar (``SX``) graph of the
links' ``theta(x)``, and the Hessian of the Lagrangian is formed from its pieces, each built in about n:

    H = lam_f J^T K J + sum_i mu_i d^2 theta_i / dx^2 + lam_f d^2 E / dx^2

with ``J = d theta / dx`` (a 10 x 10 block per link), ``K = 2 M s^-2 / r + 2 lam P`` the objective's
Hessian in ``theta`` (``M = (R B)^T (R B)``, given with the configuration's data; ``P = S^-1 N N^T S^-1``
the pull's, ``S`` the scales, ``N`` the scaled null-space basis), ``mu`` the Lagrangian's gradient in
``theta`` (``lam_f (2 B^T R^T (R B theta - z) s^-2 / r + 2 lam P (theta - theta_prior)) + S^-1 N
lam_g``) and ``E`` the entropic term. The objective and the constraints' derivatives are CasADi's.
"""

from __future__ import annotations

import numpy as np


def matrix_problem(xs, theta, pull_term, entropic_term, g, base, prior, pull_matrix, null_map, jit: dict):
    """``(nlp, hess_lag, theta_x, z)``: CasADi's problem (``x``, ``p = [vec R, z, 1/s^2, vec M]``, ``f``, ``g``),
    its Hessian of the Lagrangian (upper triangle), the parameters and ``z`` as ``MX``.

    Args:
        xs, theta, pull_term, entropic_term, g: the unknowns (SX, n) and the links' ``theta(x)``, pull,
            entropic term and constraints over them.
        base: the base parameters; prior: (n,) ``theta_prior``.
        pull_matrix: (n, n) ``lam P`` (zero without a pull); null_map: (n, k) ``S^-1 N`` of the constraints
            ``g = N^T S^-1 (theta - theta_prior)`` (k = 0 without them).
        jit: CasADi's options compiling the Hessian (empty: none).
    """
    import casadi as ca

    n, r = base.n_params, base.rank
    links = ca.Function("ineid_links", [xs], [theta, pull_term + entropic_term, g])
    mu_s, lam_s = ca.SX.sym("mu", n), ca.SX.sym("lam_f")
    second = ca.hessian(ca.dot(mu_s, theta) + lam_s * entropic_term, xs)[0]
    pieces = ca.Function("ineid_pieces", [xs, mu_s, lam_s], [ca.jacobian(theta, xs), second])
    x = ca.MX.sym("x", n)
    theta_x, rest_x, g_x = links(x)
    rp, zp, inv_s2, mp = ca.MX.sym("R", r, r), ca.MX.sym("z", r), ca.MX.sym("inv_sigma2"), ca.MX.sym("M", n, n)
    b = ca.DM(base.B)
    e = ca.mtimes(rp, ca.mtimes(b, theta_x)) - zp
    f = ca.sumsqr(e) * inv_s2 / r + rest_x
    p = ca.vertcat(ca.vec(rp), zp, inv_s2, ca.vec(mp))
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g_x.numel())
    pm = ca.DM(pull_matrix)
    q = 2 * inv_s2 / r * ca.mtimes(b.T, ca.mtimes(rp.T, e)) + 2 * ca.mtimes(pm, theta_x - ca.DM(prior))
    mu = lam_f * q + (ca.mtimes(ca.DM(null_map), lam_g) if null_map.shape[1] else 0)
    jac, sec = pieces(x, mu, lam_f)
    k = 2 * inv_s2 / r * mp + 2 * pm
    h = lam_f * ca.mtimes(jac.T, ca.mtimes(k, jac)) + sec
    hess_lag = ca.Function("ineid_hess_l", [x, p, lam_f, lam_g], [ca.triu(h)], jit)
    return {"x": x, "p": p, "f": f, "g": g_x}, hess_lag, theta_x, zp


def data_parameters(r_factor: np.ndarray, beta_hat: np.ndarray, inv_s2: float, b: np.ndarray) -> np.ndarray:
    """One configuration's parameters of :func:`matrix_problem`, ``[vec R, z, 1/s^2, vec M]``, ``M = (R B)^T (R B)``."""
    a = r_factor @ b
    return np.concatenate([r_factor.ravel(order="F"), r_factor @ beta_hat, [inv_s2], (a.T @ a).ravel(order="F")])
