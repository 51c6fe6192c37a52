"""``ineid excite``: design an excitation trajectory (the library: :mod:`ineid.excite.design`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from ineid.cli.channel_options import channel_options, chosen_channels
from ineid.cli.excite_summary import print_design, print_limits
from ineid.cli.imu_options import excite_sensors, imu_excite
from ineid.cli.options import (
    SEED,
    WORKERS,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    noise_model,
    noise_option,
    quiet,
    robot_options,
)
from ineid.cli.output import ProgressBar
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs
from ineid.cli.simulation import IMU_NOISE_KEYS

_SETTINGS = "ineid.excite.design:ExcitationSettings"


def _workspace(ctx, param, value):
    """``XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX`` -> six floats (the order and finiteness; the library checks the box)."""
    if value is None:
        return None
    try:
        box = tuple(float(v) for v in value.split(","))
    except ValueError:
        box = ()
    if len(box) != 6 or not all(math.isfinite(v) for v in box):
        raise click.BadParameter(f"{value!r}: give six numbers XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX (m, base frame)")
    return box


@click.command("excite")
@robot_options()
@click.option(
    "--duration",
    type=FiniteFloatRange(min=0, min_open=True),
    required=True,
    help="Seconds of trajectory: a whole number of periods (and of samples at --rate).",
)
@click.option(
    "--harmonics",
    type=click.IntRange(min=1),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.harmonics",
    help="Fourier harmonics per joint (at least 2 to start and end at rest).",
)
@click.option(
    "--base-frequency",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Fourier base frequency, Hz.  [default: 1/duration, one period]",
)
@click.option(
    "--criterion",
    type=LibraryChoice("ineid.excite.design:CRITERIA"),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.criterion",
    help="d-opt: -log det of the scaled information; cond: log of the scaled condition number.",
)
@click.option(
    "--candidates",
    type=click.IntRange(1, 10_000),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.candidates",
    help="Random feasible trajectories compared (at most 10,000): the best of them starts IPOPT, and the design "
    "must beat the best one or that one is returned.",
)
@click.option(
    "--starts",
    type=click.IntRange(1, 10_000),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.starts",
    help="IPOPT starts, from the best candidates (at most 10,000); the best design is kept.",
)
@click.option(
    "--max-iter",
    type=click.IntRange(0, 100_000),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.max_iter",
    help="IPOPT iterations a start, at most: more gives a better design, slower (each start stops there safe).",
)
@click.option(
    "--rate",
    type=FiniteFloatRange(min=0, min_open=True),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.rate",
    help="Samples per second in the CSV, Hz.",
)
@click.option(
    "--margin",
    type=FiniteFloatRange(0, 0.5, max_open=True),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.margin",
    help="Fraction of each joint's range kept free at each end.",
)
@click.option(
    "--velocity-scale",
    type=FiniteFloatRange(0, min_open=True),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.velocity_scale",
    help="Multiple of the model's velocity bounds used (above 1: beyond them, with a warning).",
)
@click.option(
    "--acceleration-scale",
    type=FiniteFloatRange(0, min_open=True),
    cls=LibraryOption,
    default_from=f"{_SETTINGS}.acceleration_scale",
    help="Multiple of the model's acceleration bounds used (above 1: beyond them, with a warning).",
)
@click.option(
    "--floor",
    type=FiniteFloatRange(),
    default=None,
    metavar="FLOOR",
    help="Keep every link frame and the tool frame at z >= FLOOR (m, base frame) at every instant.",
)
@click.option(
    "--self-collision/--no-self-collision",
    default=True,
    show_default=True,
    help="Keep bounding capsules of non-adjacent links (from the URDF's collision geometry) apart.",
)
@click.option(
    "--workspace",
    callback=_workspace,
    default=None,
    metavar="XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX",
    help="Keep every link frame and the tool frame inside this box (m, base frame) at every instant.",
)
@click.option(
    "--bias",
    type=LibraryChoice("ineid.identify.solve:BIAS_MODES"),
    cls=LibraryOption,
    default_from="ineid.identify.solve:SolveSettings.bias",
    help="estimate: design for ineid solve --bias estimate (six sensor offsets identified too).",
)
@click.option(
    "--seed", type=SEED, cls=LibraryOption, default_from=f"{_SETTINGS}.seed", help="Seed of the random starts."
)
@click.option(
    "--workers",
    type=WORKERS,
    default=None,
    help="Processes solving the starts, this one included (default: one per CPU, at most one per start); "
    "the design is the same with any number.",
)
@noise_option
@imu_excite
@channel_options(use_default="the base wrench (excite reads no file)")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    help="The trajectory CSV (time, q1..qn, qd1..qn, qdd1..qn).",
)
@click.option(
    "--coefficients",
    type=click.Path(path_type=Path),
    default=None,
    help="The coefficients and design record, JSON.  [default: --out with .json]",
)
@overwrite_option
@click.pass_context
def excite(
    ctx,
    robot,
    duration,
    harmonics,
    base_frequency,
    criterion,
    candidates,
    starts,
    max_iter,
    rate,
    margin,
    velocity_scale,
    acceleration_scale,
    floor,
    self_collision,
    workspace,
    bias,
    seed,
    workers,
    noise,
    imus,
    encoder_bits,
    out,
    coefficients,
    overwrite,
    **channel_flags,
) -> None:
    """Design a periodic Fourier excitation trajectory of ROBOT that identifies its unknown links well.

    The trajectory starts and ends at rest, keeps every joint within its limits (less the
    margin), velocity and acceleration bounds at every instant, and maximizes the
    information of the base wrench about the base parameters (the wrench noise of --noise
    weights the axes; default force=0.5,moment=0.05). With --use torque (or wrench,torque) it
    designs for the joint torques (noise --noise tau=STD, default 0.05 N*m), with their actuation
    model (--friction, --armature, --torque-offset) among the unknowns. With --floor and --workspace every link
    frame origin and the tool frame stay above the floor and inside the box at every instant.
    With --encoder-bits and --imu the design accounts for the joint-state errors the lab's encoders and
    link IMUs will cause (to first order: they inflate the noise).
    """
    from ineid.excite.design import design_excitation
    from ineid.excite.settings import ExcitationSettings

    coefficients = coefficients if coefficients is not None else out.with_suffix(".json")
    if coefficients.resolve() == out.resolve():
        raise click.BadParameter("the coefficients file must differ from --out", param_hint="--coefficients")
    prepare_output(out, overwrite, inputs=robot_inputs(robot))
    prepare_output(coefficients, overwrite, option="--coefficients", inputs=robot_inputs(robot))
    model = robot.load()
    channels = chosen_channels(None, channel_flags)
    sensors = excite_sensors(imus, encoder_bits, noise, model)
    settings = ExcitationSettings(
        duration=duration,
        harmonics=harmonics,
        base_frequency=base_frequency,
        criterion=criterion,
        candidates=candidates,
        starts=starts,
        max_iter=max_iter,
        rate=rate,
        margin=margin,
        velocity_scale=velocity_scale,
        acceleration_scale=acceleration_scale,
        bias=bias == "estimate",
        seed=seed,
        floor=floor,
        workspace=workspace,
        self_collision=self_collision,
        channels=channels,
        sensors=sensors,
    )
    _warn_beyond_bounds(velocity_scale, acceleration_scale)
    with ProgressBar("designing", "starts", quiet(ctx)) as bar:
        wrench = {k: v for k, v in (noise or {}).items() if k not in IMU_NOISE_KEYS}  # the IMUs': in sensors
        res = design_excitation(
            model,
            settings,
            noise=noise_model(wrench or None, model.n_dof),
            progress=bar,
            status=bar.status,
            workers=workers,
        )
    n_samples = _write_design(res, model, rate, out, coefficients, overwrite)
    print_design(res, model)
    print_limits(res, model)
    click.echo(f"wrote {out} ({n_samples:,} samples) and {coefficients}")


def _warn_beyond_bounds(velocity_scale: float, acceleration_scale: float) -> None:
    """A warning on stderr for each scale above 1 (bounds beyond the model's)."""
    for name, scale in (("--velocity-scale", velocity_scale), ("--acceleration-scale", acceleration_scale)):
        if scale > 1:
            click.echo(
                f"ineid: warning: {name} {scale:g} goes beyond the model's bounds (the URDF's, or the "
                "defaults where it gives none): make sure the arm can follow",
                err=True,
            )


def _write_design(res, model, rate: float, out: Path, coefficients: Path, overwrite: bool) -> int:
    """The design's samples at ``rate`` Hz to the CSV ``out`` and its coefficients and record to the JSON
    ``coefficients``, as a pair (an interruption leaves both old files or both new ones); returns the samples."""
    from ineid._atomic import signals_deferred
    from ineid.data.synthesis.trajectory import write_trajectory_csv, write_trajectory_json

    t, q, qd, qdd = res.trajectory.sample(rate)
    comments = [
        (
            f"ineid excitation trajectory of {model.name}: {res.trajectory.harmonics} harmonics of "
            f"{res.trajectory.base_frequency:g} Hz, {res.trajectory.duration:g} s at {rate:g} Hz"
        ),
        f"joints: {json.dumps(list(model.joint_names))}",  # JSON: names may hold commas
        f"coefficients: {coefficients.name}",
    ]
    with signals_deferred():  # a pair: an interruption leaves both old files or both new ones
        write_trajectory_json(coefficients, res.trajectory, {"design": res.to_dict()}, overwrite=overwrite)
        write_trajectory_csv(out, t, q, qd, qdd, comments, overwrite=overwrite)
    return len(t)


def register(main: click.Group) -> None:
    main.add_command(excite)
