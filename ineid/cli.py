"""The ``ineid`` command: parse arguments, call the library, print or write the result.

Heavy libraries are imported inside the commands, so ``ineid --help`` stays fast. Any
:class:`ineid.IneidError` becomes a one-line message and exit status 1; bad arguments
exit with status 2 (click's usage error).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ineid import __version__
from ineid.errors import IneidError

class _Group(click.Group):
    """A group whose commands turn library errors into one clear line."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except IneidError as e:
            raise click.ClickException(str(e)) from None


def _console():
    from rich.console import Console  # noqa: PLC0415

    return Console(highlight=False, soft_wrap=False, width=max(150, _terminal_width()))


def _terminal_width() -> int:
    import shutil  # noqa: PLC0415

    return shutil.get_terminal_size((120, 24)).columns


def _split_names(value: str | None) -> list[str] | None:
    if value is None:
        return None
    names = [v.strip() for v in value.split(",") if v.strip()]
    return names


def _parse_locked(values: tuple[str, ...]) -> dict[str, float]:
    out = {}
    for item in values:
        name, sep, val = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(val)
        except ValueError:
            raise click.BadParameter(f"expected JOINT=POSITION, got {item!r}", param_hint="--lock") from None
    return out


robot_argument = click.argument("robot", metavar="ROBOT")
unknown_links_option = click.option(
    "--unknown-links",
    metavar="LINK,LINK",
    default=None,
    help="Comma-separated links to identify (default: the built-in's choice, or all moving links).",
)
lock_option = click.option(
    "--lock", "locked", multiple=True, metavar="JOINT=POS", help="Treat a URDF joint as fixed at POS (repeatable)."
)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="ineid")
@click.option("-v", "--verbose", count=True, help="More output.")
@click.option("-q", "--quiet", is_flag=True, help="Less output.")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Identify a robot arm's inertial parameters from its base force/torque sensor.

    ROBOT is a built-in name (sweaty-arm) or a path to a serial-chain URDF file.
    """
    ctx.obj = {"verbosity": -1 if quiet else verbose}


@main.group(cls=_Group)
def robot() -> None:
    """Inspect robot models."""


@robot.command("list")
def robot_list() -> None:
    """List the built-in robots."""
    from ineid.robots import BUILTIN_ROBOTS  # noqa: PLC0415

    for name, spec in BUILTIN_ROBOTS.items():
        click.echo(f"{name}\t{spec.description}")


@robot.command("show")
@robot_argument
@unknown_links_option
@lock_option
@click.option("--gravity", nargs=3, type=float, default=None, metavar="GX GY GZ", help="m/s^2, base frame.")
def robot_show(robot: str, unknown_links: str | None, locked: tuple[str, ...], gravity) -> None:
    """Joints, links (known/unknown) and CAD parameters of ROBOT."""
    from rich.table import Table  # noqa: PLC0415

    from ineid.params import PARAM_NAMES, inertial_from_theta  # noqa: PLC0415

    model = _load_model(robot, unknown_links, locked, gravity)
    con = _console()
    con.print(f"[bold]{model.name}[/bold]  {model.urdf_path}")
    con.print(
        f"{model.n_dof} moving joints, base link {model.chain.root_link!r}, gravity {model.gravity.tolist()} m/s^2, "
        f"regressor 6 x {10 * model.n_links} ({model.op_count} operations)"
    )
    joints = Table(title="Joints (chain order)", title_justify="left")
    for col in ("#", "joint", "type", "axis", "q range", "|qd| max", "|qdd| max"):
        joints.add_column(col, justify="right" if col in ("#", "|qd| max", "|qdd| max") else "left")
    for i, j in enumerate(model.chain.joints):
        kind = "continuous" if j.continuous else j.type
        axis = " ".join(f"{v:g}" for v in j.axis)
        joints.add_row(str(i + 1), j.name, kind, axis, f"[{j.q_lower:g}, {j.q_upper:g}]", f"{j.qd_max:g}", f"{j.qdd_max:g}")
    con.print(joints)
    links = Table(title="Links", title_justify="left")
    for col in ("link", "role", "welded in", "mass kg", "com m (link frame)"):
        links.add_column(col)
    masses, coms, _ = inertial_from_theta(model.theta_cad.reshape(-1, 10))
    for i, name in enumerate(model.link_names):
        role = "unknown" if name in model.unknown_links else "known"
        welded = ", ".join(model.chain.merged_links.get(name, (name,))[1:]) or "-"
        com = " ".join(f"{v:.4f}" for v in coms[i])
        links.add_row(name, role, welded, f"{masses[i]:.4f}", com)
    con.print(links)
    params = Table(title="CAD parameters, about each link origin, link frame (SI)", title_justify="left")
    params.add_column("link")
    for p in PARAM_NAMES:
        params.add_column(p, justify="right")
    for i, name in enumerate(model.link_names):
        params.add_row(name, *(f"{v:.5g}" for v in model.theta_cad[10 * i : 10 * i + 10]))
    con.print(params)


@main.command()
@click.argument("robot", metavar="ROBOT", required=False)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the generated modules (default: ineid/generated for a built-in, else the cache).")
@click.option("--builtin", "all_builtin", is_flag=True, help="Regenerate every built-in robot in ineid/generated.")
@lock_option
@click.option("--overwrite", is_flag=True, help="Replace files in --out that ineid did not generate.")
def generate(robot: str | None, out_dir: Path | None, all_builtin: bool, locked: tuple[str, ...], overwrite: bool) -> None:
    """Derive ROBOT's base-wrench regressor and emit its CasADi and JAX modules."""
    from ineid.generated import BUILTIN_DIR  # noqa: PLC0415
    from ineid.robots import BUILTIN_ROBOTS, load_chain  # noqa: PLC0415
    from ineid.cache import cache_dir  # noqa: PLC0415
    from ineid.codegen import generate_code  # noqa: PLC0415
    from ineid.symbolic.emit import GENERATOR  # noqa: PLC0415

    if all_builtin == (robot is not None):
        raise click.UsageError("give either ROBOT or --builtin")
    jobs = []
    if all_builtin:
        if out_dir is not None:
            raise click.UsageError("--builtin writes into ineid/generated; drop --out")
        jobs = [(BUILTIN_ROBOTS[n].urdf_path, n, BUILTIN_DIR, "make generate") for n in BUILTIN_ROBOTS]
    elif robot in BUILTIN_ROBOTS and not Path(robot).is_file():
        if locked:
            raise click.UsageError("--lock applies to URDF files, not built-in robots")
        target = out_dir or BUILTIN_DIR
        jobs = [(BUILTIN_ROBOTS[robot].urdf_path, robot, target, "make generate")]
    else:
        path = Path(robot)
        if not path.is_file():
            raise click.BadParameter(
                f"{robot!r} is neither a built-in robot ({', '.join(BUILTIN_ROBOTS)}) nor an existing URDF file",
                param_hint="ROBOT",
            )
        chain = load_chain(path, locked_joints=_parse_locked(locked) or None)
        target = out_dir or cache_dir() / "generated" / chain.kinematic_fingerprint()
        jobs = [(path, chain.name, target, f"ineid generate {robot}")]
    import time  # noqa: PLC0415

    from ineid.generated import file_names  # noqa: PLC0415

    for urdf, name, target, regen in jobs:
        for fname in file_names(name):
            existing = Path(target) / fname
            if existing.exists() and not overwrite and f"Generated by {GENERATOR}" not in existing.read_text()[:400]:
                raise click.ClickException(f"{existing} exists and was not generated by ineid; pass --overwrite")
        t0 = time.perf_counter()
        chain = load_chain(urdf, locked_joints=_parse_locked(locked) or None)
        emitted = generate_code(chain, name, target, regen)
        seconds = time.perf_counter() - t0
        click.echo(
            f"{name}: {chain.n_dof} DOF, regressor 6 x {10 * chain.n_dof}, {emitted.op_count} operations "
            f"after CSE ({emitted.n_temporaries} temporaries), {seconds:.2f} s"
        )
        for fname in sorted(emitted.files):
            click.echo(f"  wrote {Path(target) / fname}")


