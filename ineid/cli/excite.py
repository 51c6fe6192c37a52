"""``ineid excite``: design an excitation trajectory (the library: :mod:`ineid.excite.design`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from ineid.cli.channel_options import channel_options, chosen_channels
from ineid.cli.imu_options import excite_sensors, imu_excite
from ineid.cli.options import (
    SEED,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    noise_model,
    noise_option,
    quiet,
    robot_options,
)
from ineid.cli.output import ProgressBar, console, shown, table
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
    rate,
    margin,
    velocity_scale,
    acceleration_scale,
    floor,
    self_collision,
    workspace,
    bias,
    seed,
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
            model, settings, noise=noise_model(wrench or None, model.n_dof), progress=bar, status=bar.status
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


def print_design(res, model) -> None:
    """The summary: criterion, scaled condition number and expected std, designed beside random Fourier."""
    import numpy as np

    from ineid.robots.gravity import describe_gravity

    con = console()
    opt, rnd = res.optimized, res.random
    sigma = res.sigma
    con.print(
        f"[bold]{res.criterion}[/bold] design of {shown(res.settings['robot'])} "
        f"({shown(', '.join(res.settings['unknown_links']))} "
        f"unknown{'; sensor offsets estimated' if res.base.bias else ''}): {res.base.rank} base parameters, "
        f"{len(res.starts)} starts from the best of {res.n_candidates} random feasible trajectories in "
        f"{res.seconds:.1f} s"
    )
    con.print(describe_gravity(model.gravity))
    channels = res.base.channels
    if len(channels) == 1 and channels.keys == ("wrench",):
        noise = (
            f"white Gaussian wrench noise, std {sigma[0]:g} {sigma[1]:g} {sigma[2]:g} N, "
            f"{sigma[3]:g} {sigma[4]:g} {sigma[5]:g} N*m"
        )
    else:
        parts, start = [], 0
        for c in channels:
            n_a, units = c.n_axes(model), c.units(model)
            values = sigma[start : start + n_a]
            start += n_a
            same = np.all(values == values[0]) and len(set(units)) == 1
            stds = (
                f"{values[0]:g} {units[0]}"
                if same
                else " ".join(f"{v:g} {u}" for v, u in zip(values, units, strict=True))
            )
            parts.append(f"{shown(c.describe())}: std {stds}")
        noise = "white Gaussian noise; " + "; ".join(parts)
        if channels.n_extra(model):
            noise += f"; extra parameters {shown(', '.join(channels.extra_names(model)))} designed for too"
    states = (
        "joint states exact"
        if res.states is None
        else f"joint states from {shown(res.states['described'])}: their errors add to the noise (below)"
    )
    con.print(f"noise model: {noise} per sample, {opt.n_samples} samples at {res.rate:g} Hz; {states}")
    best = res.best_random
    t = table(
        f"Design vs the best of {res.n_candidates} random feasible trajectories (same period, harmonics and bounds; "
        "the median one: a typical random Fourier trajectory)",
        ("", "designed", "best random", "ratio", "median random Fourier"),
        left=("",),
    )
    t.add_row(
        "-log det M (d-opt)",
        f"{opt.d_opt:.4g}",
        f"{best.d_opt:.4g}",
        f"{best.d_opt - opt.d_opt:+.3g} (diff)",
        f"{rnd.d_opt:.4g}",
    )
    t.add_row(
        "scaled condition number",
        f"{opt.condition_number:.4g}",
        f"{best.condition_number:.4g}",
        f"{best.condition_number / opt.condition_number:.3g}x",
        f"{rnd.condition_number:.4g}",
    )
    t.add_row(
        "median expected relative std",
        f"{np.median(opt.rel_std):.3g}",
        f"{np.median(best.rel_std):.3g}",
        f"{np.median(best.rel_std) / np.median(opt.rel_std):.3g}x",
        f"{np.median(rnd.rel_std):.3g}",
    )
    con.print(t)
    print_answer(res)
    t = table(
        "Expected standard deviation of each base parameter (SI units of the parameter)",
        ("base parameter", "CAD value", "std designed", "std best random", "ratio"),
        left=("base parameter",),
    )
    for k, name in enumerate(res.base.names):
        t.add_row(
            name,
            f"{res.base.cad[k]:.5g}",
            f"{opt.std[k]:.3g}",
            f"{best.std[k]:.3g}",
            f"{best.std[k] / opt.std[k]:.3g}x",
        )
    con.print(t)
    if res.states is not None:
        print_states(res.states, model)


def print_answer(res) -> None:
    """Which trajectory is the answer and by how much it beats the best random candidate; how each start ended."""
    import numpy as np

    con = console()
    ratio = res.best_random.std / res.optimized.std
    if res.answer == "optimized":
        con.print(
            f"the design beats the best of {res.n_candidates} random feasible trajectories: its expected std is "
            f"{np.median(ratio):.3g}x smaller in the median over the base parameters (smallest ratio "
            f"{np.min(ratio):.3g}x)",
            markup=False,
        )
    else:
        con.print(
            f"no start beat the best of {res.n_candidates} random feasible trajectories: that trajectory is the one "
            "written (more --starts or --harmonics may find a better one)",
            markup=False,
        )
    records = res.starts
    converged = sum(r.converged for r in records)
    settled = sum(r.settled for r in records)
    unsafe = sum(r.status.startswith("unsafe") for r in records)
    capped = sum(r.status.startswith("Maximum_Iterations") for r in records)
    con.print(
        f"starts: {len(records)} IPOPT runs from the best candidates: {converged} converged, {settled} settled at "
        f"the cap of {res.settings['max_iter']} iterations, {capped - settled} still improving at the cap, "
        f"{unsafe} unsafe",
        markup=False,
    )
    for k, r in enumerate(records, 1):
        con.print(
            f"  start {k}: criterion {r.start_value:.5g} -> {r.final_value:.5g}, {r.iterations} iterations, "
            f"{r.seconds:.1f} s, {r.status}",
            markup=False,
        )


def print_states(states: dict, model) -> None:
    """The joint-state errors the sensors give (rehearsed) and the noise they make, designed beside random."""
    con = console()
    opt, rnd = states["optimized"], states["random_fourier"]
    t = table(
        "Joint-state errors the sensors give (RMS over the samples, rehearsed; rad, rad/s, rad/s^2)",
        ("joint", "q", "qd designed", "qdd designed", "qd random", "qdd random"),
        left=("joint",),
    )
    for k, name in enumerate(model.joint_names):
        t.add_row(
            shown(name),
            f"{opt['rms_q'][k]:.3g}",
            f"{opt['rms_qd'][k]:.3g}",
            f"{opt['rms_qdd'][k]:.3g}",
            f"{rnd['rms_qd'][k]:.3g}",
            f"{rnd['rms_qdd'][k]:.3g}",
        )
    con.print(t)
    for label, values in (
        ("designed", opt["noise_std"]),
        ("random Fourier", rnd["noise_std"]),
        ("the optimizer's weights (first start)", states["weights_noise_std"]),
    ):
        con.print(f"noise std with the state errors, {label}: {' '.join(f'{v:.3g}' for v in values)}", markup=False)


def print_limits(res, model) -> None:
    """The bounds in force: each joint's velocity and acceleration bound and its source, the floor and box."""
    from ineid.excite.safety import bound_sources

    con = console()
    sources = bound_sources(model)
    scales = res.settings["velocity_scale"], res.settings["acceleration_scale"]
    t = table(
        f"Bounds kept at every instant (velocity x {scales[0]:g}, acceleration x {scales[1]:g} of the model's; "
        "default: no bound in the URDF, 3 rad/s and 10 rad/s^2)",
        ("joint", "position", "|qd| max", "from", "|qdd| max", "from"),
        left=("joint", "from"),
    )
    b = res.bounds
    for k, name in enumerate(model.joint_names):
        t.add_row(
            shown(name),
            f"[{b.q_lower[k]:.4g}, {b.q_upper[k]:.4g}]",
            f"{b.qd_max[k]:.4g}",
            sources[name][0],
            f"{b.qdd_max[k]:.4g}",
            sources[name][1],
        )
    con.print(t)
    s = res.safety or {"floor": None, "workspace": None, "self_collision": None}
    box, floor = s["workspace"], s["floor"]
    floor_text = "none" if floor is None else f"z >= {floor:g} m"
    box_text = (
        "none"
        if box is None
        else f"x [{box[0]:g}, {box[1]:g}], y [{box[2]:g}, {box[3]:g}], z [{box[4]:g}, {box[5]:g}] m"
    )
    line = f"floor: {floor_text}; workspace: {box_text} (base frame"
    if s.get("points"):
        line += (
            f"; kept by {', '.join(s['points'])} at every instant, {s['grid_points_per_period']} grid points per "
            f"period, at most {max(s['margin_between_samples']) * 1000:.3g} mm kept between them"
        )
    con.print(
        line
        + ")"
        + (
            ""
            if floor is not None or box is not None
            else "; --floor and --workspace keep the links above a floor and in a box"
        ),
        markup=False,
    )
    col = s["self_collision"]
    if col is None:
        con.print("self-collision: not checked (--no-self-collision)", markup=False)
    elif not col["pairs"]:
        con.print(
            "self-collision: not checked, no pair of non-adjacent bodies with collision geometry "
            f"({len(col['capsules'])} capsules)",
            markup=False,
        )
    else:
        shapes = ", ".join(f"{c['body']} ({c['shape']}, r {c['radius']:.3g} m)" for c in col["capsules"])
        counts = dict.fromkeys(col["pairs"], 0)  # a body with several capsules: its pair of bodies said once
        for pair in col["pairs"]:
            counts[pair] += 1
        named = "; ".join(pair if n == 1 else f"{pair} ({n} capsule pairs)" for pair, n in counts.items())
        con.print(
            f"self-collision: {len(col['pairs'])} pairs of bounding capsules kept apart at every instant: "
            f"{named}; capsules: {shapes}",
            markup=False,
        )
    for note in (col or {}).get("notes", []):
        con.print(f"  {note}", markup=False)
    if getattr(res, "feasibility", None) is not None:
        print_feasibility(res.feasibility)
    for where, label in (("samples", "the written samples"), ("dense", "a grid 10x denser")):
        if where in s:
            v = s[where]
            con.print(
                f"smallest clearance on {label}: {v['min_clearance'] * 1000:.4g} mm ({v['constraint']})", markup=False
            )


def print_feasibility(feas: dict) -> None:
    """The up-front check: how many sampled poses keep every bound, and what the rest pose breaks."""
    con = console()
    con.print(
        f"feasibility, checked before the design: {feas['feasible']:,} of {feas['sampled']:,} sampled poses keep "
        f"the floor, box and self-collision ({feas['seconds']:.2g} s); the rest pose (q = 0"
        + (f", {', '.join(feas['rest_clipped'])} clipped into the bounds" if feas["rest_clipped"] else "")
        + ") "
        + (f"breaks {'; '.join(feas['rest_violations'])}" if feas["rest_violations"] else "keeps them"),
        markup=False,
    )


def register(main: click.Group) -> None:
    main.add_command(excite)
