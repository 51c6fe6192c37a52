"""The held-out and residual checks of a solve (:mod:`ineid.identify.plausibility` runs them).

* held-out error (``held_out_error``): the median over the configurations of the relative error on the
  held-out frames (a ``--validate`` recording's, the held-out frames, or the fitted frames when none are held
  out; with offsets estimated, relative to the measurement less its mean over the frames the offsets were
  fitted on) above :data:`HELD_OUT_ERROR` on a residual above the noise: the model explains almost nothing;
* residual above the noise (:func:`check_residual_noise`, ``residual_above_noise``): the held-out (else fitted)
  residual RMS more than ``NOISE_FACTOR`` times the noise of :func:`ineid.identify.noise_figures.axis_noise`.
"""

from __future__ import annotations

import math

import numpy as np

from ineid.data.recordings.plausibility import Finding
from ineid.identify.noise_figures import NEGLIGIBLE, NOISE_FACTOR, axis_noise
from ineid.identify.unit_fits import fitted_channels

HELD_OUT_ERROR = 0.5
"""A median relative held-out wrench error above this warns (1: the model explains nothing)."""


def _held_out_frames(res, ds, validate):
    """``(measured (C, F, A), rms (C, A), dataset, where)`` of the frames the held-out check judges: the
    separate validation recording (``validate``), the held-out frames of ``ds``, or its fitted frames (none
    held out, or a validation recording not given with offsets fitted on it); the measurements centred on the
    axes whose offsets were fitted, each on the frames they were fitted on (a validation recording's on itself,
    ``ds``'s on its fitted frames)."""
    channels = fitted_channels(res, ds)  # every axis the fit saw
    mask = channels.offset_mask(ds.meta) if res.bias_hat is not None else None
    separate = bool(res.meta.get("validation")) and res.n_frames_validation
    if separate and validate is not None:
        w = np.asarray(validate.measured(channels), dtype=np.float64)
        if mask is not None:
            w = w - w.mean(axis=1, keepdims=True) * mask
        return w, res.validation_rms, validate, "held-out"
    if res.n_frames_validation and not separate:
        frames = slice(res.n_frames_fit, res.n_frames_fit + res.n_frames_validation)
        rms, where = res.validation_rms, "held-out"
    else:
        frames, rms, where = slice(0, res.n_frames_fit), res.fit_rms, "fitted"
    measured = ds.measured(channels)
    w = np.asarray(measured[:, frames], dtype=np.float64)
    if mask is not None:
        w = w - np.asarray(measured[:, : res.n_frames_fit], dtype=np.float64).mean(axis=1, keepdims=True) * mask
    return w, rms, ds, where


def _held_out_errors(res, ds, validate=None) -> tuple[np.ndarray, str, np.ndarray, object]:
    """Per configuration the relative error the held-out check uses, which frames it is on, their residual RMS
    per axis (C, A) and the dataset they are of.

    Without offsets, ``validation_rel`` (on the held-out frames of ``ds`` or a validation recording). With
    offsets estimated the offsets explain any constant (a zero wrench too: the fit then cancels the known links
    and takes their weight as an offset), so the error is taken relative to the wrench less its mean over the
    frames the offsets were fitted on: a validation recording's, whose offsets are fitted alone on it, its own.
    """
    if res.bias_hat is None and res.n_frames_validation:
        rel, rms = np.asarray(res.validation_rel, dtype=np.float64), np.asarray(res.validation_rms, dtype=np.float64)
        return rel, "held-out", rms, ds if validate is None else validate
    w, rms, frames_of, where = _held_out_frames(res, ds, validate)
    rms = np.asarray(rms, dtype=np.float64)
    ss = np.sum(w**2, axis=(1, 2))
    ssr = np.sum(rms**2, axis=1) * w.shape[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(ssr) / np.sqrt(ss), where, rms, frames_of


def _noise_ratios(res, frames_of, rms: np.ndarray, model) -> np.ndarray | None:
    """(C', A) the residual RMS (C, A) of the solved configurations over the noise (:func:`axis_noise`, with the
    angles' noise through the first solved configuration's prediction); None where the noise is unknown."""
    ok = np.flatnonzero(np.asarray(res.success, dtype=bool))
    if model is None or not len(ok):
        return None
    channels = fitted_channels(res, frames_of)
    row = min(int(ok[0]), frames_of.n_configs - 1)
    noise, _ = axis_noise(frames_of, channels, model, np.asarray(res.theta_hat)[ok[0]], row)
    if noise is None or not np.all(np.isfinite(noise)):
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rms[ok] > 0, rms[ok] / noise, 0.0)