# -- shared pieces for commands that take a robot and write a file -----------------------

gravity_option = click.option(
    "--gravity", nargs=3, type=float, default=None, metavar="GX GY GZ", help="m/s^2, base frame (default 0 0 -9.81)."
)
overwrite_option = click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")


def _load_model(robot: str, unknown_links: str | None, locked: tuple[str, ...], gravity):
    import ineid  # noqa: PLC0415

    kwargs = {"unknown_links": _split_names(unknown_links), "locked_joints": _parse_locked(locked) or None}
    if gravity is not None:
        kwargs["gravity"] = gravity
    return ineid.load_robot(robot, **kwargs)


def _check_out(out: Path, overwrite: bool) -> None:
    if out.is_dir():
        raise click.ClickException(f"{out} is a folder; give a file name such as data.h5")
    if out.exists() and not overwrite:
        raise click.ClickException(f"{out} exists; pass --overwrite to replace it")
    if not out.parent.is_dir():
        raise click.ClickException(f"folder {out.parent} does not exist; create it first")


class _ProgressBar:
    """A rich progress bar driven by ``callback(done, total)``; silent with ``-q``."""

    def __init__(self, description: str, unit: str, quiet: bool) -> None:
        from rich.progress import (  # noqa: PLC0415
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(unit),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            disable=quiet,
            console=_console_err(),
        )
        self._task = None
        self._description = description

    def __enter__(self):
        self._progress.__enter__()
        return self

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)

    def __call__(self, done: int, total: int) -> None:
        if self._task is None:
            self._task = self._progress.add_task(self._description, total=total)
        self._progress.update(self._task, completed=done, total=total)


def _console_err():
    from rich.console import Console  # noqa: PLC0415

    return Console(stderr=True, highlight=False)


def _quiet(ctx: click.Context) -> bool:
    return bool(ctx.obj and ctx.obj.get("verbosity", 0) < 0)


_NOISE_KEYS = ("force", "moment", "fx", "fy", "fz", "mx", "my", "mz", "q", "qd", "qdd")


def _parse_noise(value: str | None, n_dof: int):
    """``force=0.5,moment=0.02,qd=0.01`` -> :class:`ineid.data.NoiseModel` (or None)."""
    if not value:
        return None
    from ineid.data import NoiseModel  # noqa: PLC0415

    std = {k: 0.0 for k in _NOISE_KEYS}
    given = set()
    for item in value.split(","):
        key, sep, val = item.strip().partition("=")
        key = key.strip().lower()
        try:
            if not sep or key not in std:
                raise ValueError
            std[key] = float(val)
            if not (std[key] >= 0 and std[key] < float("inf")):
                raise ValueError
        except ValueError:
            raise click.BadParameter(
                f"expected KEY=STD with KEY in {', '.join(_NOISE_KEYS)} and STD >= 0, got {item.strip()!r}",
                param_hint="--noise",
            ) from None
        given.add(key)
    force = [std[a] if a in given else std["force"] for a in ("fx", "fy", "fz")]
    moment = [std[a] if a in given else std["moment"] for a in ("mx", "my", "mz")]
    return NoiseModel.create(n_dof, force=force, moment=moment, q=std["q"], qd=std["qd"], qdd=std["qdd"])


# -- ineid data ---------------------------------------------------------------------------


@main.group(cls=_Group)
def data() -> None:
    """Make, import and inspect datasets (HDF5; see docs/dataset.md)."""


@data.command("generate")
@click.option("--robot", default="sweaty-arm", show_default=True, metavar="ROBOT", help="Built-in name or URDF path.")
@unknown_links_option
@lock_option
@gravity_option
@click.option("--factorial", type=click.IntRange(min=1), default=None, metavar="N",
              help="N parameter sets per unknown link, all combinations (N^k configurations). Default 100.")
@click.option("--configs", type=click.IntRange(min=1), default=None, metavar="N",
              help="N configurations pairing the links' sets at random (instead of --factorial).")
@click.option("--pool", type=click.IntRange(min=1), default=None, metavar="N",
              help="With --configs: draw each link's set from a pool of N (default: a fresh set per configuration).")
