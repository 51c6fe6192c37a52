"""``ineid identifiability``, ``export-urdf`` and ``results info``."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.channel_options import channel_options, chosen_channels
from ineid.cli.options import (
    SEED,
    LibraryChoice,
    LibraryOption,
    deprecated_alias,
    robot_options,
)
from ineid.cli.output import console, plain, print_held_out_rms, shown, table
from ineid.cli.output_files import overwrite_option, prepare_output, results_inputs

_SOLVE = "ineid.identify.settings"


@click.command()
@robot_options()
@click.option(
    "--n-frames",
    type=click.IntRange(min=1),
    default=200,
    show_default=True,
    help="Random frames (uniform within the bounds) to analyse.",
)
@deprecated_alias("--frames", "n_frames", "--n-frames", type=click.IntRange(min=1))
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--data",
    "data_path",
    type=click.Path(path_type=Path),
    default=None,
    help="Analyse the frames of a dataset instead (with --config).",
)
@click.option("--config", type=click.IntRange(min=0), default=0, show_default=True, help="Configuration of --data.")
@click.option(
    "--bias",
    type=LibraryChoice(f"{_SOLVE}:BIAS_MODES"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.bias",
    help="estimate: six constant sensor offsets are identified too; shows what they cost.",
)
@channel_options(use_default="a dataset's channels, else the base wrench")
def identifiability(robot, n_frames, seed, data_path, config, bias, **channel_flags) -> None:
    """Which parameters of ROBOT's unknown links the base wrench (or the channels of --use) determines.

    With joint torques and --friction, --armature or --torque-offset, the analysis is over the links'
    parameters and the joints' extra parameters together.
    """
    from ineid.identify import analyze_frames, base_parameters

    model = robot.load()
    with_bias = bias == "estimate"
    q, qd, qdd, source, channels = _frames(model, data_path, config, n_frames, seed)
    _require_frames_memory(model, len(q))
    channels = chosen_channels(channels, channel_flags)
    base = base_parameters(model, bias=with_bias, channels=channels)
    a = analyze_frames(model, q, qd, qdd, base, bias=with_bias, channels=channels)
    con = console()
    _print_analysis(con, model, base, a, source, channels)
    _print_base_parameters(con, base, channels)
    if with_bias:
        _print_bias_cost(con, model, q, qd, qdd, channels)


def _frames(model, data_path, config: int, n_frames: int, seed: int):
    """``(q, qd, qdd, source, channels)``: the frames analysed, in words, and their channels (None: the base
    wrench): configuration ``config`` of the dataset at ``data_path``, or ``n_frames`` random frames."""
    from ineid.identify import generic_frames

    if data_path is None:
        _require_frames_memory(model, n_frames)
        q, qd, qdd = generic_frames(model, n_frames, seed)
        return q, qd, qdd, f"{n_frames} random frames within the bounds (seed {seed})", None
    from ineid.data import load_dataset

    ds = load_dataset(data_path, configs=[config], clean=False)
    if ds.meta.joint_names != model.joint_names:
        raise click.BadParameter(
            f"{data_path} is a dataset of {ds.meta.robot!r}, not of {model.name!r}", param_hint="--data"
        )
    q, qd, qdd = ds.q[0], ds.qd[0], ds.qdd[0]
    return q, qd, qdd, f"{len(q)} frames of configuration {config} of {data_path}", ds.meta.channels


def _print_analysis(con, model, base, a, source: str, channels) -> None:
    """What was analysed, and the ranks, condition and singular values of the frames (``a``, a
    :class:`ineid.identify.FrameAnalysis`) against the structure (``base``)."""
    import numpy as np

    from ineid.robots.gravity import describe_gravity

    n = base.n_params
    con.print(
        f"[bold]{shown(model.name)}[/bold]: unknown links {shown(', '.join(model.unknown_links))} "
        f"({base.n_link_params} standard parameters{f', {base.n_extra} extra' if base.n_extra else ''})"
    )
    con.print(f"frames: {shown(source)}")
    con.print(describe_gravity(model.gravity))
    if channels is not None:
        con.print(
            f"channels: {shown(channels.describe())}"
            + (f"; extra parameters: {shown(', '.join(channels.extra_names(model)))}" if base.n_extra else "")
        )
    con.print(
        f"rank {a.rank} of {n}; structural rank {base.rank} (no frames can do better): "
        f"[bold]{base.rank} identifiable combinations[/bold], {n - base.rank} null direction(s)"
    )
    cond = "inf" if not np.isfinite(a.condition_number) else f"{a.condition_number:.4g}"
    con.print(
        f"condition number (scaled, identifiable part): {cond}; fewest leading frames reaching rank "
        f"{base.rank}: {a.min_frames if a.min_frames is not None else 'never'} "
        f"(any frames need at least {a.minimum.frames}"
        + (f": {a.minimum.reason})" if a.minimum.reason else f": {a.n_axes} equations per frame)")
    )
    con.print("singular values (scaled): " + " ".join(f"{v:.3g}" for v in a.singular_values))
    if a.problem():
        con.print(f"[bold red]these frames are not enough:[/bold red] {shown(a.problem())}")


def _print_base_parameters(con, base, channels) -> None:
    """The base parameters, the null directions, and which standard parameters are identifiable alone."""
    t = table(
        "Base parameters: what the data determine (beta = B theta)", ("#", "base parameter"), left=("base parameter",)
    )
    for k, name in enumerate(base.names):
        t.add_row(str(k + 1), name)
    con.print(t)
    if base.null_basis.shape[1]:
        seen_by = "the base wrench" if channels is None or channels.keys == ("wrench",) else "the measurements"
        t = table(
            f"Null directions: parameter changes invisible in {seen_by}",
            ("#", "direction (add t times)"),
            left=("direction (add t times)",),
        )
        for k, text in enumerate(base.null_directions()):
            t.add_row(str(k + 1), text)
        con.print(t)
    ident = [p for p, ok in zip(base.param_names, base.identifiable, strict=True) if ok]
    other = [p for p, ok in zip(base.param_names, base.identifiable, strict=True) if not ok]
    con.print(f"individually identifiable ({len(ident)}): {shown(', '.join(ident) or '-')}")
    con.print(f"only in combinations ({len(other)}): {shown(', '.join(other) or '-')}")
    if base.null_basis.shape[1]:
        con.print(
            "The null directions are structural: mass on a joint axis between two unknown links does not feel "
            "that joint turn, so it acts on the base as if welded to the earlier link. Estimates of the other "
            "parameters need prior knowledge (ineid uses the CAD values) or constraints."
        )


def _require_frames_memory(model, n_frames: int) -> None:
    """The analysis holds the regressor of every frame (6 x 10 n_links) and a few copies of it."""
    from ineid._faults import require_memory

    require_memory(
        4 * n_frames * 6 * 10 * model.n_links * 8, f"analysing {n_frames:,} frames", "use fewer frames (--n-frames)"
    )


def _print_bias_cost(con, model, q, qd, qdd, channels=None) -> None:
    from ineid.identify import bias_cost

    c = bias_cost(model, q, qd, qdd, channels)
    con.print(
        f"[bold]What the six sensor offsets cost[/bold]: a wrench constant over the whole recording cannot be told "
        f"from them. Structural rank {c.base.rank} without offsets, {c.base_bias.rank} with; condition number "
        f"{c.condition[0]:.4g} -> {c.condition[1]:.4g} on these frames."
    )
    if c.new_null_directions:
        t = table(
            "Lost with the offsets: parameter changes whose only effect is a constant wrench",
            ("#", "direction (add t times)"),
            left=("direction (add t times)",),
        )
        for k, text in enumerate(c.new_null_directions):
            t.add_row(str(k + 1), text)
        con.print(t)
    if c.lost:
        con.print(f"no longer individually identifiable: {shown(', '.join(c.lost))}")
    t = table(
        "Standard deviation of each base parameter with the offsets / without (same noise, these frames)",
        ("#", "base parameter (with offsets)", "std ratio"),
        left=("base parameter (with offsets)",),
    )
    for k, (name, r) in enumerate(zip(c.base_bias.names, c.std_inflation, strict=True)):
        t.add_row(str(k + 1), name, f"{r:.3g}")
    con.print(t)


@click.command("export-urdf")
@click.argument("results_path", metavar="RESULTS", type=click.Path(path_type=Path))
@click.option("--config", type=int, required=True, help="Configuration (index in the dataset).")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .urdf file to write.")
@overwrite_option
def export_urdf_cmd(results_path, config, out, overwrite) -> None:
    """Write the model's URDF with the identified links' inertials of one configuration."""
    from ineid.identify import export_urdf, load_results

    prepare_output(out, overwrite, inputs=[("the input results file", results_path), *results_inputs(results_path)])
    res = load_results(results_path)
    export_urdf(res, config, out, overwrite=overwrite)
    click.echo(
        f"wrote {out}: {plain(', '.join(res.meta['unknown_links']))} of configuration {config} ({res.settings.method})"
    )


@click.group()
def results() -> None:
    """Inspect results files of `ineid solve`."""


@results.command("info")
@click.argument("path", metavar="RESULTS", type=click.Path(path_type=Path))
def results_info(path: Path) -> None:
    """Provenance and summary of a results file: dataset (path, fingerprint), settings, successes."""
    import json

    import numpy as np

    from ineid.identify import load_results
    from ineid.identify.constrained_std import std_note
    from ineid.report.fitted import fitted_channels, held_out_error_name
    from ineid.robots.gravity import describe_gravity

    res = load_results(path)
    m = res.meta
    con = console()
    con.print(
        f"[bold]{shown(path)}[/bold]  ineid results ({shown(res.settings.method)}), "
        f"written by ineid {shown(m['ineid_version'])}"
    )
    con.print(
        f"dataset: {shown(m.get('dataset_path') or 'unknown (in memory, or an older file)')}; "
        f"fingerprint {shown(m.get('dataset_fingerprint') or '-')}"
    )
    con.print(
        f"robot {shown(m['robot'])} ({shown(m['source'])}); "
        f"unknown links {shown(', '.join(m['unknown_links']))}; {describe_gravity(m['gravity'])}"
    )
    con.print(f"fitted: {shown(fitted_channels(m))}", soft_wrap=True)
    con.print(f"settings: {shown(json.dumps(res.settings.to_dict(), sort_keys=True))}")
    con.print(std_note(res.settings.method, m.get("std")), soft_wrap=True)
    n_ok = int(res.success.sum())
    con.print(
        f"{n_ok}/{res.n} configurations identified (indices {int(res.config_index.min())}.."
        f"{int(res.config_index.max())}) in {m['total_seconds']:.2f} s; {res.n_frames_fit} frames fitted, "
        f"{res.n_frames_validation} validated; {len(res.base.names)} base parameters"
    )
    if res.n_frames_validation and n_ok:
        with np.errstate(invalid="ignore"):  # inf (a zero wrench) between two values: nan
            median = np.median(res.validation_rel[res.success])
        con.print(f"held-out {shown(held_out_error_name(m))}: median {median:.3g}", soft_wrap=True)
    print_held_out_rms(con, res)
    for k, rec in enumerate(m.get("recordings") or []):
        con.print(
            f"recording {k + 1}: {shown(rec.get('path') or 'in memory')}, fingerprint "
            f"{shown(rec.get('fingerprint') or '-')}, {rec.get('n_frames')} frames fitted"
        )
    v = m.get("validation")
    if v:
        con.print(
            f"validation: {shown(v.get('path') or 'in memory')}, fingerprint {shown(v.get('fingerprint') or '-')}, "
            f"{v.get('n_frames')} frames; offsets: {shown(v.get('offsets') or 'none')}; relative error "
            f"{'-' if v.get('rel') is None else format(v['rel'], '.3g')} (median; RMS per axis above)"
        )
    if res.n_extra:
        con.print(f"extra parameters (after the links'): {shown(', '.join(res.param_names[-res.n_extra :]))}")
    if res.payload:
        _print_payload(con, res)
    warnings = m.get("warnings")
    if warnings is None:
        con.print("plausibility warnings: not checked when this file was written")
    else:
        con.print(f"plausibility warnings: {len(warnings) or 'none'}")
        for w in warnings:
            con.print(f"  warning: {w['message']}", markup=False, soft_wrap=True)
    for note in m.get("notes") or ():  # what the data leave open (the linear completion's rigid bodies)
        con.print(f"note: {note}", markup=False, soft_wrap=True)


def _print_payload(con, res) -> None:
    """Per payload link, its first identified configuration: mass, centre of mass, inertia about it, +- std."""
    import numpy as np

    from ineid.identify.payload import INERTIA_NAMES

    ok = np.flatnonzero(res.success)
    if not ok.size:
        return
    i = int(ok[0])
    for link, q in res.payload.items():
        rows = table(
            f"Payload {link}, configuration {int(res.config_index[i])} (link frame, SI)",
            ("quantity", "value", "std"),
            left=("quantity",),
        )
        entries = [("mass kg", q["mass"][i], q["mass_std"][i])]
        entries += [(f"com {a} m", q["com"][i, k], q["com_std"][i, k]) for k, a in enumerate("xyz")]
        entries += [
            (f"{name} about com kg*m^2", q["inertia"][i, k], q["inertia_std"][i, k])
            for k, name in enumerate(INERTIA_NAMES)
        ]
        for name, value, std in entries:
            rows.add_row(name, f"{value:.6g}", f"{std:.3g}")
        con.print(rows)


def register(main: click.Group) -> None:
    for command in (identifiability, export_urdf_cmd, results):
        main.add_command(command)
