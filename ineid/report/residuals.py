"""Is the validation residual noise, or does it show a model error? Simple, documented tests.

The residual ``r = measured - predicted`` of one configuration's validation frames (held out,
or a separate recording), per stacked axis, is compared with the sensor noise and tested for
structure a white residual does not have:

* **noise** (:func:`validation_noise`): the stated noise of synthetic data (``meta.noise``, per channel key;
  0 for clean data); for a recording the import's own estimate from the raw streams before the low-pass,
  scaled by the filter's noise bandwidth, with the joint angles' noise through the prediction added
  (:func:`ineid.identify.noise_figures.axis_noise`); a recording imported without that estimate: unknown
  (no model-error test). Other time series given no noise: the high-frequency estimate of the *measured*
  signal, ``sigma ~ 1.4826 MAD(d2 x) / sqrt(6)`` with ``d2 x`` the second differences (white noise of std
  ``sigma`` gives ``std(d2 x) = sqrt(6) sigma``; unfiltered samples only).
* **model error** (``model_error``): residual RMS above :data:`NOISE_FACTOR` times the noise (and above
  :data:`NEGLIGIBLE` of the signal's RMS).
* **offset** (``offset``): a residual mean far above the noise (:func:`ineid.identify.noise_figures.offset_axes`:
  more than ``OFFSET_FACTOR`` times the noise and ``OFFSET_Z`` standard errors off zero, the residual's
  correlation in time counted): an offset the fit does not model (``--bias estimate``, ``--torque-offset``).
* **delay** (``delay``): measurements stamped ``d`` late do not fit the model of the joints' frames,
  and the fitted parameters absorb part of the mismatch, so the residual alone does not show it.
  :func:`delay_scan` refits the linear model (every unknown column, an offset per axis, each axis
  scaled by its RMS) with the measurements shifted by whole frames, ``s`` in ``-S..S`` (``S dt`` up
  to :data:`MAX_DELAY`; whole frames, so no interpolation smooths the noise), as
  :mod:`ineid.identify.delay` does on a recording's streams. The best shift ``s != 0`` lowering the
  residual's sum of squares by more than :data:`DELAY_GAIN` (and 10 x the columns over the rows, what
  white noise lowers it by chance) warns, with ``d = s dt``.
* **friction** (``friction``): joint friction ``fc sign(qd_j) + fv qd_j`` that the model lacks
  leaves joint j's torque (or current) residual following its velocity; a channel read per motor of a
  coupled transmission (``qd_joint = C qd_motor``) follows each motor's velocity ``qd_motor = C^-1 qd_joint``
  instead. Per such axis, the share
  of the residual's variance (less its mean) that least squares on ``sign(v), v`` (``v`` its velocity) explains
  beyond the delay column ``dp/dt`` above :data:`STRUCTURE_SHARE` warns. Channels of a wrench do
  not feel joint friction (internal torques): not tested. (Beyond ``dp/dt``: on a slow trajectory a
  delayed torque's residual, ``-d dp/dt``, also follows the velocity's sign.)
* **spectral peak** (``spectral_peak``): one frequency bin of the residual's periodogram (Hann
  window, mean removed; frequencies of at least :data:`MIN_PERIODS` periods in the span, slower ones
  are trends) holding more than :data:`PEAK_SHARE` of the power, and more than
  :data:`PEAK_WHITE_FACTOR` times what white noise's largest bin typically holds
  (``ln(M) / M`` of M bins): a periodic error (a resonance, an unmodelled periodic load).

The lag-1 autocorrelation is reported, not tested: a recording low-pass filtered at import has a
correlated residual by design. The structure tests need a time series of at least
:data:`MIN_FRAMES` frames and a residual above rounding (:data:`ROUNDING`, relative to the signal).
For white noise each explained share is about (columns / frames), far below the thresholds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ineid.data.recordings.noise_estimate import difference_noise
from ineid.data.recordings.plausibility import Finding
from ineid.identify.noise_figures import NOISE_FACTOR, mean_z, offset_axes

STRUCTURE_SHARE = 0.25
"""Share of a joint torque's residual variance that friction explains above which it warns."""
PEAK_SHARE = 0.3
"""Least share of the residual's power in one frequency bin that warns."""
PEAK_WHITE_FACTOR = 6.0
"""And at least this multiple of white noise's typical largest bin share ``ln(M) / M``."""
MAX_DELAY = 0.1
"""s, the largest delay :func:`delay_scan` tries (at most :data:`MAX_SHIFT` frames)."""
MAX_SHIFT = 50
DELAY_GAIN = 0.1
"""Share of the residual's sum of squares a shifted refit must remove to warn (and 10 x the share white noise
removes by chance, about the fitted columns over the rows)."""
MAX_SCAN_FRAMES = 20_000
"""Frames of a configuration :func:`delay_scan` looks at (the first ones)."""
MIN_PERIODS = 3
"""The spectral peak test looks at frequencies of at least this many periods in the validation span."""
MIN_FRAMES = 64
"""Fewest validation frames (a time series) for the structure tests."""
NEGLIGIBLE = 1e-3
"""A residual RMS below this fraction of the signal's RMS is no model error whatever the noise (a noise-free
recording's residual is its filter's error, far below anything a model error leaves)."""
ROUNDING = 1e-9
"""A residual RMS below this fraction of the signal's RMS is rounding: no tests."""