@click.option("--frames", type=click.IntRange(min=1), default=100, show_default=True, help="Frames per configuration.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seed of every random draw.")
@click.option("--frame-mode", type=click.Choice(["uniform", "fourier"]), default="uniform", show_default=True,
              help="Independent uniform frames (the paper) or samples of Fourier excitation trajectories.")
@click.option("--harmonics", type=click.IntRange(min=1), default=5, show_default=True, help="Fourier harmonics per joint.")
@click.option("--base-frequency", type=click.FloatRange(min=0, min_open=True), default=0.1, show_default=True,
              help="Fourier base frequency, Hz; one period is sampled.")
@click.option("--mass-band", type=click.FloatRange(0, 1, max_open=True), default=0.2, show_default=True,
              help="Mass within CAD * (1 +- band).")
@click.option("--com-box", type=click.FloatRange(min=0), default=0.02, show_default=True,
              help="Centre of mass within CAD +- box per axis, m.")
@click.option("--inertia-band", type=click.FloatRange(0, 1, max_open=True), default=0.3, show_default=True,
              help="Second moments within CAD * (1 +- band), scaled with the mass.")
@click.option("--rotation", type=click.FloatRange(min=0), default=30.0, show_default=True,
              help="Largest turn of the principal axes from CAD, degrees (180: uniform).")
@click.option("--noise", default=None, metavar="KEY=STD,...",
              help="Gaussian noise std: force, moment (or fx..mz) in N, N*m; q, qd, qdd in rad, rad/s, rad/s^2.")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .h5 file to write.")
@overwrite_option
@click.pass_context
def data_generate(ctx, robot, unknown_links, locked, gravity, factorial, configs, pool, frames, seed, frame_mode,
                  harmonics, base_frequency, mass_band, com_box, inertia_band, rotation, noise, out, overwrite) -> None:
    """Sample a synthetic ground-truth dataset (the paper's: --factorial 100 --frames 100)."""
    import time  # noqa: PLC0415

    from ineid.data import Combination, DatasetSpec, FrameSampling, ParameterSampling, write_dataset  # noqa: PLC0415

    if factorial is not None and configs is not None:
        raise click.UsageError("give --factorial N or --configs N, not both")
    if pool is not None and configs is None:
        raise click.UsageError("--pool applies to --configs (random pairing)")
    _check_out(out, overwrite)
    model = _load_model(robot, unknown_links, locked, gravity)
    if configs is not None:
        combination = Combination("random", per_link=pool, n_configs=configs)
    else:
        combination = Combination("factorial", per_link=factorial or 100)
    n_configs = combination.count(len(model.unknown_links))
    if configs is None and n_configs > 10**8:
        raise click.BadParameter(
            f"{n_configs:,} configurations ({combination.per_link}^{len(model.unknown_links)}); "
            "use --configs for a random subset",
            param_hint="--factorial",
        )
    spec = DatasetSpec(
        combination=combination,
        n_frames=frames,
        seed=seed,
        parameters=ParameterSampling(mass_band, com_box, inertia_band, rotation),
        frames=FrameSampling(frame_mode, harmonics, base_frequency),
        noise=_parse_noise(noise, model.n_dof),
    )
    t0 = time.perf_counter()
    with _ProgressBar("generating", "configurations", _quiet(ctx)) as bar:
        write_dataset(model, spec, out, overwrite=overwrite, progress=bar)
    seconds = time.perf_counter() - t0
    n = n_configs * frames
    click.echo(
        f"wrote {out}: {n_configs:,} configurations x {frames} frames of {model.name} "
        f"({', '.join(model.unknown_links)} unknown) in {seconds:.1f} s ({n / seconds:,.0f} frames/s)"
    )


@data.command("import")
@click.argument("csv_file", metavar="CSV", type=click.Path(path_type=Path))
@click.option("--robot", default="sweaty-arm", show_default=True, metavar="ROBOT", help="Built-in name or URDF path.")
@unknown_links_option
@lock_option
@gravity_option
@click.option("--flip-wrench", is_flag=True,
              help="The sensor reports the wrench on the robot (the opposite of ineid's convention); negate it.")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .h5 file to write.")
@overwrite_option
def data_import(csv_file, robot, unknown_links, locked, gravity, flip_wrench, out, overwrite) -> None:
    """Import a recording from a real arm (columns: time, q1..qn, qd1..qn, qdd1..qn, fx fy fz mx my mz)."""
    from ineid.data import read_recording_csv  # noqa: PLC0415

    _check_out(out, overwrite)
    model = _load_model(robot, unknown_links, locked, gravity)
    ds = read_recording_csv(csv_file, model, flip_wrench=flip_wrench)
    ds.save(out, overwrite=overwrite)
    span = float(ds.time[0, -1] - ds.time[0, 0])
    click.echo(f"wrote {out}: one recording of {model.name}, {ds.n_frames:,} frames over {span:.3f} s")


