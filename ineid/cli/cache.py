"""``ineid cache info|clear``: the cache folder (generated code of user URDFs, parsed URDFs, compiled XLA code)."""

from __future__ import annotations

import shutil
from pathlib import Path

import click

from ineid.cli.output import console, table


def _size(path: Path) -> tuple[int, int]:
    """(files, bytes) under ``path``."""
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else []
    return len(files), sum(p.stat().st_size for p in files)


def _parts() -> dict[str, Path]:
    from ineid.cache import cache_dir, xla_cache_dir  # noqa: PLC0415
    from ineid.robots.urdf import CHAIN_SUBDIR  # noqa: PLC0415

    root = cache_dir()
    xla = xla_cache_dir()
    chains = root / CHAIN_SUBDIR
    parts = {"compiled XLA kernels": xla, "parsed URDFs": chains}
    if root.is_dir():
        for child in sorted(root.iterdir()):
            if child.is_dir() and child not in (xla, chains):
                parts[f"generated code ({child.name})"] = child
    return parts


@click.group()
def cache() -> None:
    """ineid's cache folder ($INEID_CACHE_DIR, else ~/.cache/ineid). Deleting it is always safe."""


@cache.command("info")
def cache_info() -> None:
    """Where the cache is and what it holds."""
    from ineid.cache import cache_dir  # noqa: PLC0415

    t = table(f"cache {cache_dir()}", ["part", "folder", "files", "MB"], left=(0, 1))
    for name, path in _parts().items():
        n, size = _size(path)
        t.add_row(name, str(path), str(n), f"{size / 1e6:.1f}")
    console().print(t)


@cache.command("clear")
@click.option("--xla-only", is_flag=True, help="Remove only the compiled XLA kernels, keep generated code.")
def cache_clear(xla_only: bool) -> None:
    """Delete the cache; whatever is needed is derived or compiled again on the next run."""
    from ineid.cache import cache_dir, xla_cache_dir  # noqa: PLC0415

    target = xla_cache_dir() if xla_only else cache_dir()
    n, size = _size(target)
    if target.is_dir():
        shutil.rmtree(target)
    click.echo(f"removed {target} ({n} files, {size / 1e6:.1f} MB)")


def register(main: click.Group) -> None:
    main.add_command(cache)
