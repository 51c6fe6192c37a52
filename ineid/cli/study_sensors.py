"""``ineid study sensors``: encoders alone, or with link gyroscopes and angular-acceleration sensors."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.options import SEED, PlotFile, names_in, numbers, quiet, robot_options
from ineid.cli.output import ProgressBar, console, table
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs


@click.command("sensors")
@robot_options(positional="optional", with_gravity=False)
@click.option(
    "--rates",
    default=None,
    callback=numbers(float, "--rates", 1, 1e5),
    metavar="HZ,...",
    help="Logging rates, Hz (default 100,500; --quick: 100).",
)
@click.option(
    "--bandwidths",
    default=None,
    callback=numbers(float, "--bandwidths", 0.01, 1e3),
    metavar="HZ,...",
    help="Motion bandwidths: the Fourier excitation's highest harmonic, Hz (default 0.5,2; --quick: 1).",
)
@click.option(
    "--sensors",
    default=None,
    callback=names_in("ineid.studies.sensors:SENSOR_SETS", "--sensors"),
    help="Sensor sets, comma-separated (default all).",
)
@click.option(
    "--n-configs",
    type=click.IntRange(min=1),
    default=None,
    help="Configurations (parameter sets and trajectories) per cell (default 5; --quick: 1).",
)
@click.option("--quick", is_flag=True, help="The test suite's size: one rate, one bandwidth, one configuration.")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--plot",
    "plot_path",
    type=PlotFile(),
    default=None,
    metavar="FILE",
    help="Write the errors as bars (.png, .pdf, .svg).",
)
@click.option(
    "--csv",
    "csv_path",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    metavar="FILE",
    help="Write the table as CSV.",
)
@overwrite_option
@click.pass_context
def study_sensors(ctx, robot, rates, bandwidths, sensors, n_configs, quick, seed, plot_path, csv_path, overwrite):
    """One experiment identified from fine encoders, coarse (10-, 12-bit) encoders, and coarse encoders with link
    gyroscopes and angular-acceleration sensors, over logging rate and motion bandwidth (docs/recordings.md)."""
    from dataclasses import replace

    from ineid.studies.sensors import SENSOR_SETS, SensorStudySize, plot, sensor_study, write_rows

    for p in (plot_path, csv_path):
        if p is not None:
            prepare_output(p, overwrite, inputs=robot_inputs(robot))
    size = SensorStudySize.quick() if quick else SensorStudySize()
    size = replace(
        size,
        **{k: v for k, v in (("rates", rates), ("bandwidths", bandwidths), ("n_configs", n_configs)) if v is not None},
    )
    if max(size.bandwidths) * 5 > min(size.rates) / 2:
        raise click.BadParameter(
            f"a {max(size.bandwidths):g} Hz motion needs frames at {10 * max(size.bandwidths):g} Hz "
            "or more (the filter's cut-off sits below a tenth of the rate): raise --rates or lower "
            "--bandwidths",
            param_hint="--bandwidths",
        )
    model = robot.load()
    with ProgressBar("sensor study", "cells", quiet(ctx)) as bar:
        rows = sensor_study(model, size, sensors or SENSOR_SETS, seed, progress=bar)
    t = table(
        f"Sensor study, {model.name}: {size.n_configs} configuration{'s' if size.n_configs != 1 else ''} per "
        f"cell, {size.period:g} s period, first {100 * size.fit_share:.0f} % fitted (linear)",
        ("rate Hz", "motion Hz", "sensors", "base err", "held-out err", "qd err", "qdd err", "s"),
        left=("sensors",),
    )
    for r in rows:
        t.add_row(
            f"{r.rate:g}",
            f"{r.bandwidth:g}",
            r.sensors,
            f"{r.base_error:.2g}",
            f"{r.held_out_error:.2g}",
            f"{r.qd_error:.2g}",
            f"{r.qdd_error:.2g}",
            f"{r.seconds:.1f}",
        )
    console().print(t)
    for p, write in ((csv_path, write_rows), (plot_path, plot)):
        if p is not None:
            write(rows, p)
            click.echo(f"wrote {p}")
