"""Cross-cutting: what ineid reads (:mod:`ineid._inputs`, the HDF5 audit of :mod:`ineid.data.dataset`): HDF5
files that reach outside themselves, JSON nested or sized beyond ineid's limits, and inputs that are not
regular files (a FIFO would block the reader forever).

Every case is one ``Error:`` line with exit status 1, nothing written. The hostile HDF5 files are
built with h5py from ineid's own files: an external link (to ``/etc/passwd``, and to a missing
file), external raw storage holding another file's bytes, a virtual dataset, a soft-link loop.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from ineid import _inputs, _trust
from ineid.cli import main

from .conftest import FIXTURES
from .test_faults import SOLVE, one_line


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """test_cli's (and test_faults') noisy dataset, solved as there (``SOLVE``): the compiled kernels are reused."""
    import ineid
    from ineid.data import Combination, DatasetSpec, NoiseModel, write_dataset

    path = tmp_path_factory.mktemp("inputs") / "d.h5"
    noise = NoiseModel.create(4, force=0.3, moment=0.03)
    write_dataset(
        ineid.load_robot("sweaty-arm"),
        DatasetSpec(Combination("random", n_configs=12), n_frames=30, seed=2, noise=noise),
        path,
    )
    return path


@pytest.fixture(scope="module")
def results(data) -> Path:
    out = data.parent / "r.h5"
    r = run("-q", "solve", data, *SOLVE, "--out", out)
    assert r.exit_code == 0, r.output
    return out


# -- HDF5 files that reach outside themselves ---------------------------------------------------------

HOSTILE = {
    "external link": "is an external link to '/x' in the file '/etc/passwd'",
    "external link to a missing file": "is an external link to '/x' in the file 'missing.h5'",
    "external storage": "keeps its data in the external file",
    "virtual dataset": "is a virtual dataset (its data lives in",
    "soft-link loop": "is a soft link (to '/",
}


def _hostile(src: Path, dst: Path, name: str, kind: str) -> Path:
    """A copy of ``src`` whose dataset ``name`` is replaced by ``kind`` (the same shape and type where it has one)."""
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as f:
        value = f[name][()]
        del f[name]
        if kind == "external link":
            f[name] = h5py.ExternalLink("/etc/passwd", "/x")
        elif kind == "external link to a missing file":
            f[name] = h5py.ExternalLink("missing.h5", "/x")
        elif kind == "external storage":  # another file's bytes, read as the numbers
            raw = dst.with_suffix(".bin")
            raw.write_bytes(np.full(value.shape, 0.5).tobytes())
            f.create_dataset(name, value.shape, value.dtype, external=[(str(raw), 0, value.nbytes)])
        elif kind == "virtual dataset":
            other = dst.with_suffix(".src.h5")
            with h5py.File(other, "w") as g:
                g["x"] = value
            layout = h5py.VirtualLayout(value.shape, value.dtype)
            layout[...] = h5py.VirtualSource(str(other), "x", value.shape)
            f.create_virtual_dataset(name, layout)
        else:
            f[name] = h5py.SoftLink("/loop")
            f["loop"] = h5py.SoftLink(f"/{name}")
    return dst


@pytest.mark.parametrize("kind", list(HOSTILE))
def test_a_dataset_that_reaches_outside_itself_is_refused(data, tmp_path, kind):
    path = _hostile(data, tmp_path / "d.h5", "q", kind)
    for args in (("data", "info", path), ("solve", path, "--out", tmp_path / "r.h5")):
        line = one_line(run("-q", *args))
        assert line.startswith(f"Error: {path}: ") and HOSTILE[kind] in line, line
        assert line.endswith("(this file was not written by ineid, or was edited); regenerate it with ineid")
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.parametrize("kind", list(HOSTILE))
def test_a_results_file_that_reaches_outside_itself_is_refused(results, tmp_path, kind):
    path = _hostile(results, tmp_path / "r.h5", "theta_hat", kind)
    for args in (("results", "info", path), ("report", path, "--out", tmp_path / "x.html")):
        line = one_line(run("-q", *args))
        assert line.startswith(f"Error: {path}: ") and HOSTILE[kind] in line, line
    assert not (tmp_path / "x.html").exists()


def test_a_hard_link_loop_is_walked_once(data, tmp_path):
    """Hard links are followed, each group once: a group linked into itself ends the walk, not the reader."""
    path = tmp_path / "d.h5"
    shutil.copy(data, path)
    with h5py.File(path, "a") as f:
        notes = f.create_group("notes")
        notes["again"] = notes
    assert run("data", "info", path).exit_code == 0


# -- inputs that are not regular files ----------------------------------------------------------------


class _Unblock:
    """A child process opens ``fifo`` for writing after ``seconds``, and again whenever someone reads
    it, so a reader blocked on it gets end-of-file: a regression fails the test instead of hanging it.
    (A process, not a thread: h5py holds the GIL while HDF5 opens the file.)"""

    def __init__(self, fifo: Path, seconds: float = 20.0) -> None:
        self.args = ["sh", "-c", 'sleep "$1"; while :; do : > "$2"; done', "sh", str(seconds), str(fifo)]

    def __enter__(self):
        self.child = subprocess.Popen(self.args)
        return self

    def __exit__(self, *exc) -> None:
        self.child.kill()  # still asleep, or blocked opening a FIFO nobody reads
        self.child.wait()


@pytest.mark.parametrize(
    ("what", "args"),
    [
        ("the dataset", ("data", "info", "{fifo}")),
        ("the dataset", ("solve", "{fifo}", "--out", "{tmp}/r.h5")),
        ("the results file", ("results", "info", "{fifo}")),
        (
            "the trajectory file",
            (
                "data",
                "generate",
                "--frame-mode",
                "trajectory",
                "--trajectory",
                "{fifo}",
                "--n-configs",
                "2",
                "--out",
                "{tmp}/d.h5",
            ),
        ),
    ],
)
def test_a_fifo_is_never_opened(tmp_path, what, args):
    fifo = tmp_path / ("t.json" if "trajectory" in what else "in.h5")
    os.mkfifo(fifo)
    start = time.monotonic()
    with _Unblock(fifo):
        line = one_line(run(*(a.format(fifo=fifo, tmp=tmp_path) for a in args)))
    assert time.monotonic() - start < 10
    assert line == f"Error: {what} {fifo} is a FIFO (named pipe), not a regular file; give a file"
    assert sorted(p.name for p in tmp_path.iterdir()) == [fifo.name]


def test_generate_never_reads_a_fifo_or_binary_file_in_its_output_folder(tmp_path):
    """`generate --out` looks at an existing module to tell ineid's from the user's: a FIFO is not
    opened, bytes that are not UTF-8 are not a traceback; both are the user's (--overwrite to replace)."""
    out = tmp_path / "gen"
    out.mkdir()
    os.mkfifo(out / "mixed_chain_jax.py")
    (out / "mixed_chain_casadi.py").write_bytes(b"\xff\xfe\x00 not text")
    urdf = FIXTURES / "mixed_chain.urdf"
    with _Unblock(out / "mixed_chain_jax.py"):
        line = one_line(run("generate", urdf, "--out", out))
    assert line == f"Error: {out / 'mixed_chain_jax.py'} exists; pass --overwrite to replace it"
    (out / "mixed_chain_jax.py").unlink()
    line = one_line(run("generate", urdf, "--out", out))
    assert line == f"Error: {out / 'mixed_chain_casadi.py'} exists; pass --overwrite to replace it"