@data.command("info")
@click.argument("path", metavar="FILE", type=click.Path(path_type=Path))
def data_info(path: Path) -> None:
    """Summarize a dataset: sizes, robot, settings, parameter and wrench ranges."""
    import json  # noqa: PLC0415

    import numpy as np  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from ineid.data import iter_dataset, read_meta  # noqa: PLC0415
    from ineid.params import param_names  # noqa: PLC0415

    meta, shapes = read_meta(path)
    n_configs, n_frames, n_dof = shapes["q"]
    con = _console()
    con.print(f"[bold]{path}[/bold]  ineid dataset v{meta.version} ({meta.source}), written by ineid {meta.ineid_version}")
    con.print(
        f"{n_configs:,} configuration{'s' if n_configs != 1 else ''} x {n_frames:,} frames = {n_configs * n_frames:,} "
        f"frames; robot {meta.robot}, {n_dof} joints ({', '.join(meta.joint_names)})"
    )
    con.print(f"unknown links: {', '.join(meta.unknown_links)}; known links: {', '.join(meta.known_links) or '-'}")
    con.print(f"gravity {np.asarray(meta.gravity).tolist()} m/s^2" + (f"; seed {meta.seed}" if meta.seed is not None else ""))
    if meta.locked_joints:
        con.print(f"locked joints: {meta.locked_joints}")
    if meta.sampling:
        con.print(f"sampling: {json.dumps(meta.sampling, sort_keys=True)}")
    con.print(f"noise (std): {json.dumps(meta.noise) if meta.noise else 'none (clean data)'}")
    if meta.origin:
        con.print(f"origin: {json.dumps(meta.origin, sort_keys=True)}")
    arrays = Table(title="Arrays", title_justify="left")
    for col in ("name", "shape"):
        arrays.add_column(col)
    for name in sorted(shapes):
        arrays.add_row(name, " x ".join(str(s) for s in shapes[name]) or "scalar")
    con.print(arrays)

    def ranges(name, width):
        lo, hi = np.full(width, np.inf), np.full(width, -np.inf)
        total, count = np.zeros(width), 0
        for _, block in iter_dataset(path, name):
            flat = block.reshape(-1, width)
            lo, hi = np.minimum(lo, flat.min(0)), np.maximum(hi, flat.max(0))
            total += flat.sum(0)
            count += len(flat)
        return lo, hi, total / max(count, 1)

    if "theta_unknown" in shapes:
        from ineid.robots.urdf import parse_chain  # noqa: PLC0415

        chain = parse_chain(meta.urdf, source=f"{path} (its URDF)", locked_joints=meta.locked_joints or None)
        cad = {j.link: j.theta for j in chain.joints}
        names = param_names(meta.unknown_links)
        lo, hi, mean = ranges("theta_unknown", len(names))
        table = Table(title="Unknown parameters over the configurations (SI, about each link origin)",
                      title_justify="left")
        for col in ("parameter", "CAD", "min", "mean", "max"):
            table.add_column(col, justify="left" if col == "parameter" else "right")
        for k, name in enumerate(names):
            link, _, p = name.rpartition(".")
            table.add_row(name, f"{cad[link][k % 10]:.5g}", f"{lo[k]:.5g}", f"{mean[k]:.5g}", f"{hi[k]:.5g}")
        con.print(table)
    lo, hi, mean = ranges("wrench", 6)
    table = Table(title="Wrench (N, N*m; base frame, about the base origin)", title_justify="left")
    for col in ("axis", "min", "mean", "max"):
        table.add_column(col, justify="left" if col == "axis" else "right")
    for k, axis in enumerate(("fx", "fy", "fz", "mx", "my", "mz")):
        table.add_row(axis, f"{lo[k]:.4g}", f"{mean[k]:.4g}", f"{hi[k]:.4g}")
    con.print(table)


# -- identification ------------------------------------------------------------------------


def _parse_selection(text: str | None, n: int):
    """``all``, ``A:B[:STEP]``, ``1,5,9`` or mixtures (``0:10,50``) -> sorted unique indices."""
    import numpy as np  # noqa: PLC0415

    if text is None or text.strip().lower() == "all":
        return np.arange(n)
    picked: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            if ":" in part:
                bits = [int(b) if b.strip() else None for b in part.split(":")]
                if len(bits) > 3:
                    raise ValueError
                picked += list(range(n))[slice(*bits)]
            else:
                k = int(part)
                if not -n <= k < n:
                    raise click.BadParameter(f"configuration {k} is out of range (the file has {n}: 0..{n - 1})",
                                             param_hint="--configs")
                picked.append(k % n)
        except ValueError:
            raise click.BadParameter(
                f"expected 'all', A:B[:STEP] or comma-separated indices, got {part!r}", param_hint="--configs"
            ) from None
    idx = np.unique(np.asarray(picked, dtype=np.int64))
    if idx.size == 0:
        raise click.BadParameter(f"{text!r} selects no configuration of the {n} in the file", param_hint="--configs")
    return idx


@main.command()
@robot_argument
@unknown_links_option
@lock_option
@gravity_option
@click.option("--frames", "n_frames", type=click.IntRange(min=1), default=200, show_default=True,
              help="Random frames (uniform within the bounds) to analyse.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--data", "data_path", type=click.Path(path_type=Path), default=None,
              help="Analyse the frames of a dataset instead (with --config).")
@click.option("--config", type=click.IntRange(min=0), default=0, show_default=True, help="Configuration of --data.")
def identifiability(robot, unknown_links, locked, gravity, n_frames, seed, data_path, config) -> None:
    """Which parameters of ROBOT's unknown links the base wrench determines."""
    import numpy as np  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from ineid.identify import analyze_frames, base_parameters, generic_frames  # noqa: PLC0415

    model = _load_model(robot, unknown_links, locked, gravity)
    base = base_parameters(model)
    if data_path is not None:
        from ineid.data import load_dataset  # noqa: PLC0415

        ds = load_dataset(data_path, configs=[config])
        if ds.meta.joint_names != model.joint_names:
            raise click.ClickException(f"{data_path} is a dataset of {ds.meta.robot}, not of {model.name}")
        q, qd, qdd = ds.q[0], ds.qd[0], ds.qdd[0]
        source = f"{len(q)} frames of configuration {config} of {data_path}"
    else:
        q, qd, qdd = generic_frames(model, n_frames, seed)
        source = f"{n_frames} random frames within the bounds (seed {seed})"
    a = analyze_frames(model, q, qd, qdd, base)
    con = _console()
    n = base.n_params
    con.print(f"[bold]{model.name}[/bold]: unknown links {', '.join(model.unknown_links)} ({n} standard parameters)")
    con.print(f"frames: {source}")
    con.print(
        f"rank {a.rank} of {n}; structural rank {base.rank} (no frames can do better): "
        f"[bold]{base.rank} identifiable combinations[/bold], {n - base.rank} null direction(s)"
    )
    cond = "inf" if not np.isfinite(a.condition_number) else f"{a.condition_number:.4g}"
    con.print(f"condition number (scaled, identifiable part): {cond}; fewest leading frames reaching rank "
              f"{base.rank}: {a.min_frames if a.min_frames is not None else 'never'} "
              f"(at least {-(-base.rank // 6)}: 6 equations per frame)")
    con.print("singular values (scaled): " + " ".join(f"{v:.3g}" for v in a.singular_values))
    if a.problem():
        con.print(f"[bold red]these frames are not enough:[/bold red] {a.problem()}")
    table = Table(title="Base parameters: what the data determine (beta = B theta)", title_justify="left")
    table.add_column("#", justify="right")
    table.add_column("base parameter")
    for k, name in enumerate(base.names):
        table.add_row(str(k + 1), name)
    con.print(table)
    if base.null_basis.shape[1]:
        table = Table(title="Null directions: parameter changes invisible in the base wrench", title_justify="left")
        table.add_column("#", justify="right")
        table.add_column("direction (add t times)")
        for k, text in enumerate(base.null_directions()):
            table.add_row(str(k + 1), text)
        con.print(table)
    ident = [p for p, ok in zip(base.param_names, base.identifiable) if ok]
    other = [p for p, ok in zip(base.param_names, base.identifiable) if not ok]
    con.print(f"individually identifiable ({len(ident)}): {', '.join(ident) or '-'}")
    con.print(f"only in combinations ({len(other)}): {', '.join(other) or '-'}")
    if base.null_basis.shape[1]:
        con.print(
            "The null directions are structural: mass on a joint axis between two unknown links does not feel "
            "that joint turn, so it acts on the base as if welded to the earlier link. Estimates of the other "
            "parameters need prior knowledge (ineid uses the CAD values) or constraints."
        )


