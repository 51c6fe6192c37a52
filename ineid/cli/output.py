"""Console output of the ``ineid`` commands: rich tables and progress bars.

Results go to stdout; progress bars and messages go to stderr, so ``ineid ... > file``
keeps the tables. Nothing here computes: each function renders what the library returned.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time

import click


def console():
    """A stdout console wide enough for ineid's tables."""
    from rich.console import Console

    return Console(highlight=False, soft_wrap=False, width=max(150, shutil.get_terminal_size((120, 24)).columns))


def console_err():
    from rich.console import Console

    return Console(stderr=True, highlight=False)


def plain(value: object) -> str:
    """``str(value)`` on one line: control and other unprintable characters shown escaped (``\\n``)."""
    text = str(value)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


def shown(value: object) -> str:
    """``value`` (a name or path from an input) as rich markup that prints it literally, on one line.

    A ``[bold]`` or ``[/]`` in a robot, link or joint name is text, not a style (nor a
    ``MarkupError``); wrap every such value in this before it goes into a string printed
    with rich markup.
    """
    from rich.markup import escape

    return escape(plain(value))


def table(title: str, columns, left=()):
    """A rich table with a left-justified title; columns right-justified unless named in ``left``.

    The title and the string cells are shown literally (:func:`shown`): they may hold names
    from the inputs; no cell is markup.
    """
    from rich.table import Table

    class _Table(Table):
        def add_row(self, *cells, **kwargs) -> None:
            super().add_row(*(shown(c) if isinstance(c, str) else c for c in cells), **kwargs)

    t = _Table(title=shown(title), title_justify="left")
    for col in columns:
        t.add_column(col, justify="left" if col in left else "right")
    return t


STATUS_SECONDS = 5.0
"""Seconds between two status lines of a :class:`ProgressBar` whose stderr is not a terminal."""


class ProgressBar:
    """A rich progress bar driven by ``callback(done, total)`` and, for what it is doing, :meth:`status`; silent
    with ``-q``."""

    def __init__(self, description: str, unit: str, quiet: bool) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(unit),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            disable=quiet,
            console=console_err(),
        )
        self._task = None
        self._description = shown(description)
        self._quiet, self._terminal = quiet, console_err().is_terminal
        self._last_line: float | None = None

    def __enter__(self):
        self._progress.__enter__()
        return self

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)

    def set_description(self, text: str) -> None:
        if self._task is not None:
            self._progress.update(self._task, description=shown(text))

    def __call__(self, done: int, total: int) -> None:
        if self._task is None:
            self._task = self._progress.add_task(self._description, total=total)
        self._progress.update(self._task, completed=done, total=total)

    def status(self, text: str) -> None:
        """What the work is doing now: the bar's description on a terminal; elsewhere (a log file, a pipe) a line
        ``ineid: TEXT`` on stderr at most every :data:`STATUS_SECONDS`, so a long run is never silent."""
        if self._quiet:
            return
        if self._terminal:
            if self._task is None:
                self._task = self._progress.add_task(self._description, total=None)
            self._progress.update(self._task, description=f"{self._description}: {shown(text)}")
            return
        now = time.monotonic()
        if self._last_line is None or now - self._last_line >= STATUS_SECONDS:
            self._last_line = now
            click.echo(f"ineid: {plain(text)}", err=True)


def print_results(res, out) -> None:
    """The summary of ``ineid solve``: successes, held-out error, error tables or the estimates."""
    import numpy as np

    con = console()
    n_ok = int(res.success.sum())
    _print_solve_summary(con, res, n_ok)
    # what decides the parameters the data do not: the CAD prior, or (the paper's solvers) where the solver stopped
    undecided = "no (solver)" if res.settings.method in ("lsqlin", "lsqnonlin") else "no (prior)"
    if res.theta_true is not None and n_ok:
        _print_errors(con, res, n_ok, undecided)
    elif n_ok:
        _print_estimates(con, res, int(np.flatnonzero(res.success)[0]), undecided)
    if res.bias_hat is not None and n_ok:
        i = int(np.flatnonzero(res.success)[0])
        # the axes and their units are the fitted channels' (the base wrench: fx..mz in N and N*m)
        from ineid.report.fitted import channel_records, is_wrench_only

        units = ", ".join(dict.fromkeys(res.units))
        wrenches = any("wrench" in str(r.get("kind")) for r in channel_records(res.meta))
        frame = (
            "the wrench's frame"
            if is_wrench_only(res.meta)
            else "each wrench in its sensor's frame, torques per joint"
            if wrenches
            else "per joint"
        )
        con.print(
            f"sensor offsets of configuration {int(res.config_index[i])} ({units}, {frame}): "
            + ", ".join(
                f"{shown(a)} {b:.5g} +- {s:.2g}"
                for a, b, s in zip(res.axes, res.bias_hat[i], res.bias_std[i], strict=True)
                if np.isfinite(b)
            )
        )
    con.print(f"wrote {shown(out)}")


