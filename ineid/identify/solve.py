"""Solve every selected configuration of a dataset: the engine behind ``ineid solve``.

Per configuration the first ``K`` frames are fitted; the remaining frames (if any) are
held out and the estimate's prediction error on them is reported. What is fitted is the
dataset's measurement channels (``ds.meta.channels``, :class:`ineid.channels.ChannelSet`: the
base wrench, in the frame of its sensor), their axes stacked; every per-axis array (weights,
residual RMS, offsets) runs over those axes. All methods
share the base least-squares fit: from per-axis normal-equation blocks accumulated by one
fused kernel over the frames (:mod:`ineid.identify.fused`,
:func:`ineid.identify.linear.fit_base_blocks`), with the QR of the stacks
(:func:`ineid.identify.linear.fit_base`) for the few ill-conditioned configurations;
``nonlinear`` and ``consistent`` then run IPOPT per configuration, in worker processes
when there are many. The residuals on the fitted and held-out frames come from one more
fused pass. This module is the orchestration (settings, results, the order of the steps);
the steps themselves are :mod:`ineid.identify.steps`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ineid.cache import enable_compilation_cache
from ineid.channels import ChannelSet
from ineid.errors import IdentificationError
from ineid.identify.choose import solve_channels
from ineid.identify.classical import CLASSICAL_METHODS, classical_estimate
from ineid.identify.extras import prior_with_extras
from ineid.identify.frame_minimum import FrameMinimum
from ineid.identify.fused import information_blocks
from ineid.identify.identifiability import BaseParameters, base_parameters, frame_minimum
from ineid.identify.linear import linear_estimate, linear_theta, with_exact_rss
from ineid.identify.payload import payload_section
from ineid.identify.settings import (  # the settings: BACKENDS, ... are still importable from here (__all__)
    BACKENDS,
    BIAS_MODES,
    BUILTIN_METHODS,
    HOLDOUT_FRACTION,
    METHODS,
    STARTS,
    SolveSettings,
)
from ineid.identify.steps import (  # noqa: F401  (PARALLEL_MIN_CONFIGS, physical_start, ... were here: still importable)
    BIAS_MAX_ITER,
    PARALLEL_MIN_CONFIGS,
    REFERENCE_ROWS,
    _bias_estimate,
    _casadi_fits,
    _concat_fits,
    _fused_fit,
    _offset_dof,
    _run_nlp,
    estimate_residual_sums,
    physical_start,
    predicted_wrench,
    residual_summary,
)
from ineid.identify.systems import Offsets
from ineid.progress import Progress


@dataclass
class SolveResults:
    """Estimates of the selected configurations of one dataset (see ``docs/identification.md``).

    Arrays have one row per solved configuration, in selection order. Per-axis arrays
    (``fit_rms``, ``validation_rms``; ``bias_hat`` and ``bias_std``, the sensor offsets with
    ``bias="estimate"``) are (C, A) over the fitted channels' stacked axes, named in
    :attr:`axes` (the base wrench: fx..mz, N and N*m, sensor frame).
    """

    settings: SolveSettings
    base: BaseParameters
    param_names: tuple[str, ...]
    config_index: np.ndarray
    theta_hat: np.ndarray
    theta_std: np.ndarray
    base_hat: np.ndarray
    base_std: np.ndarray
    success: np.ndarray
    status: np.ndarray
    seconds: np.ndarray
    fit_rms: np.ndarray
    validation_rms: np.ndarray
    validation_rel: np.ndarray
    n_frames_fit: int
    n_frames_validation: int
    theta_prior: np.ndarray
    theta_true: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    bias_hat: np.ndarray | None = None
    bias_std: np.ndarray | None = None
    payload: dict | None = None
    """Per payload link (:mod:`ineid.identify.payload`): mass, centre of mass, inertia about it, with std."""

    @property
    def axes(self) -> tuple[str, ...]:
        """The names of the per-axis arrays' columns (``meta["axes"]``; a file of ineid 0.1: the base wrench's)."""
        return tuple(self.meta.get("axes") or ("fx", "fy", "fz", "mx", "my", "mz"))

    @property
    def units(self) -> tuple[str, ...]:
        """The units of the per-axis arrays' columns."""
        return tuple(self.meta.get("units") or ("N", "N", "N", "N*m", "N*m", "N*m"))

    @property
    def base_true(self) -> np.ndarray | None:
        """``B theta_true``; NaN in the base parameters that involve an extra parameter whose truth is unknown."""
        if self.theta_true is None:
            return None
        unknown = np.isnan(self.theta_true)
        out = np.nan_to_num(self.theta_true) @ self.base.B.T
        out[(unknown.astype(np.float64) @ (self.base.B != 0).T.astype(np.float64)) > 0] = np.nan
        return out

    @property
    def n_extra(self) -> int:
        """The channels' extra parameters among :attr:`param_names` (the last ones; :mod:`ineid.identify.extras`)."""
        return self.base.n_extra

    @property
    def theta_links(self) -> np.ndarray:
        """(C, 10 n_u) the unknown links' estimates: :attr:`theta_hat` without the extra parameters."""
        return self.theta_hat[:, : self.theta_hat.shape[1] - self.n_extra]

    @property
    def n(self) -> int:
        return len(self.config_index)


