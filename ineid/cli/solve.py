"""``ineid solve``: identify the unknown links of a dataset (or several recordings jointly), and validate."""

from __future__ import annotations

import os
from pathlib import Path

import click

from ineid.cli.channel_options import channel_options, settings_flags
from ineid.cli.options import (
    WORKERS,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    PlotFile,
    deprecated_alias,
    parse_selection,
    quiet,
    select_alias,
    select_option,
)
from ineid.cli.output import ProgressBar, console, print_findings, print_results, shown
from ineid.cli.output_files import overwrite_option, prepare_output, run_inputs
from ineid.cli.report import check_solve_outputs, plot_span_option, report_option, write_solve_outputs

_SOLVE = "ineid.identify.settings"


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
    help="network: a trained run (--run) identifies every configuration at once. An imported recording "
    "without --method: consistent (rigid bodies whatever the noise).",
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
    type=LibraryChoice(f"{_SOLVE}:WEIGHT_MODES"),
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
    help="Write measured vs predicted values of the fitted channels (the wrench, joint torques) on the held-out "
    "frames (first solved configuration), per axis with the residual and its RMS (.png, .pdf, .svg).",
)
@click.option(
    "--mixed-filters",
    is_flag=True,
    help="Fit (and validate on) recordings imported with different filters (cut-off, filter, an estimated "
    "delay each) anyway, with a warning naming each one's; without it they are refused.",
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
    mixed_filters,
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
    from ineid.workflow import solve_dataset

    joint = len(data_paths) > 1 or validate_path is not None
    inputs = [*(("the input dataset", p) for p in data_paths), *run_inputs(run_dir)]
    if validate_path is not None:
        inputs.append(("the validation recording (--validate)", validate_path))
    prepare_output(out, overwrite, inputs=inputs)
    _refuse_network_options(ctx, method, run_dir, plot_path)
    check_solve_outputs(plot_path, plot_span, report_path, overwrite, [*inputs, ("the results file (--out)", out)])
    if sigma is not None and weights != "noise":
        raise click.UsageError("--sigma goes with --weights noise")
    meta, shapes = read_meta(data_paths[0])
    method, defaulted = _recording_default(ctx, method, meta)
    idx = parse_selection(selection, shapes["q"][0])
    settings = _settings(
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
    if joint:
        _refuse_joint_options(fit_frames, plot_path, method, backend)
    ds = load_dataset(data_paths[0], configs=idx, clean=False)
    model = ds.model()
    bar = ProgressBar(f"solving ({method})", "configurations", quiet(ctx))
    mixed = None
    if joint:
        res, solved_ds, ds, val, mixed = _solve_recordings(
            ds, data_paths[1:], validate_path, idx, settings, model, bar, mixed_filters
        )
    else:
        with bar:
            res, solved_ds, val = solve_dataset(ds, settings, model=model, progress=bar), ds, None
    _save_and_show(res, ds, model, out, overwrite, () if mixed is None else (mixed,), val)
    if defaulted:
        console().print(
            f"method {method}: the default for recordings (rigid bodies whatever the noise; --method linear for the "
            "least-squares fit)"
        )
    write_solve_outputs(
        res, solved_ds, model, method, plot_path, plot_span, report_path, out, validate=val, overwrite=overwrite
    )


def _save_and_show(res, ds, model, out: Path, overwrite: bool, more=(), validate=None) -> None:
    """The plausibility checks of ``res`` on the frames fitted (``ds``) and the validation recording
    (``validate``, or None), and the findings ``more``, recorded with it; the results saved to ``out`` and
    printed, the validation and the findings after them."""
    from ineid.identify import save_results
    from ineid.identify.physical_checks import linear_completion_note
    from ineid.identify.plausibility import check_solve

    findings = [*more, *check_solve(ds, res, model, validate)]
    res.meta["warnings"] = [f.to_dict() for f in findings]
    note = linear_completion_note(res)
    res.meta["notes"] = [] if note is None else [note]
    save_results(res, out, overwrite=overwrite)
    print_results(res, out)
    if note is not None:
        console().print(f"note: {note}")
    if res.meta.get("validation"):
        _print_validation(res)
    print_findings(findings)


RECORDING_METHOD = "consistent"
"""``--method`` when not given and the first input is an imported recording (its origin holds the import's summary):
on simulated recordings of UR5, Panda and SO-101 it gave rigid bodies every time, the linear fit never
(docs/identification.md, "Physical validity")."""


def _recording_default(ctx, method: str, meta) -> tuple[str, bool]:
    """``(method, defaulted)``: ``--method`` as given, or :data:`RECORDING_METHOD` for a recording without it."""
    given = ctx.get_parameter_source("method") is not click.core.ParameterSource.DEFAULT
    if given or not (meta.origin or {}).get("import"):
        return method, False
    return RECORDING_METHOD, True


def _refuse_network_options(ctx, method: str, run_dir, plot_path) -> None:
    """``--method network`` with ``--run`` and nothing it does not apply to (``click.UsageError``)."""
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


def _settings(**options):
    """The :class:`ineid.identify.SolveSettings` of ``options``; what it refuses as ``click.UsageError``."""
    from ineid.identify import SolveSettings

    try:
        return SolveSettings(**options)
    except ValueError as e:
        raise click.UsageError(str(e)) from None


def _refuse_joint_options(fit_frames, plot_path, method: str, backend: str) -> None:
    """Several recordings or ``--validate``: refuse what applies to one dataset (``click.UsageError``)."""
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


def _solve_recordings(ds, more_paths, validate_path, idx, settings, model, bar, mixed_filters=False):
    """``(results, ds, joined, validate, mixed)``: the recordings ``ds`` and ``more_paths`` (configurations ``idx``
    of each) fitted jointly (:func:`ineid.identify.joint.solve_recordings`) under the progress ``bar``, validated
    on the recording ``validate`` of ``validate_path`` (None: none); ``joined`` holds every frame fitted, for the
    plausibility checks; ``mixed`` the warning of recordings imported with different filters, which
    :func:`ineid.identify.joint.solve_recordings` refuses unless ``mixed_filters``."""
    from ineid.data import load_dataset
    from ineid.data.recordings.plausibility import Finding
    from ineid.identify.joint import solve_recordings

    more = [load_dataset(p, configs=idx, clean=False) for p in more_paths]
    val = None if validate_path is None else load_dataset(validate_path, configs=idx, clean=False)
    with bar:
        res = solve_recordings(
            [ds, *more], settings, model=model, validate=val, progress=bar, mixed_filters=mixed_filters
        )
    differ = res.meta.get("mixed_filters")
    mixed = None if differ is None else Finding("mixed_filters", differ)
    return res, ds, _joined(ds, more), val, mixed


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
    """The separate validation recording: its frames, its offsets, the relative error (the RMS per axis are in the
    summary's held-out lines)."""
    v = res.meta["validation"]
    if v.get("rel") is None:
        return
    console().print(
        f"validation on {shown(v['path'] or 'the validation recording')} ({v['n_frames']} frames; offsets: "
        f"{shown(v['offsets'])}): relative error {v['rel']:.3g} (median)",
        soft_wrap=True,
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


def register(main: click.Group) -> None:
    main.add_command(solve)
