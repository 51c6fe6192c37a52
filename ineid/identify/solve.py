"""Solve every selected configuration of a dataset: the engine behind ``ineid solve``.

Per configuration the first ``K`` frames are fitted; the remaining frames (if any) are
held out and the estimate's wrench prediction error on them is reported. All methods
share the base least-squares fit: from per-axis normal-equation blocks accumulated by one
fused kernel over the frames (:mod:`ineid.identify.fused`,
:func:`ineid.identify.linear.fit_base_blocks`), with the QR of the stacks
(:func:`ineid.identify.linear.fit_base`) for the few ill-conditioned configurations;
``nonlinear`` and ``consistent`` then run IPOPT per configuration, in worker processes
when there are many. The residuals on the fitted and held-out frames come from one more
fused pass.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ineid.cache import enable_compilation_cache
from ineid.errors import IdentificationError
from ineid.identify.fused import information_blocks, residual_sums
from ineid.identify.identifiability import BaseParameters, base_parameters
from ineid.identify.linear import (
    WEIGHT_MODES,
    BaseFit,
    Estimate,
    axis_weights,
    fit_base,
    fit_base_blocks,
    fit_base_casadi,
    linear_estimate,
    linear_theta,
    with_exact_rss,
)
from ineid.identify.nlp import DEFAULT_ENTROPIC, DEFAULT_PULL, NlpSolver, estimate_from_solves, nlp_estimate
from ineid.identify.systems import Offsets, check_frames, predict_wrench, remove_offsets, stack, stack_casadi
from ineid.progress import Progress

BUILTIN_METHODS = ("linear", "nonlinear", "consistent")
"""The methods identify implements itself."""
METHODS = (*BUILTIN_METHODS, "network")
"""Every method; ``network`` (a trained run) is implemented by :mod:`ineid.learn.amortized`, which
registers it when imported (:func:`register_method`): identify never imports learn."""
STARTS = ("prior", "linear")
"""IPOPT's start: the CAD values, or the linear estimate made physical."""
BACKENDS = ("jax", "casadi", "casadi-c")
"""The least-squares engine: fused JAX kernels; CasADi per configuration (QR, an independent
route; linear method only); or the fused blocks through CasADi's C code, compiled (needs a C compiler)."""
BIAS_MODES = ("none", "estimate")
"""The sensor's six constant offsets: absent (a tared sensor), or identified with the parameters."""
HOLDOUT_FRACTION = 0.2
"""Without ``frames``, this share of each configuration's frames is held out for validation."""
PARALLEL_MIN_CONFIGS = 256
"""Fewer configurations are solved in this process: starting workers costs about a second."""



@dataclass(frozen=True)
class SolveSettings:
    """How to identify.

    Attributes:
        method: ``"linear"``, ``"nonlinear"`` (the paper's mass / centre of mass / inertia
            form) or ``"consistent"`` (log-Cholesky, always physical).
        frames: frames fitted per configuration (the first ``frames``); the rest are held
            out for validation. ``None``: all but the last 20 % (all, when too few).
        weights: ``"none"``, ``"noise"`` (``1/sigma`` per wrench axis from ``axis_sigma``, or
            from the dataset's recorded noise) or ``"estimate"`` (from the residuals).
        axis_sigma: (6,) wrench noise standard deviations for ``weights="noise"``.
        start: IPOPT start, ``"prior"`` (the CAD values) or ``"linear"`` (the linear
            estimate, made physical for ``consistent`` if needed).
        pull, entropic: prior weights of the IPOPT solvers (see :mod:`ineid.identify.nlp`).
        backend: ``"jax"`` (fused normal-equation blocks, batched), ``"casadi"`` (per
            configuration, the generated CasADi function and CasADi's QR; linear method only)
            or ``"casadi-c"`` (the same blocks as ``"jax"`` from the CasADi function printed
            as C and compiled, see :mod:`ineid.identify.casadi_c`, and for ``nonlinear`` /
            ``consistent`` the IPOPT problem compiled too; needs a C compiler).
        workers: processes for the IPOPT solvers (default 1); used from
            :data:`PARALLEL_MIN_CONFIGS` configurations on. More than one uses spawned
            processes (multiprocessing): call from under ``if __name__ == "__main__":``.
        bias: ``"none"`` (the wrench holds no offset) or ``"estimate"``: six constant offsets,
            one per sensor axis, identified jointly with the parameters (every method;
            :class:`ineid.identify.systems.Offsets`). They also take the weight of whatever
            sits between the sensor and the first joint.
        run: the trained run folder of ``method="network"`` (:mod:`ineid.learn.amortized`).
    """

    method: str = "linear"
    frames: int | None = None
    weights: str = "none"
    axis_sigma: tuple[float, ...] | None = None
    start: str = "prior"
    pull: float = DEFAULT_PULL
    entropic: float = DEFAULT_ENTROPIC
    backend: str = "jax"
    workers: int | None = None
    bias: str = "none"
    run: str | None = None

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
        if self.backend == "casadi" and self.method != "linear":  # casadi-c serves every method
            raise ValueError("backend='casadi' applies to the linear method")
        if self.frames is not None and self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if self.method == "network" and self.bias != "none":
            raise ValueError("method='network' estimates no sensor offsets; use bias='none'")
        if (self.method == "network") != (self.run is not None):
            raise ValueError("method='network' needs run (a trained run folder), and run goes with method='network'")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["axis_sigma"] = None if self.axis_sigma is None else list(self.axis_sigma)
        return d


