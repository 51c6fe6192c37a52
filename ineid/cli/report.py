"""``ineid report``: one self-contained HTML page of an identification; and what ``ineid solve`` writes
beside its results (``--plot``, ``--plot-span``, ``--report``)."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.output import console, plain, shown
from ineid.cli.output_files import overwrite_option, prepare_output, results_inputs

plot_span_option = click.option(
    "--plot-span",
    "plot_span",
    default=None,
    metavar="START:STOP",
    callback=lambda ctx, param, v: _span(v),
    help="Seconds of the validation frames --plot shows (default: all of them up to 20 s, else the first 10 s); "
    "the RMS is over all of them.",
)
report_option = click.option(
    "--report",
    "report_path",
    type=click.Path(path_type=Path),
    default=None,
    metavar="FILE.html",
    help="Write the HTML report (as `ineid report`): estimates, identifiability, validation, warnings.",
)


def _span(value: str | None) -> tuple[float, float] | None:
    import math

    if value is None:
        return None
    start, sep, stop = value.partition(":")
    try:
        span = (float(start), float(stop))
    except ValueError:
        span = (math.nan, math.nan)
    if not sep or not all(math.isfinite(x) for x in span) or span[1] <= span[0]:
        raise click.BadParameter(
            f"{value!r} is not START:STOP in seconds with START < STOP (0:10)", param_hint="'--plot-span'"
        )
    return span


def check_solve_outputs(plot_path, plot_span, report_path, overwrite, inputs) -> None:
    """``ineid solve``'s checks of ``--plot`` and ``--report`` before any work."""
    if plot_span is not None and plot_path is None:
        raise click.UsageError("--plot-span chooses what --plot shows: give --plot FILE too")
    for path, option in ((plot_path, "--plot"), (report_path, "--report")):
        if path is not None:
            prepare_output(path, overwrite, option=option, inputs=inputs)


def write_solve_outputs(
    res, ds, model, method, plot_path, plot_span, report_path, out, validate=None, overwrite=False
) -> None:
    """``ineid solve``'s validation plot and HTML report of ``res`` (solved on ``ds``; ``validate``: the
    separate validation recording), each a line on the console."""
    con = console()
    if plot_path is not None and res.success.any():
        from ineid.report.plot import plot_validation, validation

        v = validation(res, ds, model)
        name = plain(res.meta["robot"])  # one line in the title, and not a page long
        plot_validation(
            v, plot_path, title=f"{name if len(name) <= 60 else name[:57] + '...'}, {method}: ", span=plot_span
        )
        from ineid.report.fitted import rms_lines

        lines = rms_lines(res.meta, v.axes, v.units, v.rms)
        con.print(f"residual RMS per axis of the plotted {shown(v.source)}: {shown('; '.join(lines))}", soft_wrap=True)
        con.print(f"wrote {shown(plot_path)}")
    elif plot_path is not None:
        con.print(f"no configuration identified: {shown(plot_path)} not written")
    if report_path is not None:
        from ineid.report.html import ReportInputs, build_report, write_report

        inputs = ReportInputs(res, ds, validate, model, results_path=Path(out))
        write_report(build_report(inputs), report_path, overwrite=overwrite)
        con.print(f"wrote {shown(report_path)}")


@click.command("report")
@click.argument("results_path", metavar="RESULTS", type=click.Path(path_type=Path))
@click.option(
    "--data",
    "data_path",
    type=click.Path(path_type=Path),
    default=None,
    metavar="DATA.h5",
    help="The dataset solved, where it is now (default: the path the results record).",
)
@click.option(
    "--validate",
    "validate_path",
    type=click.Path(path_type=Path),
    default=None,
    metavar="REC.h5",
    help="The separate validation recording (solve --validate), where it is now.",
)
@click.option(
    "--config",
    type=int,
    default=None,
    help="Configuration detailed (index in the dataset; default: the first identified).",
)
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .html file to write.")
@overwrite_option
def report(results_path, data_path, validate_path, config, out, overwrite) -> None:
    """One self-contained HTML report of a results file of `ineid solve`: robot, data, method,
    identifiability, estimates beside the CAD values with std, physical validity, validation
    (measured vs predicted, residual and its spectrum, warnings), excitation. No network needed to
    view it; print it from the browser."""
    from ineid.report.html import build_report, inputs_from_files, write_report

    read = [
        ("the input results file", results_path),
        ("the dataset (--data)", data_path),
        ("the validation recording (--validate)", validate_path),
        *results_inputs(results_path),
    ]
    prepare_output(out, overwrite, inputs=read)
    inputs = inputs_from_files(results_path, data_path, validate_path)
    html = build_report(inputs, config)
    write_report(html, out, overwrite=overwrite)
    for what, fix in inputs.missing:
        click.echo(plain(f"warning: {what}; {fix}"), err=True)
    click.echo(f"wrote {out}" + (" (missing parts are named at its top)" if inputs.missing else ""))


def register(main: click.Group) -> None:
    main.add_command(report)