def _frame_split(n_frames: int, frames: int | None, minimum: FrameMinimum) -> tuple[int, int]:
    """``(fitted, held out)`` frames a configuration; fewer than ``minimum.frames`` fitted is refused."""
    if frames is not None:
        if frames > n_frames:
            raise IdentificationError(
                f"--fit-frames {frames} but the dataset has {n_frames} frames per configuration; use at most "
                f"{n_frames}",
                status="too_many_frames",
            )
        minimum.require(frames)
        return frames, n_frames - frames
    held = int(HOLDOUT_FRACTION * n_frames)
    fit = n_frames - held
    if minimum.n_axes * fit < 2 * (minimum.rank + minimum.n_offsets):  # too few to spare any: fit them all
        fit, held = n_frames, 0
    minimum.require(fit)
    return fit, held


def _axis_sigma(ds, settings: SolveSettings, channels: ChannelSet | None = None, model=None) -> np.ndarray | None:
    """The noise per measured axis for ``weights="noise"``: given, or recorded with the data (per channel)."""
    if settings.weights != "noise":
        return None
    channels = ds.meta.channels if channels is None else channels
    n_axes = channels.n_axes(model or ds.meta)
    if settings.axis_sigma is not None:
        sigma = np.asarray(settings.axis_sigma, dtype=np.float64)
        if sigma.shape != (n_axes,):
            raise IdentificationError(
                f"axis_sigma holds {sigma.size} numbers; the channels measure {n_axes} axes "
                f"({', '.join(channels.axes(model or ds.meta))}): give one per axis",
                status="bad_noise_levels",
            )
        return sigma
    recorded = channels.noise_std(ds.meta.noise, model or ds.meta)
    if recorded is None:
        what = "the wrench noise" if channels.keys == ("wrench",) else "the noise of every channel"
        raise IdentificationError(
            f"weights='noise' needs {what} per axis: give axis_sigma (--sigma FX FY FZ MX MY MZ) "
            "or use weights='estimate'",
            status="no_noise_levels",
        )
    return recorded


