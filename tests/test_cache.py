"""The cache folder (:mod:`ineid.cache`, :mod:`ineid._trust`, :mod:`ineid.cache_clear`), a cache you can trust:
code planted in it never runs; foreign or shared folders are not used; ``cache clear`` removes only what
ineid wrote.

Every test has its own cache folder. A planted module or library writes a canary file
when it runs: the canary must never appear.
"""

from __future__ import annotations

import json
import logging
import os
import shlex
import shutil
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import ineid
from ineid import _trust, cache
from ineid.cli import main
from ineid.generated import BUILTIN_DIR, file_names
from ineid.identify import casadi_c
from ineid.robots import load_chain
from ineid.robots.codegen import default_codegen_dir, generate_code

from .conftest import FIXTURES

URDF = FIXTURES / "mixed_chain.urdf"
needs_cc = pytest.mark.skipif(casadi_c.c_compiler() is None, reason="no C compiler (cc, gcc, clang) on PATH")


@pytest.fixture
def logged(monkeypatch):
    """The WARNING lines of ineid's loggers, as a list of messages."""
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    handler = Keep(logging.WARNING)
    for name in ("ineid.cache", "ineid.robots.codegen", "ineid.identify.casadi_c", "ineid.robots.urdf"):
        logger = logging.getLogger(name)
        monkeypatch.setattr(logger, "level", logging.WARNING)
        logger.addHandler(handler)
    yield lines
    for name in ("ineid.cache", "ineid.robots.codegen", "ineid.identify.casadi_c", "ineid.robots.urdf"):
        logging.getLogger(name).removeHandler(handler)


