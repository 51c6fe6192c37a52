"""``ineid train``, ``evaluate`` and ``sweep``: networks on a dataset, beside least squares."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.options import (
    SEED,
    FiniteFloatRange,
    LibraryChoice,
    LibraryOption,
    deprecated_alias,
    parse_selection,
    quiet,
    select_alias,
    select_option,
)
from ineid.cli.output import ProgressBar, print_evaluation
from ineid.cli.output_files import overwrite_option

_CFG = "ineid.learn.train:TrainConfig"
_MODEL = "ineid.learn.models:ModelSpec"


_RUN_OPTIONS = (
    click.option(
        "--depth",
        type=click.IntRange(min=1),
        default=None,
        help="Hidden layers of --arch mlp (or of the wls frame encoder, default 2).",
    ),
    click.option(
        "--width",
        type=click.IntRange(min=1),
        default=None,
        help="Neurons per layer of --arch mlp (or of the wls frame encoder, default 32).",
    ),
    click.option("--lr", type=FiniteFloatRange(min=0, min_open=True), cls=LibraryOption, default_from=f"{_CFG}.lr"),
    click.option(
        "--schedule",
        type=LibraryChoice("ineid.learn.train:SCHEDULES"),
        cls=LibraryOption,
        default_from=f"{_CFG}.schedule",
    ),
    click.option("--epochs", type=click.IntRange(min=1), cls=LibraryOption, default_from=f"{_CFG}.epochs"),
    click.option(
        "--batch",
        type=click.IntRange(min=1),
        cls=LibraryOption,
        default_from=f"{_CFG}.batch",
        help="Samples per step.",
    ),
    click.option(
        "--alpha",
        type=FiniteFloatRange(min=0),
        cls=LibraryOption,
        default_from=f"{_CFG}.alpha",
        help="Weight of the MSE.",
    ),
    click.option(
        "--beta",
        type=FiniteFloatRange(min=0),
        cls=LibraryOption,
        default_from=f"{_CFG}.beta",
        help="Weight of the wrench residual (physics loss).",
    ),
    click.option(
        "--patience",
        type=click.IntRange(min=0),
        cls=LibraryOption,
        default_from=f"{_CFG}.patience",
        help="Early stopping: epochs without a better validation MSE (0: off).",
    ),
    click.option(
        "--train-configs",
        "n_train",
        type=click.IntRange(min=1),
        default=None,
        help="Training configurations (default 70 %).",
    ),
    click.option(
        "--val-configs",
        "n_val",
        type=click.IntRange(min=1),
        default=None,
        help="Validation configurations (default 15 %).",
    ),
    click.option(
        "--test-configs",
        "n_test",
        type=click.IntRange(min=1),
        default=None,
        help="Test configurations (default: the rest).",
    ),
    click.option("--seed", type=SEED, cls=LibraryOption, default_from=f"{_CFG}.seed"),
    click.option(
        "--dtype",
        type=LibraryChoice("ineid.learn.config:DTYPES"),
        cls=LibraryOption,
        default_from=f"{_CFG}.dtype",
        help="What the network trains in (float32: faster where the arithmetic is the cost, resolving the wrench "
        "residual to about 1e-7 of its scale; evaluation and identification stay float64).",
    ),
    click.option(
        "--physics-mode",
        type=LibraryChoice("ineid.learn.losses:PHYSICS_MODES"),
        default="cached",
        show_default=True,
        help="Regressor of the physics loss: computed once per frame, or inside the loss.",
    ),
)
"""The options of :func:`run_options`, in the order ``--help`` lists them."""


def run_options(f):
    """Options shared by ``ineid train`` and ``ineid sweep`` (the settings of one run; defaults: TrainConfig's)."""
    for o in reversed(_RUN_OPTIONS):
        f = o(f)
    return f


def _folder_id(path: Path) -> tuple[int, int] | None:
    """``(device, inode)`` of the folder at ``path`` (through a link), None if there is none: a folder
    swapped in by :func:`ineid._atomic.replace_folder` has another."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino


def train_config(model_kw: dict, kw: dict):
    """A :class:`TrainConfig` from the options; a bad combination is a usage error."""
    from ineid.learn import ModelSpec, TrainConfig

    try:
        return TrainConfig(model=ModelSpec(**model_kw), **kw)
    except ValueError as e:
        raise click.UsageError(str(e)) from None


@click.command("train")
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option(
    "--arch",
    type=LibraryChoice("ineid.learn.models:ARCHITECTURES"),
    cls=LibraryOption,
    default_from=f"{_MODEL}.arch",
    help="Table 1 of the paper, mlp, or wls (a weighted least-squares solve with learned weights and prior).",
)
@click.option(
    "--activation",
    type=LibraryChoice("ineid.learn.models:ACTIVATIONS"),
    cls=LibraryOption,
    default_from=f"{_MODEL}.activation",
)
@click.option(
    "--scaler", type=LibraryChoice("ineid.learn.scalers:SCALERS"), cls=LibraryOption, default_from=f"{_CFG}.scaler"
)
@click.option(
    "--optimizer",
    type=LibraryChoice("ineid.learn.train:OPTIMIZERS"),
    cls=LibraryOption,
    default_from=f"{_CFG}.optimizer",
)
@click.option(
    "--sample-frames",
    type=click.IntRange(min=1),
    cls=LibraryOption,
    default_from=f"{_MODEL}.frames",
    help="Frames per network sample (K).",
)
@deprecated_alias("--frames", "sample_frames", "--sample-frames", type=click.IntRange(min=1))
@click.option("--siamese", is_flag=True, help="One shared encoder per frame, embeddings averaged, then a head.")
@click.option("--loss", type=LibraryChoice("ineid.learn.losses:LOSSES"), cls=LibraryOption, default_from=f"{_CFG}.loss")
@run_options
@click.option("--out", "run_dir", type=click.Path(file_okay=False, path_type=Path), required=True, help="Run folder.")
@click.option("--resume", is_flag=True, help="Continue the run in --out from its checkpoint (same settings).")
@overwrite_option
@click.pass_context
def train_cmd(
    ctx,
    data_path,
    run_dir,
    resume,
    overwrite,
    physics_mode,
    arch,
    activation,
    depth,
    width,
    sample_frames,
    siamese,
    **kw,
) -> None:
    """Train a network on DATA.h5 into a run folder, then evaluate it on the test split.

    With --overwrite, a run already in the folder is replaced only when the new one is
    finished; an interruption leaves it untouched.
    """
    import json

    from ineid._atomic import atomic_write
    from ineid.cli.output_files import on_interrupt, prepare_output
    from ineid.data import load_dataset
    from ineid.learn import evaluate, load_run, train
    from ineid.learn.runs import EVALUATION, RUN_FILES, holds_run

    cfg = train_config(
        dict(arch=arch, activation=activation, depth=depth, width=width, siamese=siamese, frames=sample_frames), kw
    )
    prepare_output(run_dir, overwrite, kind="folder", inputs=[("the input dataset", data_path)], contents=RUN_FILES)
    left_behind = _left_behind(run_dir, data_path, replacing=overwrite and not resume and holds_run(run_dir))

    ds = load_dataset(data_path, clean=False)
    model = ds.model()
    evaluations = []

    def finish(work: Path) -> None:  # part of the run: written before a replacement is swapped in
        ev = evaluate(load_run(work), ds, model=model)
        atomic_write(work / EVALUATION, json.dumps(ev.to_dict(), indent=1))
        evaluations.append(ev)

    with on_interrupt(left_behind), ProgressBar(f"training {cfg.model.name}", "epochs", quiet(ctx)) as bar:
        result = train(
            ds,
            cfg,
            run_dir,
            dataset_path=str(data_path),
            resume=resume,
            overwrite=overwrite,
            progress=_epoch_progress(bar, cfg.model.name),
            model=model,
            physics_mode=physics_mode,
            finish=finish,
        )
    click.echo(
        f"{result.epochs_run} epochs in {result.seconds:.1f} s"
        + (" (stopped early)" if result.stopped_early else "")
        + f"; best validation MSE {result.best_val_mse:.4g} at epoch {result.best_epoch}; wrote {run_dir}"
    )
    print_evaluation(evaluations[-1])


def _left_behind(run_dir: Path, data_path: Path, replacing: bool):
    """What an interrupted ``ineid train`` says it leaves in ``run_dir`` (None: nothing to say); ``replacing``: the
    folder held a run that the new one replaces once finished."""
    from ineid.learn.runs import CHECKPOINT

    previous = _folder_id(run_dir)

    def left_behind() -> str | None:
        if replacing and _folder_id(run_dir) == previous:
            return f"{run_dir} keeps its previous run, untouched (the new one was not finished)"
        if replacing:  # the signal came during the swap, held back until the new run was in place
            return f"{run_dir} holds the new run, complete (it had replaced the previous one)"
        if (run_dir / CHECKPOINT).is_file():
            return (
                f"the run in {run_dir} can be continued with "
                f"`ineid train {data_path} ... --out {run_dir} --resume` (the same settings)"
            )
        return None

    return left_behind


def _epoch_progress(bar, name: str):
    """``progress(epoch, epochs, record)`` of :func:`ineid.learn.train`: the bar, with the epoch's losses."""

    def progress(epoch, total, rec):
        bar(epoch, total)
        bar.set_description(
            f"training {name}  loss {rec['train_loss']:.4f}  val mse "
            f"{rec['val_mse']:.4f}  val phys {rec['val_phys']:.4f}"
        )

    return progress


@click.command("evaluate")
@click.argument("run_dir", metavar="RUN_DIR", type=click.Path(path_type=Path))
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@select_option
@select_alias
@click.option("--no-linear", is_flag=True, help="Skip the classical comparisons (linear LS, Gaussian prior).")
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=None,
    help="Where to write the evaluation (JSON). Default: the run's own RUN_DIR/evaluation.json, "
    "replaced once the new evaluation is complete.",
)
@click.option("--overwrite", is_flag=True, help="Replace --out if it exists.")
def evaluate_cmd(run_dir, data_path, selection, no_linear, out, overwrite) -> None:
    """Evaluate a trained run on DATA.h5: errors, R^2, floor, wrench residual, linear LS.

    Without --select: the run's test split if DATA.h5 is its dataset, else all configurations.
    Without --out the evaluation replaces the run's evaluation.json (written by `ineid train`),
    a file derived from the run; an interrupted evaluation leaves the old one in place.
    """
    import json

    from ineid._atomic import atomic_write
    from ineid.cli.output_files import prepare_output, run_inputs
    from ineid.data import load_dataset
    from ineid.learn import evaluate, load_run
    from ineid.learn.runs import EVALUATION

    # The run's own evaluation.json is derived from the run: re-evaluating replaces it (atomically, so
    # a failed or interrupted evaluation keeps the old one). A file named with --out is the user's.
    own = out is None
    out = prepare_output(
        Path(run_dir) / EVALUATION if own else out,
        overwrite or own,
        inputs=[("the input dataset", data_path), *run_inputs(run_dir)],
    )
    replaced = " (it replaces the run's previous evaluation)" if own and out.is_file() else ""
    run = load_run(run_dir)
    ds = load_dataset(data_path, clean=False)
    configs = None if selection is None else parse_selection(selection, ds.n_configs)
    ev = evaluate(run, ds, configs, linear=not no_linear)
    atomic_write(out, json.dumps(ev.to_dict(), indent=1))
    print_evaluation(ev)
    click.echo(f"wrote {out}{replaced}")


def register(main: click.Group) -> None:
    for command in (train_cmd, evaluate_cmd):
        main.add_command(command)