@dataclass
class SolveResults:
    """Estimates of the selected configurations of one dataset (see ``docs/identification.md``).

    Arrays have one row per solved configuration, in selection order. ``bias_hat`` and
    ``bias_std`` (C, 6) are the sensor offsets (N, N*m, sensor frame) with ``bias="estimate"``.
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

    @property
    def base_true(self) -> np.ndarray | None:
        return None if self.theta_true is None else self.theta_true @ self.base.B.T

    @property
    def n(self) -> int:
        return len(self.config_index)


def _frame_split(n_frames: int, frames: int | None, rank: int) -> tuple[int, int]:
    if frames is not None:
        if frames > n_frames:
            raise IdentificationError(
                f"--fit-frames {frames} but the dataset has {n_frames} frames per configuration; use at most {n_frames}",
                status="too_many_frames",
            )
        check_frames(frames, rank)
        return frames, n_frames - frames
    held = int(HOLDOUT_FRACTION * n_frames)
    fit = n_frames - held
    if 6 * fit < 2 * rank:  # too few to spare any: fit them all
        fit, held = n_frames, 0
    check_frames(fit, rank)
    return fit, held


def _axis_sigma(ds, settings: SolveSettings) -> np.ndarray | None:
    if settings.weights != "noise":
        return None
    if settings.axis_sigma is not None:
        return np.asarray(settings.axis_sigma, dtype=np.float64)
    recorded = (ds.meta.noise or {}).get("wrench")
    if recorded is None or not np.all(np.asarray(recorded) > 0):
        raise IdentificationError(
            "weights='noise' needs the wrench noise per axis: give axis_sigma (--sigma FX FY FZ MX MY MZ) "
            "or use weights='estimate'",
            status="no_noise_levels",
        )
    return np.asarray(recorded, dtype=np.float64)


SolveMethod = Callable[..., "SolveResults"]
"""``solve(ds, settings, model, progress) -> SolveResults``, as :func:`solve_dataset`."""

_REGISTERED: dict[str, SolveMethod] = {}


def register_method(name: str, solve: SolveMethod) -> None:
    """Make ``solve_dataset`` run ``solve`` for ``SolveSettings(method=name)``, a method of :data:`METHODS`
    implemented above identify (``network``: :func:`ineid.learn.amortized.solve_with_run`, registered
    when ``ineid.learn`` is imported)."""
    if name not in METHODS or name in BUILTIN_METHODS:
        raise ValueError(f"only {', '.join(m for m in METHODS if m not in BUILTIN_METHODS)} may be registered, "
                         f"got {name!r}")
    _REGISTERED[name] = solve


def registered_method(name: str) -> SolveMethod:
    """The solver registered for ``name`` (:func:`register_method`).

    Raises:
        IdentificationError: none is: the module that provides it was not imported.
    """
    if name not in _REGISTERED:
        raise IdentificationError(f"method {name!r} runs a trained network, which ineid.learn provides: "
                                  "import ineid.learn first (it registers the method)", status="unsupported")
    return _REGISTERED[name]


def solve_dataset(ds, settings: SolveSettings = SolveSettings(), model=None, progress: Progress | None = None) -> SolveResults:
    """Identify the unknown links of every configuration in ``ds``.

    Args:
        ds: a :class:`ineid.data.Dataset` (select configurations beforehand).
        settings: method and options.
        model: the dataset's :class:`ineid.RobotModel` (default: rebuilt from the file).
        progress: ``progress(done, total)`` over configurations.

    Raises:
        IdentificationError: too few frames for the identifiable parameters, or noise
            weights without noise levels. Per-configuration failures (rank-deficient frames,
            IPOPT not converging) do not raise: they are recorded in ``success`` and ``status``.
    """
    enable_compilation_cache()
    if settings.method not in BUILTIN_METHODS:  # a trained run as the solver (registered by ineid.learn)
        return registered_method(settings.method)(ds, settings, model, progress)
    model = model or ds.model()
    with_bias = settings.bias == "estimate"
    base = base_parameters(model, bias=with_bias)
    sensor = ds.meta.sensor_transform()
    if sensor is not None and settings.backend == "casadi-c":
        raise IdentificationError("backend 'casadi-c' fits in the base frame only; this dataset's wrench is in a "
                                  "sensor frame: use backend 'jax' or 'casadi'", status="unsupported")
    prior = np.asarray(model.theta_cad[model.unknown_index], dtype=np.float64)
    n_fit, n_val = _frame_split(ds.n_frames, settings.frames, base.rank + 6 * with_bias)
    axis_sigma = _axis_sigma(ds, settings)
    c = ds.n_configs
    fit_sl = slice(0, n_fit)
    t_start = time.perf_counter()

    # 1. base least squares, batched (or per configuration through CasADi)
    offsets = None
    if settings.backend == "casadi":
        fits, rms, seconds, parts = _casadi_fits(model, ds, fit_sl, base, settings, axis_sigma, progress, sensor)
        fit = _concat_fits(fits)
        offsets = Offsets.concat(parts) if with_bias else None
    else:
        t0 = time.perf_counter()
        blocks_fn = information_blocks
        if settings.backend == "casadi-c":
            from ineid.identify.casadi_c import information_blocks_c as blocks_fn  # noqa: PLC0415
        fit, rms, offsets = _fused_fit(model, ds, fit_sl, base, settings, axis_sigma,
                                       progress if settings.method == "linear" else None, blocks_fn, sensor)
        seconds = np.full(c, (time.perf_counter() - t0) / max(c, 1))
    if with_bias:
        _offset_dof(fit)

    # 2. the residuals of the least-squares fit itself, exactly (one fused pass over every
    # frame at the linear estimate): the normal equations give the rss only up to
    # cancellation (eps * ||y||^2), the covariance and the IPOPT noise level need it exact
    theta_lin = linear_theta(fit, base, prior)
    sums = estimate_residual_sums(model, ds, n_fit, n_val, theta_lin, sensor, offsets)
    fit = with_exact_rss(fit, sums[0])

    # 3. standard parameters
    if settings.method == "linear":
        est = linear_estimate(fit, base, prior)
    else:
        start = prior if settings.start == "prior" else physical_start(theta_lin, prior, base.scales)
        est, nlp_seconds = _run_nlp(fit, base, settings, prior, rms, start, progress)
        seconds = seconds + nlp_seconds
        sums = estimate_residual_sums(model, ds, n_fit, n_val, est.theta, sensor, offsets)
    bias_hat = bias_std = None
    if with_bias:
        bias_hat, bias_std = _bias_estimate(offsets, est, base)

    # 4. residuals of the estimates on the fitted and on the held-out frames
    return dataset_results(
        ds, settings, base, prior, sums, n_fit, n_val, t_start,
        theta_hat=est.theta,
        theta_std=est.theta_std,
        base_hat=est.beta,
        base_std=est.beta_std,
        success=est.success,
        status=np.asarray(est.status, dtype=object),
        seconds=seconds,
        bias_hat=bias_hat,
        bias_std=bias_std,
    )  # fmt: skip


def dataset_results(ds, settings: SolveSettings, base: BaseParameters, theta_prior: np.ndarray, sums,
                    n_fit: int, n_val: int, t_start: float, **estimates) -> SolveResults:
    """:class:`SolveResults` of estimates on ``ds``, for every solver (the methods and a trained run).

    What every result records the same way: the configurations' file indices, the residual
    RMS on the fitted and held-out frames from ``sums`` (:func:`estimate_residual_sums`, see
    :func:`residual_summary`), the prior, the truth when the dataset has it, and
    :func:`results_meta` with the seconds since ``t_start`` (``time.perf_counter()``).
    ``estimates``: the remaining fields (``theta_hat, theta_std, base_hat, base_std,
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
        theta_true=None if ds.theta_unknown is None else np.asarray(ds.theta_unknown),
        meta=results_meta(ds, time.perf_counter() - t_start),
        **estimates,
    )


