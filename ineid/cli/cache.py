"""``ineid cache info|clear``: the cache folder (generated code of user URDFs, parsed URDFs, compiled code)."""

from __future__ import annotations

from pathlib import Path

import click

from ineid.cli.output import console, table

_PARTS = {
    "generated": "generated code of URDFs",
    "chains": "parsed URDFs",
    "casadi-c": "compiled CasADi functions",
    "xla": "compiled XLA kernels",
}


def _size(path: Path) -> tuple[int, int]:
    """(files, bytes) under ``path``."""
    files = [p for p in path.rglob("*") if p.is_file() and not p.is_symlink()] if path.is_dir() else []
    return len(files), sum(p.lstat().st_size for p in files)


def _part_problem(path: Path) -> str | None:
    from ineid._trust import stat_problem

    try:
        return stat_problem(path.lstat())
    except FileNotFoundError:
        return None


@click.group()
def cache() -> None:
    """ineid's cache folder ($INEID_CACHE_DIR, else ~/.cache/ineid). Deleting it is always safe."""


@cache.command("info")
def cache_info() -> None:
    """Where the cache is, what it holds, and whether ineid trusts it."""
    from ineid.cache import cache_state

    state = cache_state()
    t = table(f"cache {state.path}", ["part", "folder", "files", "MB"], left=(0, 1))
    for sub, name in _PARTS.items():
        n, size = _size(state.path / sub)
        t.add_row(name, str(state.path / sub), str(n), f"{size / 1e6:.1f}")
    console().print(t)
    if not state.exists:
        click.echo("trust: the folder does not exist yet (ineid creates it with mode 700 and a CACHEDIR.TAG)")
        return
    if state.private:
        click.echo(
            "trust: private (owned by you, not writable by others): ineid loads code from it "
            "after checking each file against the hash it recorded"
        )
    else:
        click.echo(f"trust: NOT TRUSTED: the folder {state.problem}; ineid loads no code from it")
    if state.marked:
        click.echo("marker: CACHEDIR.TAG present (ineid's folder; `ineid cache clear` removes ineid's entries)")
    else:
        click.echo(
            "marker: no CACHEDIR.TAG from ineid (ineid marks the folder when it is empty; it never uses "
            "or clears a folder that holds anything without the marker)"
        )
    for sub in _PARTS:
        problem = _part_problem(state.path / sub)
        if problem:
            click.echo(f"NOT TRUSTED: {state.path / sub} {problem}; ineid works without it (fix: ineid cache clear)")
    if state.foreign:
        click.echo(
            f"other entries (not ineid's, never removed): {', '.join(state.foreign[:5])}"
            + (", ..." if len(state.foreign) > 5 else "")
        )


@cache.command("clear")
@click.option("--xla-only", is_flag=True, help="Remove only the compiled XLA kernels, keep generated code.")
def cache_clear(xla_only: bool) -> None:
    """Delete what ineid put in the cache; whatever is needed is derived or compiled again on the next run.

    Only a folder marked with ineid's CACHEDIR.TAG is cleared, entry by entry: the files ineid
    listed in its manifests, parsed URDFs, JAX's kernels; anything else stays and is named.
    A folder without the marker is refused.
    """
    from ineid.cache_clear import clear_cache

    done = clear_cache(xla_only)
    click.echo(f"removed {done.path} ({done.files} files, {done.bytes / 1e6:.1f} MB)")
    if done.kept:
        click.echo(
            f"kept {len(done.kept)} entries that are not ineid's: {', '.join(done.kept[:5])}"
            + (", ..." if len(done.kept) > 5 else "")
        )


def register(main: click.Group) -> None:
    main.add_command(cache)
