"""Solve every selected configuration of a dataset: the engine behind ``ineid solve``.

Per configuration the first ``K`` frames are fitted; the remaining frames (if any) are
held out and the estimate's prediction error on them is reported. What is fitted is the
dataset's measurement channels (``ds.meta.channels``, :class:`ineid.channels.ChannelSet`: the
base wrench, in the frame of its sensor), their axes stacked; every per-axis array (weights,
residual RMS, offsets) runs over those axes.

Every method starts from one shared base least-squares fit (:func:`ineid.identify.steps.fit_dataset`):
from per-axis normal-equation blocks accumulated by one fused kernel over the frames
(:mod:`ineid.identify.fused`, :func:`ineid.identify.linear.fit_base_blocks`), with the QR of the
stacks (:func:`ineid.identify.linear.fit_base`) for the few ill-conditioned configurations, and
its residuals evaluated exactly. The method itself is looked up in :data:`ESTIMATORS`, one
function a method with one signature, ``method(shared, settings, progress)``
(:class:`ineid.identify.linear.SharedFit` -> :class:`ineid.identify.linear.MethodEstimate`):
``linear`` the null-space rule, ``nonlinear`` and ``consistent`` IPOPT per configuration
(:mod:`ineid.identify.nlp_runs`, in worker processes when there are many), ``lsqlin`` and
``lsqnonlin`` the paper's solvers (:mod:`ineid.identify.classical`). The residuals of the estimate on
the fitted and held-out frames come from one more fused pass. A method implemented above
``identify`` (``network``, a trained run) is passed in by the caller (``methods``) and solves the
dataset its own way. This module is the orchestration: which method, the two steps
(:mod:`ineid.identify.two_step`), the order of the steps.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

import numpy as np

from ineid.cache import enable_compilation_cache
from ineid.errors import IdentificationError
from ineid.identify.choose import noise_levels, solve_channels, wrench_settings
from ineid.identify.classical import lsqlin_method, lsqnonlin_method
from ineid.identify.constrained_std import std_record
from ineid.identify.friction_search import solve_searched
from ineid.identify.identifiability import base_parameters, frame_minimum
from ineid.identify.linear import MethodEstimate, SharedFit, linear_method
from ineid.identify.nlp_runs import (  # noqa: F401  (re-exported from here until ineid 0.3)
    BIAS_MAX_ITER,
    PARALLEL_MIN_CONFIGS,
    nlp_method,
    physical_start,
)
from ineid.identify.payload import payload_section
from ineid.identify.settings import (  # re-exported from here until ineid 0.3 (__all__)
    BACKENDS,
    BIAS_MODES,
    BUILTIN_METHODS,
    HOLDOUT_FRACTION,
    METHODS,
    STARTS,
    SolveSettings,
)
from ineid.identify.solve_results import (  # re-exported from here until ineid 0.3
    SolveResults,
    dataset_results,
    residual_summary,
    results_meta,
    truth_with_extras,
)
from ineid.identify.steps import (  # noqa: F401  (re-exported from here until ineid 0.3)
    REFERENCE_ROWS,
    bias_estimate,
    estimate_residual_sums,
    fit_dataset,
    predicted_wrench,
)
from ineid.identify.two_step import second_step
from ineid.progress import Progress

Estimator = Callable[[SharedFit, SolveSettings, "Progress | None"], MethodEstimate]
"""``method(shared, settings, progress) -> MethodEstimate``: a method's standard parameters from the shared fit."""
ESTIMATORS: dict[str, Estimator] = {
    "linear": linear_method,
    "nonlinear": nlp_method,
    "consistent": nlp_method,
    "lsqlin": lsqlin_method,
    "lsqnonlin": lsqnonlin_method,
}
"""The methods identify implements (:data:`ineid.identify.settings.BUILTIN_METHODS`), by name."""
SolveMethod = Callable[..., "SolveResults"]
"""``solve(ds, settings, model, progress) -> SolveResults``, as :func:`solve_dataset`: a method implemented above
identify (``network``), passed in ``methods``."""