def _offset_dof(fit: BaseFit) -> None:
    """Six more fitted unknowns (the offsets): ``s^2 = rss / (6F - r - 6)``, covariance alike."""
    scale = fit.dof / max(fit.dof - 6, 1)
    fit.dof -= 6
    fit.sigma2 *= scale
    fit.cov_beta *= scale


def _bias_estimate(off: Offsets, est: Estimate, base: BaseParameters):
    """Offsets ``b = ybar - Wbar theta_hat`` (C, 6) and their standard deviations.

    ``ybar``'s noise is independent of ``beta_hat`` (fitted on the centred frames), so
    ``var(b_a) = s^2 / (d_a^2 F) + (Wbar T cov(beta) T^T Wbar^T)_aa`` with ``d_a`` the axis
    weight and ``T`` the null-space rule's map (:func:`ineid.identify.linear.prior_map`;
    the linearization for the IPOPT methods). Where a solve failed: NaN.
    """
    from ineid.identify.linear import prior_map  # noqa: PLC0415

    bias = off.bias(est.theta)
    g = np.einsum("cap,pr->car", off.w_mean, prior_map(base))
    var = np.einsum("car,crs,cas->ca", g, np.nan_to_num(est.fit.cov_beta), g)
    var += est.fit.sigma2[:, None] / (est.fit.axis_weights**2 * off.n_frames)
    std = np.sqrt(np.maximum(var, 0.0))
    bad = ~est.success
    bias[bad], std[bad] = np.nan, np.nan
    return bias, std