@dataclass(frozen=True)
class AxisCheck:
    """One axis's residual against its noise (NaN where a quantity does not apply).

    Attributes:
        axis, unit: the axis name and unit.
        rms: residual RMS.
        noise: estimated (or stated) noise std; NaN when unknown.
        lag1: the residual's lag-1 autocorrelation.
        peak_hz, peak_share: the largest periodogram bin's frequency (Hz) and share of the power.
        friction_share: residual variance explained by joint friction (joint-torque axes only).
    """

    axis: str
    unit: str
    rms: float
    noise: float
    lag1: float = math.nan
    peak_hz: float = math.nan
    peak_share: float = math.nan
    friction_share: float = math.nan

    @property
    def ratio(self) -> float:
        """``rms / noise`` (inf for a residual above rounding on clean data, NaN when the noise is unknown)."""
        if not math.isfinite(self.noise):
            return math.nan
        return self.rms / self.noise if self.noise > 0 else (math.inf if self.rms > 0 else 1.0)


@dataclass
class ResidualCheck:
    """The residual tests of one validation (module doc).

    Attributes:
        axes: per axis, :class:`AxisCheck`.
        noise_source: where the noise figures come from (text).
        delay: ``{"shift": (delay s, gain)}`` of :func:`delay_scan` when it ran.
        warnings: what the tests found.
        tested: whether the structure tests ran (a long enough time series), and why not.
    """

    axes: list[AxisCheck]
    noise_source: str
    delay: dict[str, tuple[float, float]] = field(default_factory=dict)
    warnings: list[Finding] = field(default_factory=list)
    tested: str = ""


def delay_scan(time, values, rows, max_delay: float = MAX_DELAY) -> tuple[float, float, float] | None:
    """The whole-frame delay that best fits the model (module doc), and the share of the residual it removes.

    Args:
        time: (F,) s, uniform sampling.
        values: (F, A) the measurements less the known links' part.
        rows: (F, A, p) the regressor of the fitted columns on the same frames (in the measurements' frame).

    Returns:
        ``(d, gain, chance)``: ``d = s dt`` s (positive: the measurements are late), ``gain = 1 - r(s) / r(0)``
        with ``r`` the refit's residual sum of squares, ``chance`` the gain white noise gives about (fitted
        columns and offsets over rows); None when the frames are too few for one shift.
    """
    f = min(len(time), MAX_SCAN_FRAMES)
    dt = float(np.median(np.diff(time[:f])))
    shift = int(min(MAX_SHIFT, round(max_delay / dt))) if dt > 0 else 0
    if shift < 1 or f - 2 * shift < 4 * rows.shape[-1]:
        return None
    values, rows = np.asarray(values[:f], dtype=np.float64), np.asarray(rows[:f], dtype=np.float64)
    scale = 1.0 / np.maximum(values.std(axis=0), np.finfo(float).tiny)
    mid = rows[shift : f - shift]
    w = ((mid - mid.mean(axis=0)) * scale[None, :, None]).reshape(-1, rows.shape[-1])
    u, sv, _ = np.linalg.svd(w, full_matrices=False)
    q = u[:, sv > sv[0] * 1e-10] if sv.size and sv[0] > 0 else u[:, :0]
    sums = []
    for s in range(-shift, shift + 1):
        y = values[shift + s : f - shift + s]
        y = ((y - y.mean(axis=0)) * scale).ravel()
        sums.append(float(np.sum((y - q @ (q.T @ y)) ** 2)))
    sums = np.array(sums)
    best = int(np.argmin(sums))
    gain = 1.0 - sums[best] / sums[shift] if sums[shift] > 0 else 0.0
    return (best - shift) * dt, float(gain), (q.shape[1] + values.shape[1]) / w.shape[0]


