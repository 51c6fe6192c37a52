"""``ineid sweep``: a grid of networks trained (here, or on a Ray cluster), resumable."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.learn import run_options, train_config
from ineid.cli.options import (
    FiniteFloatRange,
    LibraryChoice,
    deprecated_alias,
    names_in,
    numbers,
    quiet,
)
from ineid.cli.output import ProgressBar, console, table
from ineid.cli.output_files import overwrite_option

_CFG = "ineid.learn.train:TrainConfig"
_MODEL = "ineid.learn.models:ModelSpec"


@click.command("sweep")
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option(
    "--archs",
    default=None,
    callback=names_in("ineid.learn.models:ARCHITECTURES", "--archs"),
    help="Architectures, comma-separated (default: the paper's Table 1, simple and funnel).",
)
@click.option(
    "--activations",
    default=None,
    callback=names_in("ineid.learn.models:ACTIVATIONS", "--activations"),
    help="Default: tanh.",
)
@click.option(
    "--scalers", default=None, callback=names_in("ineid.learn.scalers:SCALERS", "--scalers"), help="Default: robust."
)
@click.option(
    "--optimizers",
    default=None,
    callback=names_in("ineid.learn.train:OPTIMIZERS", "--optimizers"),
    help="Default: adam.",
)
@click.option(
    "--losses", default=None, callback=names_in("ineid.learn.losses:LOSSES", "--losses"), help="Default: mse."
)
@click.option(
    "--sample-frames",
    "sample_frames",
    default=None,
    callback=numbers(int, "--sample-frames", 1),
    help="Frames per network sample to try, comma-separated (default 1).",
)
@deprecated_alias("--frames-list", "sample_frames", "--sample-frames", callback=numbers(int, "--frames-list", 1))
@click.option("--siamese", type=click.Choice(["off", "on", "both"]), default="off", show_default=True)
@run_options
@click.option(
    "--engine",
    type=LibraryChoice("ineid.learn.sweep:ENGINES"),
    default="sequential",
    show_default=True,
    help="Run the trials one after another here, or as tasks on a Ray cluster (pip install 'ineid[ray]').",
)
@click.option(
    "--address",
    default=None,
    metavar="ADDR",
    help="Ray cluster to join (ray://head:10001, auto); default: a local one started for the sweep.",
)
@click.option(
    "--cpus-per-trial",
    type=FiniteFloatRange(min=0),
    default=1.0,
    show_default=True,
    help="CPUs each trial reserves (--engine ray).",
)
@click.option(
    "--gpus-per-trial",
    type=FiniteFloatRange(min=0),
    default=0.0,
    show_default=True,
    help="GPUs each trial reserves (--engine ray).",
)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the sweep in --out (same settings): finished trials are kept, interrupted ones resumed.",
)
@overwrite_option
@click.pass_context
def sweep_cmd(
    ctx,
    data_path,
    archs,
    activations,
    scalers,
    optimizers,
    losses,
    sample_frames,
    siamese,
    engine,
    address,
    cpus_per_trial,
    gpus_per_trial,
    out_dir,
    resume,
    overwrite,
    physics_mode,
    depth,
    width,
    **kw,
) -> None:
    """Train a grid of networks (here, or on a Ray cluster); write sweep.csv and sweep.png ranked by test error.

    Trials that share a network (they differ in scaler, learning rate, loss weights, seed) train
    together as one population, one compiled program (on a Ray cluster: one population a task);
    each trial's numbers are those of training it alone.

    An interrupted sweep keeps its finished trials (and the interrupted ones' checkpoints):
    continue it with the same command and --resume.
    """
    from ineid._atomic import check_output
    from ineid.cli.output_files import on_interrupt, prepare_output
    from ineid.data import load_dataset
    from ineid.learn import sweep
    from ineid.learn.sweep import SWEEP_RECORD, check_sweep_folder, run_name

    grid = _sweep_grid(archs, activations, scalers, optimizers, losses, sample_frames, siamese)
    base = train_config(dict(arch="mlp" if depth or width else "simple", depth=depth, width=width), kw)
    _check_engine(ctx, engine)
    if resume and overwrite:
        raise click.UsageError("give --resume (continue the sweep) or --overwrite (start it afresh), not both")
    try:
        cfgs = grid.configs(base)
        if not cfgs:
            raise ValueError("the grid is empty: a Siamese network needs more than one frame (--sample-frames 10)")
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    prepare_output(
        out_dir,
        overwrite,
        kind="folder",
        inputs=[("the input dataset", data_path)],
        contents=("sweep.csv", "sweep.png", SWEEP_RECORD, *(run_name(c) for c in cfgs)),
    )
    if out_dir.is_dir() and not resume:
        check_output(out_dir / "sweep.csv", overwrite)
    ds = load_dataset(data_path, clean=False)
    check_sweep_folder(ds, grid, base, out_dir, overwrite=overwrite, resume=resume)
    with on_interrupt(_left_behind(ds, cfgs, data_path, out_dir)), ProgressBar("sweep", "runs", quiet(ctx)) as bar:
        bar(0, len(cfgs))
        rows = sweep(
            ds,
            grid,
            base,
            out_dir,
            dataset_path=str(data_path),
            progress=lambda i, t, r: bar(i, t),
            overwrite=overwrite,
            physics_mode=physics_mode,
            engine=engine,
            address=address,
            cpus_per_trial=cpus_per_trial,
            gpus_per_trial=gpus_per_trial,
            resume=resume,
        )
    _print_sweep(data_path, rows)
    click.echo(f"wrote {out_dir / 'sweep.csv'} and {out_dir / 'sweep.png'}")


def _sweep_grid(archs, activations, scalers, optimizers, losses, sample_frames, siamese: str):
    """The grid of the options given (each None: the grid's default); ``siamese``: off, on or both."""
    from ineid.learn import Grid

    given = dict(
        archs=archs,
        activations=activations,
        scalers=scalers,
        optimizers=optimizers,
        losses=losses,
        frames=sample_frames,
    )
    grid = Grid(
        **{k: v for k, v in given.items() if v is not None},
        siamese={"off": (False,), "on": (True,), "both": (False, True)}[siamese],
    )
    return grid


def _left_behind(ds, cfgs, data_path, out_dir: Path):
    """What an interrupted ``ineid sweep`` says it leaves in ``out_dir``: its finished trials and how to continue
    (None before the sweep's record is written)."""
    from ineid.learn.sweep import SWEEP_RECORD, run_name, trial_state

    def left_behind() -> str | None:
        if not (out_dir / SWEEP_RECORD).is_file():
            return None
        fingerprint = ds.fingerprint()
        done = sum(trial_state(out_dir / run_name(c), c, fingerprint) == "finished" for c in cfgs)
        return (
            f"{done} of {len(cfgs)} trials in {out_dir} are finished; continue the sweep with "
            f"`ineid sweep {data_path} ... --out {out_dir} --resume` (the same settings)"
        )

    return left_behind


def _check_engine(ctx, engine: str) -> None:
    """Refuse the Ray options without ``--engine ray``; with it, say how to install Ray before anything loads."""
    ray_given = [
        f"--{n.replace('_', '-')}"
        for n in ("address", "cpus_per_trial", "gpus_per_trial")
        if ctx.get_parameter_source(n) is click.core.ParameterSource.COMMANDLINE
    ]
    if engine != "ray" and ray_given:
        raise click.UsageError(f"{', '.join(ray_given)} go with --engine ray")
    if engine == "ray":
        from ineid.learn.ray_engine import import_ray

        import_ray()  # says how to install Ray before anything is loaded


def _print_sweep(data_path, rows) -> None:
    """The trials' table, ranked by test error (a failed trial: its status), and how many failed (stderr)."""
    t = table(
        f"Sweep on {data_path}: test median relative error, ranked",
        (
            "#",
            "run",
            "standard",
            "base",
            "floor",
            "linear LS (std / base)",
            "Gaussian prior (std / base)",
            "physical",
            "epochs",
            "s",
        ),
        left=("run",),
    )
    for i, r in enumerate(rows):
        if r.status != "ok":
            t.add_row(str(i + 1), r.name, r.status, *[""] * 7)
            continue
        t.add_row(
            str(i + 1),
            r.name,
            f"{r.test_standard_median:.4g}",
            f"{r.test_base_median:.4g}",
            f"{r.floor_standard_median:.4g}",
            f"{r.linear_standard_median:.4g} / {r.linear_base_median:.3g}",
            f"{r.gaussian_standard_median:.4g} / {r.gaussian_base_median:.3g}",
            f"{100 * r.physical_share:.0f}%",
            str(r.epochs_run),
            f"{r.seconds:.0f}",
        )
    console().print(t)
    failed = [r for r in rows if r.status != "ok"]
    if failed:
        click.echo(
            f"{len(failed)} of {len(rows)} trials failed (see the table and sweep.csv's status column)", err=True
        )


def register(main: click.Group) -> None:
    main.add_command(sweep_cmd)