def solve_dataset(
    ds,
    settings: SolveSettings = SolveSettings(),
    model=None,
    progress: Progress | None = None,
    methods: Mapping[str, SolveMethod] | None = None,
) -> SolveResults:
    """Identify the unknown links of every configuration in ``ds``.

    Args:
        ds: a :class:`ineid.data.Dataset` (select configurations beforehand).
        settings: method and options.
        model: the dataset's :class:`ineid.RobotModel` (default: rebuilt from the file).
        progress: ``progress(done, total)`` over configurations.
        methods: solvers of the methods implemented above identify, by name (``{"network":
            ineid.learn.solve_with_run}``; :func:`ineid.workflow.solve_dataset` passes every one).

    Raises:
        IdentificationError: too few frames for the identifiable parameters, or noise
            weights without noise levels. Per-configuration failures (rank-deficient frames,
            IPOPT not converging) do not raise: they are recorded in ``success`` and ``status``.
    """
    enable_compilation_cache()
    estimator = ESTIMATORS.get(settings.method)
    if estimator is None:  # a trained run as the solver (ineid.learn's, passed in)
        return _passed_method(settings.method, methods)(ds, settings, model, progress)
    model = model or ds.model()
    if settings.searched_velocities:  # the friction's nonlinear velocities first (ineid.identify.friction_search)
        return solve_searched(ds, settings, model, solve_dataset, progress, methods)
    t_start = time.perf_counter()
    if settings.two_step:  # the links from the wrench, then the torques' extras (ineid.identify.two_step)
        first = solve_dataset(ds, wrench_settings(ds, settings, model), model, progress, methods)
        return second_step(first, ds, settings, model, t_start)

    # what is fitted: the channels and their noise, the base parameters, the frames fitted and held out
    with_bias = settings.estimates_offsets
    channels = solve_channels(ds, settings, model)
    axis_sigma = noise_levels(ds, settings, channels, model)
    base = base_parameters(model, bias=with_bias, channels=channels)
    n_fit, n_val = frame_minimum(model, with_bias, channels).split(ds.n_frames, settings.frames)
    # 1, 2. the base least-squares fit of every configuration, and its residuals (ineid.identify.steps)
    step = fit_dataset(ds, model, settings, channels, base, (n_fit, n_val), axis_sigma, progress)
    # 3. the method's standard parameters from it
    out = estimator(step.shared, settings, progress)
    est = out.estimate
    # 4. the residuals of the estimate on the fitted and on the held-out frames, its offsets
    sums = step.sums
    if not out.is_linear:
        sums = step.residual_sums(model, ds, (n_fit, n_val), est.theta, channels)
    bias_hat, bias_std = (None, None) if step.offsets is None else bias_estimate(step.offsets, est, base)
    res = dataset_results(
        ds,
        settings,
        base,
        step.shared.prior,
        sums,
        n_fit,
        n_val,
        t_start,
        channels=channels,
        model=model,
        theta_hat=est.theta,
        theta_std=est.theta_std,
        base_hat=est.beta,
        base_std=est.beta_std,
        success=est.success,
        status=np.asarray(est.status, dtype=object),
        seconds=step.seconds + out.seconds,
        bias_hat=bias_hat,
        bias_std=bias_std,
        payload=payload_section(model, base, est.theta[:, : base.n_link_params], est.fit.cov_beta, est.success),
    )
    res.meta["std"] = std_record([ds], est)  # what the std was computed from (results info, the report)
    return res


def _passed_method(name: str, methods: Mapping[str, SolveMethod] | None) -> SolveMethod:
    """The solver of a method implemented above identify, from the caller's ``methods``.

    Raises:
        IdentificationError: none passed under ``name`` (status ``unsupported``).
    """
    solve = (methods or {}).get(name)
    if solve is None:
        raise IdentificationError(
            f"method {name!r} runs a trained network, which ineid.learn provides: use "
            "ineid.workflow.solve_dataset, or pass methods={'network': ineid.learn.solve_with_run}",
            status="unsupported",
        )
    return solve


__all__ = [
    "BACKENDS",
    "BIAS_MODES",
    "BUILTIN_METHODS",
    "ESTIMATORS",
    "HOLDOUT_FRACTION",
    "METHODS",
    "STARTS",
    "Estimator",
    "SolveMethod",
    "SolveResults",
    "SolveSettings",
    "dataset_results",
    "residual_summary",
    "results_meta",
    "solve_dataset",
    "truth_with_extras",
]