@main.command()
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(["linear", "nonlinear", "consistent"]), default="linear", show_default=True)
@click.option("--frames", type=click.IntRange(min=1), default=None,
              help="Frames fitted per configuration (the first K; the rest validate). Default: 80 %.")
@click.option("--configs", "selection", default=None, metavar="SEL",
              help="Configurations: all (default), A:B[:STEP], or 1,5,9.")
@click.option("--weights", type=click.Choice(["none", "noise", "estimate"]), default="none", show_default=True,
              help="Row weights per wrench axis: none, from the noise levels (--sigma or the file), or estimated.")
@click.option("--sigma", nargs=6, type=float, default=None, metavar="FX FY FZ MX MY MZ",
              help="Wrench noise std per axis (N, N*m) for --weights noise.")
@click.option("--start", type=click.Choice(["prior", "linear"]), default="prior", show_default=True,
              help="IPOPT start: the CAD values, or the linear estimate (made physical).")
@click.option("--backend", type=click.Choice(["jax", "casadi"]), default="jax", show_default=True,
              help="Linear method: batched JAX/NumPy, or CasADi per configuration.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Processes for IPOPT (default: CPU count; fewer than 256 configurations run in one).")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Results file (.h5).")
@overwrite_option
@click.pass_context
def solve(ctx, data_path, method, frames, selection, weights, sigma, start, backend, workers, out, overwrite) -> None:
    """Identify the unknown links of every selected configuration of DATA.h5."""
    import os  # noqa: PLC0415

    from ineid.data import load_dataset, read_meta  # noqa: PLC0415
    from ineid.identify import SolveSettings, save_results, solve_dataset  # noqa: PLC0415

    _check_out(out, overwrite)
    if backend == "casadi" and method != "linear":
        raise click.UsageError("--backend casadi applies to --method linear")
    if sigma is not None and weights != "noise":
        raise click.UsageError("--sigma goes with --weights noise")
    _, shapes = read_meta(data_path)
    idx = _parse_selection(selection, shapes["q"][0])
    ds = load_dataset(data_path, configs=idx)
    settings = SolveSettings(
        method=method, frames=frames, weights=weights, axis_sigma=tuple(sigma) if sigma else None, start=start,
        backend=backend, workers=workers or os.cpu_count() or 1,
    )  # fmt: skip
    with _ProgressBar(f"solving ({method})", "configurations", _quiet(ctx)) as bar:
        res = solve_dataset(ds, settings, progress=bar)
    save_results(res, out, overwrite=overwrite)
    _print_results(res, out)


def _print_results(res, out) -> None:
    import numpy as np  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from ineid.identify import error_summary  # noqa: PLC0415

    con = _console()
    n_ok = int(res.success.sum())
    total = res.meta.get("total_seconds", float("nan"))
    con.print(
        f"[bold]{res.settings.method}[/bold] on {res.meta['robot']}: {n_ok}/{res.n} configurations identified "
        f"in {total:.2f} s ({1e3 * total / max(res.n, 1):.2f} ms each); fitted {res.n_frames_fit} frames each"
        + (f", validated on {res.n_frames_validation}" if res.n_frames_validation else "")
    )
    if n_ok < res.n:
        statuses, counts = np.unique(res.status[~res.success].astype(str), return_counts=True)
        con.print("failed: " + "; ".join(f"{c} x {s}" for s, c in zip(statuses, counts)))
    if res.n_frames_validation and n_ok:
        rel = res.validation_rel[res.success]
        con.print(f"held-out wrench error ||w - Psi theta_hat|| / ||w||: median {np.median(rel):.3g}, "
                  f"95th percentile {np.percentile(rel, 95):.3g}")
    if res.theta_true is not None and n_ok:
        for title, est, truth, names, ident in (
            ("standard parameters", res.theta_hat, res.theta_true, res.param_names, res.base.identifiable),
            ("base parameters (what the data determine)", res.base_hat, res.base_true, res.base.names, None),
        ):
            table = Table(title=f"Relative error, {title}, over {n_ok} configurations", title_justify="left")
            for col in ("parameter", "median", "95th pct", "within 1%", "within 5%") + (("identifiable",) if ident is not None else ()):
                table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
            for row in error_summary(est, truth, names, res.success, ident):
                cells = [row.name, f"{row.median:.3g}", f"{row.p95:.3g}", f"{100 * row.within_1:.1f}%",
                         f"{100 * row.within_5:.1f}%"]
                if ident is not None:
                    cells.append("yes" if row.identifiable else "no (prior)")
                table.add_row(*cells)
            con.print(table)
        from ineid.params import all_links_physical  # noqa: PLC0415

        valid = all_links_physical(np.nan_to_num(res.theta_hat[res.success]))
        con.print(f"physically valid estimates: {100 * valid.mean():.1f}%")
    elif n_ok:
        i = int(np.flatnonzero(res.success)[0])
        table = Table(title=f"Estimates of configuration {int(res.config_index[i])} (SI, about each link origin)",
                      title_justify="left")
        for col in ("parameter", "estimate", "std", "prior (CAD)", "identifiable"):
            table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
        for k, name in enumerate(res.param_names):
            std = res.theta_std[i, k]
            table.add_row(name, f"{res.theta_hat[i, k]:.6g}", "-" if not np.isfinite(std) else f"{std:.3g}",
                          f"{res.theta_prior[k]:.6g}", "yes" if res.base.identifiable[k] else "no (prior)")
        con.print(table)
        table = Table(title="Base parameters", title_justify="left")
        for col in ("base parameter", "estimate", "std"):
            table.add_column(col, justify="left" if col == "base parameter" else "right")
        for k, name in enumerate(res.base.names):
            table.add_row(name, f"{res.base_hat[i, k]:.6g}", f"{res.base_std[i, k]:.3g}")
        con.print(table)
    con.print(f"wrote {out}")


