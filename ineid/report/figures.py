"""The figures of the validation plot and the HTML report (matplotlib, Agg; no display needed).

* :func:`validation_figure`: per axis, measured against predicted over a readable span, the
  residual under it (with the noise band ``+-sigma`` where the noise is known);
* :func:`spectrum_figure`: each axis's residual amplitude spectrum (Hann window), the noise's
  white level beside it;
* :func:`data_uri`: a figure as an inline ``data:image/png;base64,...`` (the report needs no
  file or network beside it).

Names from the inputs (axis names, the robot's) are drawn literally: mathtext off.
"""

from __future__ import annotations

import base64
import io

import numpy as np

DEFAULT_SPAN = 10.0
"""Seconds a long validation span is cut to by default (one of up to twice this is shown whole)."""


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def default_span(time: np.ndarray, series: bool) -> tuple[float, float] | None:
    """The whole span (None) when it is at most 2 x :data:`DEFAULT_SPAN` s or no time series; else its first 10 s."""
    if not series or len(time) < 2 or time[-1] - time[0] <= 2 * DEFAULT_SPAN:
        return None
    return float(time[0]), float(time[0] + DEFAULT_SPAN)


def _window(v, span) -> tuple[np.ndarray, str]:
    """The frames of ``v`` inside ``span`` and the text saying which part is shown."""
    span = default_span(v.time, v.series) if span is None else span
    if span is None:
        return np.arange(len(v.time)), "whole span"
    keep = np.flatnonzero((v.time >= span[0]) & (v.time <= span[1]))
    if keep.size < 2:
        from ineid.errors import DatasetError

        raise DatasetError(
            f"the span {span[0]:g}..{span[1]:g} s holds {keep.size} validation frames; the frames run "
            f"from {v.time[0]:.6g} to {v.time[-1]:.6g} s"
        )
    if keep.size == len(v.time):
        return keep, "whole span"
    return keep, f"{v.time[keep[0]]:.4g}..{v.time[keep[-1]]:.4g} s of {v.time[0]:.4g}..{v.time[-1]:.4g} s"


