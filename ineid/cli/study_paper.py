"""``ineid study paper``: the paper's section 4 on its own data layout, per parameter, its claims checked.

The command prints its sections one after the other (:data:`SECTIONS` order): the classical solvers
(:mod:`ineid.studies.paper`), then the paper's claims, and with ``--networks DIR`` the paper's
network exploration (``ineid study networks --plan decisive``, its quick size with ``--quick``).
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from ineid.cli.options import SEED, WORKERS, LibraryChoice, PlotFile, names_in, numbers, quiet, robot_options
from ineid.cli.output import ProgressBar, console, shown, table
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs

_STUDY = "ineid.studies.paper"


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.0f}%"


def print_classical(con, rows, title: str) -> None:
    """A table with a row per parameter and method: per number of frames the share within 5 %, in the 50-95 %
    accuracy band, and the median relative error; then each parameter's identifiability reason."""
    frames = sorted({r.frames for r in rows})
    methods = list(dict.fromkeys(r.method for r in rows))
    params = list(dict.fromkeys(r.parameter for r in rows))
    by = {(r.parameter, r.method, r.frames): r for r in rows}
    cols = ["parameter", "id.", "method"]
    for f in frames:
        cols += [f"F={f} <=5%", f"F={f} 50-95%", f"F={f} med"]
    t = table(title, cols, left=("parameter", "method"))
    for p in params:
        for i, m in enumerate(methods):
            cells = []
            for f in frames:
                r = by[(p, m, f)]
                cells += [
                    _pct(r.within_5),
                    _pct(r.band_50_95),
                    "-" if math.isnan(r.median_error) else f"{r.median_error:.2g}",
                ]
            ident = ("yes" if r.identifiable else "no") if i == 0 else ""
            t.add_row(shown(p) if i == 0 else "", ident, m, *cells)
    con.print(t)
    t = table(
        "Why: the standard parameters each one needs, and the base parameters (what the data fix) they appear in",
        ("parameter", "why"),
        left=("parameter", "why"),
    )
    for p in params:
        t.add_row(shown(p), shown(by[(p, methods[0], frames[0])].reason))
    con.print(t)


def print_claims(con, claims) -> None:
    t = table(
        "The paper's claims (section 4), checked",
        ("claim", "verdict", "evidence"),
        left=("claim", "verdict", "evidence"),
    )
    for claim, verdict, evidence in claims:
        t.add_row(claim, verdict, shown(evidence))
    con.print(t)


SECTIONS = ("classical", "claims", "networks")
"""What the command prints, in order (the networks with ``--networks``)."""


@click.command("paper")
@robot_options(positional="optional", with_gravity=False)
@click.option(
    "--quick",
    is_flag=True,
    help="The CI size: 20 random configurations of 100 frames (default: the "
    "paper's 100 x 100 factorial configurations).",
)
@click.option(
    "--n-configs",
    type=click.IntRange(min=1),
    default=None,
    help="Random configurations instead of the paper's 10,000 (overrides --quick).",
)
@click.option(
    "--frames",
    default="4,10,100",
    show_default=True,
    callback=numbers(int, "--frames", 1),
    help="Frames fitted per configuration, comma-separated.",
)
@click.option(
    "--methods",
    default=None,
    callback=names_in(f"{_STUDY}:METHODS", "--methods"),
    help="Comma-separated, default all: lsqlin, lsqnonlin, linear, consistent.",
)
@click.option(
    "--parameters",
    type=LibraryChoice(f"{_STUDY}:PARAMETERS"),
    default="paper",
    show_default=True,
    help="paper: mass, centre of mass, inertia about it (the paper's 20); standard: ineid's (first "
    "moments, inertia about the link origin).",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--workers", type=WORKERS, default=1, show_default=True, help="Processes for consistent's IPOPT.")
@click.option(
    "--csv",
    "csv_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write the rows (method, frames, parameter) as CSV.",
)
@click.option(
    "--plot",
    "plot_path",
    type=PlotFile(),
    default=None,
    help="Write the share within 5 % per parameter (PNG, or the format of the suffix).",
)
@click.option(
    "--networks",
    "networks_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    metavar="DIR",
    help="Then the paper's network exploration too (ineid study networks --plan decisive, "
    "--quick with --quick), its sweeps and claims written to DIR (sweaty-arm only).",
)
@overwrite_option
@click.pass_context
def study_paper(
    ctx,
    robot,
    quick,
    n_configs,
    frames,
    methods,
    parameters,
    seed,
    workers,
    csv_path,
    plot_path,
    networks_dir,
    overwrite,
):
    """The paper's classical experiments on ROBOT (default sweaty-arm): lsqlin, lsqnonlin, linear and consistent
    on the paper's layout of clean data, per parameter in the paper's terms (share within 5 %, the 50-95 %
    accuracy band), with why each parameter is or is not identifiable, and the paper's claims checked; with
    --networks, then its network exploration (`ineid study networks`)."""
    from dataclasses import replace

    from ineid.identify.identifiability import frame_minimum
    from ineid.studies.paper import METHODS, SIZES, check_claims, paper_study, plot, write_rows

    for path, option in ((csv_path, "--csv"), (plot_path, "--plot")):
        if path is not None:
            prepare_output(path, overwrite, inputs=robot_inputs(robot), option=option)
    if networks_dir is not None:
        if robot.robot != "sweaty-arm":
            raise click.UsageError(f"--networks re-runs the paper's networks on sweaty-arm; drop it for {robot.robot}")
        if networks_dir.exists() and any(networks_dir.iterdir()) and not overwrite:
            raise click.UsageError(
                f"--networks {networks_dir} holds files; give an empty or new folder, or "
                "--overwrite (or continue it with ineid study networks --resume)"
            )
    size = SIZES["quick" if quick else "full"]
    if n_configs is not None:
        size = replace(size, per_link=None, n_configs=n_configs)
    model = robot.load()
    methods = methods or tuple(METHODS)
    with ProgressBar("paper study", "solves", quiet(ctx)) as bar:
        rows, _ = paper_study(model, size, frames, methods, seed, workers, parameters, progress=bar)
    n = size.combination().count(len(model.unknown_links))
    con = console()
    print_classical(
        con,
        rows,
        f"The paper's classical experiments, {model.name}: {n:,} configurations, clean data, "
        f"{parameters} parameters (share within 5 %, in the 50-95 % accuracy band, median "
        "relative error)",
    )
    minimum = frame_minimum(model)
    print_claims(con, check_claims(rows, minimum))
    written = []
    if csv_path is not None:
        write_rows(rows, csv_path)
        written.append(str(csv_path))
    if plot_path is not None:
        plot(rows, plot_path, f"{model.name}: share of {n:,} configurations within 5 %")
        written.append(str(plot_path))
    if written:
        click.echo(f"wrote {' and '.join(written)}")
    if networks_dir is not None:  # the networks' section: the same command as ineid study networks
        from ineid.cli.study_networks import study_networks

        ctx.invoke(study_networks, plan_name="decisive", quick=quick, out_dir=networks_dir, overwrite=overwrite)