@main.command("export-urdf")
@click.argument("results_path", metavar="RESULTS", type=click.Path(path_type=Path))
@click.option("--config", type=int, required=True, help="Configuration (index in the dataset).")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The .urdf file to write.")
@overwrite_option
def export_urdf_cmd(results_path, config, out, overwrite) -> None:
    """Write the model's URDF with the identified links' inertials of one configuration."""
    from ineid.identify import export_urdf, load_results  # noqa: PLC0415

    _check_out(out, overwrite)
    res = load_results(results_path)
    export_urdf(res, config, out, overwrite=overwrite)
    click.echo(f"wrote {out}: {', '.join(res.meta['unknown_links'])} of configuration {config} ({res.settings.method})")


@main.group(cls=_Group)
def study() -> None:
    """Studies that sweep settings and write a table and a plot."""


@study.command("noise")
@click.option("--robot", default="sweaty-arm", show_default=True, metavar="ROBOT")
@unknown_links_option
@click.option("--levels", default="0,0.5,1,2,4", show_default=True,
              help="Noise levels, multiples of force 0.5 N, moment 0.05 N*m, qd 0.01 rad/s, qdd 0.1 rad/s^2.")
@click.option("--frames", "frames_text", default="10,50,200", show_default=True, help="Frame counts per configuration.")
@click.option("--configs", type=click.IntRange(min=1), default=200, show_default=True, help="Configurations per level.")
@click.option("--methods", default="linear,weighted,consistent", show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Processes for IPOPT (default: CPU count).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for noise_study.csv and noise_study.png.")
@overwrite_option
@click.pass_context
def study_noise(ctx, robot, unknown_links, levels, frames_text, configs, methods, seed, workers, out_dir, overwrite):
    """Errors and physical validity of linear, weighted and consistent estimates under noise."""
    import os  # noqa: PLC0415

    from rich.table import Table  # noqa: PLC0415

    from ineid.identify.study import STUDY_METHODS, noise_study, plot, write_rows  # noqa: PLC0415

    def numbers(text, cast, hint):
        try:
            vals = [cast(v) for v in text.split(",") if v.strip()]
            if not vals or any(v < 0 for v in vals) or (cast is int and any(v < 1 for v in vals)):
                raise ValueError
            return vals
        except ValueError:
            raise click.BadParameter(f"expected comma-separated non-negative numbers, got {text!r}", param_hint=hint) from None

    lv = numbers(levels, float, "--levels")
    fr = numbers(frames_text, int, "--frames")
    ms = [m.strip() for m in methods.split(",") if m.strip()]
    bad = [m for m in ms if m not in STUDY_METHODS]
    if bad or not ms:
        raise click.BadParameter(f"methods are {', '.join(STUDY_METHODS)}, got {methods!r}", param_hint="--methods")
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, png_path = out_dir / "noise_study.csv", out_dir / "noise_study.png"
    for p in (csv_path, png_path):
        if p.exists() and not overwrite:
            raise click.ClickException(f"{p} exists; pass --overwrite to replace it")
    model = _load_model(robot, unknown_links, (), None)
    with _ProgressBar("noise study", "solves", _quiet(ctx)) as bar:
        rows = noise_study(model, lv, fr, configs, seed, ms, workers or os.cpu_count() or 1, progress=bar)
    table = Table(title=f"Noise study, {model.name}, {configs} configurations per level", title_justify="left")
    for col in ("level", "frames", "method", "base err (median)", "base err (p95)", "standard err (median)",
                "identifiable std. err", "invalid", "failed", "s"):
        table.add_column(col, justify="left" if col == "method" else "right")
    for r in rows:
        table.add_row(f"{r.level:g}", str(r.frames), r.method, f"{r.base_error_median:.3g}", f"{r.base_error_p95:.3g}",
                      f"{r.standard_error_median:.3g}", f"{r.identifiable_error_median:.3g}",
                      f"{100 * r.invalid_share:.1f}%", f"{100 * r.failed_share:.1f}%", f"{r.seconds:.1f}")
    _console().print(table)
    write_rows(rows, csv_path)
    plot(rows, png_path)
    click.echo(f"wrote {csv_path} and {png_path}")


# -- learning -------------------------------------------------------------------------------


def _train_options(f):
    """Options shared by `ineid train` and `ineid sweep` (the settings of one run)."""
    opts = [
        click.option("--depth", type=click.IntRange(min=1), default=None, help="Hidden layers of --arch mlp."),
        click.option("--width", type=click.IntRange(min=1), default=None, help="Neurons per layer of --arch mlp."),
        click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=1e-3, show_default=True),
        click.option("--schedule", type=click.Choice(["constant", "cosine"]), default="constant", show_default=True),
        click.option("--epochs", type=click.IntRange(min=1), default=100, show_default=True),
        click.option("--batch", type=click.IntRange(min=1), default=256, show_default=True, help="Samples per step."),
        click.option("--alpha", type=click.FloatRange(min=0), default=1.0, show_default=True, help="Weight of the MSE."),
        click.option("--beta", type=click.FloatRange(min=0), default=1.0, show_default=True,
                     help="Weight of the wrench residual (physics loss)."),
        click.option("--patience", type=click.IntRange(min=0), default=20, show_default=True,
                     help="Early stopping: epochs without a better validation MSE (0: off)."),
        click.option("--train-configs", type=click.IntRange(min=1), default=None, help="Training configurations (70 %)."),
        click.option("--val-configs", type=click.IntRange(min=1), default=None, help="Validation configurations (15 %)."),
        click.option("--test-configs", type=click.IntRange(min=1), default=None, help="Test configurations (the rest)."),
        click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True),
        click.option("--physics-mode", type=click.Choice(["cached", "inline"]), default="cached", show_default=True,
                     help="Regressor of the physics loss: computed once per frame, or inside the loss."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def _base_train_config(kw: dict):
    from ineid.learn import ModelSpec, TrainConfig  # noqa: PLC0415

    try:
        model = ModelSpec(arch=kw.get("arch", "simple"), activation=kw.get("activation", "tanh"), depth=kw["depth"],
                          width=kw["width"], siamese=kw.get("siamese", False), frames=kw.get("frames", 1))
        return TrainConfig(
            model=model, scaler=kw.get("scaler", "standard"), loss=kw.get("loss", "mse"), alpha=kw["alpha"],
            beta=kw["beta"], optimizer=kw.get("optimizer", "adam"), lr=kw["lr"], schedule=kw["schedule"],
            epochs=kw["epochs"], batch=kw["batch"], patience=kw["patience"], seed=kw["seed"],
            n_train=kw["train_configs"], n_val=kw["val_configs"], n_test=kw["test_configs"],
        )
    except ValueError as e:
        raise click.UsageError(str(e)) from None


@main.command("train")
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option("--arch", type=click.Choice(["simple", "net1", "net2", "net3", "net4", "net5", "net6", "net7", "funnel",
                                           "mlp"]), default="simple", show_default=True, help="Table 1 of the paper, or mlp.")
@click.option("--activation", type=click.Choice(["tanh", "relu", "gelu", "sigmoid", "elu", "silu"]), default="tanh",
              show_default=True)
@click.option("--scaler", type=click.Choice(["standard", "robust", "minmax"]), default="standard", show_default=True)
@click.option("--optimizer", type=click.Choice(["sgd", "adam", "adamw"]), default="adam", show_default=True)
@click.option("--frames", type=click.IntRange(min=1), default=1, show_default=True, help="Frames per sample (K).")
@click.option("--siamese", is_flag=True, help="One shared encoder per frame, embeddings averaged, then a head.")
@click.option("--loss", type=click.Choice(["mse", "physics"]), default="mse", show_default=True)
@_train_options
@click.option("--out", "run_dir", type=click.Path(file_okay=False, path_type=Path), required=True, help="Run folder.")
@click.option("--resume", is_flag=True, help="Continue the run in --out from its checkpoint (same settings).")
@overwrite_option
@click.pass_context
def train_cmd(ctx, data_path, run_dir, resume, overwrite, physics_mode, **kw) -> None:
    """Train a network on DATA.h5 into a run folder, then evaluate it on the test split."""
    import json  # noqa: PLC0415

    from ineid.data import load_dataset  # noqa: PLC0415
    from ineid.learn import evaluate, load_run, train  # noqa: PLC0415

    cfg = _base_train_config(kw)
    ds = load_dataset(data_path)
    model = ds.model()
    quiet = _quiet(ctx)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn  # noqa: PLC0415

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("epochs"),
                  TimeElapsedColumn(), disable=quiet, console=_console_err()) as prog:
        task = prog.add_task(f"training {cfg.model.name}", total=cfg.epochs)

        def progress(epoch, total, rec):
            prog.update(task, completed=epoch, description=(
                f"training {cfg.model.name}  loss {rec['train_loss']:.4f}  val mse {rec['val_mse']:.4f}"
                f"  val phys {rec['val_phys']:.4f}"))

        try:
            result = train(ds, cfg, run_dir, dataset_path=str(data_path), resume=resume, overwrite=overwrite,
                           progress=progress, model=model, physics_mode=physics_mode)
        except KeyboardInterrupt:
            raise click.ClickException(
                f"interrupted; {run_dir} keeps the last finished epoch: continue with the same command and --resume"
            ) from None
    click.echo(
        f"{result.epochs_run} epochs in {result.seconds:.1f} s"
        + (" (stopped early)" if result.stopped_early else "")
        + f"; best validation MSE {result.best_val_mse:.4g} at epoch {result.best_epoch}; wrote {run_dir}"
    )
    ev = evaluate(load_run(run_dir), ds, model=model)
    (run_dir / "evaluation.json").write_text(json.dumps(ev.to_dict(), indent=1))
    _print_evaluation(ev)


