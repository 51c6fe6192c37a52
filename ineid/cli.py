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

    import ineid  # noqa: PLC0415
    from ineid.params import PARAM_NAMES, inertial_from_theta  # noqa: PLC0415

    kwargs = {"unknown_links": _split_names(unknown_links), "locked_joints": _parse_locked(locked) or None}
    if gravity is not None:
        kwargs["gravity"] = gravity
    model = ineid.load_robot(robot, **kwargs)
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
    from ineid.robots.model import cache_dir, generate_code  # noqa: PLC0415
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
