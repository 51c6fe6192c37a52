"""The noise a fit's residual is judged against, and the unmodelled-offset check.

**Noise per axis** (:func:`axis_noise`), what a model that explains the signal leaves:

* a synthetic dataset: the noise its settings state (``meta.noise``; clean data: 0; glitches counted: a share
  ``r`` of the frames with force noise ``s`` times larger makes the force noise's std ``sqrt(1 - r + r s^2)`` times
  the rest's), plus what its stated ``q``, ``qd``, ``qdd`` noise does to the prediction (as below);
* a recording: the import's own estimate (:mod:`ineid.data.recordings.noise_estimate`: the raw streams' part
  above the cut-off, scaled by the filter's noise bandwidth), plus, with estimates given, what the joint
  angles' noise does to the prediction: the frames' ``q``, ``qd``, ``qdd`` noise (the angles' own, through the
  filter and the central differences) times the prediction's sensitivity to each, by finite differences on
  :data:`SENSITIVITY_FRAMES` frames, ``sigma_a^2 = sigma_sensor^2 + mean_frames sum_j (dw_a / dx_j sigma_x_j)^2``;
* else unknown (None).

**Unmodelled offsets** (:func:`check_offsets`, ``unmodelled_offsets``): on the axes whose offsets the fit did not
identify (``--bias estimate`` for a wrench, ``--torque-offset`` for joint torques), the mean of the fitted
frames' residual more than :data:`OFFSET_FACTOR` times the sensor noise (and above :data:`NEGLIGIBLE` of the
axis's RMS) with ``|z| > OFFSET_Z``, ``z = mean / (std sqrt(tau / n))``: ``tau`` the residual's integrated
autocorrelation time (:func:`correlation_time`; 1 for frames that are no time series), so a low-passed residual,
whose samples are far from independent, does not pass for evidence. A least-squares residual has no mean along
a column the fit holds (gravity along the base's z takes a constant force there into the mass), so what shows
is an offset the model cannot hold.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ineid.data.recordings.noise_estimate import frames_noise
from ineid.data.recordings.plausibility import Finding

NOISE_FACTOR = 3.0
"""A residual RMS within this multiple of the noise is noise (above it: a model error,
:mod:`ineid.report.residuals`)."""
SENSITIVITY_FRAMES = 48
"""Frames (evenly spread) the prediction's sensitivity to the angles' noise is averaged over."""
OFFSET_FACTOR = 3.0
"""A residual mean above this multiple of the sensor noise (per frame) may be an offset."""
OFFSET_Z = 5.0
"""And it must stand this many standard errors off zero (the residuals' correlation in time counted)."""
NEGLIGIBLE = 1e-3
"""A residual mean below this fraction of the axis's RMS is no offset whatever the noise (noise-free data)."""
MAX_CONFIGS = 4
"""Configurations the offset check looks at (the first solved ones): the mean of one needs its whole residual."""


def sensor_noise(meta, channels, model) -> tuple[np.ndarray | None, str]:
    """``(noise (A,), source)``: the noise std per stacked axis of ``channels`` that ``meta`` states (synthetic) or
    its import estimated (a recording; NaN on a channel it did not measure), or ``(None, why not)``."""
    n_axes = channels.n_axes(model)
    if meta.source == "synthetic":
        out = np.zeros(n_axes)
        stated = meta.noise or {}
        # glitches: a share r of the frames with force noise s times larger, std sqrt(1 - r + r s^2) times the rest
        glitch = math.sqrt(
            1 + float(stated.get("glitch_rate", 0.0)) * (float(stated.get("glitch_scale", 1.0)) ** 2 - 1)
        )
        for b in channels.blocks(model):
            values = stated.get(b.channel.key)
            if values is not None:
                out[b.start : b.stop] = np.broadcast_to(np.asarray(values, dtype=np.float64), (b.stop - b.start,))
                if "wrench" in b.channel.kind:
                    out[b.start : b.start + 3] *= glitch
        return out, (
            "stated by the synthetic dataset (its noise settings)" if meta.noise else "none: clean synthetic data"
        )
    recorded = frames_noise(meta.origin) if meta.source == "recording" else None
    if recorded is None:
        return None, "unknown (a recording imported without a noise estimate: import it again)"
    out = np.full(n_axes, np.nan)
    for b in channels.blocks(model):
        values = recorded.get(b.channel.key)
        if values is not None and len(values) == b.stop - b.start:
            out[b.start : b.stop] = values
    method = (meta.origin or {}).get("noise", {}).get("method", "the raw streams")
    return out, f"estimated at import from {method}"


def state_noise(meta, n_dof: int) -> dict[str, np.ndarray]:
    """Per state (``q``, ``qd``, ``qdd``) the frames' noise std per joint: a synthetic dataset's stated, a
    recording's import estimate (through the filter and the differences); empty when neither says."""
    if meta.source == "synthetic":
        record = meta.noise or {}
    else:
        record = (frames_noise(meta.origin) if meta.source == "recording" else None) or {}
    out = {}
    for k in ("q", "qd", "qdd"):
        if k in record:
            values = np.nan_to_num(np.asarray(record[k], dtype=np.float64))
            out[k] = np.broadcast_to(values, (n_dof,)).copy()
    return {k: v for k, v in out.items() if np.any(v > 0)}


def prediction_noise(model, ds, theta_u, channels, config: int = 0) -> np.ndarray | None:
    """(A,) the std the joint states' noise (:func:`state_noise`) gives the prediction of ``theta_u`` (one
    configuration's estimates, links and extras) on configuration row ``config`` of ``ds`` (module docstring);
    None when no state noise is known."""
    from ineid.identify.steps import predicted_wrench

    sigma = state_noise(ds.meta, ds.n_dof)
    if not sigma or not np.all(np.isfinite(theta_u)):
        return None
    pick = np.unique(np.linspace(0, ds.n_frames - 1, min(SENSITIVITY_FRAMES, ds.n_frames)).astype(int))
    base = {k: np.asarray(getattr(ds, k)[config, pick], dtype=np.float64) for k in ("q", "qd", "qdd")}
    states = [base]
    for k, s in sigma.items():
        for j in np.flatnonzero(s > 0):
            for sign in (1.0, -1.0):
                moved = dict(base)
                moved[k] = base[k].copy()
                moved[k][:, j] += sign * s[j]
                states.append(moved)
    stacked = SimpleNamespace(
        **{k: np.concatenate([st[k] for st in states])[None] for k in ("q", "qd", "qdd")},
        theta_known=_known_of(ds, [config]),
        meta=ds.meta,
    )
    w = predicted_wrench(model, stacked, np.asarray(theta_u, dtype=np.float64)[None], channels=channels)[0]
    w = w.reshape(len(states), len(pick), -1)
    steps = (w[1::2] - w[2::2]) / 2  # central differences: sensitivity times the noise's std
    return np.sqrt(np.mean(np.sum(steps**2, axis=0), axis=0))


def _known_of(ds, rows):
    """The known links' parameters of configuration rows ``rows`` (one set for all, or one per configuration)."""
    known = np.asarray(ds.theta_known, dtype=np.float64)
    return known if known.ndim < 2 else known[rows]


def axis_noise(ds, channels, model, theta_u=None, config: int = 0) -> tuple[np.ndarray | None, str]:
    """``(noise (A,), source)``: :func:`sensor_noise` and, with ``theta_u`` given, the joint states' noise
    through the prediction (:func:`prediction_noise`) added in quadrature."""
    noise, source = sensor_noise(ds.meta, channels, model)
    if noise is None or theta_u is None:
        return noise, source
    spread = prediction_noise(model, ds, theta_u, channels, config)
    if spread is None:
        return noise, source
    return np.sqrt(noise**2 + spread**2), source + ", with the joint states' noise through the prediction"


def correlation_time(r: np.ndarray) -> float:
    """The integrated autocorrelation time ``tau = 1 + 2 sum_k rho_k`` (in samples) of ``r`` (F,), summed up to
    the first lag ``k >= 5 tau`` (Sokal's window); at least 1."""
    c = np.asarray(r, dtype=np.float64) - np.mean(r)
    n = len(c)
    if n < 4 or not np.any(c):
        return 1.0
    size = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(c, size)
    acf = np.fft.irfft(spec * np.conj(spec), size)[:n]
    rho = acf / acf[0]
    tau = 1.0
    for k in range(1, n):
        tau += 2 * rho[k]
        if k >= 5 * tau:
            break
    return float(min(max(tau, 1.0), n))


def mean_z(r: np.ndarray, series: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(mean (A,), z (A,))`` of a residual ``r`` (F, A): ``z = mean / (std sqrt(tau / F))``, ``tau`` the
    :func:`correlation_time` of each axis (1 when the frames are no time series)."""
    r = np.asarray(r, dtype=np.float64)
    mean, std = r.mean(axis=0), r.std(axis=0)
    tau = np.array([correlation_time(r[:, a]) if series else 1.0 for a in range(r.shape[1])])
    with np.errstate(divide="ignore", invalid="ignore"):
        z = mean / (std * np.sqrt(tau / len(r)))
    return mean, np.where(std > 0, z, np.where(mean != 0, np.inf, 0.0))


def offset_axes(mean, z, noise, scale) -> np.ndarray:
    """(A,) bool: the axes whose residual mean is an offset (module docstring); ``noise`` NaN: by ``z`` and
    ``scale`` (the axis's RMS) alone."""
    noise = np.asarray(noise, dtype=np.float64)
    big = np.where(np.isfinite(noise), np.abs(mean) > OFFSET_FACTOR * noise, True)
    return big & (np.abs(mean) > NEGLIGIBLE * np.asarray(scale)) & (np.abs(z) > OFFSET_Z)


def offset_hint(channels, model, axes_flagged) -> str:
    """The options that model the offsets of the axes flagged (A,) bool: ``--bias estimate`` for a sensor's,
    ``--torque-offset`` for joint torques' and motor currents'."""
    hints = []
    for b in channels.blocks(model):
        if axes_flagged[b.start : b.stop].any():
            actuated = b.channel.kind in ("joint_torque", "motor_current")
            hint = "solve --torque-offset" if actuated else "solve --bias estimate"
            if hint not in hints:
                hints.append(hint)
    return " or ".join(hints)


def check_offsets(res, ds, model, channels) -> Finding | None:
    """Unmodelled offsets on the fitted frames of ``ds`` (module docstring), on the first :data:`MAX_CONFIGS`
    solved configurations; an axis warns when it does on most of them.

    Args:
        res: the :class:`ineid.identify.SolveResults` of ``ds``.
        ds: the solved :class:`ineid.data.Dataset` (its configurations in ``res``'s order).
        model: its :class:`ineid.RobotModel`.
        channels: the channels fitted.
    """
    from ineid.identify.steps import predicted_wrench

    held = np.concatenate(
        [
            np.full(b.stop - b.start, bool(b.channel.offsets or getattr(b.channel, "torque_offset", False)))
            for b in channels.blocks(model)
        ]
    )
    if held.all():
        return None
    rows = np.flatnonzero(np.asarray(res.success, dtype=bool) & np.all(np.isfinite(res.theta_hat), axis=1))
    rows = rows[:MAX_CONFIGS]
    if not len(rows):
        return None
    n_fit = res.n_frames_fit
    frames = slice(0, n_fit)
    measured = np.asarray(ds.measured(channels)[rows, frames], dtype=np.float64)
    sub = SimpleNamespace(q=ds.q[rows], qd=ds.qd[rows], qdd=ds.qdd[rows], theta_known=_known_of(ds, rows), meta=ds.meta)
    r = measured - predicted_wrench(model, sub, np.asarray(res.theta_hat)[rows], frames, channels=channels)
    noise, _ = sensor_noise(ds.meta, channels, model)
    noise = np.full(r.shape[-1], np.nan) if noise is None else noise
    series = ds.time is not None and ds.meta.source == "recording"
    votes, means, zs = np.zeros(r.shape[-1]), [], []
    for k in range(len(rows)):
        mean, z = mean_z(r[k][:, ~held], series)
        scale = np.sqrt(np.mean(measured[k][:, ~held] ** 2, axis=0))
        votes[~held] += offset_axes(mean, z, noise[~held], scale)
        full_mean, full_z = np.zeros(r.shape[-1]), np.zeros(r.shape[-1])
        full_mean[~held], full_z[~held] = mean, z
        means.append(full_mean)
        zs.append(full_z)
    flagged = votes > len(rows) / 2
    if not flagged.any():
        return None
    names, units = channels.axes(model), channels.units(model)
    mean, z = np.median(means, axis=0), np.median(zs, axis=0)
    shown = ", ".join(
        f"{names[a]} {mean[a]:+.3g} {units[a]} (z {abs(z[a]):.3g}"
        + (f", {abs(mean[a]) / noise[a]:.3g}x the noise" if np.isfinite(noise[a]) and noise[a] > 0 else "")
        + ")"
        for a in np.flatnonzero(flagged)[:6]
    )
    return Finding(
        "unmodelled_offsets",
        f"the fitted frames' residual has a mean far above the noise on {int(flagged.sum())} of "
        f"{len(names)} axes ({shown}): constant offsets the fit does not model; identify them "
        f"({offset_hint(channels, model, flagged)})",
    )