SolveMethod = Callable[..., "SolveResults"]
"""``solve(ds, settings, model, progress) -> SolveResults``, as :func:`solve_dataset`."""


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
    if settings.method not in BUILTIN_METHODS:  # a trained run as the solver (ineid.learn's, passed in)
        solve = (methods or {}).get(settings.method)
        if solve is None:
            raise IdentificationError(
                f"method {settings.method!r} runs a trained network, which ineid.learn provides: use "
                "ineid.workflow.solve_dataset, or pass methods={'network': ineid.learn.solve_with_run}",
                status="unsupported",
            )
        return solve(ds, settings, model, progress)
    model = model or ds.model()
    if settings.two_step:  # the links from the wrench, then the torques' extras (ineid.identify.two_step)
        from ineid.identify.two_step import second_step, wrench_settings

        t_start = time.perf_counter()
        first = solve_dataset(ds, wrench_settings(ds, settings, model), model, progress, methods)
        return dataset_results(ds, settings, t_start=t_start, **second_step(first, ds, settings, model))
    with_bias = settings.bias == "estimate"
    channels = solve_channels(ds, settings, model)
    base = base_parameters(model, bias=with_bias, channels=channels)
    prior = prior_with_extras(model, channels)  # [theta_cad_u, 0 for each extra parameter]
    n_offsets = int(channels.offset_mask(model).sum())
    n_fit, n_val = _frame_split(ds.n_frames, settings.frames, frame_minimum(model, with_bias, channels))
    axis_sigma = _axis_sigma(ds, settings, channels, model)
    c = ds.n_configs
    fit_sl = slice(0, n_fit)
    t_start = time.perf_counter()

    # 1. base least squares, batched (or per configuration through CasADi)
    offsets = None
    if settings.backend == "casadi":
        fits, rms, seconds, parts = _casadi_fits(model, ds, fit_sl, base, settings, axis_sigma, progress, channels)
        fit = _concat_fits(fits)
        offsets = Offsets.concat(parts) if with_bias else None
    else:
        t0 = time.perf_counter()
        blocks_fn = information_blocks
        if settings.backend == "casadi-c":
            from ineid.identify.casadi_c import information_blocks_c as blocks_fn
        fit, rms, offsets = _fused_fit(
            model,
            ds,
            fit_sl,
            base,
            settings,
            axis_sigma,
            progress if settings.method == "linear" else None,
            blocks_fn,
            channels,
        )
        seconds = np.full(c, (time.perf_counter() - t0) / max(c, 1))
    if with_bias:
        _offset_dof(fit, n_offsets)

    # 2. the residuals of the least-squares fit itself, exactly (one fused pass over every
    # frame at the linear estimate): the normal equations give the rss only up to
    # cancellation (eps * ||y||^2), the covariance and the IPOPT noise level need it exact
    theta_lin = linear_theta(fit, base, prior)
    sums = estimate_residual_sums(model, ds, n_fit, n_val, theta_lin, channels, offsets)
    fit = with_exact_rss(fit, sums[0])
    if settings.known_uncertainty:  # the known links' CAD uncertainty (ineid.identify.known)
        from ineid.identify.known import with_known_uncertainty

        fit = with_known_uncertainty(fit, model, base, ds, fit_sl, channels, settings)

    # 3. standard parameters
    if settings.method == "linear":
        est = linear_estimate(fit, base, prior)
    elif settings.method in CLASSICAL_METHODS:  # the paper's solvers on the same base fit
        est, classical_seconds = classical_estimate(settings, fit, base, prior, progress)
        seconds = seconds + classical_seconds
        sums = estimate_residual_sums(model, ds, n_fit, n_val, est.theta, channels, offsets)
    else:
        start = prior if settings.start == "prior" else physical_start(theta_lin, prior, base.scales, base.n_extra)
        est, nlp_seconds = _run_nlp(fit, base, settings, prior, rms, start, progress)
        seconds = seconds + nlp_seconds
        sums = estimate_residual_sums(model, ds, n_fit, n_val, est.theta, channels, offsets)
    bias_hat = bias_std = None
    if with_bias:
        bias_hat, bias_std = _bias_estimate(offsets, est, base)

    # 4. residuals of the estimates on the fitted and on the held-out frames
    return dataset_results(
        ds,
        settings,
        base,
        prior,
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
        seconds=seconds,
        bias_hat=bias_hat,
        bias_std=bias_std,
        payload=payload_section(model, base, est.theta[:, : base.n_link_params], est.fit.cov_beta, est.success),
    )