def _concat_fits(fits: list[BaseFit]) -> BaseFit:
    if len(fits) == 1:
        return fits[0]
    cat = {f.name: np.concatenate([getattr(x, f.name) for x in fits]) for f in dataclasses.fields(BaseFit) if f.name != "dof"}
    return BaseFit(dof=fits[0].dof, **cat)


def estimate_residual_sums(model, ds, n_fit: int, n_val: int, theta_unknown: np.ndarray, sensor=None,
                           offsets: Offsets | None = None):
    """:func:`ineid.identify.fused.residual_sums` of the unknown links' estimates (NaN rows as zeros),
    in the sensor frame, with the offsets ``b = ybar - Wbar theta`` that go with them."""
    theta = model.full_theta(np.nan_to_num(theta_unknown), ds.theta_known)
    bias = None if offsets is None else np.nan_to_num(offsets.bias(theta_unknown))
    frames = slice(0, n_fit + n_val)
    return residual_sums(model, ds.q[:, frames], ds.qd[:, frames], ds.qdd[:, frames], ds.wrench[:, frames],
                         theta, n_fit, sensor, bias)


def residual_summary(sums, n_fit: int, n_val: int, theta_unknown: np.ndarray):
    """``(fit_rms (C, 6), validation_rms (C, 6), validation_rel (C,))`` from :func:`estimate_residual_sums`.

    ``rms_a = sqrt(ssr_a / frames)`` per wrench axis; ``rel = ||R - predicted|| / ||R||`` over the
    held-out frames; NaN where ``theta_unknown`` has a non-finite entry (a failed solve) and,
    for the held-out columns, when no frame is held out.
    """
    ssr_fit, ssr_held, ss_held = sums
    failed = ~np.all(np.isfinite(theta_unknown), axis=1)
    fit_rms = np.sqrt(ssr_fit / n_fit)
    fit_rms[failed] = np.nan
    c = len(theta_unknown)
    if not n_val:
        return fit_rms, np.full((c, 6), np.nan), np.full(c, np.nan)
    val_rms = np.sqrt(ssr_held / n_val)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero wrench: inf (ineid solve warns)
        val_rel = np.sqrt(ssr_held.sum(axis=1)) / np.sqrt(ss_held)
    val_rms[failed] = np.nan
    val_rel[failed] = np.nan
    return fit_rms, val_rms, val_rel


