"""A recording's own noise, measured at import from the raw streams, before the low-pass.

A lab's recording states no noise: the import measures it. Each measured channel's raw stream
(the wrench at its own rate, the joint torques and currents at the joints') is put on a uniform
grid at its own rate, and its noise is read from the part the filter removes:

* with a low-pass at ``fc`` (:class:`ineid.data.recordings.signals.LowPass`, ``|H| = 1 / (1 + (f/fc)^4)``),
  the high-frequency part ``x - H x`` (the filter's edges left out). White noise of std ``s`` at rate
  ``r`` leaves it a variance ``s^2 (1 - HIGH_PASS_SHARE fc / (r / 2))`` (``HIGH_PASS_SHARE = 5 pi / (8 sqrt 2)``:
  ``int_0^inf (1 - H)^2 df = inf - (2 int H - int H^2) df``, ``int H df = pi fc / (2 sqrt 2)``); the raw std is
  ``1.4826 MAD / sqrt(that share)`` (the MAD: a glitch or a step does not inflate it). The frames keep
  ``s sqrt(NOISE_BANDWIDTH fc / (r / 2))`` (:data:`ineid.data.recordings.imus.NOISE_BANDWIDTH`), what the
  residual of a model that explains the signal has left (spline resampling of the filtered signal keeps it);
* without a filter (measured ``qd``, ``qdd``, no cut-off), ``1.4826 MAD(d2 x) / sqrt 6`` of the second
  differences ``d2 x`` (white noise gives ``std(d2 x) = sqrt 6 s``; a smooth motion sampled fast adds little),
  and the frames keep it all.

What is above the cut-off and is no noise (a vibration, a motion faster than the cut-off) counts as noise:
it is what the filtered frames do not hold, so no model fitted to them explains it either. The record
goes to the dataset's ``origin["noise"]`` (:func:`import_noise`); :func:`frames_noise` reads it back per
channel key, as ``meta.noise`` holds a synthetic dataset's stated noise.
"""

from __future__ import annotations

import math

import numpy as np

from ineid.data.recordings import signals

HIGH_PASS_SHARE = 5 * math.pi / (8 * math.sqrt(2))
"""``int_0^inf (2 H - H^2) df / fc`` of the low-pass: white noise's variance share ``x - H x`` loses is this
times ``fc / (r / 2)``."""
MIN_SAMPLES = 16
"""Fewest samples (the filter's edges left out) a stream's estimate is made from; NaN below."""


def _noise_bandwidth() -> float:
    from ineid.data.recordings.imus import NOISE_BANDWIDTH

    return NOISE_BANDWIDTH


def robust_std(x: np.ndarray) -> np.ndarray:
    """(A,) ``1.4826 MAD`` of ``x`` (N, A) per column: the std of Gaussian samples, unmoved by a few outliers."""
    x = np.asarray(x, dtype=np.float64)
    return 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)


def difference_noise(x: np.ndarray, min_samples: int = MIN_SAMPLES) -> np.ndarray:
    """(A,) white-noise std of ``x`` (N, A) from its second differences, ``1.4826 MAD(d2 x) / sqrt 6``; NaN with
    fewer than ``min_samples`` differences."""
    d2 = np.diff(np.asarray(x, dtype=np.float64), n=2, axis=0)
    if len(d2) < min_samples:
        return np.full(np.shape(x)[1], np.nan)
    return robust_std(d2) / math.sqrt(6.0)


def stream_noise(t: np.ndarray, x: np.ndarray, cutoff: float | None) -> tuple[np.ndarray, np.ndarray]:
    """``(raw, frames)`` (A,) noise std of one stream ``x(t)`` (N, A): of its raw samples, and what a filter at
    ``cutoff`` Hz (None: no filter) leaves of it (module docstring); NaN where the stream is too short."""
    t, x = np.asarray(t, dtype=np.float64), np.asarray(x, dtype=np.float64)
    h = float(np.median(np.diff(t)))
    _, xu = signals.to_uniform(t, x, h)
    rate = 1.0 / h
    if cutoff is None or cutoff >= 0.45 * rate:
        raw = difference_noise(xu)
        return raw, raw if cutoff is None else raw * math.sqrt(min(1.0, _noise_bandwidth() * cutoff / (rate / 2)))
    low = signals.LowPass(cutoff, rate)
    high = (xu - low.apply(xu))[low.edge_samples : len(xu) - low.edge_samples]
    if len(high) < MIN_SAMPLES:
        nan = np.full(x.shape[1], np.nan)
        return nan, nan
    raw = robust_std(high) / math.sqrt(max(1.0 - HIGH_PASS_SHARE * cutoff / (rate / 2), 1e-3))
    return raw, raw * math.sqrt(_noise_bandwidth() * cutoff / (rate / 2))