def dataset_results(
    ds,
    settings: SolveSettings,
    base: BaseParameters,
    theta_prior: np.ndarray,
    sums,
    n_fit: int,
    n_val: int,
    t_start: float,
    channels: ChannelSet | None = None,
    model=None,
    **estimates,
) -> SolveResults:
    """:class:`SolveResults` of estimates on ``ds``, for every solver (the methods and a trained run).

    What every result records the same way: the configurations' file indices, the residual
    RMS on the fitted and held-out frames from ``sums`` (:func:`estimate_residual_sums`, see
    :func:`residual_summary`), the prior, the truth when the dataset has it, and
    :func:`results_meta` with the seconds since ``t_start`` (``time.perf_counter()``) and the
    channels fitted (default: the dataset's; ``model`` names their axes, default the dataset's
    metadata). ``estimates``: the remaining fields (``theta_hat, theta_std, base_hat, base_std,
    success, status, seconds``, optionally ``bias_hat, bias_std``).
    """
    fit_rms, val_rms, val_rel = residual_summary(sums, n_fit, n_val, estimates["theta_hat"])
    return SolveResults(
        settings=settings,
        base=base,
        param_names=tuple(base.param_names),
        config_index=np.asarray(ds.config_index, dtype=np.int64),
        fit_rms=fit_rms,
        validation_rms=val_rms,
        validation_rel=val_rel,
        n_frames_fit=n_fit,
        n_frames_validation=n_val,
        theta_prior=theta_prior,
        theta_true=truth_with_extras(ds, base),
        meta=results_meta(ds, time.perf_counter() - t_start, channels, model),
        **estimates,
    )


def truth_with_extras(ds, base: BaseParameters) -> np.ndarray | None:
    """The true ``[theta_u, x]`` of synthetic data (C, 10 n_u + n_extra): the links' from the dataset, the extra
    parameters' from its ``extra_truth`` record (NaN where it has none); None without the links' truth."""
    if ds.theta_unknown is None:
        return None
    theta = np.asarray(ds.theta_unknown, dtype=np.float64)
    if not base.n_extra:
        return theta
    truth = getattr(ds.meta, "extra_truth", None) or {}
    names = base.param_names[base.n_link_params :]
    extra = np.array([float(truth.get(n, np.nan)) for n in names])
    return np.concatenate([theta, np.broadcast_to(extra, (len(theta), len(names)))], axis=1)


def results_meta(ds, total_seconds: float, channels: ChannelSet | None = None, model=None) -> dict:
    """What a results file records of its dataset (robot, URDF, links, gravity, sensor, path and fingerprint)
    and of the channels fitted (their records, the stacked axes' names and units)."""
    channels = ds.meta.channels if channels is None else channels
    names = model or ds.meta
    return {
        "robot": ds.meta.robot,
        "source": ds.meta.source,
        "urdf": ds.meta.urdf,
        "unknown_links": list(ds.meta.unknown_links),
        "gravity": np.asarray(ds.meta.gravity).tolist(),
        "locked_joints": ds.meta.locked_joints,
        "dataset_path": None if ds.path is None else str(ds.path),
        "dataset_fingerprint": ds.fingerprint(),
        "sensor": ds.meta.sensor,
        "channels": channels.to_list(),
        "axes": list(channels.axes(names)),
        "units": list(channels.units(names)),
        "total_seconds": total_seconds,
    }


__all__ = [
    "BACKENDS",
    "BIAS_MODES",
    "BUILTIN_METHODS",
    "HOLDOUT_FRACTION",
    "METHODS",
    "STARTS",
    "SolveMethod",
    "SolveResults",
    "SolveSettings",
    "dataset_results",
    "results_meta",
    "solve_dataset",
    "truth_with_extras",
]
