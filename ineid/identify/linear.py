"""The ``linear`` method: standard parameters from the base least-squares fit by a prior rule.

The data determine only the base parameters ``beta = B theta`` (:mod:`ineid.identify.identifiability`),
fitted by weighted least squares (:mod:`ineid.identify.least_squares`, :class:`BaseFit`: the fit every
method starts from, :class:`SharedFit`). The ``linear`` method completes them by the null-space rule: the
standard parameters are the solution closest to a prior (default: the CAD values) in the scaled metric, among
all that reproduce ``beta_hat``:

    theta_hat = argmin || (theta - theta_prior) / scale ||   s.t.   B theta = beta_hat
              = theta_prior + T (beta_hat - B theta_prior),   T = S (B S)^+

with ``S = diag(scale)`` (:func:`ineid.identify.systems.parameter_scales`). Individually
identifiable parameters do not depend on the prior; their standard deviations are
``sqrt(diag(T cov(beta) T^T))``; the others get NaN, because the data say nothing about them.

Every method returns an :class:`Estimate` (:class:`MethodEstimate`, with what it took).

References:
    Gautier & Khalil (1990); Khalil & Dombre (2002), ch. 12; Atkeson, An, Hollerbach (1986).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.identify.identifiability import BaseParameters
from ineid.identify.least_squares import (  # noqa: F401  (BaseFit, fit_base, ... were defined here: still importable)
    ESTIMATE_ROUNDS,
    NORMAL_MAX_COND,
    WEIGHT_MODES,
    BaseFit,
    axis_weights,
    fit_base,
    fit_base_blocks,
    with_exact_rss,
)
from ineid.identify.settings import SolveSettings
from ineid.progress import Progress


def prior_map(base: BaseParameters) -> np.ndarray:
    """``T = S (B S)^+`` (10 n_u, r): the null-space rule's map from base to standard parameters."""
    s = base.scales
    return s[:, None] * np.linalg.pinv(base.B * s[None, :])


def standard_from_base(beta: np.ndarray, base: BaseParameters, theta_prior: np.ndarray) -> np.ndarray:
    """``theta = theta_prior + T (beta - B theta_prior)``: closest to the prior, reproducing ``beta``.

    Args:
        beta: (..., r).
        theta_prior: (10 n_u,) or (..., 10 n_u).
    """
    t = prior_map(base)
    prior = np.asarray(theta_prior, dtype=np.float64)
    return prior + (beta - prior @ base.B.T) @ t.T


def standard_std(cov_beta: np.ndarray, base: BaseParameters) -> np.ndarray:
    """Standard deviations of the standard parameters; NaN where not identifiable. (C, 10 n_u)."""
    t = prior_map(base)
    var = np.einsum("cps,ps->cp", np.matmul(t, cov_beta), t)  # diag(T cov T^T)
    std = np.sqrt(np.maximum(var, 0.0))
    std[:, ~base.identifiable] = np.nan
    return std


@dataclass
class Estimate:
    """Estimates of a batch of configurations, the same for every method.

    Attributes:
        theta: (C, 10 n_u) standard parameters of the unknown links (NaN where failed).
        theta_std: (C, 10 n_u) standard deviations, NaN where not identifiable.
        beta: (C, r) base parameters ``B theta``.
        beta_std: (C, r).
        success: (C,) bool.
        status: (C,) text: "ok", or why not (solver status, rank deficiency).
        fit: the base least-squares fit behind them.
        n_active: (C,) how many constraints the std runs through (the constrained methods), or None.
    """

    theta: np.ndarray
    theta_std: np.ndarray
    beta: np.ndarray
    beta_std: np.ndarray
    success: np.ndarray
    status: np.ndarray
    fit: BaseFit
    n_active: np.ndarray | None = None


def linear_theta(fit: BaseFit, base: BaseParameters, theta_prior: np.ndarray) -> np.ndarray:
    """(C, 10 n_u) standard parameters from a base fit by the null-space rule; NaN rows where not full rank."""
    theta = standard_from_base(np.nan_to_num(fit.beta), base, theta_prior)
    theta[~fit.full_rank] = np.nan
    return theta


def linear_estimate(fit: BaseFit, base: BaseParameters, theta_prior: np.ndarray) -> Estimate:
    """Standard parameters from a base fit by the null-space rule (see module doc)."""
    theta = linear_theta(fit, base, theta_prior)
    ok = fit.full_rank
    std = standard_std(np.nan_to_num(fit.cov_beta), base)
    std[~ok] = np.nan
    beta_std = np.sqrt(np.maximum(np.diagonal(fit.cov_beta, axis1=1, axis2=2), 0.0))
    status = np.where(ok, "ok", [f"rank_deficient ({k} of {base.rank})" for k in fit.rank]).astype(object)
    return Estimate(theta, std, fit.beta.copy(), beta_std, ok.copy(), status, fit)


@dataclass(frozen=True)
class SharedFit:
    """The base least-squares fit of a batch of configurations, which every method starts from.

    What :data:`ineid.identify.solve.ESTIMATORS` hands a method (``method(shared, settings, progress)``):
    made once per solve (:func:`ineid.identify.steps.fit_dataset`; several recordings:
    :func:`ineid.identify.joint.solve_recordings`), whatever the method.

    Attributes:
        base: the base parameters of ``[theta_u, x]``.
        prior: (n,) the prior ``[theta_cad_u, 0 for each extra parameter]``.
        fit: the base fit, its residual sum of squares exact (and with the known links' uncertainty).
        theta_lin: (C, n) the linear estimate (:func:`linear_theta`; NaN rows where not full rank).
        data_rms: (C,) RMS of the weighted data (the noise-free floor of IPOPT's variance).
    """

    base: BaseParameters
    prior: np.ndarray
    fit: BaseFit
    theta_lin: np.ndarray
    data_rms: np.ndarray


@dataclass(frozen=True)
class MethodEstimate:
    """What a method makes of a :class:`SharedFit`.

    Attributes:
        estimate: the standard parameters of every configuration.
        seconds: (C,) what the method took per configuration, beyond the shared fit.
        is_linear: the estimate is the shared fit's own linear one (``theta_lin``): the residuals
            already evaluated there stand.
    """

    estimate: Estimate
    seconds: np.ndarray
    is_linear: bool = False


def linear_method(shared: SharedFit, settings: SolveSettings, progress: Progress | None = None) -> MethodEstimate:
    """``linear``: the null-space rule on the shared fit (:func:`linear_estimate`; ``settings`` chooses nothing)."""
    est = linear_estimate(shared.fit, shared.base, shared.prior)
    return MethodEstimate(est, np.zeros(len(shared.theta_lin)), is_linear=True)
