"""``ineid data import``: a real arm's recording (CSV, ROS bag) into a dataset."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.imu_options import imu_import
from ineid.cli.options import (
    FiniteFloatRange,
    quiet,
    robot_options,
)
from ineid.cli.output import ProgressBar, plain, print_findings
from ineid.cli.output_files import folder_inputs, overwrite_option, prepare_output, robot_inputs
from ineid.cli.simulation import (
    gear_ratio_option,
    torque_constant_option,
)

_SAMPLING = "ineid.data.synthesis.sampling"


def _finite(ctx, param, value: float) -> float:
    """A finite number (click's FloatRange lets inf through)."""
    import math

    if not math.isfinite(value):
        raise click.BadParameter(f"{value} is not a finite number")
    return value


def _delay(ctx, param, value: str) -> float | None:
    """``--delay``: seconds, or ``auto`` (None: estimate it)."""
    if value.strip().lower() == "auto":
        return None
    try:
        return float(value)
    except ValueError:
        raise click.BadParameter(f"{value!r} is neither a number of seconds nor 'auto'") from None


@click.command("import")
@click.argument("paths", metavar="PATH...", nargs=-1, required=True, type=click.Path(path_type=Path))
@robot_options(positional="option")
@click.option(
    "--sensor-pose",
    default=None,
    metavar="X,Y,Z,R,P,Y|FRAME|LINK:X,Y,Z,R,P,Y",
    help="The sensor frame in the base frame (m, rad, URDF rpy), a URDF link (welded to the base, or to "
    "a moving link: a wrist sensor), or LINK:x,y,z,r,p,y in URDF link LINK's frame (default: the "
    "bag's wrench frame_id if the URDF has that link, else the base frame).",
)
@click.option(
    "--cutoff",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    metavar="HZ",
    help="Low-pass cut-off of angles and wrench (default: chosen from the joint angles when qd, qdd "
    "are derived, from their pooled spectra for several recordings; no filter when they are measured).",
)
@click.option(
    "--rate",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    metavar="HZ",
    help="Rate of the frames (default: the slower stream's nominal rate, estimated from its time stamps and "
    "snapped to a clean value such as 1000 Hz; the summary says how).",
)
@click.option(
    "--allow-gaps",
    is_flag=True,
    help="Import a stream with gaps longer than the filter's support (3 periods of the cut-off), interpolating "
    "across them; without it such a gap is an error naming it.",
)
@click.option(
    "--keep-repeats",
    is_flag=True,
    help="Use the rows that repeat every value of their stream's previous row under a new time stamp as data; "
    "by default rows that hold the previous sample while the stream moves are dropped as missing.",
)
@click.option(
    "--delay",
    default="0",
    show_default=True,
    metavar="S|auto",
    callback=_delay,
    help="How late the wrench time stamps are against the joints' (s), or auto: estimated from the "
    "model within +-50 ms (several recordings: the median of their estimates, for all).",
)
@click.option("--joint-topic", default="/joint_states", show_default=True, help="Bags: the JointState topic.")
@click.option("--wrench-topic", default=None, help="Bags: the WrenchStamped topic (needed when there are several).")
@click.option(
    "--flip-wrench",
    is_flag=True,
    help="The sensor reports the wrench on the robot (the opposite of ineid's convention); negate it.",
)
@click.option(
    "--wrench-scale",
    type=click.FloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    metavar="FACTOR",
    callback=_finite,
    help="Multiply every force and moment by FACTOR (0.001 for a wrench in mN and N*mm).",
)
@click.option(
    "--angle-unit",
    type=click.Choice(["rad", "deg"]),
    default="rad",
    show_default=True,
    help="Unit of the revolute joints' angles (and of measured qd, qdd); deg converts them to rad.",
)
@click.option(
    "--time-unit",
    type=click.Choice(["s", "ms", "us", "ns"]),
    default="s",
    show_default=True,
    help="Unit of the time stamps (of every stream); converted to s.",
)
@click.option(
    "--force-unit",
    type=click.Choice(["N", "mN", "kN"]),
    default="N",
    show_default=True,
    help="Unit of the wrench's forces; converted to N (before --wrench-scale).",
)
@click.option(
    "--moment-unit",
    type=click.Choice(["Nm", "Nmm", "kNm"]),
    default="Nm",
    show_default=True,
    help="Unit of the wrench's moments (Nmm: N*mm, also mN*m); converted to N*m (before --wrench-scale).",
)
@torque_constant_option
@gear_ratio_option
@click.option(
    "--coupling",
    default=None,
    metavar="FILE",
    type=click.Path(dir_okay=False),
    help="The torques or currents are per motor of a coupled transmission (JSON, CSV or a URDF's "
    "<transmission>s): the CSV's columns tau1..taun (i1..in) in the motors' order, or tau_<motor> (i_<motor>) "
    "by the motors' names; stored with the channel (docs/identification.md).",
)
@imu_import
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    required=True,
    help="The .h5 file to write; for several recordings a folder (made if missing) that receives one STEM.h5 "
    "per recording.",
)
@overwrite_option
@click.pass_context
def data_import(
    ctx,
    paths,
    robot,
    sensor_pose,
    cutoff,
    rate,
    allow_gaps,
    keep_repeats,
    delay,
    joint_topic,
    wrench_topic,
    flip_wrench,
    wrench_scale,
    angle_unit,
    time_unit,
    force_unit,
    moment_unit,
    torque_constant,
    gear_ratio,
    coupling,
    imus,
    imu_topics,
    imu_delay,
    imu_noise,
    out,
    overwrite,
) -> None:
    """Import a recording: a CSV (time, q1..qn, [qd1..qn, qdd1..qn,] [tau1..taun,] fx fy fz mx my mz; the wrench
    optional with torques), a ROS 1 .bag, or a ROS 2 bag folder or .mcap (sensor_msgs/JointState with its
    effort as joint torques, geometry_msgs/WrenchStamped). Link IMUs (imu_<NAME>_wx.. columns named by --imu,
    sensor_msgs/Imu topics named by --imu-topic): qd, qdd fused from the encoders and the IMUs
    (docs/recordings.md). Each stream's noise is measured from its part above the cut-off (data info shows it).

    Several recordings of one experiment (to be fitted and validated together: ineid solve A.h5 B.h5
    --validate C.h5) are imported together into the folder --out, with one filter and one wrench delay: the
    cut-off rule on their pooled spectra (or --cutoff), the median of their delay estimates (or --delay); the
    summary prints each one's own choice."""
    from ineid.data.recordings.settings import ImportSettings

    several = len(paths) > 1
    outs = _outputs(paths, out, overwrite, robot) if several else [out]
    if not several:
        prepare_output(out, overwrite, inputs=[*folder_inputs(paths[0], "the input recording"), *robot_inputs(robot)])
    model = robot.load()
    from ineid.data.recordings.imus import parse_imu_text

    for text in imus:  # a mount that does not parse is said before the file is read
        parse_imu_text(text, model)
    settings = ImportSettings(
        sensor_pose=sensor_pose,
        cutoff=cutoff,
        rate=rate,
        delay=delay or 0.0,
        estimate_delay=delay is None,
        flip_wrench=flip_wrench,
        angle_unit=angle_unit,
        wrench_scale=wrench_scale,
        time_unit=time_unit,
        force_unit=force_unit,
        moment_unit=moment_unit,
        torque_constant=torque_constant,
        gear_ratio=gear_ratio,
        coupling=None if coupling is None else str(coupling),
        imus=tuple(imus),
        imu_delay=imu_delay,
        imu_noise=imu_noise,
        allow_gaps=allow_gaps,
        keep_repeats=keep_repeats,
    )
    topics = {"joint_topic": joint_topic, "wrench_topic": wrench_topic, "imu_topics": tuple(imu_topics)}
    what = f"{len(paths)} recordings" if several else paths[0].name
    with ProgressBar(f"reading {what}", "rows/messages", quiet(ctx)) as bar:
        if several:
            from ineid.workflow import import_experiment

            experiment = import_experiment(paths, model, settings, progress=bar, **topics)
            imported, lines = list(zip(experiment.datasets, experiment.summaries, strict=True)), experiment.lines()
        else:
            from ineid.workflow import import_recording

            imported, lines = [import_recording(paths[0], model, settings, progress=bar, **topics)], []
    from ineid.data.recordings.plausibility import check_dataset
    from ineid.robots.gravity import describe_gravity

    for line in lines:
        click.echo(plain(line))
    for (ds, summary), path in zip(imported, outs, strict=True):
        ds.save(path, overwrite=overwrite)
        click.echo(f"wrote {path}: one recording of {plain(model.name)}; {describe_gravity(model.gravity)}")
        for line in summary.lines():
            click.echo(f"  {plain(line)}")
        print_findings(check_dataset(ds, model))


def _outputs(paths: tuple[Path, ...], out: Path, overwrite: bool, robot) -> list[Path]:
    """``out/STEM.h5`` for each recording of several, each checked and locked (:func:`prepare_output`); the
    folder made when missing; two recordings of one stem refused (``click.BadParameter``)."""
    stems = [p.stem if p.suffix else p.name for p in paths]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        raise click.BadParameter(
            f"several recordings are named {twice[0]!r}, and each is written to --out as STEM.h5; "
            "import them separately, or rename one",
            param_hint="PATH...",
        )
    if (out.exists() and not out.is_dir()) or (not out.exists() and out.suffix.lower() == ".h5"):
        raise click.BadParameter(
            f"{out} is a file name; several recordings go to a folder, one STEM.h5 each", param_hint="--out"
        )
    out.mkdir(parents=True, exist_ok=True)
    inputs = [x for p in paths for x in folder_inputs(p, "an input recording")] + robot_inputs(robot)
    return [prepare_output(out / f"{s}.h5", overwrite, inputs=inputs) for s in stems]
