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

import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ineid.cache import enable_compilation_cache
from ineid.channels import ChannelSet
from ineid.errors import IdentificationError
from ineid.identify.choose import actuation_requested, check_actuation, solve_channels
from ineid.identify.classical import CLASSICAL_METHODS, classical_estimate
from ineid.identify.extras import prior_with_extras
from ineid.identify.frame_minimum import FrameMinimum
from ineid.identify.fused import information_blocks
from ineid.identify.identifiability import BaseParameters, base_parameters, frame_minimum
from ineid.identify.linear import WEIGHT_MODES, linear_estimate, linear_theta, with_exact_rss
from ineid.identify.nlp import DEFAULT_ENTROPIC, DEFAULT_PULL
from ineid.identify.payload import payload_section
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

BUILTIN_METHODS = ("linear", "nonlinear", "consistent", *CLASSICAL_METHODS)
"""The methods identify implements itself; ``lsqlin``, ``lsqnonlin``: the paper's (:mod:`ineid.identify.classical`)."""
METHODS = (*BUILTIN_METHODS, "network")
"""Every method; ``network`` (a trained run) is implemented by :mod:`ineid.learn.amortized` and passed to
:func:`solve_dataset` in ``methods`` (:func:`ineid.workflow.solve_dataset` does): identify never imports learn."""
STARTS = ("prior", "linear")
"""IPOPT's start: the CAD values, or the linear estimate made physical."""
BACKENDS = ("jax", "casadi", "casadi-c")
"""The least-squares engine: fused JAX kernels; CasADi per configuration (QR, an independent
route; linear method only); or the fused blocks through CasADi's C code, compiled (needs a C compiler)."""
BIAS_MODES = ("none", "estimate")
"""The sensors' constant offsets (six for the base wrench): absent (a tared sensor), or identified with the
parameters (every channel's, :meth:`ineid.channels.ChannelSet.with_offsets`)."""
HOLDOUT_FRACTION = 0.2
"""Without ``frames``, this share of each configuration's frames is held out for validation."""