@pytest.fixture
def cache_root(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv("INEID_CACHE_DIR", str(root))
    return root


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """The mixed chain's generated modules and manifest, derived once for this module."""
    folder = tmp_path_factory.mktemp("template")
    chain = load_chain(URDF)
    generate_code(chain, chain.name, folder)
    return folder


def _plant(path: Path, canary: Path) -> None:
    path.write_text(f"import pathlib; pathlib.Path({str(canary)!r}).write_text('ran')\n" + path.read_text())


def _fill(folder: Path, template: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for p in template.iterdir():
        shutil.copy(p, folder / p.name)
    return folder


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


# -- generated modules -------------------------------------------------------------------------


@pytest.mark.parametrize("manifest", ["kept", "deleted"])
def test_planted_code_in_a_cached_module_never_runs(template, cache_root, tmp_path, logged, manifest):
    """A line prepended to the cached JAX module (the manifest left, or deleted too) is not run:
    the module is regenerated, with one warning line saying why."""
    folder = _fill(default_codegen_dir(load_chain(URDF)), template)
    jax_file = folder / file_names("mixed-chain")[0]
    canary = tmp_path / "canary"
    _plant(jax_file, canary)
    if manifest == "deleted":
        (folder / _trust.MANIFEST).unlink()
    model = ineid.load_robot(URDF)
    assert not canary.exists()
    reason = "does not match its manifest (mixed_chain_jax.py was modified" if manifest == "kept" else "has no MANIFEST"
    assert logged == [m for m in logged if "the cached generated code of mixed-chain" in m] and len(logged) == 1
    assert f"in {folder} {reason}" in logged[0] and logged[0].endswith("; regenerating")
    assert jax_file.read_bytes() == (template / jax_file.name).read_bytes()  # regenerated in place
    assert _trust.verified(folder, file_names("mixed-chain"), private=True)
    assert model.n_dof == 3 and model.op_count > 0


def test_untrusted_cache_folder_is_not_used(template, cache_root, tmp_path, logged):
    """A cache folder writable by others holds a planted module with a matching manifest (whoever
    can write there can write both): ineid loads nothing from it and derives in a private folder."""
    folder = _fill(default_codegen_dir(load_chain(URDF)), template)
    canary = tmp_path / "canary"
    _plant(folder / file_names("mixed-chain")[0], canary)
    _trust.write_manifest(folder, {n: (folder / n).read_bytes() for n in file_names("mixed-chain")}, private=True)
    cache_root.chmod(0o777)
    model = ineid.load_robot(URDF)
    assert not canary.exists() and model.n_dof == 3
    assert len(logged) == 1
    assert logged[0].startswith(f"the cache folder {cache_root} is writable by group or others, so ineid loads no code")
    assert f"chmod 700 {cache_root}" in logged[0]


def test_foreign_cache_folders_are_not_used(cache_root, monkeypatch, logged):
    """Owned by another user (tests cannot chown: the current user is made to look like someone
    else), or a subfolder writable by others: code goes to a private temporary folder, and
    JAX's compilation cache (native code) stays off."""
    import jax

    inside = cache.private_folder("generated", "abc")
    assert inside == cache_root / "generated" / "abc"
    (cache_root / "generated").chmod(0o775)
    elsewhere = cache.private_folder("generated", "abc")
    assert not elsewhere.is_relative_to(cache_root) and _mode(elsewhere.parent.parent) == 0o700
    assert logged == [
        (
            f"the cache folder {cache_root / 'generated'} is writable by group or others, so ineid "
            "loads no code from it and works in a private temporary folder this time; fix: ineid cache clear"
        )
    ]

    def as_if_foreign(path):  # the cache folder's owner seen as another user; nothing else
        with monkeypatch.context() as m:
            m.setattr(_trust, "current_uid", lambda: os.geteuid() + 1)
            return _trust.root_problem(path)

    monkeypatch.setattr(cache, "root_problem", as_if_foreign)
    assert not cache.private_folder("chains").is_relative_to(cache_root)
    assert f"the cache folder {cache_root} is owned by another user" in logged[1]
    before = jax.config.jax_compilation_cache_dir
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        assert cache.enable_compilation_cache() is None and jax.config.jax_compilation_cache_dir is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    assert len(logged) == 2  # one line per problem and process
    state = cache.cache_state()
    assert not state.private and "owned by another user" in state.problem


def test_cache_folders_are_created_private(tmp_path, monkeypatch):
    """Even under umask 000: the cache, its parents that ineid makes, and every subfolder are 0700,
    and the cache is marked with a CACHEDIR.TAG."""
    root = tmp_path / "new" / "cache"
    monkeypatch.setenv("INEID_CACHE_DIR", str(root))
    old = os.umask(0)
    try:
        folders = [cache.private_folder(*parts) for parts in (("generated", "abc"), ("chains",), ("casadi-c",))]
        folders.append(cache._private_xla_dir())
    finally:
        os.umask(old)
    for p in (root.parent, root, root / "generated", *folders):
        assert _mode(p) == 0o700, p
    assert (root / cache.MARKER).read_text().startswith("Signature: 8a477f597d28d172789f06886806bc55\n")
    assert cache.cache_state().marked and cache.cache_state().private


def test_user_folder_gets_a_manifest_and_is_checked(tmp_path, logged):
    """`ineid generate --out` writes a manifest; load_robot(codegen_dir=) uses the folder
    (any permissions) while the files match it and regenerates them when they do not."""
    out = tmp_path / "gen"
    r = CliRunner().invoke(main, ["generate", str(URDF), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert f"wrote {out / 'MANIFEST.json'}" in r.output
    doc = json.loads((out / "MANIFEST.json").read_text())
    assert doc["sha256"] == {n: _trust.sha256((out / n).read_bytes()) for n in file_names("mixed-chain")}
    out.chmod(0o777)  # the user's folder, the user's choice: only the content is checked
    stamp = (out / "mixed_chain_jax.py").stat().st_mtime_ns
    ineid.load_robot(URDF, codegen_dir=out)
    assert (out / "mixed_chain_jax.py").stat().st_mtime_ns == stamp and logged == []
    canary = tmp_path / "canary"
    _plant(out / "mixed_chain_casadi.py", canary)
    ineid.load_robot(URDF, codegen_dir=out)
    assert not canary.exists()
    assert logged == [
        (
            f"the generated code of mixed-chain in {out} does not match its manifest "
            "(mixed_chain_casadi.py was modified after ineid wrote it); regenerating"
        )
    ]
    assert not (BUILTIN_DIR / "MANIFEST.json").exists()  # package code: not checked, no manifest


def test_a_foreign_manifest_in_the_way_needs_overwrite(tmp_path):
    out = tmp_path / "gen"
    out.mkdir()
    (out / "MANIFEST.json").write_text('{"mine": 1}')
    r = CliRunner().invoke(main, ["generate", str(URDF), "--out", str(out)])
    assert (
        r.exit_code == 1
        and r.output.strip() == f"Error: {out / 'MANIFEST.json'} exists; pass --overwrite to replace it"
    )
    assert (out / "MANIFEST.json").read_text() == '{"mine": 1}'


# -- parsed URDFs ------------------------------------------------------------------------------


def test_parsed_urdf_entries_are_trusted_like_code(cache_root, logged):
    from ineid.robots.urdf import CHAIN_SUBDIR, parse_chain

    text = URDF.read_bytes()
    chain = parse_chain(text, source="a.urdf")
    (entry,) = (cache_root / CHAIN_SUBDIR).glob("*.json")
    entry.write_text("{damaged")  # parsed again, silently, as before
    assert parse_chain(text, source="a.urdf").kinematic_fingerprint() == chain.kinematic_fingerprint()
    assert logged == []
    entry.chmod(0o666)
    assert parse_chain(text, source="a.urdf").kinematic_fingerprint() == chain.kinematic_fingerprint()
    assert logged == [
        (
            f"the cache of parsed URDFs in {entry.parent} has a file that is writable by group or "
            f"others ({entry.name}); parsing the URDF again"
        )
    ]
    assert _mode(entry) & 0o022 == 0  # replaced by a fresh entry


# -- compiled CasADi functions -----------------------------------------------------------------


@needs_cc
def test_planted_library_in_casadi_c_is_not_loaded(cache_root, tmp_path, logged):
    import casadi as ca

    x = ca.SX.sym("x", 2)
    fn = ca.Function("ineid_trust_probe", [x], [2 * x])
    assert np.asarray(casadi_c.compile_function(fn)([1.0, 2.0])).ravel().tolist() == [2.0, 4.0]
    (library,) = (cache_root / "casadi-c").glob("*.so")
    canary = tmp_path / "canary"
    evil = tmp_path / "evil.c"
    evil.write_text(
        "#include <stdio.h>\n"
        f'__attribute__((constructor)) static void ran(void) {{ FILE *f = fopen("{canary}", "w"); fclose(f); }}\n'
    )
    cc = shlex.split(casadi_c.c_compiler())
    subprocess.run([*cc, "-shared", "-fPIC", "-o", str(library), str(evil)], check=True, capture_output=True)
    again = casadi_c.compile_function(fn)
    assert not canary.exists()
    assert np.asarray(again([3.0, 4.0])).ravel().tolist() == [6.0, 8.0]
    assert len(logged) == 1 and f"function ineid_trust_probe in {library.parent} does not match its record" in logged[0]
    assert logged[0].endswith("compiling it again")
    library.chmod(0o777)  # the right bytes, but anyone could have swapped them
    casadi_c.compile_function(fn)
    assert len(logged) == 2 and f"has a file that is writable by group or others ({library.name})" in logged[1]
    assert _mode(library) & 0o022 == 0


# -- ineid cache clear / info ------------------------------------------------------------------


def test_cache_clear_refuses_a_folder_that_is_not_ineids(tmp_path, monkeypatch):
    home = tmp_path / "home"
    for rel in ("notes.txt", "xla/mine.txt", "generated/mine.py"):
        (home / rel).parent.mkdir(parents=True, exist_ok=True)
        (home / rel).write_text("mine")
    monkeypatch.setenv("INEID_CACHE_DIR", str(home))
    runner = CliRunner()
    for args in (["cache", "clear"], ["cache", "clear", "--xla-only"]):
        r = runner.invoke(main, args)
        assert r.exit_code == 1 and "Traceback" not in r.output
        assert r.output.strip() == (
            f"Error: {home} is not an ineid cache folder (no CACHEDIR.TAG from ineid, and it holds generated, "
            "notes.txt, xla); nothing removed; set INEID_CACHE_DIR to ineid's own cache folder (or unset it) and "
            "clear again"
        )
    assert sorted(str(p.relative_to(home)) for p in home.rglob("*") if p.is_file()) == [
        "generated/mine.py",
        "notes.txt",
        "xla/mine.txt",
    ]
    info = runner.invoke(main, ["cache", "info"])
    assert info.exit_code == 0 and "marker: no CACHEDIR.TAG from ineid" in info.output
    assert "other entries (not ineid's, never removed): notes.txt" in info.output


@pytest.mark.parametrize("layout", ["generated and chains", "generated only"])
def test_a_project_folder_is_never_adopted_or_cleared(tmp_path, monkeypatch, logged, layout):
    """INEID_CACHE_DIR names a project folder holding ineid's subfolder names with the user's files
    and no marker: `robot show` works in a private temporary folder (one warning naming the folder and
    the fix) and writes nothing there; `cache clear` refuses in one line; nothing of the user's is lost."""
    project = tmp_path / "project"
    mine = {"generated/my_model.py": "# mine\n", "chains/robots.json": "{}"}
    if layout == "generated only":
        mine.pop("chains/robots.json")
    for rel, text in mine.items():
        (project / rel).parent.mkdir(parents=True, exist_ok=True)
        (project / rel).write_text(text)
    monkeypatch.setenv("INEID_CACHE_DIR", str(project))
    monkeypatch.setattr(cache, "_warned", set())
    runner = CliRunner()
    r = runner.invoke(main, ["robot", "show", str(URDF)])
    assert r.exit_code == 0, r.output
    shown = "chains, generated" if len(mine) == 2 else "generated"
    assert logged == [
        f"the cache folder {project} is not empty and has no CACHEDIR.TAG from ineid (it holds {shown}), so ineid "
        "loads no code from it and works without a cache this time (in a private temporary folder); fix: set "
        "INEID_CACHE_DIR to a new or empty folder (ineid marks it as its cache), or unset it"
    ]
    for args in (["cache", "clear"], ["cache", "clear", "--xla-only"]):
        r = runner.invoke(main, args)
        assert r.exit_code == 1 and r.output.strip() == (
            f"Error: {project} is not an ineid cache folder (no CACHEDIR.TAG from ineid, and it holds {shown}); "
            "nothing removed; set INEID_CACHE_DIR to ineid's own cache folder (or unset it) and clear again"
        )
    assert {p.relative_to(project).as_posix(): p.read_text() for p in project.rglob("*") if p.is_file()} == mine
    info = runner.invoke(main, ["cache", "info"])
    assert "trust: NOT TRUSTED: the folder is not empty and has no CACHEDIR.TAG from ineid" in info.output


def test_an_empty_folder_is_marked_and_a_planted_marker_fifo_does_not_hang(tmp_path, monkeypatch, logged):
    """An existing empty folder becomes ineid's cache (marked), even while another process's marker
    temporary is there; a FIFO under the marker's name is not a marker (and is never waited on)."""
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / f".{cache.MARKER}.99999.tmp.TAG").write_text("")  # another process marking it right now
    monkeypatch.setenv("INEID_CACHE_DIR", str(empty))
    assert cache.private_folder("chains") == empty / "chains" and cache.cache_state().marked
    fifo = tmp_path / "fifo"
    fifo.mkdir()
    os.mkfifo(fifo / cache.MARKER)
    monkeypatch.setenv("INEID_CACHE_DIR", str(fifo))
    assert not cache.private_folder("chains").is_relative_to(fifo)
    assert "is not empty and has no CACHEDIR.TAG from ineid (it holds CACHEDIR.TAG)" in logged[-1]


def _jax_name(kind: str) -> str:
    return f"jit_f-{'ab' * 32}-{kind}"


def test_cache_clear_removes_only_what_ineid_wrote(template, cache_root, tmp_path):
    """A marked cache holding ineid's entries (generated code and its manifest, a parsed URDF, a
    compiled library and its record, JAX's kernels, a killed run's temporaries) and the user's files
    in every part (unlisted, misnamed, a foreign manifest, a symbolic link to a folder of theirs):
    clear removes the first kind, names and keeps the second, and follows no link."""
    from ineid.robots.urdf import CHAIN_SUBDIR, parse_chain

    generated = _fill(default_codegen_dir(load_chain(URDF)), template)
    parse_chain(URDF.read_bytes(), source="a.urdf")
    chain_entries = sorted((cache_root / CHAIN_SUBDIR).glob("*.json"))  # this one and load_chain's
    libs = cache.private_folder("casadi-c")
    (libs / f"probe_{'0' * 16}.so").write_bytes(b"\x7fELF")
    _trust.write_manifest(libs, {f"probe_{'0' * 16}.so": b"\x7fELF"}, private=True, manifest=f"probe_{'0' * 16}.json")
    xla = cache.private_folder("xla")
    for name in (_jax_name("cache"), _jax_name("atime"), ".lockfile"):
        (xla / name).write_bytes(b"kernel")
    (generated / f".mixed_chain_jax.py.{2**22 + 1}.tmp.py").write_text("partial")  # a killed write
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "keep.txt").write_text("mine")
    user = {
        "generated/my_model.py": "mine",
        f"generated/{generated.name}/notes.txt": "mine",
        f"chains/{'f' * 32}.json": '{"mine": 1}',
        "chains/mine.json": "{}",
        "casadi-c/mine.so": "mine",
        "casadi-c/other.json": '{"format": "x"}',
        "xla/mine.txt": "mine",
        "notes.txt": "mine",
    }
    for rel, text in user.items():
        (cache_root / rel).write_text(text)
    (cache_root / "generated" / "link").symlink_to(theirs)
    info = CliRunner().invoke(main, ["cache", "info"])
    assert "trust: private" in info.output and "marker: CACHEDIR.TAG present" in info.output
    r = CliRunner().invoke(main, ["cache", "clear"])
    assert r.exit_code == 0, r.output
    assert r.output.splitlines() == [
        f"removed {cache_root} ({9 + len(chain_entries)} files, 0.0 MB)",
        f"kept 9 entries that are not ineid's: casadi-c/mine.so, casadi-c/other.json, chains/{'f' * 32}.json, "
        f"chains/mine.json, generated/{generated.name}/notes.txt, ...",
    ]
    left = {p.relative_to(cache_root).as_posix() for p in cache_root.rglob("*") if p.is_file() and not p.is_symlink()}
    assert left == {*user, cache.MARKER}
    assert (cache_root / "generated" / "link").is_symlink() and (theirs / "keep.txt").read_text() == "mine"
    assert not any(p.exists() for p in chain_entries) and not (generated / _trust.MANIFEST).exists()
    for rel in user:
        (cache_root / rel).unlink()
    (cache_root / "generated" / "link").unlink()
    r = CliRunner().invoke(main, ["cache", "clear"])
    assert r.output.strip() == f"removed {cache_root} (0 files, 0.0 MB)" and not cache_root.exists()