def derivative_noise(sigma_q: np.ndarray, cutoff: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """``(qd, qdd)`` (n,) noise std of the angles' derivatives: white angle noise ``sigma_q`` (n,) at ``rate`` Hz
    through the low-pass at ``cutoff`` and the central differences of
    :func:`ineid.data.recordings.signals.derivatives` (``sin(w h) / h``, ``(2 - 2 cos(w h)) / h^2``):
    ``sigma^2 (2 / r) int_0^{r/2} |H D|^2 df``."""
    h = 1.0 / rate
    f = np.linspace(0.0, rate / 2, 8193)
    gain = signals.LowPass(cutoff, rate).gain(f) if cutoff < 0.45 * rate else np.ones_like(f)
    w = 2 * np.pi * f * h
    share = [float(np.trapezoid((gain * d) ** 2, f) * 2 / rate) for d in (np.sin(w) / h, (2 - 2 * np.cos(w)) / h**2)]
    sigma_q = np.asarray(sigma_q, dtype=np.float64)
    return sigma_q * math.sqrt(share[0]), sigma_q * math.sqrt(share[1])


def import_noise(arrays, cutoff: float | None) -> dict:
    """The import's noise record (``origin["noise"]``): per channel key, the raw streams' noise std per axis
    (``raw``) and what the frames keep (``frames``); the joint angles' (``raw["q"]``) and what the frames'
    ``qd``, ``qdd`` keep of it (``frames["qd"]``, ``frames["qdd"]``: :func:`derivative_noise`, or the measured
    ones' own); the cut-off and the method in words.

    Args:
        arrays: the checked streams (:class:`ineid.data.recordings.frames.RecordingArrays`).
        cutoff: Hz, the filters' cut-off (None: no filter).
    """
    raw, frames = {}, {}
    streams = {k: (arrays.tq, v) for k, v in {**arrays.joint_arrays, **arrays.riders}.items()}
    if arrays.has_wrench:
        streams[arrays.wrench_channel.key] = (arrays.tw, arrays.wrench)
    for key, (t, x) in streams.items():
        r, f = stream_noise(t, x, cutoff)
        raw[key], frames[key] = _listed(r), _listed(f)
    if not arrays.measured and cutoff is not None:
        sigma_q = np.array([math.nan if v is None else v for v in raw["q"]], dtype=np.float64)
        qd, qdd = derivative_noise(sigma_q, cutoff, 1.0 / arrays.hq)
        frames["qd"], frames["qdd"] = _listed(qd), _listed(qdd)
    method = (
        f"the raw streams' part above the {cutoff:g} Hz cut-off (1.4826 MAD), the frames' share by the filter's "
        "noise bandwidth"
        if cutoff is not None
        else "the raw streams' second differences (1.4826 MAD / sqrt 6); no filter"
    )
    return {"method": method, "cutoff": cutoff, "raw": raw, "frames": frames}


def _listed(values: np.ndarray) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=np.float64)]


def frames_noise(origin: dict | None) -> dict[str, list[float]] | None:
    """Per channel key the noise std per axis the frames of a recording keep (``origin["noise"]["frames"]``,
    NaN where not measured), or None when the import recorded none."""
    record = (origin or {}).get("noise")
    if not isinstance(record, dict) or not isinstance(record.get("frames"), dict):
        return None
    return {k: [math.nan if v is None else float(v) for v in vs] for k, vs in record["frames"].items()}


def noise_line(origin: dict | None) -> str | None:
    """``data info``'s noise line of a recording: per channel the raw stream's noise std per axis and what the
    frames keep, and the joint angles'; None when the import recorded none."""
    record = (origin or {}).get("noise")
    if not isinstance(record, dict) or not isinstance(record.get("raw"), dict):
        return None
    cutoff = record.get("cutoff")
    how = f"above the {cutoff:.3g} Hz cut-off" if cutoff else "from the second differences, no filter"
    parts = []
    for key, raw in record["raw"].items():
        if key in ("qd", "qdd"):
            continue
        kept = record.get("frames", {}).get(key)
        name = {"q": "joint angles"}.get(key, key)
        parts.append(f"{name} {_shown(raw)} raw" + (f", {_shown(kept)} in the frames" if kept and cutoff else ""))
    return f"noise (std, estimated at import {how}): " + "; ".join(parts)


def _shown(values) -> str:
    return "[" + " ".join("-" if v is None else f"{v:.3g}" for v in values) + "]"
