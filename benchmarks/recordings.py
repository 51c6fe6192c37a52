"""Recordings against MuJoCo's truth: every file path, every method, and the filter's alternatives.

The recording is the tests' (``tests/mujoco_arm.py``): ``sweaty-arm`` simulated by MuJoCo
(RK4, joint damping and dry friction, 10 s at 1 kHz) on a 6-axis F/T sensor turned nearly
upside down 3-5 cm off the base origin, with constant offsets; joint angles only. Tables:

1. **Paths.** The same recording written as CSV, ROS 1 bag, ROS 2 bag (sqlite3 and MCAP)
   and a bare ``.mcap``, imported by ``import_recording`` (ineid's default filter and
   cut-off) and identified by each method with ``bias="estimate"``; the tared CSV also
   with ``bias="none"``. Error: per base parameter ``|beta_hat - beta| / max(|beta|,
   scale)`` (the tests' measure), largest and median over the 16 (17 without offsets).
2. **Filters.** Zero-phase Butterworth (order 2, forward and backward) + central
   differences (ineid's), Savitzky-Golay (``scipy.signal.savgol_filter``, cubic, derivatives
   from the fitted polynomials) and a cubic smoothing spline
   (``scipy.interpolate.make_smoothing_spline``, derivatives of the spline), each applied
   with the *same* smoother to the angles and the wrench, swept over its bandwidth, on the
   noise-free recording, with 17-bit encoders (quantized angles), and with 17-bit encoders and
   wrench noise (0.1 N, 0.005 N*m). Columns: RMS error of ``qd`` and ``qdd`` against MuJoCo's states
   relative to their RMS, the base-parameter error of the linear method with offsets, and
   the seconds the smoothing took. Every variant drops the same 0.1 s at each end.
3. **Delay.** Joints and wrench at 500 Hz on interleaved clocks, the wrench stamped late by a
   known delay: ``estimate_delay``'s answer, its time, and the base-parameter error after.

Run: ``PYTHONPATH=. python benchmarks/recordings.py`` (needs ``mujoco``, the dev extra).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import cpu_description  # benchmarks/machine.py

from ineid.data.recordings.pipeline import Streams, import_recording, recording_dataset
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.signals import LowPass, choose_cutoff, derivatives
from ineid.identify import SolveSettings, solve_dataset
from ineid.identify.delay import estimate_delay

POSE = "0.03,-0.02,-0.05,3.1,0.2,0.7"
EDGE_S = 0.1
ENCODER_BITS = 17
WRENCH_SIGMA = np.array([0.1, 0.1, 0.1, 0.005, 0.005, 0.005])


def base_error(res, theta_unknown) -> np.ndarray:
    b = res.base
    truth = theta_unknown @ b.B.T
    return np.abs(res.base_hat[0] - truth) / np.maximum(np.abs(truth), b.scales[b.base_index])


def paths_table(lab) -> None:
    print("\n1. Every path, ineid's import (default filter and cut-off), error against MuJoCo's truth")
    print(f"{'file':<12} {'bias':<9} {'method':<11} {'import s':>9} {'solve s':>8} {'max err':>9} {'median err':>11}")
    settings = ImportSettings(sensor_pose=POSE)
    cases = [(k, "estimate") for k in ("csv", "ros1", "sqlite3", "mcap", "bare-mcap")] + [("csv-tared", "none")]
    for kind, _ in cases:  # the files are written before the timings, and JAX compiles once, untimed
        lab.file(kind)
    solve_dataset(
        import_recording(lab.file("csv"), lab.model, settings)[0], SolveSettings(bias="estimate"), model=lab.model
    )
    for kind, bias in cases:
        path = lab.file(kind)
        t0 = time.perf_counter()
        ds, summary = import_recording(path, lab.model, settings)
        t_import = time.perf_counter() - t0
        for method in ("linear", "nonlinear", "consistent"):
            t0 = time.perf_counter()
            res = solve_dataset(ds, SolveSettings(method=method, bias=bias), model=lab.model)
            t_solve = time.perf_counter() - t0
            err = base_error(res, lab.theta_unknown)
            print(
                f"{kind:<12} {bias:<9} {method:<11} {t_import:>9.2f} {t_solve:>8.2f} {err.max():>9.2e} "
                f"{np.median(err):>11.2e}"
            )
    print(f"(import: {summary.lines()[1]})")


def butterworth(t, q, w, fc):
    h = t[1] - t[0]
    lp = LowPass(fc, 1.0 / h)
    qs = lp.apply(q)
    qd, qdd = derivatives(qs, h)
    return qs, qd, qdd, lp.apply(w)


def savgol(t, q, w, window):
    from scipy.signal import savgol_filter

    h = t[1] - t[0]
    kw = {"window_length": window, "polyorder": 3, "axis": 0, "mode": "interp"}
    return (
        savgol_filter(q, **kw),
        savgol_filter(q, deriv=1, delta=h, **kw),
        savgol_filter(q, deriv=2, delta=h, **kw),
        savgol_filter(w, **kw),
    )


def spline(t, q, w, lam):
    from scipy.interpolate import make_smoothing_spline

    cols = []
    for x in q.T:
        s = make_smoothing_spline(t, x, lam=lam)
        cols.append((s(t), s.derivative(1)(t), s.derivative(2)(t)))
    ws = np.column_stack([make_smoothing_spline(t, x, lam=lam)(t) for x in w.T])
    return (*(np.column_stack([c[i] for c in cols]) for i in range(3)), ws)


def spline_gcv_lam(t, q) -> tuple[float, float]:
    """The ``lam`` scipy's generalized cross-validation picks per joint angle (their median), and
    the seconds the GCV fits took (recovering ``lam``, which scipy does not return, not counted)."""
    from scipy.interpolate import make_smoothing_spline

    lams, seconds = [], 0.0
    for x in q.T:
        t0 = time.perf_counter()
        fitted = make_smoothing_spline(t, x)(t)  # lam by GCV
        seconds += time.perf_counter() - t0
        lams.append(_match_lam(t, x, fitted))
    return float(np.median(lams)), seconds


def _match_lam(t, x, fitted) -> float:
    """The ``lam`` whose fit leaves the same residual sum of squares (monotonic in ``lam``), by bisection in log10."""
    from scipy.interpolate import make_smoothing_spline

    lo, hi = -30.0, 10.0
    target = np.sum((x - fitted) ** 2)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        r = np.sum((x - make_smoothing_spline(t, x, lam=10**mid)(t)) ** 2)
        lo, hi = (mid, hi) if r < target else (lo, mid)
    return 10 ** (0.5 * (lo + hi))


def evaluate(lab, t, q_true, qd_true, qdd_true, smoothed, seconds):
    qs, qd, qdd, ws = smoothed
    h = t[1] - t[0]
    k = int(round(EDGE_S / h))
    sl = slice(k, len(t) - k)

    def rel(a, b):
        return float(np.sqrt(np.mean((a[sl] - b[sl]) ** 2)) / np.sqrt(np.mean(b[sl] ** 2)))

    streams = Streams(t[sl], qs[sl], qd[sl], qdd[sl], t[sl], ws[sl], "benchmark")
    ds, _ = recording_dataset(streams, lab.model, ImportSettings(sensor_pose=POSE))
    res = solve_dataset(ds, SolveSettings(bias="estimate"), model=lab.model)
    return rel(qd, qd_true), rel(qdd, qdd_true), float(base_error(res, lab.theta_unknown).max()), seconds


def filters_table(lab, encoders: bool, wrench_noise: bool, rng) -> None:
    sim = lab.sim
    t, q, w = sim.time, sim.q.copy(), lab.reading.copy()
    title = []
    if encoders:
        res = 2 * np.pi / 2**ENCODER_BITS
        q = np.round(q / res) * res
        title.append(f"{ENCODER_BITS}-bit encoders")
    if wrench_noise:
        w = w + rng.normal(size=w.shape) * WRENCH_SIGMA
        title.append(f"wrench noise {WRENCH_SIGMA[0]:g} N / {WRENCH_SIGMA[3]:g} N*m")
    rate = 1.0 / (t[1] - t[0])
    choice = choose_cutoff(q, rate)
    title = ", ".join(title) or "noise-free"
    print(f"\n2. Filters, {title}; ineid's default cut-off: {choice.cutoff:.3g} Hz ({choice.limited})")
    print(f"{'smoother':<34} {'qd err':>9} {'qdd err':>9} {'base err':>9} {'smooth s':>9}")
    rows = []
    fcs = sorted({5.0, 10.0, 20.0, 40.0, 70.0, 100.0, round(choice.cutoff, 3)})
    for fc in fcs:
        t0 = time.perf_counter()
        sm = butterworth(t, q, w, fc)
        rows.append(
            (
                f"Butterworth fc={fc:g} Hz" + (" (default)" if fc == round(choice.cutoff, 3) else ""),
                evaluate(lab, t, sim.q, sim.qd, sim.qdd, sm, time.perf_counter() - t0),
            )
        )
    for window in (11, 21, 41, 81, 161, 321):
        t0 = time.perf_counter()
        sm = savgol(t, q, w, window)
        rows.append(
            (
                f"Savitzky-Golay cubic, {window} samples",
                evaluate(lab, t, sim.q, sim.qd, sim.qdd, sm, time.perf_counter() - t0),
            )
        )
    h = t[1] - t[0]
    for fc in (5.0, 10.0, 20.0, 40.0, 100.0):
        lam = 1.0 / (h * (2 * np.pi * fc) ** 4)  # |H(f)| = 1 / (1 + lam h^-1 (2 pi f)^4): half gain at fc
        t0 = time.perf_counter()
        sm = spline(t, q, w, lam)
        rows.append(
            (
                f"smoothing spline, half gain {fc:g} Hz",
                evaluate(lab, t, sim.q, sim.qd, sim.qdd, sm, time.perf_counter() - t0),
            )
        )
    lam, t_gcv = spline_gcv_lam(t, q)
    t0 = time.perf_counter()
    sm = spline(t, q, w, lam)
    fc_gcv = (1.0 / (lam * h)) ** 0.25 / (2 * np.pi)
    rows.append(
        (
            f"smoothing spline, GCV ({fc_gcv:.3g} Hz)",
            evaluate(lab, t, sim.q, sim.qd, sim.qdd, sm, t_gcv + time.perf_counter() - t0),
        )
    )
    for name, (e_qd, e_qdd, e_base, sec) in rows:
        print(f"{name:<34} {e_qd:>9.2e} {e_qdd:>9.2e} {e_base:>9.2e} {sec:>9.3f}")


def delay_table(lab) -> None:
    sim = lab.sim
    t, q, w = sim.time, sim.q, lab.reading
    print("\n3. Delay estimated from the model: joints at 500 Hz, wrench at 500 Hz half a sample later, stamped late")
    print(
        f"{'true delay ms':>13} {'estimate ms':>12} {'error us':>9} {'residual':>9} {'at 0':>9} {'seconds':>8} "
        f"{'base err':>9}"
    )
    for true in (0.003, -0.0123, 0.0):
        streams = Streams(t[0::2], q[0::2], None, None, t[1::2] + true, w[1::2], "benchmark")
        t0 = time.perf_counter()
        est = estimate_delay(streams, lab.model, ImportSettings(sensor_pose=POSE))
        seconds = time.perf_counter() - t0
        ds, _ = recording_dataset(streams, lab.model, ImportSettings(sensor_pose=POSE, delay=est.delay))
        err = base_error(solve_dataset(ds, SolveSettings(bias="estimate"), model=lab.model), lab.theta_unknown).max()
        print(
            f"{1e3 * true:>13.4g} {1e3 * est.delay:>12.5g} {1e6 * abs(est.delay - true):>9.2f} "
            f"{est.residual:>9.2e} {est.residual_at_zero:>9.2e} {seconds:>8.2f} {err:>9.2e}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="seconds simulated (default 10)")
    args = parser.parse_args()
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.mujoco_arm import LabRecording

    print(f"machine: {cpu_description()}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        lab = LabRecording(Path(tmp), duration=args.duration)
        print(
            f"MuJoCo: {args.duration:g} s at 1 kHz simulated in {time.perf_counter() - t0:.1f} s; "
            f"max |qd| {np.abs(lab.sim.qd).max():.2f} rad/s, max |qdd| {np.abs(lab.sim.qdd).max():.1f} rad/s^2"
        )
        paths_table(lab)
        rng = np.random.default_rng(0)
        filters_table(lab, encoders=False, wrench_noise=False, rng=rng)
        filters_table(lab, encoders=True, wrench_noise=False, rng=rng)
        filters_table(lab, encoders=True, wrench_noise=True, rng=rng)
        delay_table(lab)


if __name__ == "__main__":
    main()