def _within_noise(res, frames_of, rms: np.ndarray, model) -> bool:
    """Whether the residual RMS (C, A) stays within ``NOISE_FACTOR`` times the noise on every axis of most solved
    configurations: what is left is noise, not a model that explains nothing. False where the noise is unknown."""
    ratios = _noise_ratios(res, frames_of, rms, model)
    return ratios is not None and bool(np.all(ratios <= NOISE_FACTOR, axis=1).mean() > 0.5)


def check_residual_noise(res, ds, validate=None, model=None) -> Finding | None:
    """A residual RMS (on the held-out frames, else the fitted ones) above ``NOISE_FACTOR`` times the noise
    (:func:`ineid.identify.noise_figures.axis_noise`) and above ``NEGLIGIBLE`` of the measurements' RMS, on any axis
    (median over the solved configurations): the model misses something the noise does not explain.

    Args: as :func:`check_held_out_error`.
    """
    ok = np.asarray(res.success, dtype=bool)
    if model is None or not ok.any():
        return None
    w, rms, frames_of, where = _held_out_frames(res, ds, validate)
    ratios = _noise_ratios(res, frames_of, np.asarray(rms, dtype=np.float64), model)
    if ratios is None:
        return None
    scale = np.sqrt(np.mean(w[ok] ** 2, axis=1))
    ratio = np.median(np.where(np.asarray(rms, dtype=np.float64)[ok] > NEGLIGIBLE * scale, ratios, 0.0), axis=0)
    bad = np.flatnonzero(ratio > NOISE_FACTOR)
    if not len(bad):
        return None
    names = fitted_channels(res, frames_of).axes(model)
    shown = ", ".join(
        f"{names[a]} {ratio[a]:.3g}x" if np.isfinite(ratio[a]) else f"{names[a]} (clean data)" for a in bad[:6]
    )
    return Finding(
        "residual_above_noise",
        f"the {where} frames' residual RMS is more than {NOISE_FACTOR:g} x the noise on {len(bad)} of {len(names)} "
        f"axes ({shown}): the model misses something; check the sensor pose (data import --sensor-pose), the known "
        "links' CAD values, friction (joint torques) and the delay (data import --delay auto)",
    )


def check_held_out_error(res, ds, validate=None, model=None) -> Finding | None:
    """A model that explains almost nothing: median relative error above :data:`HELD_OUT_ERROR`, on a residual
    above the noise.

    The relative error is against the held-out measurements' spread (about their mean where offsets were
    fitted: :func:`_held_out_errors`); a residual within ``NOISE_FACTOR`` times the noise on every axis
    (:func:`ineid.identify.noise_figures.axis_noise`: stated by a synthetic dataset, estimated at import for
    a recording) is noise, whatever that error (a wrench that hardly varies): no warning.

    Args:
        res: the :class:`ineid.identify.SolveResults` of ``ds``.
        ds: the solved :class:`ineid.data.Dataset` (its configurations in ``res``'s order).
        validate: the separate validation recording ``res`` was validated on (``solve --validate``), or None.
        model: its :class:`ineid.RobotModel` (None: the noise is not consulted).
    """
    ok = np.asarray(res.success, dtype=bool)
    if not ok.any():
        return None
    err, where, rms, frames_of = _held_out_errors(res, ds, validate)
    err = err[ok]
    err = np.where(np.isnan(err), np.inf, err)  # 0 / 0: a zero wrench and a zero prediction
    with np.errstate(invalid="ignore"):  # inf - inf between the two middle values: NaN, taken as inf
        median = float(np.median(err))
    median = math.inf if math.isnan(median) else median
    if not median > HELD_OUT_ERROR:
        return None
    if math.isfinite(median) and _within_noise(res, frames_of, rms, model):
        return None
    shown = (
        f"error {median:.3g}"
        if math.isfinite(median)
        else (f"the {where} wrench is " + ("constant" if res.bias_hat is not None else "zero"))
    )
    untared = ", an untared sensor (solve --bias estimate)" if res.settings.bias == "none" else ""
    return Finding(
        "held_out_error",
        f"the model explains almost nothing of the {where} wrench ({shown}"
        + (f", median over {len(err)} configurations" if len(err) > 1 else "")
        + "): check the units, the wrench's sign (data import --flip-wrench), the sensor pose (--sensor-pose), "
        f"the time alignment (data import --delay auto){untared}, "
        "or whether the wrench channel holds the sensor at all",
    )
