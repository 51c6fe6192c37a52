"""``ineid robot list|show`` and ``ineid generate``: robot models and their generated code."""

from __future__ import annotations

import time
from pathlib import Path

import click

from ineid.cli.options import lock_option, robot_options
from ineid.cli.output import console, plain, shown, table
from ineid.cli.output_files import overwrite_option


@click.group()
def robot() -> None:
    """Inspect robot models."""


@robot.command("list")
def robot_list() -> None:
    """List the built-in robots."""
    from ineid.robots import BUILTIN_ROBOTS

    for name, spec in BUILTIN_ROBOTS.items():
        click.echo(f"{name}\t{spec.description}")


@robot.command("show")
@robot_options()
def robot_show(robot) -> None:
    """Joints, links (known/unknown) and CAD parameters of ROBOT."""
    from ineid.params import PARAM_NAMES, inertial_from_theta
    from ineid.robots.gravity import describe_gravity

    model = robot.load()
    con = console()
    con.print(f"[bold]{shown(model.name)}[/bold]  {shown(model.model_path)}")
    con.print(
        f"{model.n_dof} moving joints, base link {shown(repr(model.chain.root_link))}, "
        f"regressor 6 x {10 * model.n_links} ({model.op_count} operations)"
    )
    con.print(describe_gravity(model.gravity))
    tree = not model.chain.is_serial  # a tree names each joint's parent joint
    joints = table(
        "Joints (chain order: depth first, each parent before its children)" if tree else "Joints (chain order)",
        ("#", "joint", *(("after",) if tree else ()), "type", "axis", "q range", "|qd| max", "|qdd| max"),
        left=("joint", "after", "type", "axis", "q range") if tree else ("joint", "type", "axis", "q range"),
    )
    for i, j in enumerate(model.chain.joints):
        kind = "continuous" if j.continuous else j.type
        axis = " ".join(f"{v:g}" for v in j.axis)
        parent = model.chain.parents[i]
        after = (model.chain.joints[parent].name if parent >= 0 else "(base)",) if tree else ()
        joints.add_row(
            str(i + 1), j.name, *after, kind, axis, f"[{j.q_lower:g}, {j.q_upper:g}]", f"{j.qd_max:g}", f"{j.qdd_max:g}"
        )
    con.print(joints)
    links = table(
        "Links",
        ("link", "role", "welded in", "mass kg", "com m (link frame)"),
        left=("link", "role", "welded in", "mass kg", "com m (link frame)"),
    )
    masses, coms, _ = inertial_from_theta(model.theta_cad.reshape(-1, 10))
    for i, name in enumerate(model.link_names):
        role = "unknown" if name in model.unknown_links else "known"
        welded = ", ".join(model.chain.merged_links.get(name, (name,))[1:]) or "-"
        com = " ".join(f"{v:.4f}" for v in coms[i])
        links.add_row(name, role, welded, f"{masses[i]:.4f}", com)
    con.print(links)
    welded = [b for b in model.chain.body_links.values() if b.parent]
    if welded:
        extra = table(
            "Links welded to a moving link (name one in --unknown-links to identify it as a payload)",
            ("link", "welded to", "role", "mass kg", "origin m (body frame)"),
            left=("link", "welded to", "role", "origin m (body frame)"),
        )
        for b in welded:
            role = "unknown (payload)" if b.name in model.unknown_links else ("frame" if b.theta[0] <= 0 else "known")
            extra.add_row(b.name, b.body, role, f"{b.theta[0]:.4f}", " ".join(f"{v:.4f}" for v in b.body_p_link))
        con.print(extra)
    for note in model.chain.notes:
        con.print(f"note: {shown(note)}")
    params = table("CAD parameters, about each link origin, link frame (SI)", ("link", *PARAM_NAMES), left=("link",))
    for i, name in enumerate(model.link_names):
        params.add_row(name, *(f"{v:.5g}" for v in model.theta_cad[10 * i : 10 * i + 10]))
    con.print(params)


