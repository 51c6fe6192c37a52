"""The constant delay between a recording's wrench and joint clocks, estimated from the model.

A wrench stamped ``t`` that was measured at ``t - d`` breaks ``w(t) = X Psi(q(t), qd(t),
qdd(t)) theta + b``. For a candidate delay ``d`` the frames' regressor stays what it is (the
joints are not touched) and only the wrench is read at ``t + d`` from the filtered wrench
stream (a cubic spline through it), so the least-squares residual of the linear model with
offsets

    r(d) = min over theta, b of  sum_k || D (w(t_k + d) - X Psi_k theta - b) ||^2

is a projection: ``r(d) = || (I - Q Q^T) D y_c(d) ||^2`` with ``Q`` an orthonormal basis of
the centred, axis-scaled base columns, computed once (``D``: one over each axis's RMS, so
forces and moments count alike; ``y_c``: centred per axis). The estimate is the ``d`` in
``[-max_delay, max_delay]`` that minimizes ``r``: a scan at a quarter of the frame interval,
then a bounded scalar minimization around the best point (``scipy.optimize``).
Only the model's structure enters (``theta`` and ``b`` are fitted for every ``d``), not its
CAD values. On the tests' MuJoCo recording (joints and wrench at 500 Hz on interleaved
clocks, the wrench stamped 3 ms late) it finds the delay to within 10 microseconds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ineid.data.recordings import signals
from ineid.data.recordings.pipeline import recording_dataset
from ineid.data.recordings.settings import ImportSettings
from ineid.data.recordings.summary import DelayEstimate
from ineid.data.recordings.timing import audit_stream
from ineid.errors import DatasetError
from ineid.identify.identifiability import base_parameters
from ineid.identify.systems import remove_offsets, stack

MAX_DELAY = 0.05
"""s, the default search range: delays within +-50 ms."""


def estimate_delay(streams, model, settings: ImportSettings, max_delay: float = MAX_DELAY) -> DelayEstimate:
    """The wrench delay (s; positive: the wrench stamps are late) that best fits the model (module docstring).

    Args:
        streams: the recording's :class:`ineid.data.recordings.streams.Streams`.
        model: the :class:`ineid.RobotModel`.
        settings: the :class:`ineid.data.recordings.settings.ImportSettings` (cut-off, rate, sensor pose,
            sign); its ``delay`` is ignored.
        max_delay: s, half the search range.

    Raises:
        DatasetError: as :func:`ineid.data.recordings.pipeline.recording_dataset`, or a recording too
            short for the search range.
    """
    from scipy.interpolate import make_interp_spline
    from scipy.optimize import minimize_scalar

    if not (max_delay > 0 and np.isfinite(max_delay)):
        raise DatasetError(f"the delay search range must be a positive number of seconds, got {max_delay}")
    ds, summary = recording_dataset(streams, model, replace(settings, delay=0.0, estimate_delay=False))
    t = ds.time[0]
    # the wrench stream as recording_dataset filters it, on its own uniform grid, as a spline
    # (its rows that hold the previous sample dropped, at its nominal step: ineid.data.recordings.timing)
    tw = np.asarray(streams.wrench_time, dtype=np.float64)
    w = np.asarray(streams.wrench, dtype=np.float64) * (-1.0 if settings.flip_wrench else 1.0)
    audit, kept = audit_stream("wrench", tw, w, settings.keep_repeats)
    tw_u, w_u = signals.to_uniform(tw[kept], w[kept], audit.step)
    hw = audit.step
    edge = 0.0
    if summary.cutoff is not None:
        w_u = signals.LowPass(summary.cutoff, 1.0 / hw).apply(w_u)
        edge = signals.edge_seconds(summary.cutoff)
    keep = (t - max_delay >= tw_u[0] + edge) & (t + max_delay <= tw_u[-1] - edge)
    base = base_parameters(model, bias=True)
    if keep.sum() < 2 * base.rank:
        raise DatasetError(
            f"{streams.source}: {keep.sum()} frames remain for a delay search over +-{max_delay:g} s; "
            "record longer or give --delay"
        )
    spline = make_interp_spline(tw_u, w_u, k=3, axis=0)
    t = t[keep]
    # a recording's one channel: the base wrench, in its sensor's frame
    w, y0 = stack(
        model,
        ds.q[:, keep],
        ds.qd[:, keep],
        ds.qdd[:, keep],
        np.zeros((1, len(t), 6)),
        ds.theta_known,
        ds.meta.channels,
    )
    wc, _, _ = remove_offsets(w, np.zeros_like(y0))
    scale = spline(t).std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    d_rows = np.tile(1.0 / scale, len(t))
    q_basis, _ = np.linalg.qr(wc[0][:, base.base_index] * d_rows[:, None])

    def objective(d: float) -> float:
        y = spline(t + d).reshape(-1) + y0[0]
        y = (y.reshape(-1, 6) - y.reshape(-1, 6).mean(axis=0)).reshape(-1) * d_rows
        e = y - q_basis @ (q_basis.T @ y)
        return float(e @ e / (y @ y))

    step = 0.25 * float(np.median(np.diff(t)))
    grid = np.arange(-max_delay, max_delay + 0.5 * step, step)
    values = np.array([objective(d) for d in grid])
    k = int(np.argmin(values))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": 1e-7})
    d = float(best.x) if best.fun <= values[k] else float(grid[k])
    return DelayEstimate(d, float(np.sqrt(objective(d))), float(np.sqrt(objective(0.0))))