# -- JSON -----------------------------------------------------------------------------------------------

DEEP = "[" * 100_000 + "]" * 100_000
TOO_DEEP = f"nested deeper than the {_inputs.JSON_MAX_DEPTH} levels ineid reads (JSON_MAX_DEPTH)"


def test_json_limits():
    deepest = "[" * _inputs.JSON_MAX_DEPTH + "]" * _inputs.JSON_MAX_DEPTH
    assert _inputs.parse_json(deepest) is not None
    assert _inputs.parse_json('{"a": "' + "[" * 1000 + '\\"["}') == {"a": "[" * 1000 + '"['}  # brackets in strings
    for text in (DEEP, "[" + deepest + "]", '{"a": ' * 65 + "1" + "}" * 65):
        with pytest.raises(_inputs.JsonDepthError, match=r"nested deeper than the 64 levels"):
            _inputs.parse_json(text)
    with pytest.raises(ValueError, match="over the 10 bytes ineid reads as JSON"):
        _inputs.parse_json("[1, 2, 3, 4]", max_bytes=10)


def test_a_deep_parsed_urdf_entry_is_parsed_again(tmp_path, monkeypatch):
    from ineid.robots.urdf import CHAIN_SUBDIR, parse_chain

    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "cache"))
    text = (FIXTURES / "mixed_chain.urdf").read_bytes()
    first = parse_chain(text, source="a.urdf")
    (entry,) = (tmp_path / "cache" / CHAIN_SUBDIR).glob("*.json")
    entry.write_text(DEEP)
    assert parse_chain(text, source="a.urdf").kinematic_fingerprint() == first.kinematic_fingerprint()
    assert entry.read_text().startswith('{"name"')  # replaced by a fresh entry


def test_a_deep_manifest_is_damaged(tmp_path):
    (tmp_path / _trust.MANIFEST).write_text(DEEP)
    with pytest.raises(_trust.Untrusted, match="has a damaged MANIFEST.json"):
        _trust.recorded_hashes(tmp_path, private=False)
    assert not _trust.is_manifest(tmp_path / _trust.MANIFEST)


def test_deep_json_in_run_and_trajectory_files(data, tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(DEEP)
    (run_dir / "scalers.json").write_text("{}")
    (run_dir / "model.msgpack").write_bytes(b"\x80")
    line = one_line(run("-q", "evaluate", run_dir, data, "--out", tmp_path / "ev.json"))
    assert (
        line == f"Error: {run_dir / 'config.json'} is damaged (JSON {TOO_DEEP}); "
        "train the run again (ineid train ... --overwrite) or restore the file from a copy"
    )
    traj = tmp_path / "t.json"
    traj.write_text(DEEP)
    line = one_line(
        run(
            "-q",
            "data",
            "generate",
            "--frame-mode",
            "trajectory",
            "--trajectory",
            traj,
            "--n-configs",
            2,
            "--out",
            tmp_path / "d.h5",
        )
    )
    assert line == f"Error: {traj}: not a trajectory record (JSON {TOO_DEEP})"
    assert not (tmp_path / "d.h5").exists() and not (tmp_path / "ev.json").exists()


@pytest.mark.parametrize(("which", "attr"), [("data", "sampling"), ("results", "settings")])
def test_deep_json_attributes_of_hdf5_files(request, tmp_path, which, attr):
    path = tmp_path / "f.h5"
    shutil.copy(request.getfixturevalue(which), path)
    with h5py.File(path, "a") as f:
        f.attrs[attr] = DEEP
    line = one_line(run("-q", "data" if which == "data" else "results", "info", path))
    assert line.startswith(f"Error: {path}: attribute {attr!r} is JSON {TOO_DEEP}"), line
