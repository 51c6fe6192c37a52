"""Signal processing for recordings: one time base, zero-phase low-pass, derivatives.

A lab records joint angles (encoders) and the sensor wrench, often at different rates and
on different clocks. ineid turns them into frames ``(q, qd, qdd, wrench)`` on one uniform
time base:

1. **Uniform sampling.** A stream whose sample intervals vary (jitter) is interpolated
   onto a uniform grid at its own nominal rate by a cubic spline (:func:`to_uniform`; the rate:
   :func:`ineid.data.recordings.timing.nominal_interval`).
2. **Zero-phase low-pass** (:class:`LowPass`): a Butterworth filter of order 2 run
   forward and backward (``scipy.signal.sosfiltfilt``): ``|H(f)| = 1 / (1 + (f/fc)^4)``,
   no phase shift (the magnitude of a cubic smoothing spline). The *same* filter is
   applied to the joint angles and to the wrench, so both keep the same frequency
   content and ``w_f ~ Psi(q_f, qd_f, qdd_f) theta`` holds as long as the regressor
   changes slowly over the filter's span.
3. **Derivatives** of the filtered angles by central differences (:func:`derivatives`):
   ``qd_k = (q_{k+1} - q_{k-1}) / 2h`` and ``qdd_k = (q_{k+1} - 2 q_k + q_{k-1}) / h^2``,
   whose relative error at frequency ``f`` is about ``(2 pi f h)^2 / 6`` and
   ``(2 pi f h)^2 / 12``: below 1e-3 up to ``f = 0.012 / h`` (12 Hz at 1 kHz).
4. **Ends.** The filter's start-up spoils the first and last samples; :func:`edge_seconds`
   is how much is dropped at each end (``EDGE_PERIODS`` periods of the cut-off: the
   error of ``qdd`` there has decayed to about 1e-6 of its RMS, measured).

The default cut-off (:func:`choose_cutoff`) comes from the joint angles' spectrum; see its
docstring for the rule and ``docs/recordings.md`` (``benchmarks/recordings.py``) for the
measurements behind the filter (Butterworth against Savitzky-Golay and smoothing splines)
and the rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.errors import DatasetError

FILTER_ORDER = 2
"""Butterworth order of each pass (forward and backward: a 4th-order zero-phase magnitude)."""
EDGE_PERIODS = 3.0
"""Samples within this many cut-off periods ``1/fc`` of either end are dropped."""
JITTER_RTOL = 1e-6
"""Sample intervals that differ from their median by less than this (relative) count as uniform."""


def median_interval(t: np.ndarray, what: str) -> float:
    """The median sample interval of increasing time stamps ``t`` (s).

    Raises:
        DatasetError: fewer than two samples, or time stamps that do not increase (naming
            the first offending sample).
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2:
        raise DatasetError(f"{what}: {t.size} sample{'s' if t.size != 1 else ''}; a recording needs many more")
    dt = np.diff(t)
    if not np.all(dt > 0):
        k = int(np.flatnonzero(~(dt > 0))[0])
        raise DatasetError(
            f"{what}: time does not increase at sample {k + 1} ({float(t[k])!r} s, then {float(t[k + 1])!r} s); "
            "sort the samples by time and drop repeated ones"
        )
    return float(np.median(dt))


def is_uniform(t: np.ndarray, rtol: float = JITTER_RTOL) -> bool:
    """Whether all sample intervals equal their median within ``rtol``."""
    dt = np.diff(np.asarray(t, dtype=np.float64))
    h = np.median(dt)
    return bool(np.all(np.abs(dt - h) <= rtol * h))