REFERENCE_ROWS = 200_000
"""Frames per batch when configurations are refitted through the stacked QR (reference)."""


def _fused_fit(model, ds, fit_sl, base, settings, axis_sigma, progress,
               blocks_fn=information_blocks, sensor=None) -> tuple[BaseFit, np.ndarray, Offsets | None]:
    """The base fit of every configuration from fused normal-equation blocks (``blocks_fn``),
    ill-conditioned ones refitted through QR of their stacks; the RMS of the weighted data, (C,);
    with ``settings.bias == "estimate"`` the fit of the frames centred per axis, and the means taken out."""
    q, qd, qdd, wrench = (a[:, fit_sl] for a in (ds.q, ds.qd, ds.qdd, ds.wrench))
    with_bias = settings.bias == "estimate"
    extra = {} if sensor is None and not with_bias else {"sensor": sensor, "sums": with_bias}
    if blocks_fn is information_blocks and not with_bias and settings.weights != "estimate":
        # the row weights are known before the frames are read: blocks summed over the axes
        extra["axis_weights"] = axis_weights(settings.weights, axis_sigma, ds.n_configs)
    blocks = blocks_fn(model, base, q, qd, qdd, wrench, ds.theta_known, progress=progress, **extra)
    offsets = None
    if with_bias:
        blocks, offsets = blocks.centred(base)
    fit, refit = fit_base_blocks(blocks, base, settings.weights, axis_sigma)
    rows = np.flatnonzero(refit)
    per = max(1, REFERENCE_ROWS // max(blocks.n_frames, 1))
    for start in range(0, len(rows), per):
        idx = rows[start : start + per]
        w, y = stack(model, q[idx], qd[idx], qdd[idx], wrench[idx], ds.theta_known, sensor)
        if with_bias:
            w, y, _ = remove_offsets(w, y)
        ref = fit_base(w, y, base, settings.weights, axis_sigma)
        for f in dataclasses.fields(BaseFit):
            if f.name != "dof":
                getattr(fit, f.name)[idx] = getattr(ref, f.name)
    _, _, yy = blocks.weighted(fit.axis_weights)
    return fit, np.sqrt(yy / (6 * blocks.n_frames)), offsets


def results_meta(ds, total_seconds: float) -> dict:
    """What a results file records of its dataset (robot, URDF, links, gravity, sensor, path and fingerprint)."""
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
        "total_seconds": total_seconds,
    }