@click.command()
@click.argument("robot", metavar="ROBOT", required=False)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder for the generated modules (default: ineid/generated for a built-in, else the cache).",
)
@click.option("--builtin", "all_builtin", is_flag=True, help="Regenerate every built-in robot in ineid/generated.")
@lock_option
@overwrite_option
def generate(robot: str | None, out_dir: Path | None, all_builtin: bool, locked: dict | None, overwrite: bool) -> None:
    """Derive ROBOT's base-wrench regressor and emit its CasADi and JAX modules.

    Files ineid generated are regenerated in place; any other file in the way needs --overwrite.
    """
    from ineid._atomic import check_output
    from ineid._trust import MANIFEST, is_manifest
    from ineid.cli.output_files import check_not_input
    from ineid.generated import BUILTIN_DIR, file_names
    from ineid.robots import BUILTIN_ROBOTS
    from ineid.robots.codegen import default_codegen_dir, generate_code
    from ineid.robots.load import robot_file_chain
    from ineid.symbolic.emit import GENERATOR

    if all_builtin == (robot is not None):
        raise click.UsageError("give either ROBOT or --builtin")
    if all_builtin:
        if out_dir is not None:
            raise click.UsageError("--builtin writes into ineid/generated; drop --out")
        jobs = [(BUILTIN_ROBOTS[n].urdf_path, n, BUILTIN_DIR, "make generate") for n in BUILTIN_ROBOTS]
    elif robot in BUILTIN_ROBOTS and not Path(robot).is_file():
        if locked:
            raise click.UsageError("--lock applies to URDF files, not built-in robots")
        jobs = [(BUILTIN_ROBOTS[robot].urdf_path, robot, out_dir or BUILTIN_DIR, "make generate")]
    else:
        path = Path(robot)
        if not path.exists():  # a FIFO or a folder is refused by robot_file_chain, naming what it is
            raise click.BadParameter(
                f"{robot!r} is neither a built-in robot ({', '.join(BUILTIN_ROBOTS)}) nor an existing URDF file (or "
                "MJCF)",
                param_hint="ROBOT",
            )
        chain = robot_file_chain(path, locked)[0]
        jobs = [(path, chain.name, out_dir or default_codegen_dir(chain), f"ineid generate {robot}")]
    for urdf, name, target, _ in jobs:
        for fname in (*file_names(name), MANIFEST):  # the robot file itself is never replaced, even with --overwrite
            check_not_input(Path(target) / fname, [("the robot file", Path(urdf))], kind="folder", folder=Path(target))
        for fname in file_names(name):
            existing = Path(target) / fname
            if existing.exists() and f"Generated by {GENERATOR}" not in _head(existing):
                check_output(existing, overwrite)  # a file ineid did not write
        manifest = Path(target) / MANIFEST
        if Path(target).resolve() != BUILTIN_DIR and manifest.exists() and not is_manifest(manifest):
            check_output(manifest, overwrite)
    for urdf, name, target, regen in jobs:
        t0 = time.perf_counter()
        chain = robot_file_chain(urdf, locked)[0]
        emitted = generate_code(chain, name, target, regen)
        seconds = time.perf_counter() - t0
        click.echo(
            f"{plain(name)}: {chain.n_dof} DOF, regressor 6 x {10 * chain.n_dof}, {emitted.op_count} operations "
            f"in {emitted.n_lines} named values, {seconds:.2f} s"
        )
        for fname in sorted(emitted.files):
            click.echo(f"  wrote {plain(Path(target) / fname)}")
        if Path(target).resolve() != BUILTIN_DIR:
            click.echo(
                f"  wrote {plain(Path(target) / MANIFEST)} (SHA-256 of each file, checked before ineid loads it)"
            )


def _head(path: Path) -> str:
    """The first 400 bytes of ``path`` as text; empty for a FIFO, a folder or a device (never opened)."""
    if not path.is_file():
        return ""
    with path.open("rb") as f:
        return f.read(400).decode("utf-8", "replace")


def register(main: click.Group) -> None:
    main.add_command(robot)
    main.add_command(generate)