def _print_evaluation(ev) -> None:
    import numpy as np  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    con = _console()
    con.print(f"evaluated on {ev.n_configs} configurations ({ev.extra.get('configs')}), {ev.frames_used} frames each")
    table = Table(title="Relative error of the standard parameters (median / 95th percentile) and R^2", title_justify="left")
    for col in ("parameter", "network", "p95", "R^2", "floor (null space)", "linear LS", "identifiable"):
        table.add_column(col, justify="left" if col in ("parameter", "identifiable") else "right")
    for k, name in enumerate(ev.network["names"]):
        lin = f"{ev.linear['median'][k]:.3g}" if ev.linear else "-"
        table.add_row(name, f"{ev.network['median'][k]:.3g}", f"{ev.network['p95'][k]:.3g}",
                      f"{ev.network['r2'][k]:.3f}", f"{ev.floor['median'][k]:.3g}", lin,
                      "yes" if ev.identifiable[k] else "no")
    con.print(table)
    table = Table(title="Relative error of the base parameters (median)", title_justify="left")
    for col in ("base parameter", "network", "R^2", "linear LS"):
        table.add_column(col, justify="left" if col == "base parameter" else "right")
    for k, name in enumerate(ev.network_base["names"]):
        lin = f"{ev.linear_base['median'][k]:.3g}" if ev.linear_base else "-"
        table.add_row(name, f"{ev.network_base['median'][k]:.3g}", f"{ev.network_base['r2'][k]:.3f}", lin)
    con.print(table)
    lin = (f"; linear LS: standard {ev.linear['overall_median']:.4g}, base {ev.linear_base['overall_median']:.4g}, "
           f"physical {100 * ev.linear_physical_share:.0f}%") if ev.linear else ""
    con.print(
        f"median over all parameters: network standard {ev.network['overall_median']:.4g}, base "
        f"{ev.network_base['overall_median']:.4g} (per sample, before averaging: {ev.per_sample_median:.4g}); "
        f"null-space floor {ev.floor['overall_median']:.4g}{lin}"
    )
    rms = ", ".join(f"{v:.3g}" for v in ev.wrench_rms)
    con.print(f"wrench residual of the predictions, RMS per axis (N, N*m): {rms}; normalized {ev.wrench_normalized:.4g}; "
              f"physically valid predictions {100 * ev.physical_share:.0f}%")
    del np


