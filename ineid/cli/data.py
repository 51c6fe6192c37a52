"""``ineid data generate|import|info``: make, import and inspect datasets."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import click

from ineid.cli.imu_options import check_imu_generate, imu_generate, imu_rehearsal
from ineid.cli.options import (
    SEED,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    deprecated_alias,
    noise_model,
    noise_option,
    quiet,
    robot_options,
)
from ineid.cli.output import ProgressBar, console, plain, shown, table
from ineid.cli.output_files import overwrite_option, prepare_output, robot_inputs
from ineid.cli.simulation import (
    channels_option,
    drives,
    friction_truth_option,
    gear_ratio_option,
    simulated_channels,
    torque_constant_option,
)
from ineid.cli.simulation import friction_truth as simulation_truth

_SAMPLING = "ineid.data.synthesis.sampling"


@click.group()
def data() -> None:
    """Make, import and inspect datasets (HDF5; see docs/dataset.md)."""


@data.command("generate")
@robot_options(positional="optional")
@click.option(
    "--factorial",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="N parameter sets per unknown link, all combinations (N^k configurations). Default 100.",
)
@click.option(
    "--n-configs",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="N configurations pairing the links' sets at random (instead of --factorial).",
)
@deprecated_alias("--configs", "n_configs", "--n-configs", type=click.IntRange(min=1))
@click.option(
    "--pool",
    type=click.IntRange(min=1),
    default=None,
    metavar="N",
    help="With --n-configs: draw each link's set from a pool of N (default: a fresh set per configuration).",
)
@click.option(
    "--n-frames",
    type=click.IntRange(min=1),
    cls=LibraryOption,
    default_from="ineid.data.synthesis.generate:DatasetSpec.n_frames",
    help="Frames per configuration.",
)
@deprecated_alias("--frames", "n_frames", "--n-frames", type=click.IntRange(min=1))
@click.option(
    "--seed",
    type=SEED,
    cls=LibraryOption,
    default_from="ineid.data.synthesis.generate:DatasetSpec.seed",
    help="Seed of every random draw.",
)
@click.option(
    "--frame-mode",
    type=LibraryChoice(f"{_SAMPLING}:FRAME_MODES"),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:FrameSampling.mode",
    help="Independent uniform frames (the paper), samples of random Fourier excitation trajectories, "
    "or the samples of one designed trajectory (--trajectory).",
)
@click.option(
    "--trajectory",
    type=click.Path(path_type=Path, exists=True, dir_okay=False),
    default=None,
    metavar="FILE",
    help="With --frame-mode trajectory: ineid excite's CSV (its rows are the frames) or JSON "
    "(--n-frames samples over its duration, default its CSV's rows).",
)
@click.option(
    "--harmonics",
    type=click.IntRange(1, 1000),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:FrameSampling.harmonics",
    help="Fourier harmonics per joint (at most 1000).",
)
@click.option(
    "--base-frequency",
    type=FiniteFloatRange(0, 1000, min_open=True),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:FrameSampling.base_frequency",
    help="Fourier base frequency, Hz (at most 1000); one period is sampled.",
)
@click.option(
    "--mass-band",
    type=FiniteFloatRange(0, 1, max_open=True),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:ParameterSampling.mass_rel",
    help="Mass within CAD * (1 +- band).",
)
@click.option(
    "--com-box",
    type=FiniteFloatRange(min=0),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:ParameterSampling.com_box",
    help="Centre of mass within CAD +- box per axis, m.",
)
@click.option(
    "--inertia-band",
    type=FiniteFloatRange(0, 1, max_open=True),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:ParameterSampling.inertia_rel",
    help="Second moments within CAD * (1 +- band), scaled with the mass.",
)
@click.option(
    "--rotation",
    type=FiniteFloatRange(min=0),
    cls=LibraryOption,
    default_from=f"{_SAMPLING}:ParameterSampling.orientation_deg",
    help="Largest turn of the principal axes from CAD, degrees (180: uniform).",
)
@channels_option
@click.option(
    "--sensor-pose",
    default=None,
    metavar="X,Y,Z,R,P,Y|FRAME|LINK[:X,Y,Z,R,P,Y]",
    help="Where the F/T sensor of the wrench channel sits: under the base at a pose in the base frame "
    "(m, rad, URDF rpy) or a URDF frame welded to the base (its reading is in its frame), or on a "
    "moving link (LINK:pose in the link's frame, or a URDF frame welded to one): the wrench at that "
    "link, stored under wrench_<link>. Default: the base wrench in the base frame.",
)
@friction_truth_option
@torque_constant_option
@gear_ratio_option
@noise_option
@imu_generate
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .h5 file to write.")
@overwrite_option
@click.pass_context
def data_generate(
    ctx,
    robot,
    factorial,
    n_configs,
    pool,
    n_frames,
    seed,
    frame_mode,
    trajectory,
    harmonics,
    base_frequency,
    mass_band,
    com_box,
    inertia_band,
    rotation,
    channels,
    sensor_pose,
    friction_truth,
    torque_constant,
    gear_ratio,
    noise,
    imus,
    gyro_bias,
    encoder_bits,
    out,
    overwrite,
) -> None:
    """Sample a synthetic ground-truth dataset of ROBOT (default sweaty-arm; the paper's: --factorial 100)."""
    from ineid.data import DatasetSpec, FrameSampling, ParameterSampling, write_dataset

    frames_given = ctx.get_parameter_source("n_frames") is click.core.ParameterSource.COMMANDLINE
    _check_generate_options(
        factorial, n_configs, pool, frames_given, frame_mode, trajectory, channels, friction_truth, noise, sensor_pose
    )
    check_imu_generate(imus, gyro_bias, encoder_bits, noise, frame_mode)
    prepare_output(out, overwrite, inputs=[*robot_inputs(robot), ("the trajectory file", trajectory)])
    model = robot.load()
    drive_values = drives(channels, torque_constant, gear_ratio, model.n_dof)
    sensor = None
    if sensor_pose is not None:
        from ineid.channels import sensor_channel

        sensor = sensor_channel(sensor_pose, model)
    sampled = None
    if trajectory is not None:
        from ineid.data.synthesis.trajectory import check_trajectory_fits, load_trajectory

        sampled = load_trajectory(trajectory, n_frames=n_frames if frames_given else None)
        check_trajectory_fits(sampled, model)
        n_frames = sampled.n_frames
    combination, total = _combination(factorial, n_configs, pool, len(model.unknown_links))
    try:
        spec = DatasetSpec(
            combination=combination,
            n_frames=n_frames,
            seed=seed,
            parameters=ParameterSampling(mass_band, com_box, inertia_band, rotation),
            frames=FrameSampling(frame_mode, harmonics, base_frequency, trajectory=sampled),
            noise=noise_model(noise, model.n_dof, "wrench" if sensor is None else sensor.key),
            channels=simulated_channels(channels, drive_values, sensor),
            extra_truth=simulation_truth(friction_truth, model.joint_names),
            imu=imu_rehearsal(imus, gyro_bias, encoder_bits, noise, model),
        )
    except ValueError as e:  # a setting the options' own checks let through
        raise click.UsageError(str(e)) from None
    from ineid.robots.gravity import describe_gravity

    t0 = time.perf_counter()
    with ProgressBar("generating", "configurations", quiet(ctx)) as bar:
        write_dataset(model, spec, out, overwrite=overwrite, progress=bar)
    seconds = time.perf_counter() - t0
    click.echo(
        f"wrote {out}: {total:,} configurations x {n_frames} frames of {plain(model.name)} "
        f"({plain(', '.join(model.unknown_links))} "
        f"unknown{'; ' + plain(spec.channels.describe()) if spec.channels else ''}) "
        f"in {seconds:.1f} s "
        f"({total * n_frames / seconds:,.0f} frames/s); {describe_gravity(model.gravity)}"
    )


def _check_generate_options(
    factorial, n_configs, pool, frames_given, frame_mode, trajectory, channels, friction_truth, noise, sensor_pose
) -> None:
    """Refuse ``data generate`` options that do not go together (:class:`click.UsageError`, exit 2): each one's
    message names what it needs."""
    if factorial is not None and n_configs is not None:
        raise click.UsageError("give --factorial N or --n-configs N, not both")
    if pool is not None and n_configs is None:
        raise click.UsageError("--pool applies to --n-configs (random pairing)")
    if (frame_mode == "trajectory") != (trajectory is not None):
        raise click.UsageError("--frame-mode trajectory and --trajectory FILE go together")
    if trajectory is not None and frames_given and trajectory.suffix.lower() != ".json":
        raise click.BadParameter(
            "the rows of a trajectory CSV are the frames; drop --n-frames (or give its .json)", param_hint="--n-frames"
        )
    torque = channels is not None and "torque" in channels
    if friction_truth and not (torque or (channels is not None and "current" in channels)):
        raise click.UsageError(
            "--friction-truth is what joint torques add: simulate them with --channels wrench,torque (or torque)"
        )
    if noise and "tau" in noise and not torque:
        raise click.UsageError(
            "tau noise is the joint torques': simulate them with --channels wrench,torque (or torque)"
        )
    if noise and "current" in noise and not (channels is not None and "current" in channels):
        raise click.UsageError("current noise is the motor currents': simulate them with --channels ...,current")
    if (
        noise
        and not (channels is None or "wrench" in channels)
        and any(k in noise for k in ("force", "moment", "fx", "fy", "fz", "mx", "my", "mz", "glitch"))
    ):
        raise click.UsageError("force and moment noise is the base wrench's: add it with --channels wrench,torque")
    if sensor_pose is not None and not (channels is None or "wrench" in channels):
        raise click.UsageError("--sensor-pose places the F/T sensor of the wrench channel: add wrench to --channels")


def _combination(factorial, n_configs, pool, n_unknown: int):
    """``(combination, total)``: how ``data generate`` pairs the links' parameter sets (``--n-configs``,
    ``--factorial``, or the default), and the configurations it gives for ``n_unknown`` unknown links.

    Raises:
        click.BadParameter: a factorial design of more than 10^8 configurations.
    """
    from ineid.data import Combination

    if n_configs is not None:
        combination = Combination("random", per_link=pool, n_configs=n_configs)
    elif factorial is not None:
        combination = Combination("factorial", per_link=factorial)
    else:
        combination = Combination()
    total = combination.count(n_unknown)
    if n_configs is None and total > 10**8:
        raise click.BadParameter(
            f"{total:,} configurations ({combination.per_link}^{n_unknown}); use --n-configs for a random subset",
            param_hint="--factorial",
        )
    return combination, total


@data.command("info")
@click.argument("path", metavar="FILE", type=click.Path(path_type=Path))
def data_info(path: Path) -> None:
    """Summarize a dataset: sizes, robot, settings, parameter and wrench ranges."""
    from ineid.data import read_meta

    meta, shapes = read_meta(path)
    con = console()
    _print_settings(con, path, meta, shapes)
    if "theta_unknown" in shapes:
        _print_parameter_ranges(con, path, meta)
    _print_channel_ranges(con, path, meta)


def _noise_line(meta) -> str:
    """``data info``'s noise line: the stated noise of synthetic data, the import's estimate of a recording."""
    if meta.source == "recording":
        from ineid.data.recordings.noise_estimate import noise_line

        line = noise_line(meta.origin)
        return shown(line) if line else "noise: not estimated (imported by an older ineid; import the recording again)"
    return f"noise (std): {shown(json.dumps(meta.noise)) if meta.noise else 'none (clean data)'}"


def _print_settings(con, path: Path, meta, shapes: dict) -> None:
    """``data info``'s header: the file, sizes, robot, links, gravity, sampling, noise, origin, the channels and
    their sensor frames, the simulated actuation, and the table of the arrays' shapes."""
    import numpy as np

    n_configs, n_frames, n_dof = shapes["q"]
    con.print(
        f"[bold]{shown(path)}[/bold]  ineid dataset v{shown(meta.version)} ({shown(meta.source)}), "
        f"written by ineid {shown(meta.ineid_version)}"
    )
    con.print(
        f"{n_configs:,} configuration{'s' if n_configs != 1 else ''} x {n_frames:,} frames = {n_configs * n_frames:,} "
        f"frames; robot {shown(meta.robot)}, {n_dof} joints ({shown(', '.join(meta.joint_names))})"
    )
    con.print(
        f"unknown links: {shown(', '.join(meta.unknown_links))}; "
        f"known links: {shown(', '.join(meta.known_links) or '-')}"
    )
    from ineid.robots.gravity import describe_gravity

    con.print(describe_gravity(np.asarray(meta.gravity)) + (f"; seed {meta.seed}" if meta.seed is not None else ""))
    if meta.locked_joints:
        con.print(f"locked joints: {shown(meta.locked_joints)}")
    if meta.sampling:
        con.print(f"sampling: {shown(json.dumps(_rounded(meta.sampling), sort_keys=True))}")
    con.print(_noise_line(meta))
    if meta.origin:
        con.print(f"origin: {shown(json.dumps(_rounded(meta.origin), sort_keys=True))}")
    from ineid.data.recordings.timing import timing_lines

    for line in timing_lines(meta.origin):  # a recording's time stamps as the import audited them
        con.print(shown(line))
    several = len(meta.channels) > 1
    if several:
        con.print(f"measurement channels: {shown(meta.channels.describe())}")
    for c in meta.channels:
        pose = getattr(c, "sensor", None)  # an F/T sensor's pose: under the base, or on a link (its frame)
        if pose is not None:
            where = f"link {c.link!r}'s frame" if getattr(c, "link", None) else "the base frame"
            con.print(
                f"sensor frame{f' of {c.key}' if several else ''} in {shown(where)}: {shown(pose.describe())}"
                + (f"; wrench messages in frame {shown(repr(pose.frame_id))}" if pose.frame_id else "")
            )
    if meta.extra_truth:
        con.print(f"simulated actuation (extra_truth): {shown(json.dumps(meta.extra_truth))}")
    arrays = table("Arrays", ("name", "shape"), left=("name", "shape"))
    for name in sorted(shapes):
        arrays.add_row(name, " x ".join(str(s) for s in shapes[name]) or "scalar")
    con.print(arrays)


def _rounded(record):
    """``record`` (JSON-able) with its floats to 10 significant digits: a rate of 100.00000000000213 Hz (the
    mean of time steps, round-off and all) reads 100."""
    if isinstance(record, dict):
        return {k: _rounded(v) for k, v in record.items()}
    if isinstance(record, (list, tuple)):
        return [_rounded(v) for v in record]
    if isinstance(record, float) and math.isfinite(record):
        return float(f"{record:.10g}")
    return record


def _ranges(path: Path, name: str, width: int):
    """``(min, max, mean)`` (width,) each of array ``name`` of the dataset at ``path`` over every row, read block
    by block."""
    import numpy as np

    from ineid.data import iter_dataset

    lo, hi = np.full(width, np.inf), np.full(width, -np.inf)
    total, count = np.zeros(width), 0
    for _, block in iter_dataset(path, name):
        flat = block.reshape(-1, width)
        lo, hi = np.minimum(lo, flat.min(0)), np.maximum(hi, flat.max(0))
        total += flat.sum(0)
        count += len(flat)
    return lo, hi, total / max(count, 1)


def _print_parameter_ranges(con, path: Path, meta) -> None:
    """The table of the unknown parameters over the configurations beside the URDF's (CAD) values."""
    from ineid.params import param_names
    from ineid.robots.urdf import parse_chain

    chain = parse_chain(meta.urdf, source=f"{path} (its URDF)", locked_joints=meta.locked_joints or None)
    cad = {j.link: j.theta for j in chain.joints}
    names = param_names(meta.unknown_links)
    lo, hi, mean = _ranges(path, "theta_unknown", len(names))
    t = table(
        "Unknown parameters over the configurations (SI, about each link origin)",
        ("parameter", "CAD", "min", "mean", "max"),
        left=("parameter",),
    )
    for k, name in enumerate(names):
        link = name.rpartition(".")[0]
        t.add_row(name, f"{cad[link][k % 10]:.5g}", f"{lo[k]:.5g}", f"{mean[k]:.5g}", f"{hi[k]:.5g}")
    con.print(t)


def _print_channel_ranges(con, path: Path, meta) -> None:
    """One table per channel: its values' range axis by axis, in its own units (a wrench: in which frame)."""
    from ineid.channels import BaseWrench

    for c in meta.channels:
        axes = c.axes(meta)
        lo, hi, mean = _ranges(path, c.key, len(axes))
        units = ", ".join(dict.fromkeys(c.units(meta)))
        if isinstance(c, BaseWrench):
            frame = "base frame, about the base origin" if c.sensor is None else "sensor frame, about the sensor origin"
            title = f"{'Wrench' if c.key == 'wrench' else shown(c.key)} ({units}; {frame})"
        else:
            title = f"{shown(c.key)}: {shown(c.describe())} ({units})"
        t = table(title, ("axis", "min", "mean", "max"), left=("axis",))
        for k, axis in enumerate(axes):
            t.add_row(shown(axis), f"{lo[k]:.4g}", f"{mean[k]:.4g}", f"{hi[k]:.4g}")
        con.print(t)


def register(main: click.Group) -> None:
    from ineid.cli.data_import import data_import

    data.add_command(data_import)
    main.add_command(data)