def _casadi_fits(model, ds, fit_sl, base, settings, axis_sigma, progress, sensor=None):
    """The linear fit through CasADi, one configuration at a time (an independent route)."""
    fits, rms, seconds, offsets = [], np.empty(ds.n_configs), np.zeros(ds.n_configs), []
    for i in range(ds.n_configs):
        t0 = time.perf_counter()
        w, y = stack_casadi(model, ds.q[i, fit_sl], ds.qd[i, fit_sl], ds.qdd[i, fit_sl], ds.wrench[i, fit_sl],
                            ds.theta_known, sensor)
        if settings.bias == "estimate":
            wc, yc, off = remove_offsets(w[None], y[None])
            w, y = wc[0], yc[0]
            offsets.append(off)
        f = fit_base(w[None], y[None], base, settings.weights, axis_sigma)
        beta = fit_base_casadi(w, y, base, f.axis_weights[0])
        if f.full_rank[0]:
            f.beta[0] = beta
        fits.append(f)
        rows = np.tile(f.axis_weights[0], y.shape[0] // 6)
        rms[i] = np.sqrt(np.mean((y * rows) ** 2))
        seconds[i] = time.perf_counter() - t0
        if progress is not None:
            progress(i + 1, ds.n_configs)
    return fits, rms, seconds, offsets


def physical_start(theta_lin: np.ndarray, prior: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Linear estimates as IPOPT starts, moved towards the prior until they are rigid bodies.

    Per configuration, ``prior + t (theta_lin - prior)`` with the largest ``t`` in
    ``1, 1/2, ..., 1/64`` whose links all have a positive definite pseudo-inertia, in each
    link's mass and length units (smallest eigenvalue at least 1e-4 of the largest);
    the prior where none does (it must be physical).
    """
    from ineid.identify.nlp import scaled_pseudo_inertia  # noqa: PLC0415

    lin = np.where(np.isfinite(theta_lin), theta_lin, prior)
    c = len(lin)
    start = np.broadcast_to(prior, lin.shape).copy()
    pending = np.ones(c, dtype=bool)
    for t in 0.5 ** np.arange(7):
        cand = prior + t * (lin - prior)
        good = pending.copy()
        for i in np.flatnonzero(pending):
            w = np.linalg.eigvalsh(scaled_pseudo_inertia(cand[i], scales))
            good[i] = bool(np.all(w[:, 0] >= 1e-4 * w[:, -1]))
        start[good] = cand[good]
        pending &= ~good
    return start


BIAS_MAX_ITER = 3000
"""IPOPT iterations with offsets estimated (500 otherwise): centring the frames worsens the scaled
problem's conditioning (``sweaty-arm``: 52 -> 279) and the consistent solver from the CAD start
took 807 iterations on the MuJoCo test recording (a few tenths of a second)."""


def _nlp_options(settings: SolveSettings) -> dict | None:
    return {"max_iter": BIAS_MAX_ITER} if settings.bias == "estimate" else None


def _nlp_worker_init(method, base, prior, pull, entropic, compiled, options=None):
    global _WORKER_SOLVER  # noqa: PLW0603 - one compiled solver per worker process
    _WORKER_SOLVER = NlpSolver.build(method, base, prior, pull, entropic, options, compiled=compiled)


def _nlp_worker(args):
    r, beta, sigma2, rms, start, full_rank = args
    out = []
    for i in range(len(r)):
        t0 = time.perf_counter()
        if not full_rank[i]:
            out.append((None, False, None, time.perf_counter() - t0))
            continue
        th, ok, status, _ = _WORKER_SOLVER.solve_one(r[i], beta[i], sigma2[i], rms[i], start[i])
        out.append((th, ok, status, time.perf_counter() - t0))
    return out


def _run_nlp(fit, base, settings, prior, rms, start, progress) -> tuple[Estimate, np.ndarray]:
    c = fit.beta.shape[0]
    start = np.broadcast_to(start, (c, base.n_params))
    workers = settings.workers or 1
    seconds = np.zeros(c)
    if workers <= 1 or c < PARALLEL_MIN_CONFIGS:
        solver = NlpSolver.build(settings.method, base, prior, settings.pull, settings.entropic,
                                 _nlp_options(settings), compiled=settings.backend == "casadi-c")
        t = [time.perf_counter()]

        def timed(done, total):
            now = time.perf_counter()
            seconds[done - 1] = now - t[0]
            t[0] = now
            if progress is not None:
                progress(done, total)

        est = nlp_estimate(fit, solver, rms, start, progress=timed)
        return est, seconds
    import multiprocessing as mp  # noqa: PLC0415
    from concurrent.futures import ProcessPoolExecutor  # noqa: PLC0415

    block = max(8, min(256, c // (4 * workers)))
    jobs = [
        (fit.R[i:i + block], fit.beta[i:i + block], fit.sigma2[i:i + block], rms[i:i + block], start[i:i + block],
         fit.full_rank[i:i + block])
        for i in range(0, c, block)
    ]  # fmt: skip
    theta = np.full((c, base.n_params), np.nan)
    success = np.zeros(c, dtype=bool)
    status = np.empty(c, dtype=object)
    ctx = mp.get_context("spawn")  # JAX's threads and fork do not mix
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_nlp_worker_init,
                             initargs=(settings.method, base, prior, settings.pull, settings.entropic,
                                       settings.backend == "casadi-c", _nlp_options(settings))) as pool:
        done = 0
        for j, out in enumerate(pool.map(_nlp_worker, jobs)):
            for k, (th, ok, st, sec) in enumerate(out):
                i = j * block + k
                seconds[i] = sec
                if th is None:
                    status[i] = f"rank_deficient ({fit.rank[i]} of {base.rank})"
                    continue
                success[i] = ok
                status[i] = "ok" if ok else st
                if ok:
                    theta[i] = th
            done += len(out)
            if progress is not None:
                progress(done, c)
    return estimate_from_solves(theta, success, status, fit, base), seconds


def identify_frames(
    model,
    q,
    qd,
    qdd,
    wrench,
    method: str = "linear",
    weights: str = "none",
    axis_sigma=None,
    start: str = "prior",
    bias: str = "none",
    sensor_pose=None,
) -> SolveResults:
    """Identify the unknown links from one set of frames (a recording); all frames are fitted.

    Args:
        model: the :class:`ineid.RobotModel` (unknown links, gravity, CAD prior).
        q, qd, qdd: (F, n_dof); wrench: (F, 6), the sensor reading in ineid's convention.
        method, weights, axis_sigma, start, bias: as in :class:`SolveSettings`.
        sensor_pose: the :class:`ineid.sensor.SensorPose` the wrench is read in (None: the base frame).

    Returns:
        One-row :class:`SolveResults` (``theta_hat[0]``, ``theta_std[0]``, ``base_hat[0]``, ...).

    Raises:
        IdentificationError: too few frames, frames that do not determine the base
            parameters (with what is missing), or an IPOPT failure (``.status`` holds
            IPOPT's return status).
    """
    from ineid.data.schema import Dataset, DatasetMeta  # noqa: PLC0415
    from ineid.identify.identifiability import analyze_frames  # noqa: PLC0415

    arrays = [np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench)]
    for label, a, width in zip(("q", "qd", "qdd", "wrench"), arrays, (model.n_dof,) * 3 + (6,), strict=True):
        if a.ndim != 2 or a.shape[1] != width or len(a) != len(arrays[0]):
            raise ValueError(f"{label} must have shape (n_frames, {width}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise IdentificationError(f"{label} holds NaN or infinite values; drop or repair those frames",
                                      status="non_finite")
    base = base_parameters(model, bias=bias == "estimate")
    check_frames(len(arrays[0]), base.rank + 6 * (bias == "estimate"))
    analysis = analyze_frames(model, *arrays[:3], base, bias=bias == "estimate")
    if not analysis.ok:
        raise IdentificationError(analysis.problem(), status="rank_deficient")
    meta = DatasetMeta.for_model(model, source="recording",
                                 sensor=None if sensor_pose is None else sensor_pose.to_dict())
    ds = Dataset(meta, *(a[None] for a in arrays), theta_known=model.theta_cad[model.known_index])
    res = solve_dataset(
        ds,
        SolveSettings(method=method, frames=len(arrays[0]), weights=weights,
                      axis_sigma=None if axis_sigma is None else tuple(axis_sigma), start=start, bias=bias),
        model=model,
    )  # fmt: skip
    if not res.success[0]:
        raise IdentificationError(
            f"the {method} solver failed ({res.status[0]}); try start='linear', more frames, or the linear method",
            status=str(res.status[0]),
        )
    return res


def predicted_wrench(model, ds, theta_u, frames=slice(None), sensor=None, bias=None) -> np.ndarray:
    """What the estimates predict the sensor reads: ``X Psi theta + b`` (C, F, 6) on ``frames`` of ``ds``.

    Args:
        theta_u: (C, 10 n_u) the unknown links' estimates (the known links' come from ``ds``).
        sensor: the 6x6 wrench transform (default: the dataset's sensor pose).
        bias: (C, 6) estimated offsets, or None.
    """
    sensor = ds.meta.sensor_transform() if sensor is None else sensor
    theta = model.full_theta(np.nan_to_num(theta_u), ds.theta_known)
    w = predict_wrench(model, ds.q[:, frames], ds.qd[:, frames], ds.qdd[:, frames], theta, sensor)
    return w if bias is None else w + np.nan_to_num(bias)[:, None, :]