@main.command("evaluate")
@click.argument("run_dir", metavar="RUN_DIR", type=click.Path(path_type=Path))
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option("--configs", "selection", default=None, metavar="SEL",
              help="Configurations (default: the run's test split if DATA.h5 is its dataset, else all).")
@click.option("--no-linear", is_flag=True, help="Skip the linear least-squares comparison.")
def evaluate_cmd(run_dir, data_path, selection, no_linear) -> None:
    """Evaluate a trained run on DATA.h5: errors, R^2, floor, wrench residual, linear LS."""
    import json  # noqa: PLC0415

    from ineid.data import load_dataset  # noqa: PLC0415
    from ineid.learn import evaluate, load_run  # noqa: PLC0415

    run = load_run(run_dir)
    ds = load_dataset(data_path)
    configs = None if selection is None else _parse_selection(selection, ds.n_configs)
    ev = evaluate(run, ds, configs, linear=not no_linear)
    (Path(run_dir) / "evaluation.json").write_text(json.dumps(ev.to_dict(), indent=1))
    _print_evaluation(ev)


@main.command("sweep")
@click.argument("data_path", metavar="DATA.h5", type=click.Path(path_type=Path))
@click.option("--archs", default="simple,net1,net2,net3,net4,net5,net6,net7,funnel", show_default=True)
@click.option("--activations", default="tanh", show_default=True)
@click.option("--scalers", default="robust", show_default=True)
@click.option("--optimizers", default="adam", show_default=True)
@click.option("--losses", default="mse", show_default=True)
@click.option("--frames-list", default="1", show_default=True, help="Frames per sample to try (comma-separated).")
@click.option("--siamese", type=click.Choice(["off", "on", "both"]), default="off", show_default=True)
@_train_options
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@overwrite_option
@click.pass_context
def sweep_cmd(ctx, data_path, archs, activations, scalers, optimizers, losses, frames_list, siamese, out_dir,
              overwrite, physics_mode, **kw) -> None:
    """Train a grid of networks one after another; write sweep.csv and sweep.png ranked by test error."""
    from rich.table import Table  # noqa: PLC0415

    from ineid.data import load_dataset  # noqa: PLC0415
    from ineid.learn import Grid, sweep  # noqa: PLC0415
    from ineid.learn.models import ACTIVATIONS, ARCHITECTURES  # noqa: PLC0415

    def names(text, allowed, hint):
        vals = tuple(v.strip() for v in text.split(",") if v.strip())
        bad = [v for v in vals if v not in allowed]
        if bad or not vals:
            raise click.BadParameter(f"choose from {', '.join(allowed)}; got {text!r}", param_hint=hint)
        return vals

    try:
        ks = tuple(int(v) for v in frames_list.split(",") if v.strip())
        if not ks or min(ks) < 1:
            raise ValueError
    except ValueError:
        raise click.BadParameter(f"expected positive integers, got {frames_list!r}", param_hint="--frames-list") from None
    grid = Grid(
        archs=names(archs, list(ARCHITECTURES), "--archs"),
        activations=names(activations, list(ACTIVATIONS), "--activations"),
        scalers=names(scalers, ["standard", "robust", "minmax"], "--scalers"),
        optimizers=names(optimizers, ["sgd", "adam", "adamw"], "--optimizers"),
        losses=names(losses, ["mse", "physics"], "--losses"),
        frames=ks,
        siamese={"off": (False,), "on": (True,), "both": (False, True)}[siamese],
    )
    base = _base_train_config({**kw, "arch": "mlp" if kw["depth"] or kw["width"] else "simple"})
    if (out_dir / "sweep.csv").exists() and not overwrite:
        raise click.ClickException(f"{out_dir} holds a sweep; pass --overwrite to replace it")
    try:
        cfgs = grid.configs(base)
        if not cfgs:
            raise ValueError("the grid is empty: a Siamese network needs more than one frame (--frames-list 10)")
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    ds = load_dataset(data_path)
    n = len(cfgs)
    with _ProgressBar("sweep", "runs", _quiet(ctx)) as bar:
        bar(0, n)
        rows = sweep(ds, grid, base, out_dir, dataset_path=str(data_path), progress=lambda i, t, r: bar(i, t),
                     overwrite=overwrite, physics_mode=physics_mode)
    table = Table(title=f"Sweep on {data_path}: test median relative error, ranked", title_justify="left")
    for col in ("#", "run", "standard", "base", "floor", "linear LS (std / base)", "physical", "epochs", "s"):
        table.add_column(col, justify="left" if col == "run" else "right")
    for i, r in enumerate(rows):
        table.add_row(str(i + 1), r.name, f"{r.test_standard_median:.4g}", f"{r.test_base_median:.4g}",
                      f"{r.floor_standard_median:.4g}", f"{r.linear_standard_median:.4g} / {r.linear_base_median:.3g}",
                      f"{100 * r.physical_share:.0f}%", str(r.epochs_run), f"{r.seconds:.0f}")
    _console().print(table)
    click.echo(f"wrote {out_dir / 'sweep.csv'} and {out_dir / 'sweep.png'}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
