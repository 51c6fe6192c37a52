"""``ineid export-mjcf``: the MuJoCo model with the identified links' inertials (``export-urdf``'s twin)."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.output import plain
from ineid.cli.output_files import overwrite_option, prepare_output, results_inputs


@click.command("export-mjcf")
@click.argument("results_path", metavar="RESULTS", type=click.Path(path_type=Path))
@click.option(
    "--robot",
    "robot",
    required=True,
    type=click.Path(path_type=Path),
    help="The MJCF (.xml) of the results' robot: identified from it, or the same robot (names must match).",
)
@click.option("--config", type=int, required=True, help="Configuration (index in the dataset).")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .xml file to write.")
@overwrite_option
def export_mjcf_cmd(results_path, robot, config, out, overwrite) -> None:
    """Write the MJCF ROBOT with the identified bodies' inertials of one configuration; the rest of the file as it
    was."""
    from ineid.identify import load_results
    from ineid.robots.mjcf_write import export_mjcf

    inputs = [("the input results file", results_path), ("the input MJCF", robot), *results_inputs(results_path)]
    prepare_output(out, overwrite, inputs=inputs)
    res = load_results(results_path)
    export_mjcf(res, config, robot, out, overwrite=overwrite)
    click.echo(
        f"wrote {out}: {plain(', '.join(res.meta['unknown_links']))} of configuration {config} ({res.settings.method})"
    )


def register(main: click.Group) -> None:
    main.add_command(export_mjcf_cmd)