def stated_noise(noise: dict | None, blocks, n_axes: int) -> np.ndarray:
    """(A,) the noise std per stacked axis that synthetic data states (``meta.noise`` by channel key; clean: 0).

    ``blocks``: ``(key, start, stop, kind)`` of each channel among the stacked axes.
    """
    out = np.zeros(n_axes)
    for key, start, stop, _ in blocks:
        values = (noise or {}).get(key)
        if values is not None:
            out[start:stop] = np.broadcast_to(np.asarray(values, dtype=np.float64), (stop - start,))
    return out


def validation_noise(res, ds, model, row: int) -> tuple[np.ndarray | None, str]:
    """``(noise (A,) or None, source)`` of the validation frames of ``ds`` (the solved dataset, or the separate
    validation recording), for the axes ``res`` was fitted on, with its results row ``row``'s estimates (module
    doc); a recording imported without a noise estimate: NaN (unknown)."""
    from ineid.identify.noise_figures import axis_noise
    from ineid.identify.unit_fits import fitted_channels

    channels = fitted_channels(res, ds)
    theta = np.asarray(res.theta_hat, dtype=np.float64)[row]
    noise, source = axis_noise(ds, channels, model, theta, min(row, ds.n_configs - 1))
    if noise is None:
        return np.full(channels.n_axes(model), np.nan), source
    return noise, source


def explained_share(r: np.ndarray, columns: np.ndarray) -> float:
    """Share of ``r``'s (F,) sum of squares that least squares on ``columns`` (F, k) explains (0 if none)."""
    ss = float(r @ r)
    if ss <= 0 or not columns.size:
        return 0.0
    coef, *_ = np.linalg.lstsq(columns, r, rcond=None)
    fit = columns @ coef
    return float(min(1.0, (fit @ fit) / ss))


def periodogram_peak(r: np.ndarray, dt: float) -> tuple[float, float, int]:
    """``(frequency Hz, share of power, bins)`` of the largest bin of ``r``'s Hann-windowed periodogram among
    those of at least :data:`MIN_PERIODS` periods in the span (slower ones are trends, not periods)."""
    x = (r - r.mean()) * np.hanning(len(r))
    p = np.abs(np.fft.rfft(x)) ** 2
    p = p[1:]  # the mean is out; bin 0 is what the window leaves of it
    total = p.sum()
    p = p[MIN_PERIODS - 1 :]
    if total <= 0 or not p.size:
        return math.nan, math.nan, len(p)
    k = int(np.argmax(p)) + MIN_PERIODS - 1
    return float((k + 1) / (len(r) * dt)), float(p[k - MIN_PERIODS + 1] / total), len(p)