@dataclass(frozen=True)
class SolveSettings:
    """How to identify.

    Attributes:
        method: ``"linear"``, ``"nonlinear"`` (the paper's mass / centre of mass / inertia
            form) or ``"consistent"`` (log-Cholesky, always physical); ``"lsqlin"``, ``"lsqnonlin"``: the
            paper's MATLAB solvers over every standard parameter, its reference (:mod:`ineid.identify.classical`).
        frames: frames fitted per configuration (the first ``frames``); the rest are held
            out for validation. ``None``: all but the last 20 % (all, when too few).
        weights: ``"estimate"`` (the default: the noise of each measured axis estimated from the
            residuals, :mod:`ineid.identify.weighting`), ``"noise"`` (``1/sigma`` per measured axis
            from ``axis_sigma``, or from the dataset's recorded noise) or ``"none"`` (equal noise on
            every axis assumed: the standard deviations are wrong where it differs).
        axis_sigma: (A,) noise standard deviations per measured axis (the base wrench: fx..mz)
            for ``weights="noise"``.
        start: IPOPT's (and ``lsqnonlin``'s) start, ``"prior"`` (the CAD values) or ``"linear"`` (the linear
            estimate, made physical for ``consistent`` if needed).
        bounds: ``lsqlin``'s box, ``theta_cad -/+ bounds * max(|theta_cad|, scale)``
            (:func:`ineid.identify.classical.cad_bounds`); None: unbounded (minimum norm).
        pull, entropic: prior weights of the IPOPT solvers (see :mod:`ineid.identify.nlp`).
        backend: ``"jax"`` (fused normal-equation blocks, batched), ``"casadi"`` (per
            configuration, the generated CasADi function and CasADi's QR; no compilation)
            or ``"casadi-c"`` (the same blocks as ``"jax"`` from the CasADi function printed
            as C and compiled, see :mod:`ineid.identify.casadi_c`, and for ``nonlinear`` /
            ``consistent`` the IPOPT problem compiled too; needs a C compiler).
        workers: processes for the IPOPT solvers (default 1); used from
            :data:`ineid.identify.steps.PARALLEL_MIN_CONFIGS` configurations on. More than one uses spawned
            processes (multiprocessing): call from under ``if __name__ == "__main__":``.
        bias: ``"none"`` (the wrench holds no offset) or ``"estimate"``: constant offsets,
            one per sensor axis (six for the base wrench), identified jointly with the parameters (every method;
            :class:`ineid.identify.systems.Offsets`). They also take the weight of whatever
            sits between the sensor and the first joint.
        run: the trained run folder of ``method="network"`` (:mod:`ineid.learn.amortized`).
        known_uncertainty: ``(link, fraction)`` pairs, the known links' CAD uncertainty
            (:mod:`ineid.identify.known`: std ``fraction * max(|theta_cad|, scale)`` per
            parameter) added to the reported covariance; link ``"*"`` for every known link.
            Empty: the CAD values are taken as exact.
        use: the dataset's channels fitted, by key or kind (``("wrench",)``, ``("torque",)``,
            ``("wrench", "torque")``; :mod:`ineid.identify.choose`); None: every channel it has.
        friction: the joint torques' friction model, any of ``"viscous"``, ``"coulomb"``;
            ``coulomb_zone`` (rad/s) smooths ``sign(qd)`` into ``tanh(qd / zone)``;
            ``asymmetric_friction``: one coefficient per direction. ``armature``: rotor inertia
            ``Ia qdd``; ``torque_offset``: a constant torque per joint. Each adds extra kept
            columns to the joint-torque channels (``<joint>.fv``, ...), identified with the links'
            parameters and recorded after them (:mod:`ineid.identify.extras`); refused without a
            joint-torque channel among those fitted.
        two_step: FloBaRoID's two steps (:mod:`ineid.identify.two_step`): the links from the
            wrench alone, then the joint torques' extra parameters from their residual with the
            links fixed; needs both channels.
        torque_constant_unknown: the motor-current channels' torque constants are identified too
            (``<joint>.k``, relative to their nominal values), in step 2 of ``two_step`` (needs it).
    """

    method: str = "linear"
    frames: int | None = None
    weights: str = "estimate"
    axis_sigma: tuple[float, ...] | None = None
    start: str = "prior"
    pull: float = DEFAULT_PULL
    entropic: float = DEFAULT_ENTROPIC
    backend: str = "jax"
    workers: int | None = None
    bias: str = "none"
    run: str | None = None
    known_uncertainty: tuple[tuple[str, float], ...] = ()
    use: tuple[str, ...] | None = None
    friction: tuple[str, ...] = ()
    coulomb_zone: float = 0.0
    asymmetric_friction: bool = False
    armature: bool = False
    torque_offset: bool = False
    two_step: bool = False
    torque_constant_unknown: bool = False
    bounds: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.weights not in WEIGHT_MODES:
            raise ValueError(f"weights must be one of {', '.join(WEIGHT_MODES)}, got {self.weights!r}")
        if self.start not in STARTS:
            raise ValueError(f"start must be one of {', '.join(STARTS)}, got {self.start!r}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if self.bias not in BIAS_MODES:
            raise ValueError(f"bias must be one of {', '.join(BIAS_MODES)}, got {self.bias!r}")
        if self.backend == "casadi-c" and self.bias == "estimate":
            raise ValueError("backend='casadi-c' does not estimate sensor offsets; use backend 'jax' or 'casadi'")
        if self.backend == "casadi" and self.method not in BUILTIN_METHODS:  # casadi-c serves every method
            raise ValueError("backend='casadi' applies to identify's own methods, not a trained network")
        if self.bounds is not None and (self.method != "lsqlin" or not (np.isfinite(self.bounds) and self.bounds > 0)):
            raise ValueError(f"bounds (a fraction > 0 of the CAD values) go with method='lsqlin', got {self.bounds}")
        if self.frames is not None and self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if self.method == "network" and self.bias != "none":
            raise ValueError("method='network' estimates no sensor offsets; use bias='none'")
        if (self.method == "network") != (self.run is not None):
            raise ValueError("method='network' needs run (a trained run folder), and run goes with method='network'")
        pairs = tuple((str(link), float(f)) for link, f in self.known_uncertainty)
        object.__setattr__(self, "known_uncertainty", pairs)  # lists from a results file: hashable pairs
        for link, f in pairs:
            if not (np.isfinite(f) and f >= 0):
                raise ValueError(f"known_uncertainty of {link!r} must be a fraction >= 0, got {f}")
        if pairs and self.method == "network":
            raise ValueError("method='network' does not propagate the known links' uncertainty")
        if self.use is not None:  # lists from a results file: hashable tuples
            object.__setattr__(self, "use", tuple(str(u) for u in self.use))
        object.__setattr__(self, "friction", tuple(str(f) for f in self.friction))
        check_actuation(self)
        if self.method == "network" and (actuation_requested(self) or self.two_step):
            raise ValueError(
                "method='network' predicts the links from the channels it was trained on; "
                "leave the friction, armature, torque-offset and two-step options out"
            )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["axis_sigma"] = None if self.axis_sigma is None else list(self.axis_sigma)
        d["known_uncertainty"] = [list(p) for p in self.known_uncertainty]
        d["use"] = None if self.use is None else list(self.use)
        d["friction"] = list(self.friction)
        return d


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
