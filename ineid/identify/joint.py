"""Several recordings of one robot fitted jointly, and the prediction error on a separate one.

``ineid solve a.h5 b.h5 ... --validate c.h5``: configuration ``i`` of every input (the same
selection of each; a recording has one) is one identification, fitted from the frames of
all inputs together. A factor of stacked rows is the factor of the stacked factors, so each
input's per-axis triangular factors (:mod:`ineid.identify.qr_blocks`, one compiled kernel for every
input and the validation recording) are joined, and the fit is the QR of every input's rows to
round-off, its residuals exact without another pass over the frames; with ``bias="estimate"``
each input is centred on its own first (its own offsets: a sensor tared differently, or not at
all, per session; Frisch-Waugh-Lovell as in :class:`ineid.identify.systems.Offsets`), which
costs one residual degree of freedom per offset and input. Every frame of the inputs is fitted (no
frames held out); the validation
recording is predicted with the fitted parameters, its residual RMS per axis and relative
error ``||w - w_hat|| / ||w||`` reported. With ``bias="estimate"`` its own offsets are
unknown too: they are fitted alone on it with the parameters fixed (the mean residual per
axis taken out), so the figures measure the parameters, not the offsets.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from ineid.errors import IdentificationError
from ineid.identify.choose import noise_levels, solve_channels
from ineid.identify.constrained_std import std_record
from ineid.identify.extras import prior_with_extras
from ineid.identify.identifiability import BaseParameters, base_parameters, frame_minimum
from ineid.identify.known import with_known_uncertainty
from ineid.identify.least_squares import BaseFit, subtract_offset_dof
from ineid.identify.linear import Estimate, SharedFit, linear_theta
from ineid.identify.qr_blocks import FactorBlocks, factor_blocks, fit_base_factors
from ineid.identify.settings import SolveSettings
from ineid.identify.solve import ESTIMATORS
from ineid.identify.solve_results import SolveResults, results_meta, truth_with_extras
from ineid.identify.steps import bias_estimate, predicted_wrench
from ineid.identify.systems import check_frames
from ineid.identify.time_correlation import FittedFrames, filtered_frames, recording_covariance
from ineid.progress import Progress


def _robot_of(ds) -> tuple:
    m = ds.meta
    return (m.urdf, tuple(m.unknown_links), np.asarray(m.gravity).tolist(), m.locked_joints or {}, m.channels.to_list())


def _label(ds, i: int) -> str:
    return str(ds.path) if ds.path is not None else f"input {i + 1}"


def _file_label(ds, fallback: str) -> str:
    """What names a dataset in a message: its path, else the file it was imported from, else ``fallback``."""
    if ds.path is not None:
        return str(ds.path)
    origin = getattr(ds.meta, "origin", None)
    return str(origin["file"]) if isinstance(origin, dict) and origin.get("file") else fallback


def check_same_robot(datasets, validate=None) -> None:
    """Refuse recordings of different robots (URDF, unknown links, gravity, locked joints, channels) in one line.

    Raises:
        IdentificationError: status ``different_robots``; ``config_mismatch`` when the inputs
            hold different numbers of configurations; ``different_bodies`` for synthetic datasets
            whose true parameters differ (nothing joint to fit).
    """
    everything = [*datasets, *([] if validate is None else [validate])]
    first = everything[0]
    for i, ds in enumerate(everything[1:], start=1):
        if _robot_of(ds) != _robot_of(first):
            what = [
                n
                for n, a, b in zip(
                    ("URDF", "unknown links", "gravity", "locked joints", "channels"),
                    _robot_of(first),
                    _robot_of(ds),
                    strict=True,
                )
                if a != b
            ]
            role = "--validate" if validate is not None and ds is validate else "input"
            raise IdentificationError(
                f"{role} {_label(ds, i)} is a recording of robot {ds.meta.robot!r} but {_label(first, 0)} is of "
                f"{first.meta.robot!r} (they differ in {', '.join(what)}): fit and validate with recordings of one "
                "robot, the same URDF, unknown links and channels",
                status="different_robots",
            )
        if ds.n_configs != first.n_configs:
            raise IdentificationError(
                f"{_label(ds, i)} holds {ds.n_configs} configurations and {_label(first, 0)} {first.n_configs}: "
                "select the same number from each (--select), configuration i of each is fitted together",
                status="config_mismatch",
            )
        if (
            ds.theta_unknown is not None
            and first.theta_unknown is not None
            and not np.allclose(ds.theta_unknown, first.theta_unknown, rtol=1e-12, atol=0.0)
        ):
            raise IdentificationError(
                f"{_label(ds, i)} and {_label(first, 0)} are synthetic datasets of different true parameters "
                "(other seeds or sampling): a joint fit needs recordings of the same bodies; split one dataset's "
                "frames instead",
                status="different_bodies",
            )


JOINT_METHODS = ("linear", "nonlinear", "consistent")
"""The methods that fit several recordings jointly (with backend ``jax``)."""


def solve_recordings(
    datasets,
    settings: SolveSettings,
    model=None,
    validate=None,
    progress: Progress | None = None,
    mixed_filters: bool = False,
) -> SolveResults:
    """Identify from several recordings jointly; optionally report the prediction error on ``validate``.

    Args:
        datasets: :class:`ineid.data.Dataset` s of one robot, the same number of configurations each.
        settings: a :class:`ineid.identify.SolveSettings` (``backend="jax"``; ``frames`` must be None:
            every frame of the inputs is fitted).
        model: the robot (default: rebuilt from the first dataset).
        validate: a dataset of the same robot (same configurations count), or None.
        progress: ``progress(done, total)`` over configurations of the IPOPT methods.
        mixed_filters: fit (and validate on) recordings imported with different filters
            (:func:`ineid.data.recordings.filters.check_filters`); their difference, in words, is then
            ``meta["mixed_filters"]`` (``ineid solve --mixed-filters``).

    Returns:
        :class:`SolveResults` whose ``fit_rms`` is over all inputs' frames and whose
        ``validation_rms``, ``validation_rel`` and ``n_frames_validation`` are of ``validate``
        (NaN, 0 without it); ``meta["recordings"]`` lists the inputs (path, fingerprint, frames,
        and their offsets with ``bias="estimate"``), ``meta["validation"]`` the validation
        recording and its figures.

    Raises:
        IdentificationError: recordings of different robots, different configuration counts,
            too few frames, or settings this route does not take.
        DatasetError: recordings imported with different filters (cut-off, filter, an estimated wrench delay)
            fitted or validated together, without ``mixed_filters``.
    """
    from ineid.data.recordings.filters import check_filters

    datasets = list(datasets)
    check_same_robot(datasets, validate)
    labelled = [(_file_label(d, f"input {i + 1}"), d) for i, d in enumerate(datasets)]
    if validate is not None:
        labelled.append((_file_label(validate, "the validation recording"), validate))
    mixed = check_filters(labelled, mixed_filters)
    _check_joint_settings(settings)
    t_start = time.perf_counter()
    ds0 = datasets[0]
    model = model or ds0.model()
    with_bias = settings.estimates_offsets
    channels = solve_channels(ds0, settings, model)
    mask = channels.offset_mask(model) if with_bias else None
    base = base_parameters(model, bias=with_bias, channels=channels)
    prior = prior_with_extras(model, channels)  # [theta_cad_u, 0 for each extra parameter]
    n_total = sum(d.n_frames for d in datasets)
    if with_bias:  # each input centred on its own: counting, the per-configuration rank checks do the rest
        check_frames(n_total, base.rank + int(mask.sum()) * len(datasets), channels.n_axes(model))
    else:  # the inputs' frames stacked: the structural minimum (ineid.identify.frame_minimum)
        frame_minimum(model, False, channels).require(n_total)
    axis_sigma = noise_levels(ds0, settings, channels, model)

    # 1. the triangular factors of each input (centred on its own with offsets), joined, and their base fit
    longest = max(d.n_frames for d in [*datasets, *([] if validate is None else [validate])])
    factors, offsets = _input_factors(datasets, model, base, channels, mask, longest)
    fit = _joint_fit(factors, base, settings.weights, axis_sigma, mask)

    # 2. the residuals of every input at the linear estimate, from the factors: exact, no pass over the frames
    def residuals(theta):
        return _factor_residuals(factors, base, theta)

    theta_lin = linear_theta(fit, base, prior)
    taken = offsets or [None] * len(datasets)
    parts = [FittedFrames(d, slice(None), o, filtered_frames(d)) for d, o in zip(datasets, taken, strict=True)]
    fit = recording_covariance(model, parts, base, fit, channels, theta_lin)  # filtered recordings' frames
    if settings.known_uncertainty:
        fit = with_known_uncertainty(
            fit, model, base, datasets, slice(None), channels, settings.known_uncertainty, with_bias
        )

    # 3. standard parameters, by the method (ineid.identify.solve.ESTIMATORS)
    e = _joined(factors).information().e
    rms = np.sqrt(np.einsum("ca,ca->c", fit.axis_weights**2, e) / (channels.n_axes(model) * n_total))
    est = ESTIMATORS[settings.method](SharedFit(base, prior, fit, theta_lin, rms), settings, progress).estimate
    fit_rms = np.sqrt(residuals(est.theta) / n_total)
    fit_rms[~np.all(np.isfinite(est.theta), axis=1)] = np.nan

    # 4. the offsets of each input, the validation recording
    recordings = _recordings_meta(datasets, est, base, offsets)
    meta = results_meta(ds0, 0.0, channels, model)
    val_rms, val_rel, n_val = _validation(model, base, validate, est, channels, mask, meta, longest)
    meta["recordings"] = recordings
    if mixed is not None:
        meta["mixed_filters"] = mixed.message
    meta["std"] = std_record(datasets, est)
    meta["total_seconds"] = time.perf_counter() - t_start
    return _joint_results(settings, ds0, base, prior, est, fit_rms, (val_rms, val_rel, n_val), n_total, meta)


def _joint_results(settings, ds0, base: BaseParameters, prior, est: Estimate, fit_rms, validation, n_total, meta):
    """The :class:`SolveResults` of a joint fit: the estimates, the residual RMS over every input's frames
    (``fit_rms``), ``validation = (rms, rel, frames)`` of the validation recording, the offsets of the first
    input (``meta["recordings"]`` holds every input's), the seconds shared out over the configurations."""
    c = ds0.n_configs
    first = meta["recordings"][0]
    val_rms, val_rel, n_val = validation
    return SolveResults(
        settings=settings,
        base=base,
        param_names=tuple(base.param_names),
        config_index=np.asarray(ds0.config_index, dtype=np.int64),
        theta_hat=est.theta,
        theta_std=est.theta_std,
        base_hat=est.beta,
        base_std=est.beta_std,
        success=est.success,
        status=np.asarray(est.status, dtype=object),
        seconds=np.full(c, meta["total_seconds"] / max(c, 1)),
        fit_rms=fit_rms,
        validation_rms=val_rms,
        validation_rel=val_rel,
        n_frames_fit=n_total,
        n_frames_validation=n_val,
        theta_prior=prior,
        theta_true=truth_with_extras(ds0, base),
        meta=meta,
        bias_hat=np.asarray(first["bias_hat"]) if "bias_hat" in first else None,
        bias_std=np.asarray(first["bias_std"]) if "bias_std" in first else None,
    )


def _check_joint_settings(settings: SolveSettings) -> None:
    """Refuse what several recordings are not fitted with (``IdentificationError``, status ``unsupported``)."""
    if settings.method not in JOINT_METHODS or settings.backend != "jax":
        raise IdentificationError(
            "several recordings or --validate are fitted by the linear, nonlinear and "
            "consistent methods with backend 'jax'",
            status="unsupported",
        )
    if settings.two_step:
        raise IdentificationError(
            "--two-step fits one dataset; leave it out with several recordings or --validate", status="unsupported"
        )
    if settings.frames is not None:
        raise IdentificationError(
            "with several recordings or --validate every frame of the inputs is fitted: "
            "leave out --fit-frames (--validate holds out a whole recording)",
            status="unsupported",
        )


def _input_factors(datasets, model, base: BaseParameters, channels, mask, longest: int) -> tuple[list, list]:
    """Each input's :func:`ineid.identify.qr_blocks.factor_blocks` (one compiled shape, for ``longest`` frames),
    and the offsets taken out of each (each centred on its own on ``mask``'s axes; none when ``mask`` is None)."""
    factors, offsets = [], []
    for ds in datasets:
        f = factor_blocks(
            model,
            base,
            ds.q,
            ds.qd,
            ds.qdd,
            ds.measured(channels),
            ds.theta_known,
            channels,
            offsets=mask is not None,
            n_frames_max=longest,
        )
        if mask is not None:
            f, off = f.centred(mask)
            offsets.append(off)
        factors.append(f)
    return factors, offsets


def _joined(factors: list[FactorBlocks]) -> FactorBlocks:
    return functools.reduce(FactorBlocks.joined, factors)


def _factor_residuals(factors: list[FactorBlocks], base: BaseParameters, theta: np.ndarray) -> np.ndarray:
    """(C, A) the residual sum of squares per axis of ``theta`` (C, n; NaN rows as zeros) over every input, each
    with its own offsets ``b = ybar - Wbar theta`` where they were taken out: ``sum_k |Rt_k [beta; -1]|^2``,
    ``beta = B theta`` (``W theta = W_b B theta`` for every frame)."""
    beta = np.nan_to_num(np.asarray(theta, dtype=np.float64)[:, : base.n_params]) @ base.B.T
    return sum(f.axis_rss(beta) for f in factors)


def _joint_fit(factors: list[FactorBlocks], base: BaseParameters, weights: str, axis_sigma, mask) -> BaseFit:
    """The base fit of every input's frames together from their joined factors (the QR of every stacked row, to
    round-off), one residual degree of freedom less per offset and input."""
    lost = mask.astype(np.float64) * len(factors) if mask is not None else None
    fit = fit_base_factors(_joined(factors), base, weights, axis_sigma, lost)
    if mask is not None:
        subtract_offset_dof(fit, int(mask.sum()) * len(factors))
    return fit


def _recordings_meta(datasets, est: Estimate, base: BaseParameters, offsets: list) -> list[dict]:
    """``meta["recordings"]``: each input's path, fingerprint and frames, and its offsets and their standard
    deviations (:func:`ineid.identify.steps.bias_estimate`) when they were fitted."""
    recordings = []
    for k, d in enumerate(datasets):
        rec = {"path": None if d.path is None else str(d.path), "fingerprint": d.fingerprint(), "n_frames": d.n_frames}
        if offsets:
            b, s = bias_estimate(offsets[k], est, base)
            rec.update(bias_hat=b.tolist(), bias_std=s.tolist())
        recordings.append(rec)
    return recordings


def _validation(
    model, base: BaseParameters, validate, est: Estimate, channels, mask, meta: dict, longest: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """``(rms (C, A), rel (C,), frames)`` of ``validate`` (as :func:`validation_error`, from its triangular
    factors: the fit's compiled kernel, its offsets on ``mask``'s axes fitted alone on it by centring), recorded
    in ``meta["validation"]``; NaN and 0 without it."""
    c = len(est.theta)
    if validate is None:
        return np.full((c, channels.n_axes(model)), np.nan), np.full(c, np.nan), 0
    (factors,), _ = _input_factors([validate], model, base, channels, mask, longest)
    ssr = _factor_residuals([factors], base, est.theta)
    measured = validate.measured(channels)
    val_rms = np.sqrt(ssr / validate.n_frames)
    with np.errstate(divide="ignore", invalid="ignore"):
        val_rel = np.sqrt(ssr.sum(axis=1)) / np.linalg.norm(measured, axis=(1, 2))
    failed = ~np.all(np.isfinite(est.theta), axis=1)
    val_rms[failed], val_rel[failed] = np.nan, np.nan
    ok = est.success
    meta["validation"] = {
        "path": None if validate.path is None else str(validate.path),
        "fingerprint": validate.fingerprint(),
        "n_frames": validate.n_frames,
        "offsets": "fitted alone on it, parameters fixed" if mask is not None else "none",
        "rms": np.median(val_rms[ok], axis=0).tolist() if ok.any() else None,
        "rel": float(np.median(val_rel[ok])) if ok.any() else None,
    }
    return val_rms, val_rel, validate.n_frames


def validation_error(model, ds, theta_u, channels, offset_mask=None) -> tuple[np.ndarray, np.ndarray]:
    """``(rms (C, A), rel (C,))`` of ``ds``'s measurements against the prediction of ``theta_u`` (C, 10 n_u).

    ``offset_mask`` (A,) bool: those axes' offsets are fitted alone on ``ds`` with the
    parameters fixed (the mean residual taken out); None: none. NaN where ``theta_u`` is not finite.
    """
    measured = ds.measured(channels)
    resid = measured - predicted_wrench(model, ds, theta_u, channels=channels)
    if offset_mask is not None:
        resid = resid - resid.mean(axis=1, keepdims=True) * offset_mask
    rms = np.sqrt(np.mean(resid**2, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.linalg.norm(resid, axis=(1, 2)) / np.linalg.norm(measured, axis=(1, 2))
    failed = ~np.all(np.isfinite(theta_u), axis=1)
    rms[failed], rel[failed] = np.nan, np.nan
    return rms, rel