def check_residual(
    time,
    measured,
    predicted,
    axes,
    units,
    blocks,
    qd=None,
    noise=None,
    noise_source: str = "",
    delay: tuple[float, float] | None = None,
    couplings=None,
) -> ResidualCheck:
    """Test one validation's residual (module doc).

    Args:
        time: (F,) s, or None when the frames are no time series (independent samples).
        measured, predicted: (F, A) the channels' values.
        axes, units: (A,) names and units.
        blocks: ``(key, start, stop, kind)`` per channel among the A axes (kind: the channel's, such as
            ``"wrench"`` or ``"joint_torque"``).
        qd: (F, n_dof) joint velocities of the frames (rad/s), for the friction test.
        noise: (A,) the noise std (:func:`validation_noise`), or None: estimated from ``measured``'s second
            differences.
        noise_source: how the stated noise was found (text).
        delay: :func:`delay_scan`'s ``(delay s, gain, chance)`` of these frames' configuration, or None: not
            tested.
        couplings: ``{channel key: C}`` of the channels read per motor of a coupled transmission (joints x
            motors, ``qd_joint = C qd_motor``): their friction test uses the motors' velocities.
    """
    measured, predicted = np.asarray(measured, dtype=np.float64), np.asarray(predicted, dtype=np.float64)
    r = measured - predicted
    n_frames, n_axes = r.shape
    rms = np.sqrt(np.mean(r**2, axis=0))
    scale = np.sqrt(np.mean(measured**2, axis=0))
    series = time is not None and n_frames >= 3 and bool(np.all(np.diff(time) > 0))
    if noise is None:
        noise = difference_noise(measured, min_samples=3) if series else np.full(n_axes, np.nan)
        noise_source = (
            "estimated from the measured signal's second differences (right for unfiltered samples)"
            if series
            else "unknown (the frames are no time series; give the noise)"
        )
    out = ResidualCheck([], noise_source)
    above = rms > ROUNDING * np.maximum(scale, np.finfo(float).tiny)
    tested = series and n_frames >= MIN_FRAMES
    out.tested = (
        ""
        if tested
        else (
            f"only {n_frames} validation frames (the structure tests need {MIN_FRAMES})"
            if series
            else "the frames are no time series"
        )
    )
    dt = float(np.median(np.diff(time))) if series else math.nan
    rate = np.gradient(predicted, time, axis=0) if tested else None
    velocity = _axis_velocities(blocks, qd, couplings or {})
    for a in range(n_axes):
        ra = r[:, a]
        extra = {}
        if tested and above[a]:
            c = ra - ra.mean()
            extra["lag1"] = float((c[1:] @ c[:-1]) / (c @ c)) if c @ c > 0 else math.nan
            extra["peak_hz"], extra["peak_share"], _ = periodogram_peak(ra, dt)
            if a in velocity:  # beyond what a delay explains (module doc)
                g = rate[:, a : a + 1] - rate[:, a].mean()
                f = _friction_columns(velocity[a])
                extra["friction_share"] = explained_share(c, np.hstack([g, f])) - explained_share(c, g)
        out.axes.append(AxisCheck(axes[a], units[a], float(rms[a]), float(noise[a]), **extra))
    _model_error(out, rms > NEGLIGIBLE * scale)
    _offsets(out, r, np.asarray(noise, dtype=np.float64), scale, series, blocks)
    if tested:
        _structure(out, r, delay)
    return out


def _model_error(out: ResidualCheck, above: np.ndarray) -> None:
    bad = [(c, c.ratio) for c, ok in zip(out.axes, above, strict=True) if ok and c.ratio > NOISE_FACTOR]
    if bad:
        worst = max(bad, key=lambda x: x[1])
        text = ", ".join(f"{c.axis} {r:.3g}x" if math.isfinite(r) else f"{c.axis} (clean data)" for c, r in bad[:6])
        out.warnings.append(
            Finding(
                "model_error",
                (
                    f"residual RMS is more than {NOISE_FACTOR:g} x the noise on {len(bad)} of {len(out.axes)} axes "
                    f"({text}): "
                    f"the model misses something (worst {worst[0].axis}); check the sensor pose, the known links' CAD "
                    "values, friction (joint torques) and the delay"
                ),
            )
        )


