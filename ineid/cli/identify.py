"""``ineid identifiability``, ``solve``, ``export-urdf``, ``study noise`` (``study formulations``: its own module)
and ``results info``."""

from __future__ import annotations

import os
from pathlib import Path

import click

from ineid.cli.channel_options import channel_options, chosen_channels, settings_flags
from ineid.cli.options import (
    NOISE_MAX,
    SEED,
    WORKERS,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    PlotFile,
    deprecated_alias,
    names_in,
    numbers,
    parse_selection,
    quiet,
    robot_options,
    select_alias,
    select_option,
)
from ineid.cli.output import ProgressBar, console, plain, print_findings, print_results, shown, table
from ineid.cli.output_files import overwrite_option, prepare_output, results_inputs, robot_inputs, run_inputs
from ineid.cli.report import check_solve_outputs, plot_span_option, report_option, write_solve_outputs

_SOLVE = "ineid.identify.solve"


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
@channel_options()
def identifiability(robot, n_frames, seed, data_path, config, bias, **channel_flags) -> None:
    """Which parameters of ROBOT's unknown links the base wrench (or the channels of --use) determines.

    With joint torques and --friction, --armature or --torque-offset, the analysis is over the links'
    parameters and the joints' extra parameters together.
    """
    import numpy as np

    from ineid.identify import analyze_frames, base_parameters, generic_frames

    model = robot.load()
    with_bias = bias == "estimate"
    channels = None  # the base wrench, or what --data measures (chosen by --use and the actuation options)
    if data_path is not None:
        from ineid.data import load_dataset

        ds = load_dataset(data_path, configs=[config], clean=False)
        if ds.meta.joint_names != model.joint_names:
            raise click.BadParameter(
                f"{data_path} is a dataset of {ds.meta.robot!r}, not of {model.name!r}", param_hint="--data"
            )
        q, qd, qdd = ds.q[0], ds.qd[0], ds.qdd[0]
        source = f"{len(q)} frames of configuration {config} of {data_path}"
        channels = ds.meta.channels
    else:
        _require_frames_memory(model, n_frames)
        q, qd, qdd = generic_frames(model, n_frames, seed)
        source = f"{n_frames} random frames within the bounds (seed {seed})"
    _require_frames_memory(model, len(q))
    channels = chosen_channels(channels, channel_flags)
    base = base_parameters(model, bias=with_bias, channels=channels)
    a = analyze_frames(model, q, qd, qdd, base, bias=with_bias, channels=channels)
    con = console()
    n = base.n_params
    con.print(
        f"[bold]{shown(model.name)}[/bold]: unknown links {shown(', '.join(model.unknown_links))} "
        f"({base.n_link_params} standard parameters{f', {base.n_extra} extra' if base.n_extra else ''})"
    )
    con.print(f"frames: {shown(source)}")
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
    if with_bias:
        _print_bias_cost(con, model, q, qd, qdd, channels)


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