def _print_solve_summary(con, res, n_ok: int) -> None:
    """How many configurations were identified, in what time, why the others failed; what was fitted, under
    which gravity; the held-out error and RMS per axis."""
    import numpy as np

    from ineid.identify.constrained_std import std_note
    from ineid.report.fitted import fitted_channels, held_out_error_name
    from ineid.robots.gravity import describe_gravity

    total = res.meta.get("total_seconds", float("nan"))
    con.print(
        f"[bold]{res.settings.method}[/bold] on {shown(res.meta['robot'])}: {n_ok}/{res.n} configurations identified "
        f"in {total:.2f} s ({1e3 * total / max(res.n, 1):.2f} ms each); fitted {res.n_frames_fit} frames each"
        + (f", validated on {res.n_frames_validation}" if res.n_frames_validation else "")
    )
    con.print(f"fitted: {shown(fitted_channels(res.meta))}; {describe_gravity(res.meta['gravity'])}", soft_wrap=True)
    con.print(std_note(res.settings.method, res.meta.get("std")), soft_wrap=True)
    if n_ok < res.n:
        statuses, counts = np.unique(res.status[~res.success].astype(str), return_counts=True)
        con.print("failed: " + "; ".join(f"{c} x {s}" for s, c in zip(statuses, counts, strict=True)))
    if res.n_frames_validation and n_ok:
        rel = res.validation_rel[res.success]
        with np.errstate(invalid="ignore"):  # inf (a zero wrench) between two values: nan (solve warns)
            median, p95 = np.median(rel), np.percentile(rel, 95)
        con.print(
            f"held-out {shown(held_out_error_name(res.meta))}: median {median:.3g}, 95th percentile {p95:.3g}",
            soft_wrap=True,
        )
    print_held_out_rms(con, res)


def print_held_out_rms(con, res) -> None:
    """The held-out RMS of every fitted axis, one line per channel in its units (nothing held out: says so)."""
    from ineid.report.fitted import held_out_rms, rms_lines

    found = held_out_rms(res)
    if found is None:
        if not res.n_frames_validation:
            con.print("held-out RMS: none (no frame held out)")
        return
    rms, frames = found
    lines = rms_lines(res.meta, res.axes, res.units, rms)
    con.print(f"held-out RMS ({shown(frames)}):")
    for line in lines:  # one line per channel, unwrapped: a joint's name and its value stay together
        con.print(f"  {shown(line)}", soft_wrap=True)


def _print_errors(con, res, n_ok: int, undecided: str) -> None:
    """Synthetic data: the relative errors of the standard and base parameters against the truth, and the share
    of physically valid estimates."""
    import numpy as np

    from ineid.identify import error_summary
    from ineid.params import all_links_physical

    for title, est, truth, names, ident in (
        ("standard parameters", res.theta_hat, res.theta_true, res.param_names, res.base.identifiable),
        ("base parameters (what the data determine)", res.base_hat, res.base_true, res.base.names, None),
    ):
        columns = ("parameter", "median", "95th pct", "within 1%", "within 5%")
        columns += ("identifiable",) if ident is not None else ()
        tab = table(f"Relative error, {title}, over {n_ok} configurations", columns, left=("parameter", "identifiable"))
        no_truth = np.all(np.isnan(truth[res.success]), axis=0)  # extra parameters the file does not simulate
        for k, row in enumerate(error_summary(est, truth, names, res.success, ident)):
            if no_truth[k]:
                continue
            cells = [
                row.name,
                f"{row.median:.3g}",
                f"{row.p95:.3g}",
                f"{100 * row.within_1:.1f}%",
                f"{100 * row.within_5:.1f}%",
            ]
            if ident is not None:
                cells.append("yes" if row.identifiable else undecided)
            tab.add_row(*cells)
        con.print(tab)
    valid = all_links_physical(np.nan_to_num(res.theta_links[res.success]))
    con.print(f"physically valid estimates: {100 * valid.mean():.1f}%")


