"""A validation plot a person can look at: measured against predicted wrench over time.

For one configuration (a recording has one) the held-out frames' measured wrench and the
estimate's prediction ``X Psi(q, qd, qdd) theta_hat + b_hat`` (sensor frame, offsets
included when estimated), one panel per axis, with the residual's RMS per axis in each
panel's title. Without held-out frames the fitted frames are shown, and the title says so.
Any other measurement channels the results were fitted on are shown the same way, one
panel per stacked axis, named and in the units the channels give.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ineid.channels import WRENCH_AXES as AXES
from ineid.channels import WRENCH_UNITS as UNITS
from ineid.channels import ChannelSet
from ineid.errors import DatasetError


@dataclass
class Validation:
    """Measured and predicted wrench of one configuration's validation frames.

    Attributes:
        time: (F,) s (frame numbers when the dataset has no time stamps).
        measured, predicted: (F, A) the channels' values (the base wrench: N, N*m, its sensor's frame).
        rms: (A,) RMS of ``measured - predicted`` per axis.
        held_out: the frames were held out of the fit (else: the fitted frames).
        config: the configuration's index in the dataset file.
        frame: ``"sensor"`` or ``"base"``.
        axes, units: the names and units of the A axes.
    """

    time: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    rms: np.ndarray
    held_out: bool
    config: int
    frame: str
    axes: tuple[str, ...] = AXES
    units: tuple[str, ...] = UNITS


def validation(res, ds, model=None, config: int | None = None) -> Validation:
    """The :class:`Validation` of ``res`` (``ineid solve``'s results) on the dataset it was solved on.

    Args:
        res: :class:`ineid.identify.SolveResults`.
        ds: the dataset, with the same configurations selected.
        model: its :class:`ineid.RobotModel` (default: rebuilt from the dataset).
        config: which configuration (index in the file); default the first solved one.

    Raises:
        DatasetError: the configuration was not solved, or none was.
    """
    from ineid.identify.steps import predicted_wrench  # noqa: PLC0415

    model = model or ds.model()
    solved = np.flatnonzero(res.success)
    if not solved.size:
        raise DatasetError("no configuration was identified, so there is nothing to validate; see the solver status")
    if config is None:
        i = int(solved[0])
    else:
        hits = np.flatnonzero(np.asarray(res.config_index) == config)
        if not hits.size or not res.success[hits[0]]:
            raise DatasetError(f"configuration {config} was not solved; solved ones: {res.config_index[solved][:10].tolist()}")
        i = int(hits[0])
    held_out = res.n_frames_validation > 0
    frames = slice(res.n_frames_fit, res.n_frames_fit + res.n_frames_validation) if held_out else slice(0, res.n_frames_fit)
    one = ds.select(configs=[i])
    records = res.meta.get("channels")  # the channels fitted (a results file of ineid 0.1: the dataset's)
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    bias = None if res.bias_hat is None else res.bias_hat[i : i + 1]
    pred = predicted_wrench(model, one, res.theta_hat[i : i + 1], frames, bias=bias, channels=channels)[0]
    meas = one.measured(channels)[0, frames]
    t = one.time[0, frames] if one.time is not None else np.arange(ds.n_frames, dtype=np.float64)[frames]
    rms = np.sqrt(np.mean((meas - pred) ** 2, axis=0))
    frame = "sensor" if channels.transform(model) is not None else "base"
    return Validation(t, meas, pred, rms, held_out, int(res.config_index[i]), frame, channels.axes(model),
                      channels.units(model))


def plot_validation(v: Validation, path: str | Path, title: str = "") -> Path:
    """One panel per axis (fx..mz for the base wrench) of measured and predicted values over time, RMS in
    each title, the axes down two columns; written atomically.

    ``title`` (it may hold names from the inputs) is drawn literally: mathtext is off for it.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from ineid._atomic import save_figure  # noqa: PLC0415

    n_rows = -(-len(v.axes) // 2)
    fig, axes = plt.subplots(n_rows, 2, figsize=(12, 3 * n_rows), sharex=True, squeeze=False)
    for k, ax in enumerate(axes.T.ravel()):
        if k >= len(v.axes):
            ax.set_visible(False)
            continue
        ax.plot(v.time, v.measured[:, k], lw=1.2, color="0.3", label="measured")
        ax.plot(v.time, v.predicted[:, k], lw=0.9, color="tab:red", ls="--", label="predicted")
        scale = np.sqrt(np.mean(v.measured[:, k] ** 2))
        rel = f", {100 * v.rms[k] / scale:.2g} % of RMS" if scale > 0 else ""
        # axis names may come from the inputs (joint names): literal text
        ax.set_title(f"{v.axes[k]}: residual RMS {v.rms[k]:.3g} {v.units[k]}{rel}", fontsize=10, parse_math=False)
        ax.set_ylabel(f"{v.axes[k]} ({v.units[k]})", parse_math=False)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    axes[0, 0].legend(loc="best", fontsize=9)
    which = "held-out frames" if v.held_out else "fitted frames (none held out)"
    # The title holds the robot's name: literal text, never mathtext (a "$" in it would be parsed).
    fig.suptitle(f"{title}measured vs predicted wrench, {which}, configuration {v.config}, {v.frame} frame",
                 parse_math=False)
    fig.tight_layout()
    try:
        return save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