def _offsets(out: ResidualCheck, r, noise, scale, series: bool, blocks) -> None:
    """The ``offset`` warning: the axes whose residual mean is far above the noise (module doc)."""
    if len(r) < 3:
        return
    mean, z = mean_z(r, series)
    flagged = offset_axes(mean, z, noise, scale)
    if not flagged.any():
        return
    torque = any(kind in FRICTION_KINDS and flagged[start:stop].any() for _, start, stop, kind in blocks)
    wrench = any(kind not in FRICTION_KINDS and flagged[start:stop].any() for _, start, stop, kind in blocks)
    options = " or ".join(o for o, on in (("--bias estimate", wrench), ("--torque-offset", torque)) if on)
    text = ", ".join(
        f"{c.axis} {m:+.3g} {c.unit} (z {abs(zz):.3g})"
        for c, m, zz, f in zip(out.axes, mean, z, flagged, strict=True)
        if f
    )
    out.warnings.append(
        Finding(
            "offset",
            f"the residual's mean is far above the noise on {int(flagged.sum())} of {len(out.axes)} axes ({text}): "
            f"an offset the fit does not model; solve with {options}",
        )
    )


FRICTION_KINDS = ("joint_torque", "motor_current")
"""Channels that feel joint friction (a wrench sensor measures the links' motion, whatever the joints' torques)."""


def _axis_velocities(blocks, qd, couplings) -> dict[int, np.ndarray]:
    """Stacked axis -> (F,) the velocity its friction follows, for the channels of :data:`FRICTION_KINDS` (one axis
    per joint or motor): joint j's ``qd_j``, or with a coupling ``C`` (``couplings[key]``) motor m's
    ``(C^-1 qd_joint)_m``."""
    if qd is None:
        return {}
    qd = np.asarray(qd, dtype=np.float64)
    out = {}
    for key, start, stop, kind in blocks:
        if kind not in FRICTION_KINDS or stop - start != qd.shape[1]:
            continue
        c = couplings.get(key)
        v = qd if c is None else np.linalg.solve(np.asarray(c, dtype=np.float64), qd.T).T
        out.update({start + j: v[:, j] for j in range(qd.shape[1])})
    return out


def _friction_columns(v: np.ndarray) -> np.ndarray:
    """(F, 2) Coulomb and viscous friction of one joint (or motor) of velocity ``v``, mean removed: ``sign(v)``,
    ``v``."""
    f = np.column_stack([np.sign(v), v])
    return f - f.mean(axis=0)


def _structure(out: ResidualCheck, r, delay) -> None:
    if delay is not None:
        d, gain, chance = delay
        out.delay = {"shift": (d, gain)}
        if gain > max(DELAY_GAIN, 10 * chance) and d != 0:
            out.warnings.append(
                Finding(
                    "delay",
                    (
                        f"the measurements read {abs(d) * 1e3:.3g} ms {'late' if d > 0 else 'early'} against the "
                        "joints: "
                        f"refitted with them shifted so, the residual's sum of squares drops by {gain:.0%}; "
                        "re-import with "
                        "--delay auto (or the delay in seconds)"
                    ),
                )
            )
    fric = [c for c in out.axes if c.friction_share > STRUCTURE_SHARE]
    if fric:
        out.warnings.append(
            Finding(
                "friction",
                (
                    f"the residual of {', '.join(c.axis for c in fric[:6])} follows the joint's velocity (friction "
                    "explains up "
                    f"to {max(c.friction_share for c in fric):.0%} of its variance): unmodelled joint friction; "
                    "identify it "
                    "(--friction viscous,coulomb) or fit channels that do not feel it (the base wrench)"
                ),
            )
        )
    m = len(r) // 2
    peaks = [c for c in out.axes if c.peak_share > PEAK_SHARE and c.peak_share > PEAK_WHITE_FACTOR * math.log(m) / m]
    if peaks:
        c = max(peaks, key=lambda c: c.peak_share)
        out.warnings.append(
            Finding(
                "spectral_peak",
                (
                    f"one frequency holds {c.peak_share:.0%} of the residual's power on {c.axis} ({c.peak_hz:.3g} Hz; "
                    f"{len(peaks)} axes in all): a periodic error the model lacks (a resonance, a periodic load, "
                    "friction "
                    "on a periodic trajectory)"
                ),
            )
        )