@click.command()
@click.argument("data_paths", metavar="DATA.h5...", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--validate",
    "validate_path",
    type=click.Path(path_type=Path),
    default=None,
    metavar="REC.h5",
    help="A separate recording of the same robot: the fitted parameters' prediction error on it "
    "(RMS per axis, relative). With --bias estimate its own offsets are fitted alone on it.",
)
@click.option(
    "--method",
    type=LibraryChoice(f"{_SOLVE}:METHODS"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.method",
    help="network: a trained run (--run) identifies every configuration at once.",
)
@click.option(
    "--run",
    "run_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    metavar="RUN",
    help="Run folder of `ineid train`, for --method network.",
)
@click.option(
    "--fit-frames",
    type=click.IntRange(min=1),
    default=None,
    help="Frames fitted per configuration (the first K; the rest validate). Default: 80 %.",
)
@deprecated_alias("--frames", "fit_frames", "--fit-frames", type=click.IntRange(min=1))
@select_option
@select_alias
@click.option(
    "--weights",
    type=LibraryChoice("ineid.identify.linear:WEIGHT_MODES"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.weights",
    help="Row weights per wrench axis: estimated from the residuals (default: calibrated std when the noise "
    "differs per axis), from the noise levels (--sigma or the file), or none (equal noise assumed).",
)
@click.option(
    "--sigma",
    nargs=6,
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    metavar="FX FY FZ MX MY MZ",
    help="Wrench noise std per axis (N, N*m) for --weights noise.",
)
@click.option(
    "--start",
    type=LibraryChoice(f"{_SOLVE}:STARTS"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.start",
    help="IPOPT's (and lsqnonlin's) start: the CAD values, or the linear estimate (made physical).",
)
@click.option(
    "--bounds",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    metavar="FRACTION",
    help="lsqlin only: keep every parameter within FRACTION of max(|CAD value|, its scale) of its CAD "
    "value (0.5: 50 %). Default: unbounded, the minimum-norm solution.",
)
@click.option(
    "--backend",
    type=LibraryChoice(f"{_SOLVE}:BACKENDS"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.backend",
    help="Least squares: fused JAX kernels; CasADi per configuration (no compilation); or "
    "casadi-c, the CasADi route compiled to C (IPOPT problems too; needs a C compiler).",
)
@click.option(
    "--workers",
    type=WORKERS,
    default=None,
    help="Processes for IPOPT (default: CPU count, at most 4 x; fewer than 256 configurations run in one).",
)
@click.option(
    "--bias",
    type=LibraryChoice(f"{_SOLVE}:BIAS_MODES"),
    cls=LibraryOption,
    default_from=f"{_SOLVE}:SolveSettings.bias",
    help="estimate: identify six constant sensor offsets with the parameters (an untared sensor).",
)
@click.option(
    "--known-uncertainty",
    "known_uncertainty",
    multiple=True,
    metavar="[LINK=]FRACTION",
    callback=lambda ctx, param, v: _known_uncertainty(v),
    help="The known links' CAD uncertainty, added to the reported std: each known parameter off by "
    "FRACTION of max(|CAD value|, the link's scale) (0.05: 5 %); LINK=FRACTION for one link "
    "(repeatable; overrides a plain FRACTION). Default: the CAD taken as exact.",
)
@channel_options(two_step=True)
@click.option(
    "--plot",
    "plot_path",
    type=PlotFile(),
    default=None,
    metavar="FILE",
    help="Write measured vs predicted wrench of the held-out frames (first solved configuration), "
    "per axis with the residual and its RMS (.png, .pdf, .svg).",
)
@plot_span_option
@report_option
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Results file (.h5).")
@overwrite_option
@click.pass_context
def solve(
    ctx,
    data_paths,
    validate_path,
    method,
    run_dir,
    fit_frames,
    selection,
    weights,
    sigma,
    start,
    bounds,
    backend,
    workers,
    bias,
    known_uncertainty,
    plot_path,
    plot_span,
    report_path,
    out,
    overwrite,
    **channel_flags,
) -> None:
    """Identify the unknown links of every selected configuration of DATA.h5.

    Several DATA files (recordings of one robot): configuration i of each is fitted jointly from
    all their frames (each with its own offsets under --bias estimate); --validate REC.h5 reports
    the prediction error on a separate recording.

    --method network: a trained run (--run RUN) estimates all configurations in batches; with
    --fit-frames, a multiple of the run's frames per sample.

    --use wrench,torque chooses the channels (default: every one the file has); --friction, --armature,
    --torque-offset model the joint torques' actuation, identified with the links (--two-step: after them).
    """
    from ineid.data import load_dataset, read_meta
    from ineid.identify import SolveSettings, save_results
    from ineid.workflow import solve_dataset

    data_path = data_paths[0]
    joint = len(data_paths) > 1 or validate_path is not None
    inputs = [*(("the input dataset", p) for p in data_paths), *run_inputs(run_dir)]
    if validate_path is not None:
        inputs.append(("the validation recording (--validate)", validate_path))
    prepare_output(out, overwrite, inputs=inputs)
    if (method == "network") != (run_dir is not None):
        raise click.UsageError("--method network needs --run RUN (a trained run folder), and --run goes with it")
    given = [
        f"--{n.replace('_', '-')}"
        for n in ("weights", "sigma", "start", "backend", "workers", "bias", "known_uncertainty")
        if ctx.get_parameter_source(n) is click.core.ParameterSource.COMMANDLINE
    ]
    if method == "network" and plot_path is not None:
        given.append("--plot")
    if method == "network" and given:
        raise click.UsageError(f"{', '.join(given)} do not apply to --method network")
    check_solve_outputs(plot_path, plot_span, report_path, overwrite, [*inputs, ("the results file (--out)", out)])
    if sigma is not None and weights != "noise":
        raise click.UsageError("--sigma goes with --weights noise")
    _, shapes = read_meta(data_path)
    idx = parse_selection(selection, shapes["q"][0])
    try:
        settings = SolveSettings(
            method=method,
            frames=fit_frames,
            weights=weights,
            axis_sigma=tuple(sigma) if sigma else None,
            start=start,
            backend=backend,
            workers=workers or os.cpu_count() or 1,
            bias=bias,
            run=None if run_dir is None else str(run_dir),
            known_uncertainty=known_uncertainty,
            bounds=bounds,
            **settings_flags(channel_flags),
        )
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    if joint:
        for opt, bad in (
            ("--fit-frames", fit_frames is not None),
            ("--plot", plot_path is not None),
            ("--method network", method == "network"),
            ("--backend", backend != "jax"),
        ):
            if bad:
                raise click.UsageError(
                    f"{opt} does not apply to several recordings or --validate "
                    "(every frame of the inputs is fitted, by the jax backend)"
                )
    ds = load_dataset(data_path, configs=idx, clean=False)
    model = ds.model()
    val = None
    if joint:
        from ineid.identify.joint import solve_recordings

        more = [load_dataset(p, configs=idx, clean=False) for p in data_paths[1:]]
        val = None if validate_path is None else load_dataset(validate_path, configs=idx, clean=False)
        with ProgressBar(f"solving ({method})", "configurations", quiet(ctx)) as bar:
            res = solve_recordings([ds, *more], settings, model=model, validate=val, progress=bar)
        solved_ds, ds = ds, _joined(ds, more)  # the plausibility checks see every frame fitted
    else:
        with ProgressBar(f"solving ({method})", "configurations", quiet(ctx)) as bar:
            res = solve_dataset(ds, settings, model=model, progress=bar)
        solved_ds = ds
    from ineid.identify.plausibility import check_solve

    findings = check_solve(ds, res, model)
    res.meta["warnings"] = [f.to_dict() for f in findings]
    save_results(res, out, overwrite=overwrite)
    print_results(res, out)
    if res.meta.get("validation"):
        _print_validation(res)
    print_findings(findings)
    write_solve_outputs(
        res, solved_ds, model, method, plot_path, plot_span, report_path, out, validate=val, overwrite=overwrite
    )


def _joined(ds, more):
    """One dataset of the frames of ``ds`` and ``more`` (same robot, configurations), for the plausibility checks."""
    import dataclasses

    import numpy as np

    if not more:
        return ds
    every = (ds, *more)
    arrays = {k: np.concatenate([getattr(d, k) for d in every], axis=1) for k in ("q", "qd", "qdd")}
    if ds.wrench is not None:
        arrays["wrench"] = np.concatenate([d.wrench for d in every], axis=1)
    arrays["channel_values"] = {
        k: np.concatenate([d.channel_values[k] for d in every], axis=1) for k in ds.channel_values
    }
    return dataclasses.replace(ds, **arrays, clean={}, time=None)


def _print_validation(res) -> None:
    v = res.meta["validation"]
    if v.get("rel") is None:
        return
    console().print(
        f"validation on {shown(v['path'] or 'the validation recording')} ({v['n_frames']} frames; offsets "
        f"{v['offsets']}): residual RMS per axis ({' '.join(res.axes)}) "
        + " ".join(f"{r:.3g}" for r in v["rms"])
        + f"; relative error {v['rel']:.3g} (median)"
    )


def _known_uncertainty(values) -> tuple[tuple[str, float], ...]:
    """``--known-uncertainty`` values as ``(link, fraction)`` pairs (link ``*``: every known link)."""
    import math

    pairs = []
    for v in values:
        link, _, text = v.rpartition("=")
        try:
            f = float(text)
        except ValueError:
            f = math.nan
        if not (math.isfinite(f) and 0 <= f < 10) or (v.count("=") and not link):
            raise click.BadParameter(
                f"{v!r} is not FRACTION or LINK=FRACTION with 0 <= FRACTION < 10 (0.05: 5 %)",
                param_hint="'--known-uncertainty'",
            )
        pairs.append((link or "*", f))
    return tuple(pairs)


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
    """Inspect results files of ``ineid solve``."""


@results.command("info")
@click.argument("path", metavar="RESULTS", type=click.Path(path_type=Path))
def results_info(path: Path) -> None:
    """Provenance and summary of a results file: dataset (path, fingerprint), settings, successes."""
    import json

    import numpy as np

    from ineid.identify import load_results

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
        f"unknown links {shown(', '.join(m['unknown_links']))}; gravity {shown(m['gravity'])} m/s^2"
    )
    con.print(f"settings: {shown(json.dumps(res.settings.to_dict(), sort_keys=True))}")
    n_ok = int(res.success.sum())
    con.print(
        f"{n_ok}/{res.n} configurations identified (indices {int(res.config_index.min())}.."
        f"{int(res.config_index.max())}) in {m['total_seconds']:.2f} s; {res.n_frames_fit} frames fitted, "
        f"{res.n_frames_validation} validated; {len(res.base.names)} base parameters"
    )
    if res.n_frames_validation and n_ok:
        with np.errstate(invalid="ignore"):  # inf (a zero wrench) between two values: nan
            median = np.median(res.validation_rel[res.success])
        con.print(f"held-out relative wrench error: median {median:.3g}")
    for k, rec in enumerate(m.get("recordings") or []):
        con.print(
            f"recording {k + 1}: {shown(rec.get('path') or 'in memory')}, fingerprint "
            f"{shown(rec.get('fingerprint'))}, {rec.get('n_frames')} frames fitted"
        )
    v = m.get("validation")
    if v:
        rms = " ".join("-" if r is None else f"{r:.3g}" for r in (v.get("rms") or []))
        con.print(
            f"validation: {shown(v.get('path') or 'in memory')}, fingerprint {shown(v.get('fingerprint'))}, "
            f"{v.get('n_frames')} frames; offsets {shown(v.get('offsets'))}; RMS per axis ({' '.join(res.axes)}) "
            f"{rms or '-'}; relative error {'-' if v.get('rel') is None else format(v['rel'], '.3g')} (median)"
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
    for command in (identifiability, solve, export_urdf_cmd, results, study):
        main.add_command(command)
