"""``ineid study networks``: the paper's network exploration (activations x scalers x optimizers, Table 1 and
Siamese networks) at its scale, and its claims checked."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ineid.cli.options import FiniteFloatRange, LibraryChoice, numbers, quiet
from ineid.cli.output import ProgressBar, console, table
from ineid.cli.output_files import overwrite_option

_NETS = "ineid.studies.paper_networks"


def _fmt(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:.4g}"


@click.command("networks")
@click.option(
    "--plan",
    "plan_name",
    type=click.Choice(["full", "decisive"]),
    default="full",
    show_default=True,
    help="full: every activation x scaler x optimizer on Table 1's networks (and simple, funnel) and on "
    "Table 1's Siamese networks; decisive: one factor at a time around tanh / robust / SGD on "
    "Network 1, and the Siamese claim's cells.",
)
@click.option(
    "--quick",
    is_flag=True,
    help="The CI size: a 2 x 2 x 2 grid on the simple network, 24 configurations "
    "of 20 frames, 2 epochs, one seed (claims then not decidable).",
)
@click.option(
    "--data",
    "data_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Train on this dataset (default: the paper's, generated: 10,000 configurations x 100 frames).",
)
@click.option("--epochs", type=click.IntRange(min=1), default=None, help="Epochs of every trial (default 100).")
@click.option(
    "--siamese-epochs",
    type=click.IntRange(min=1),
    default=None,
    help="Epochs of the decisive plan's Siamese-claim cells (default 10).",
)
@click.option("--n-train", type=click.IntRange(min=1), default=None, help="Training configurations (default 3,000).")
@click.option("--n-val", type=click.IntRange(min=1), default=None, help="Validation configurations (default 500).")
@click.option("--n-test", type=click.IntRange(min=1), default=None, help="Test configurations (default 500).")
@click.option(
    "--seeds",
    default=None,
    callback=numbers(int, "--seeds", 0),
    help="Seeds, comma-separated: one sweep each (default 0,1; two or more decide a claim).",
)
@click.option(
    "--lr",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="The learning rate of every optimizer (default 1e-3).",
)
@click.option(
    "--engine",
    type=LibraryChoice("ineid.learn.sweep:ENGINES"),
    default="sequential",
    show_default=True,
    help="Run the trials here one after another, or as Ray tasks (pip install 'ineid[ray]').",
)
@click.option("--address", default=None, metavar="ADDR", help="Ray cluster to join (--engine ray).")
@click.option("--cpus-per-trial", type=FiniteFloatRange(min=0), default=None, help="CPUs per trial (--engine ray).")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Study folder: one sweep folder per part and seed, networks.csv, claims.csv.",
)
@click.option("--resume", is_flag=True, help="Continue the study in --out (same settings): finished trials are kept.")
@overwrite_option
@click.pass_context
def study_networks(
    ctx,
    plan_name,
    quick,
    data_path,
    epochs,
    siamese_epochs,
    n_train,
    n_val,
    n_test,
    seeds,
    lr,
    engine,
    address,
    cpus_per_trial,
    out_dir,
    resume,
    overwrite,
):
    """The paper's exploration of its networks, re-run: activations x scalers x optimizers on Table 1's networks
    and Siamese networks at its training size (3,000 configurations) and epochs (100), with its claims (tanh,
    robust scaler, SGD; the Siamese Network 6) judged beyond the seed-to-seed spread. A part's trials that share a
    network (its scalers and seeds) train together as one population."""
    from dataclasses import replace

    from ineid.cli.output_files import on_interrupt, prepare_output
    from ineid.studies.paper_claims import check_claims, write_claims
    from ineid.studies.paper_networks import (
        FILE,
        SIZES,
        check_study_folder,
        plan,
        run_study,
        sweep_folders,
        trials,
    )

    if resume and overwrite:
        raise click.UsageError("give --resume (continue the study) or --overwrite (start it afresh), not both")
    engine_kw = _engine_options(engine, address, cpus_per_trial)
    size = SIZES["quick" if quick else "paper"]
    given = dict(
        epochs=epochs, siamese_epochs=siamese_epochs, n_train=n_train, n_val=n_val, n_test=n_test, seeds=seeds, lr=lr
    )
    size = replace(size, **{k: v for k, v in given.items() if v is not None})
    parts = plan("quick" if quick else plan_name)
    inputs = [("the input dataset", data_path)]
    prepare_output(
        out_dir, overwrite, kind="folder", inputs=inputs, contents=(FILE, "claims.csv", *{p.name for p in parts})
    )
    ds = _study_dataset(data_path, size)
    check_study_folder(ds, parts, size, out_dir, resume=resume, overwrite=overwrite)

    def left_behind() -> str | None:
        started = [f for f in sweep_folders(parts, size, out_dir) if f.is_dir()]
        if not started:
            return None
        return f"the study in {out_dir} can be continued with the same command and --resume"

    with on_interrupt(left_behind), ProgressBar("network study", "trials", quiet(ctx)) as bar:
        bar(0, trials(parts, size))
        rows = run_study(
            ds,
            parts,
            size,
            out_dir,
            progress=lambda i, t, r: bar(i, t),
            resume=resume,
            overwrite=overwrite,
            engine=engine,
            **engine_kw,
        )
    verdicts = check_claims(rows)
    write_claims(verdicts, out_dir / "claims.csv")
    _print_study(rows, verdicts, f"Network study ({'quick' if quick else plan_name})", size.n_train)
    failed = [r for r in rows if r.status != "ok"]
    if failed:
        click.echo(f"{len(failed)} of {len(rows)} trials failed (see networks.csv's status column)", err=True)
    click.echo(f"wrote {out_dir / FILE} and {out_dir / 'claims.csv'}")


def _engine_options(engine: str, address: str | None, cpus_per_trial: float | None) -> dict:
    """The Ray options given (refused without ``--engine ray``); with Ray, say how to install it before anything
    loads."""
    engine_kw = {k: v for k, v in (("address", address), ("cpus_per_trial", cpus_per_trial)) if v is not None}
    if engine != "ray" and engine_kw:
        raise click.UsageError("--address and --cpus-per-trial go with --engine ray")
    if engine == "ray":
        from ineid.learn.ray_engine import import_ray

        import_ray()
    return engine_kw


def _study_dataset(data_path, size):
    """The dataset at ``data_path``, or (None) the sweaty-arm's generated at the study's size."""
    if data_path is not None:
        from ineid.data import load_dataset

        return load_dataset(data_path, clean=False)
    from ineid.data import generate_dataset
    from ineid.robots.load import load_robot

    return generate_dataset(load_robot("sweaty-arm"), size.dataset)


def _print_study(rows, verdicts, title: str, n_train: int) -> None:
    """The trials' table (test median relative errors) and the claims' verdicts."""
    con = console()
    t = table(
        f"{title}: {n_train} training configurations, test median relative error",
        ("part", "seed", "run", "standard", "base", "linear LS", "epochs", "s"),
        left=("part", "run"),
    )
    for r in rows:
        t.add_row(
            r.part,
            str(r.seed),
            r.name,
            _fmt(r.test_standard_median) if r.status == "ok" else r.status,
            _fmt(r.test_base_median),
            _fmt(r.linear_standard_median),
            str(r.epochs_run),
            _fmt(r.seconds),
        )
    con.print(t)
    c = table("The paper's claims", ("claim", "verdict", "why"), left=("claim", "verdict", "why"))
    for v in verdicts:
        c.add_row(v.claim, v.verdict, v.why)
    con.print(c)