def _print_estimates(con, res, i: int, undecided: str) -> None:
    """The standard and base parameters of configuration ``i`` (a successful one), with their std; a value below
    its resolution shown as ``0 (round-off)`` (:mod:`ineid.report.roundoff`)."""
    import numpy as np

    from ineid.report.roundoff import base_scale, parameter_scale, shown_value

    tab = table(
        f"Estimates of configuration {int(res.config_index[i])} (SI, about each link origin)",
        ("parameter", "estimate", "std", "prior (CAD)", "identifiable"),
        left=("parameter", "identifiable"),
    )
    for k, name in enumerate(res.param_names):
        std, scale = res.theta_std[i, k], parameter_scale(res.base, k)
        tab.add_row(
            name,
            shown_value(res.theta_hat[i, k], scale, std),
            "-" if not np.isfinite(std) else shown_value(std, scale, digits=3),
            f"{res.theta_prior[k]:.6g}",
            "yes" if res.base.identifiable[k] else undecided,
        )
    con.print(tab)
    tab = table("Base parameters", ("base parameter", "estimate", "std"), left=("base parameter",))
    for k, name in enumerate(res.base.names):
        std, scale = res.base_std[i, k], base_scale(res.base, k)
        tab.add_row(name, shown_value(res.base_hat[i, k], scale, std), shown_value(std, scale, digits=3))
    con.print(tab)


def print_evaluation(ev) -> None:
    """The report of ``ineid evaluate``: the network beside the floor and least squares."""

    con = console()
    con.print(
        f"evaluated on {ev.n_configs} configurations ({shown(ev.extra.get('configs'))}), {ev.frames_used} frames each"
    )
    tab = table(
        "Relative error of the standard parameters (median / 95th percentile) and R^2",
        ("parameter", "network", "p95", "R^2", "floor (null space)", "linear LS", "Gaussian prior", "identifiable"),
        left=("parameter", "identifiable"),
    )
    for k, name in enumerate(ev.network["names"]):
        lin = f"{ev.linear['median'][k]:.3g}" if ev.linear else "-"
        gp = f"{ev.gaussian['median'][k]:.3g}" if ev.gaussian else "-"
        tab.add_row(
            name,
            f"{ev.network['median'][k]:.3g}",
            f"{ev.network['p95'][k]:.3g}",
            f"{ev.network['r2'][k]:.3f}",
            f"{ev.floor['median'][k]:.3g}",
            lin,
            gp,
            "yes" if ev.identifiable[k] else "no",
        )
    con.print(tab)
    tab = table(
        "Relative error of the base parameters (median)",
        ("base parameter", "network", "R^2", "linear LS", "Gaussian prior"),
        left=("base parameter",),
    )
    for k, name in enumerate(ev.network_base["names"]):
        lin = f"{ev.linear_base['median'][k]:.3g}" if ev.linear_base else "-"
        gp = f"{ev.gaussian_base['median'][k]:.3g}" if ev.gaussian_base else "-"
        tab.add_row(name, f"{ev.network_base['median'][k]:.3g}", f"{ev.network_base['r2'][k]:.3f}", lin, gp)
    con.print(tab)
    lin = (
        (
            f"; linear LS: standard {ev.linear['overall_median']:.4g}, base {ev.linear_base['overall_median']:.4g}, "
            f"physical {100 * ev.linear_physical_share:.0f}%"
        )
        if ev.linear
        else ""
    )
    if ev.gaussian:
        lin += (
            f"; Gaussian prior: standard {ev.gaussian['overall_median']:.4g}, base "
            f"{ev.gaussian_base['overall_median']:.4g}"
        )
    con.print(
        f"median over all parameters: network standard {ev.network['overall_median']:.4g}, base "
        f"{ev.network_base['overall_median']:.4g} (per sample, before averaging: {ev.per_sample_median:.4g}); "
        f"null-space floor {ev.floor['overall_median']:.4g}{lin}"
    )
    rms = ", ".join(f"{v:.3g}" for v in ev.wrench_rms)
    con.print(
        f"wrench residual of the predictions, RMS per axis (N, N*m): {rms}; normalized {ev.wrench_normalized:.4g}; "
        f"physically valid predictions {100 * ev.physical_share:.0f}%"
    )