def to_uniform(t: np.ndarray, x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``x(t)`` (N, ...) onto ``t[0] + k dt`` within ``[t[0], t[-1]]`` by a cubic spline.

    A stream that is already uniform at ``dt`` is returned as it is (no interpolation).
    """
    from scipy.interpolate import make_interp_spline

    t = np.asarray(t, dtype=np.float64)
    if is_uniform(t) and abs(np.median(np.diff(t)) - dt) <= JITTER_RTOL * dt:
        return t, np.asarray(x, dtype=np.float64)
    grid = t[0] + dt * np.arange(int(math.floor((t[-1] - t[0]) / dt * (1 + 1e-12))) + 1)
    return grid, interpolate(t, x, grid, make_interp_spline)


def interpolate(t: np.ndarray, x: np.ndarray, t_new: np.ndarray, _spline=None) -> np.ndarray:
    """Cubic-spline (not-a-knot) values of samples ``x(t)`` (N, ...) at ``t_new`` (inside ``[t[0], t[-1]]``)."""
    if _spline is None:
        from scipy.interpolate import make_interp_spline as _spline

    t = np.asarray(t, dtype=np.float64)
    if len(t) < 4:
        return np.stack([np.interp(t_new, t, col) for col in np.asarray(x).reshape(len(t), -1).T], -1).reshape(
            (len(t_new),) + np.shape(x)[1:]
        )
    return _spline(t, np.asarray(x, dtype=np.float64), k=3, axis=0)(t_new)


def on_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, bool]:
    """``x`` at ``grid``: the samples themselves where the stream's stamps are the grid, else a cubic spline."""
    i0 = int(np.searchsorted(t, grid[0] - 1e-9 * abs(grid[0]) - 1e-12))
    part = t[i0 : i0 + len(grid)]
    h = (grid[-1] - grid[0]) / max(len(grid) - 1, 1)
    if len(part) == len(grid) and np.all(np.abs(part - grid) <= 1e-6 * h):
        return np.array(x[i0 : i0 + len(grid)]), False
    return interpolate(t, x, grid), True


@dataclass(frozen=True)
class LowPass:
    """A zero-phase Butterworth low-pass: ``order`` forward, then backward.

    Attributes:
        cutoff: Hz, where each pass is 3 dB down (the two passes: 6 dB).
        rate: Hz, the sampling rate of the signals it filters.
        order: order of each pass.
    """

    cutoff: float
    rate: float
    order: int = FILTER_ORDER

    def __post_init__(self) -> None:
        if not (self.cutoff > 0 and math.isfinite(self.cutoff)):
            raise DatasetError(f"the cut-off must be a positive number of Hz, got {self.cutoff}")
        if self.cutoff >= 0.45 * self.rate:
            raise DatasetError(
                f"cut-off {self.cutoff:g} Hz is too close to the Nyquist frequency of {self.rate:g} Hz sampling "
                f"({self.rate / 2:g} Hz); use --cutoff below {0.45 * self.rate:g} Hz"
            )

    def sos(self) -> np.ndarray:
        from scipy.signal import butter

        return butter(self.order, self.cutoff, fs=self.rate, output="sos")

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Filter ``x`` (N, ...) along its first axis, zero phase."""
        from scipy.signal import sosfiltfilt

        x = np.asarray(x, dtype=np.float64)
        pad = min(len(x) - 1, 3 * self.edge_samples)
        return sosfiltfilt(self.sos(), x, axis=0, padtype="odd", padlen=pad)

    @property
    def edge_samples(self) -> int:
        """Samples spoiled at each end: ``EDGE_PERIODS`` periods of the cut-off."""
        return int(math.ceil(EDGE_PERIODS * self.rate / self.cutoff))

    def gain(self, f: np.ndarray) -> np.ndarray:
        """``|H(f)|`` of the two passes: ``1 / (1 + (f / cutoff)^(2 order))``."""
        return 1.0 / (1.0 + (np.asarray(f, dtype=np.float64) / self.cutoff) ** (2 * self.order))


def edge_seconds(cutoff: float) -> float:
    """Seconds dropped at each end of a stream filtered at ``cutoff`` Hz."""
    return EDGE_PERIODS / cutoff


def derivatives(q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(qd, qdd)`` of uniformly sampled ``q`` (N, n) by central differences (one-sided at the ends).

    ``qd_k = (q_{k+1} - q_{k-1}) / (2 dt)``, ``qdd_k = (q_{k+1} - 2 q_k + q_{k-1}) / dt^2``;
    the two end samples (second-order one-sided formulas) are among those dropped anyway.
    """
    q = np.asarray(q, dtype=np.float64)
    if len(q) < 4:
        raise DatasetError(f"{len(q)} joint samples are too few to differentiate; record more")
    qd = np.gradient(q, dt, axis=0, edge_order=2)
    qdd = np.empty_like(q)
    qdd[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) / dt**2
    qdd[0], qdd[-1] = 2 * qdd[1] - qdd[2], 2 * qdd[-2] - qdd[-3]
    return qd, qdd


ACCELERATION_NOISE = 0.01
"""The default cut-off lets through joint-angle noise worth at most this share of the accelerations' RMS."""
CUTOFF_RANGE = (1.0, 0.1)
"""The default cut-off is at least 1 Hz and at most 0.1 x the sampling rate."""
MOTION_SHARE = 0.999
"""The motion's band ends where the joint velocities' motion power reaches this share (:func:`motion_band`)."""
MOTION_SNR = 1000.0
"""Only spectrum bins this many times above the noise floor count as motion (:func:`motion_band`)."""
MOTION_FACTOR = 3.0
"""The default cut-off is at least this many times the motion's band (the regressor's products of angles,
velocities and sines reach past the motion's own band, and a cut-off below them filters the model away)."""


@dataclass(frozen=True)
class CutoffChoice:
    """The default cut-off and what it was chosen from.

    Attributes:
        cutoff: Hz.
        noise_rms: (n_dof,) the joint angles' white-noise level (rad), from the spectrum's floor.
        acceleration_noise: RMS of the noise the filtered accelerations keep, as a share of
            their signal's RMS (all joints pooled).
        limited: ``"noise"`` (the rule), ``"motion"`` (:data:`MOTION_FACTOR` times the motion's band, above
            what the noise allows), ``"rate"`` (the upper bound, 0.1 x the rate: the noise allows more) or
            ``"floor"`` (the 1 Hz lower bound).
        motion_hz: Hz, the motion's band (:func:`motion_band`; 0 when no bin stands out of the noise).
        noise_cutoff: Hz, what the noise rule alone allows (within :data:`CUTOFF_RANGE`).
    """

    cutoff: float
    noise_rms: np.ndarray
    acceleration_noise: float
    limited: str
    motion_hz: float = 0.0
    noise_cutoff: float | None = None


def choose_cutoff(q: np.ndarray, rate: float) -> CutoffChoice:
    """The cut-off for joint angles ``q`` (N, n) sampled at ``rate`` Hz, from their spectrum.

    Welch's power spectral density ``P_j(f)`` of each joint's angle (linear trend removed)
    holds the motion at low frequencies over a flat floor ``N_j`` of encoder noise
    (quantization, electronics): ``N_j`` is the median density over ``f >= rate / 4``.
    Differentiating twice weights both by ``(2 pi f)^4``; after the filter the
    accelerations keep the noise and the motion

        noise(fc)  = sum_j sum_f N_j (2 pi f)^4 |H_fc(f)|^2
        motion(fc) = sum_j sum_f max(P_j - N_j, 0) (2 pi f)^4 |H_fc(f)|^2

    and the noise rule's cut-off is the highest ``fc`` with ``sqrt(noise / motion)`` at most
    :data:`ACCELERATION_NOISE` (1 %). The cut-off is that, or :data:`MOTION_FACTOR` (3) times the
    motion's band (:func:`motion_band`) where that is higher, within :data:`CUTOFF_RANGE`.

    The noise rule alone bounds only the noise that least squares sees; on fast motion read by coarse
    encoders it filters the motion itself away, and the model with it (10-bit encoders at 100 Hz, motion
    up to 2 Hz: base-parameter error 0.20 at its 2.8 Hz, 0.036 at the motion rule's 6.5 Hz;
    ``docs/recordings.md``). On the MuJoCo recording of the tests (1 kHz, 17-bit encoders) the noise rule
    decides: 24 Hz, next to the 20 Hz with the smallest identification error of the cut-offs tried
    (``benchmarks/recordings.py``), and on noise-free data the upper bound, where the error is smallest.
    """
    return pooled_cutoff([angle_spectrum(q, rate)])


@dataclass(frozen=True)
class AngleSpectrum:
    """Welch's power spectral density of a recording's joint angles (:func:`angle_spectrum`).

    Attributes:
        f: (F,) Hz.
        p: (F, n) each joint's density.
        floor: (n,) each joint's noise floor, the median density over ``f >= rate / 4``.
        rate: Hz, the sampling rate.
        seconds: s, the recording's length (its share of the rows when several are pooled).
    """

    f: np.ndarray
    p: np.ndarray
    floor: np.ndarray
    rate: float
    seconds: float


def angle_spectrum(q: np.ndarray, rate: float) -> AngleSpectrum:
    """The :class:`AngleSpectrum` of joint angles ``q`` (N, n) sampled at ``rate`` Hz (linear trend removed,
    segments of about 4 s)."""
    from scipy.signal import welch

    q = np.asarray(q, dtype=np.float64)
    nper = int(min(len(q), 2 ** int(math.ceil(math.log2(4 * rate)))))
    f, p = welch(q, fs=rate, nperseg=nper, axis=0, detrend="linear")
    return AngleSpectrum(f, p, np.median(p[f >= 0.25 * rate], axis=0), float(rate), len(q) / rate)


def pooled_cutoff(spectra) -> CutoffChoice:
    """The cut-off of :func:`choose_cutoff` for the rows of several recordings fitted together: their
    accelerations' noise and motion powers summed (each recording weighted by its length), the motion's band
    of their pooled power, the upper bound that of the slowest rate; one recording's is its own choice.

    Args:
        spectra: each recording's :class:`AngleSpectrum`.
    """
    spectra = list(spectra)
    total = sum(s.seconds for s in spectra)
    weights = [s.seconds / total * (s.f[1] - s.f[0]) / (spectra[0].f[1] - spectra[0].f[0]) for s in spectra]
    w4 = [(2 * np.pi * s.f) ** 4 for s in spectra]
    noise_w = [(s.floor[None, :] * w[:, None]).sum(axis=1) for s, w in zip(spectra, w4, strict=True)]
    motion_w = [
        (np.maximum(s.p - s.floor[None, :], 0.0) * w[:, None]).sum(axis=1) for s, w in zip(spectra, w4, strict=True)
    ]
    rate = min(s.rate for s in spectra)
    lo, hi = CUTOFF_RANGE[0], CUTOFF_RANGE[1] * rate
    noise_rms = np.max([np.sqrt(s.floor * s.rate / 2) for s in spectra], axis=0)

    def ratio(fc: float) -> float:
        g2 = [LowPass(fc, rate).gain(s.f) ** 2 for s in spectra]
        noise = sum(k * np.sum(n * g) for k, n, g in zip(weights, noise_w, g2, strict=True))
        motion = sum(k * np.sum(m * g) for k, m, g in zip(weights, motion_w, g2, strict=True))
        return float(np.sqrt(noise / max(motion, 1e-300)))

    candidates = np.geomspace(lo, hi, 241)
    ok = [fc for fc in candidates if ratio(fc) <= ACCELERATION_NOISE]
    by_noise = float(max(ok)) if ok else lo
    band = motion_band(spectra, weights)
    fc = min(max(by_noise, MOTION_FACTOR * band), hi)
    if fc >= hi * (1 - 1e-9):
        limited = "rate"
    elif fc > by_noise:
        limited = "motion"
    else:
        limited = "noise" if ok else "floor"
    return CutoffChoice(fc, noise_rms, ratio(fc), limited, band, by_noise)


def motion_band(spectra, weights=None) -> float:
    """Hz, where the joint angles' motion ends: the lowest frequency below which :data:`MOTION_SHARE` of the
    joint velocities' motion power ``sum_j (P_j - N_j) (2 pi f)^2`` lies, counting only bins at least
    :data:`MOTION_SNR` times above their joint's noise floor ``N_j`` (0 when none is).

    Velocities, not accelerations: a recording's accelerations jump where dry friction stops a joint, and
    their power (weighted by ``f^4``) spreads far past the motion's own band (the tests' MuJoCo arm: 99.9 %
    below 14 Hz against 3.4 Hz for the velocities); the bins' threshold keeps a coarse encoder's steps, whose
    harmonics stand out of a flat floor on slow motion, out of the band.

    Args:
        spectra: each recording's :class:`AngleSpectrum`, their powers pooled.
        weights: each one's weight in the pool (None: equal).
    """
    f = np.concatenate([s.f for s in spectra])
    power = np.concatenate(
        [
            k
            * (
                np.where(s.p > MOTION_SNR * s.floor[None, :], s.p - s.floor[None, :], 0.0)
                * ((2 * np.pi * s.f) ** 2)[:, None]
            ).sum(axis=1)
            for s, k in zip(spectra, weights or [1.0] * len(spectra), strict=True)
        ]
    )
    order = np.argsort(f, kind="stable")
    f, power = f[order], power[order]
    total = power.sum()
    if not total > 0:
        return 0.0
    return float(f[min(int(np.searchsorted(np.cumsum(power) / total, MOTION_SHARE)), len(f) - 1)])
