"""A validation plot a person can look at: measured against predicted wrench over time.

For one configuration (a recording has one) the held-out frames' measured wrench and the
estimate's prediction ``X Psi(q, qd, qdd) theta_hat + b_hat`` (sensor frame, offsets
included when estimated), one panel per axis with the residual ``measured - predicted``
under it, and the residual's RMS per axis in each panel's title. Without held-out frames the
fitted frames are shown, and the title says so. Any other measurement channels the results
were fitted on are shown the same way, one panel per stacked axis, named and in the units
the channels give. A long validation span is shown in part (``span``, default the first
:data:`ineid.report.figures.DEFAULT_SPAN` seconds of one longer than twice that), the
RMS always over all of it. :func:`validation_on` is the same for a separate recording
(``ineid solve ... --validate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
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
        series: ``time`` holds time stamps of a time series (else frame numbers of independent frames).
        qd: (F, n_dof) the frames' joint velocities, rad/s (None when unknown).
        blocks: ``(channel key, start, stop, channel kind)`` of each channel among the A axes.
        couplings: ``{channel key: C}`` of the channels read per motor of a coupled transmission.
        source: where the frames come from (text: "held-out frames", "the recording X").
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
    series: bool = False
    qd: np.ndarray | None = None
    blocks: tuple[tuple[str, int, int, str], ...] = (("wrench", 0, 6, "wrench"),)
    source: str = ""
    couplings: dict = field(default_factory=dict)

    def measured_text(self) -> str:
        """What the axes hold, in words: ``"joint torques 'tau' and base wrench 'wrench' (base frame)"`` (a
        wrench's frame is named, a joint channel has none)."""
        from ineid.report.fitted import channel_name

        names = [
            channel_name({"kind": kind, "key": key}) + (f" ({self.frame} frame)" if "wrench" in kind else "")
            for key, _, _, kind in self.blocks
        ]
        return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


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
    from ineid.identify.steps import predicted_wrench

    model = model or ds.model()
    i = _solved(res, config)
    held_out = res.n_frames_validation > 0
    frames = (
        slice(res.n_frames_fit, res.n_frames_fit + res.n_frames_validation) if held_out else slice(0, res.n_frames_fit)
    )
    one = ds.select(configs=[i])
    records = res.meta.get("channels")  # the channels fitted (a results file without them: the dataset's)
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    bias = None if res.bias_hat is None else res.bias_hat[i : i + 1]
    pred = predicted_wrench(model, one, res.theta_hat[i : i + 1], frames, bias=bias, channels=channels)[0]
    meas = one.measured(channels)[0, frames]
    t = one.time[0, frames] if one.time is not None else np.arange(ds.n_frames, dtype=np.float64)[frames]
    source = "held-out frames" if held_out else "fitted frames (none held out)"
    return _validation(model, channels, meas, pred, t, one, frames, held_out, int(res.config_index[i]), source)


def validation_on(res, ds, model=None, config: int | None = None) -> Validation:
    """The :class:`Validation` of ``res`` on a separate recording ``ds`` (``ineid solve ... --validate ds``).

    Every frame of ``ds`` is predicted by the estimates; with offsets estimated
    (``bias="estimate"``) each axis's offset is fitted alone on ``ds``, the parameters fixed (the
    mean residual taken out), as :func:`ineid.identify.joint.validation_error` does.

    Raises:
        DatasetError: the configuration was not solved, or none was.
    """
    from ineid.identify.steps import predicted_wrench

    model = model or ds.model()
    i = _solved(res, config)
    records = res.meta.get("channels")
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    one = ds.select(configs=[i])
    meas = one.measured(channels)[0]
    pred = predicted_wrench(model, one, res.theta_hat[i : i + 1], channels=channels)[0]
    if res.settings.bias == "estimate":
        pred = pred + (meas - pred).mean(axis=0) * channels.offset_mask(model)
    t = one.time[0] if one.time is not None else np.arange(ds.n_frames, dtype=np.float64)
    name = "frames of the validation recording" if ds.path is None else f"frames of the recording {Path(ds.path).name}"
    return _validation(model, channels, meas, pred, t, one, slice(None), True, int(res.config_index[i]), name)


def _solved(res, config: int | None) -> int:
    """The row of ``res`` holding configuration ``config`` (the file's index; None: the first solved one).

    Raises:
        DatasetError: none was solved, or ``config`` was not.
    """
    solved = np.flatnonzero(res.success)
    if not solved.size:
        raise DatasetError("no configuration was identified, so there is nothing to validate; see the solver status")
    hits = solved if config is None else np.flatnonzero((np.asarray(res.config_index) == config) & res.success)
    if not hits.size:
        raise DatasetError(
            f"configuration {config} was not solved; solved ones: {res.config_index[solved][:10].tolist()}"
        )
    return int(hits[0])


def _validation(model, channels, meas, pred, t, one, frames, held_out, config, source) -> Validation:
    rms = np.sqrt(np.mean((meas - pred) ** 2, axis=0))
    frame = "sensor" if channels.transform(model) is not None else "base"
    blocks = tuple((b.channel.key, b.start, b.stop, b.channel.kind) for b in channels.blocks(model))
    return Validation(
        t,
        meas,
        pred,
        rms,
        held_out,
        config,
        frame,
        channels.axes(model),
        channels.units(model),
        series=one.time is not None,
        qd=np.asarray(one.qd[0, frames]),
        blocks=blocks,
        source=source,
        couplings={
            b.channel.key: c
            for b in channels.blocks(model)
            if (c := getattr(b.channel, "coupling_matrix", lambda: None)()) is not None
        },
    )


def plot_validation(v: Validation, path: str | Path, title: str = "", span: tuple[float, float] | None = None) -> Path:
    """One panel per axis (fx..mz for the base wrench) of measured and predicted values over time with the
    residual under it, RMS in each title, the axes down two columns; written atomically.

    ``span``: ``(start, stop)`` seconds shown (default: :func:`ineid.report.figures.default_span`).
    ``title`` (it may hold names from the inputs) is drawn literally: mathtext is off for it.
    """
    import matplotlib.pyplot as plt

    from ineid._atomic import save_figure
    from ineid.report.figures import validation_figure

    fig = validation_figure(v, title=title, span=span)
    try:
        return save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
