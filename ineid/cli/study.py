"""``ineid study``: the noise study here; ``study formulations``, ``paper``, ``sensors`` and ``networks``
in their own modules."""

from __future__ import annotations

import os
from pathlib import Path

import click

from ineid.cli.options import (
    NOISE_MAX,
    SEED,
    WORKERS,
    deprecated_alias,
    names_in,
    numbers,
    quiet,
    robot_options,
)
from ineid.cli.output import ProgressBar, console, table
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs

_SOLVE = "ineid.identify.solve"


@click.group()
def study() -> None:
    """Studies that sweep settings and write a table and a plot."""


@study.command("noise")
@robot_options(positional="optional", with_gravity=False)
@click.option(
    "--levels",
    default="0,0.5,1,2,4",
    show_default=True,
    callback=numbers(float, "--levels", 0, NOISE_MAX),
    help="Noise levels, multiples of force 0.5 N, moment 0.05 N*m, qd 0.01 rad/s, qdd 0.1 rad/s^2.",
)
@click.option(
    "--fit-frames",
    default="10,50,200",
    show_default=True,
    callback=numbers(int, "--fit-frames", 1),
    help="Frames fitted per configuration, comma-separated (one study line each).",
)
@deprecated_alias("--frames", "fit_frames", "--fit-frames", callback=numbers(int, "--frames", 1))
@click.option(
    "--n-configs", type=click.IntRange(min=1), default=200, show_default=True, help="Configurations per level."
)
@deprecated_alias("--configs", "n_configs", "--n-configs", type=click.IntRange(min=1))
@click.option(
    "--methods",
    default="linear,weighted,consistent",
    show_default=True,
    callback=names_in("ineid.studies.noise:STUDY_METHODS", "--methods"),
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--workers", type=WORKERS, default=None, help="Processes for IPOPT (default: CPU count, at most 4 x).")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for noise_study.csv and noise_study.png.",
)
@overwrite_option
@click.pass_context
def study_noise(ctx, robot, levels, fit_frames, n_configs, methods, seed, workers, out_dir, overwrite):
    """Errors and physical validity of linear, weighted and consistent estimates under noise."""
    from ineid.studies.noise import noise_study, plot, write_rows

    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, png_path = out_dir / "noise_study.csv", out_dir / "noise_study.png"
    for p in (csv_path, png_path):
        prepare_output(p, overwrite, inputs=robot_inputs(robot))
    model = robot.load()
    with ProgressBar("noise study", "solves", quiet(ctx)) as bar:
        rows = noise_study(
            model, levels, fit_frames, n_configs, seed, methods, workers or os.cpu_count() or 1, progress=bar
        )
    t = table(
        f"Noise study, {model.name}, {n_configs} configurations per level",
        (
            "level",
            "frames",
            "method",
            "base err (median)",
            "base err (p95)",
            "standard err (median)",
            "identifiable std. err",
            "invalid",
            "failed",
            "s",
        ),
        left=("method",),
    )
    for r in rows:
        t.add_row(
            f"{r.level:g}",
            str(r.frames),
            r.method,
            f"{r.base_error_median:.3g}",
            f"{r.base_error_p95:.3g}",
            f"{r.standard_error_median:.3g}",
            f"{r.identifiable_error_median:.3g}",
            f"{100 * r.invalid_share:.1f}%",
            f"{100 * r.failed_share:.1f}%",
            f"{r.seconds:.1f}",
        )
    console().print(t)
    write_rows(rows, csv_path)
    plot(rows, png_path)
    click.echo(f"wrote {csv_path} and {png_path}")


def register(main: click.Group) -> None:
    from ineid.cli.study_formulations import study_formulations
    from ineid.cli.study_networks import study_networks
    from ineid.cli.study_paper import study_paper
    from ineid.cli.study_sensors import study_sensors

    study.add_command(study_formulations)
    study.add_command(study_paper)
    study.add_command(study_sensors)
    study.add_command(study_networks)
    main.add_command(study)