def validation_figure(v, title: str = "", span: tuple[float, float] | None = None, noise=None, columns: int = 2):
    """Measured vs predicted and the residual per axis of :class:`ineid.report.plot.Validation` ``v``.

    Args:
        span: ``(start, stop)`` s shown (default :func:`default_span`); RMS are over every frame of ``v``.
        noise: (A,) noise std per axis: a ``+-sigma`` band on the residual (NaN: none).
        columns: panels side by side.
    """
    plt = _plt()
    keep, shown = _window(v, span)
    n_axes = len(v.axes)
    n_rows = -(-n_axes // columns)
    fig = plt.figure(figsize=(6 * columns, 3.6 * n_rows + 0.8))
    grid = fig.add_gridspec(n_rows, columns, hspace=0.38, wspace=0.22)
    t = v.time[keep]
    x_label = "time (s)" if v.series else "frame"
    for k in range(n_axes):
        row, col = (k % n_rows, k // n_rows)
        cell = grid[row, col].subgridspec(2, 1, height_ratios=[2.2, 1], hspace=0.08)
        top = fig.add_subplot(cell[0])
        bottom = fig.add_subplot(cell[1], sharex=top)
        top.plot(t, v.measured[keep, k], lw=1.2, color="0.3", label="measured")
        top.plot(t, v.predicted[keep, k], lw=0.9, color="tab:red", ls="--", label="predicted")
        scale = np.sqrt(np.mean(v.measured[:, k] ** 2))
        rel = f", {100 * v.rms[k] / scale:.2g} % of RMS" if scale > 0 else ""
        top.set_title(f"{v.axes[k]}: residual RMS {v.rms[k]:.3g} {v.units[k]}{rel}", fontsize=10, parse_math=False)
        top.set_ylabel(f"{v.axes[k]} ({v.units[k]})", parse_math=False)
        top.tick_params(labelbottom=False)
        resid = v.measured[keep, k] - v.predicted[keep, k]
        sigma = np.nan if noise is None else float(noise[k])
        if np.isfinite(sigma) and sigma > 0:
            bottom.axhspan(-sigma, sigma, color="tab:blue", alpha=0.12, lw=0, label="+-noise")
        bottom.plot(t, resid, lw=0.8, color="tab:blue")
        bottom.axhline(0, color="0.5", lw=0.6)
        bottom.set_ylabel("residual", fontsize=9)
        if row == n_rows - 1 or k == n_axes - 1:
            bottom.set_xlabel(x_label)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        if k == 0:
            top.legend(loc="best", fontsize=8)
    which = v.source or ("held-out frames" if v.held_out else "fitted frames (none held out)")
    _heading(fig, f"{title}measured vs predicted, {which}, configuration {v.config}: {v.measured_text()} ({shown})")
    return fig


def _heading(fig, text: str) -> None:
    """``text`` as the figure's title, wrapped to its width, in a band of its own above the panels' titles.

    The band is sized in inches (lines of the title, then the panels' own titles), so no title overlaps
    a panel whatever the figure's height. The title may hold the robot's name: literal text, never
    mathtext (a "$" in it would be parsed).
    """
    import textwrap

    height, width = fig.get_figheight(), fig.get_figwidth()
    lines = textwrap.wrap(text, width=max(40, int(10 * width))) or [""]
    fig.suptitle("\n".join(lines), parse_math=False, y=1 - 0.12 / height, va="top", fontsize=12)
    band = 0.12 + 0.24 * len(lines) + 0.4  # inches: the margin, the title's lines, the first panels' titles
    fig.subplots_adjust(left=0.08, right=0.98, top=1 - band / height, bottom=0.5 / height)


def spectrum_figure(v, noise=None, columns: int = 3):
    """The residual's amplitude spectrum per axis (Hann window, mean removed), ``v`` a time series.

    The amplitude is ``|rfft(w r)| * 2 / sum(w)`` (a sinusoid of amplitude ``a`` at a bin's frequency
    reads ``a``); white noise of std ``sigma`` reads ``2 sigma sqrt(sum(w^2)) / sum(w)`` (RMS over the bins),
    drawn dashed where the noise is known.
    """
    plt = _plt()
    from matplotlib import ticker

    n_axes = len(v.axes)
    n_rows = -(-n_axes // columns)
    fig, axes = plt.subplots(n_rows, columns, figsize=(4.2 * columns, 2.6 * n_rows), squeeze=False)
    dt = float(np.median(np.diff(v.time)))
    w = np.hanning(len(v.time))
    freq = np.fft.rfftfreq(len(w), dt)
    white = 2 * np.sqrt(np.sum(w**2)) / np.sum(w)
    for k, ax in enumerate(axes.ravel()):
        if k >= n_axes:
            ax.set_visible(False)
            continue
        r = v.measured[:, k] - v.predicted[:, k]
        amp = np.abs(np.fft.rfft((r - r.mean()) * w)) * 2 / np.sum(w)
        top = float(np.max(amp[1:])) if amp.size > 1 else 0.0
        floor = top * 1e-4 if top > 0 else 1.0  # four decades: a log axis down to rounding would hold only ticks
        ax.semilogy(freq[1:], np.maximum(amp[1:], floor), lw=0.8, color="tab:blue")
        sigma = np.nan if noise is None else float(noise[k])
        if np.isfinite(sigma) and sigma > 0:
            ax.axhline(sigma * white, color="0.4", ls="--", lw=0.8, label="white noise level")
            ax.legend(fontsize=7, loc="upper right")
        ax.set_title(f"{v.axes[k]} residual ({v.units[k]})", fontsize=9, parse_math=False)
        ax.grid(alpha=0.3)
        # plain tick labels ("1e-02"): the default ones are mathtext, which costs more than the rest of the figure
        ax.yaxis.set_major_formatter(ticker.LogFormatter(labelOnlyBase=True))
        ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        if k // columns == n_rows - 1 or k + columns >= n_axes:
            ax.set_xlabel("frequency (Hz)")
    fig.subplots_adjust(
        left=0.07,
        right=0.98,
        top=1 - 0.35 / fig.get_figheight(),
        bottom=0.55 / fig.get_figheight(),
        hspace=0.45,
        wspace=0.25,
    )
    return fig


def data_uri(fig, dpi: int = 96) -> str:
    """``fig`` as an inline PNG ``data:`` URI (the figure is closed)."""
    plt = _plt()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
