"""``ineid study formulations``: the base wrench against joint torques on MuJoCo data with joint friction."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ineid.cli.options import SEED, PlotFile, names_in, quiet, robot_options
from ineid.cli.output import ProgressBar, console, table
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs

_STUDY = "ineid.studies.formulations"


def _fmt(x: float, percent: bool = True) -> str:
    if math.isnan(x):  # not modelled
        return "-"
    return f"{100 * x:.3g}%" if percent else f"{x:.3g}"


@click.command("formulations")
@robot_options(positional="optional", with_gravity=False)
@click.option(
    "--quick", is_flag=True, help="The CI size: 2 configurations of 6 s at 50 Hz (default: 10 of 30 s at 100 Hz)."
)
@click.option("--n-configs", type=click.IntRange(min=1), default=None, help="Configurations (overrides the size).")
@click.option(
    "--duration",
    type=click.FloatRange(min=1.0, max=600.0),
    default=None,
    help="Seconds simulated per configuration (overrides the size).",
)
@click.option(
    "--formulations",
    default=None,
    callback=names_in(f"{_STUDY}:FORMULATIONS", "--formulations"),
    help="Comma-separated, default all: wrench, torque, torque+friction, both, two-step.",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--plot", "plot_path", type=PlotFile(), default=None, help="Write the plot (PNG, or the format of the suffix)."
)
@click.option(
    "--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path), default=None, help="Write the table as CSV."
)
@overwrite_option
@click.pass_context
def study_formulations(ctx, robot, quick, n_configs, duration, formulations, seed, plot_path, csv_path, overwrite):
    """The paper's claim, measured: ROBOT (default sweaty-arm) simulated by MuJoCo with joint friction
    (viscous, Coulomb, Stribeck), armature and sensor noise, identified from the base wrench, from joint
    torques with and without a friction model, and from both. Needs MuJoCo (pip install 'ineid[mujoco]')."""
    from dataclasses import replace

    from ineid.studies.formulations import (
        FORMULATIONS,
        SIZES,
        formulations_study,
        plot,
        write_rows,
    )
    from ineid.studies.mujoco_sim import import_mujoco

    import_mujoco("ineid study formulations")
    for path, option in ((plot_path, "--plot"), (csv_path, "--csv")):
        if path is not None:
            prepare_output(path, overwrite, inputs=robot_inputs(robot), option=option)
    size = SIZES["quick" if quick else "full"]
    size = replace(size, n_configs=n_configs or size.n_configs, duration=duration or size.duration)
    model = robot.load()
    with ProgressBar("formulations study", "configurations + formulations", quiet(ctx)) as bar:
        rows, data, results = formulations_study(model, size, seed, formulations or tuple(FORMULATIONS), progress=bar)
    _print_study(rows, data, model, size)
    written = []
    if csv_path is not None:
        write_rows(rows, csv_path)
        written.append(str(csv_path))
    if plot_path is not None:
        plot(rows, results, data, model, plot_path)
        written.append(str(plot_path))
    if written:
        click.echo(f"wrote {' and '.join(written)}")


def _print_study(rows, data, model, size) -> None:
    """One line per formulation (errors of the base parameters, the held-out channels and the drives' terms), and
    the drives the simulation gave each joint."""
    f = data.friction.per_joint(model.n_dof)
    t = table(
        f"Formulations study, {model.name}: {size.n_configs} MuJoCo configurations of {size.duration:g} s at "
        f"{size.rate:g} Hz, joint friction and armature, noise wrench 0.5 N / 0.05 N*m, torques 0.05 N*m",
        (
            "formulation",
            "params",
            "rank",
            "base err ideal",
            "base err friction",
            "held-out wrench",
            "held-out torque",
            "links' torque",
            "fv err",
            "fc err",
            "Ia err",
            "failed",
            "s",
        ),
        left=("formulation",),
    )
    for r in rows:
        t.add_row(
            r.formulation,
            str(r.n_params),
            str(r.rank),
            _fmt(r.base_error_ideal),
            _fmt(r.base_error),
            _fmt(r.wrench_error),
            _fmt(r.torque_error),
            _fmt(r.link_torque_error),
            _fmt(r.fv_error),
            _fmt(r.fc_error),
            _fmt(r.ia_error),
            f"{100 * r.failed_share:.0f}%",
            f"{r.seconds:.1f}",
        )
    con = console()
    con.print(t)
    con.print(
        "simulated drives per joint ("
        + ", ".join(model.joint_names)
        + "): "
        + "; ".join(
            f"{k} " + " ".join(f"{v:.3g}" for v in f[k])
            for k in ("viscous", "coulomb", "stribeck", "stribeck_velocity", "armature")
        ),
        markup=False,
    )