class DerivationProgress(logging.Handler):
    """Shows a SymPy derivation's progress on stderr, from the records :mod:`ineid.symbolic` logs.

    Nothing for a derivation that ends within ``delay`` seconds; after that, a progress bar
    with the step and the elapsed time on a terminal (it keeps ticking through a long step),
    else one line per step. A record with
    ``derivation_step = (done, total)`` and ``done == total`` ends the derivation.
    """

    delay = 1.0
    """Seconds a derivation runs before its progress is shown."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self._guard = threading.Lock()
        self._start = 0.0
        self._timer: threading.Timer | None = None
        self._progress = None
        self._task = None
        self._state: tuple[int, int, str] | None = None
        self._lines = False

    def emit(self, record: logging.LogRecord) -> None:
        step = getattr(record, "derivation_step", None)
        if step is None:
            return
        done, total = step
        text = plain(getattr(record, "derivation_text", record.getMessage()))
        with self._guard:
            if done >= total:
                self._finish(text)
                return
            if self._state is None:
                self._start = time.monotonic()
            self._state = (done, total, text)
            if self._progress is not None or self._lines:
                self._update()
            elif time.monotonic() - self._start >= self.delay:
                self._show_now()
            elif self._timer is None:  # shows it while a long step (the elimination) runs
                self._timer = threading.Timer(self.delay, self._show)
                self._timer.daemon = True
                self._timer.start()

    def _show(self) -> None:
        with self._guard:
            if self._state is not None and self._progress is None and not self._lines:
                self._show_now()

    def _show_now(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        con = console_err()
        if con.is_terminal:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._progress = Progress(
                TextColumn("deriving the regressor:"),
                TextColumn("{task.description}", markup=False),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=con,
            )
            self._progress.start()
            self._task = self._progress.add_task("", total=self._state[1])
        else:
            self._lines = True
        self._update()

    def _update(self) -> None:
        done, total, text = self._state
        if self._progress is not None:  # the bar counts finished steps: step `done` is under way
            self._progress.update(self._task, completed=done - 1, total=total, description=text)
        elif self._lines:
            click.echo(f"ineid: deriving the regressor, step {done} of {total}: {text}", err=True)

    def _finish(self, text: str) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self._progress is not None:
            self._progress.update(self._task, completed=self._state[1], description=text)
            self._progress.stop()
        elif self._lines:
            click.echo(f"ineid: deriving the regressor: {text}", err=True)
        self._timer = self._progress = self._task = self._state = None
        self._lines = False


def show_derivation_progress(on: bool) -> None:
    """Show (or stop showing) derivation progress on stderr (:class:`DerivationProgress`); idempotent.

    While on, the ``ineid.symbolic`` logger is at INFO so that its step records are made
    even when INFO messages are not shown (the ``ineid`` handler's own level drops those).
    """
    logger = logging.getLogger("ineid.symbolic")
    logger.handlers[:] = [h for h in logger.handlers if not isinstance(h, DerivationProgress)]
    logger.setLevel(logging.INFO if on else logging.NOTSET)
    if on:
        logger.addHandler(DerivationProgress())


def print_findings(findings) -> None:
    """Plausibility warnings (:class:`ineid.data.recordings.plausibility.Finding`), one line each on stderr.

    Shown with ``-q`` too: a quiet run is the one whose user would not look at the numbers.
    """
    import click

    for f in findings:
        click.echo(f"ineid: warning: {plain(f.message)}", err=True)
