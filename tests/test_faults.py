"""Cross-cutting: one line for every fault (:mod:`ineid._faults`): full and read-only disks, permissions, absurd
option values, damaged files.

Each case is a command that once ended in a traceback (or a segmentation fault); now it exits
with status 1 (or 2 for a usage error), prints one line naming the file or setting and the
fix, and leaves no output and no temporary file. Disks cannot be filled in CI, so the faults
are injected where a real full disk fails (the OSError h5py or Python raises there); one
test fills a real tmpfs when it can mount one (root).
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from ineid._faults import describe_fault, fault_path
from ineid._temporary import temporary_path
from ineid.cli import main

from .conftest import FIXTURES


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line(result, code=1) -> str:
    """The error line of a failed command: the expected status, no traceback, one ``Error:`` line."""
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output and "Exception ignored" not in result.output, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, result.output
    return errors[0]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def h5py_error(code: int, path: Path, cls=OSError):
    """An error as h5py raises it when HDF5 fails to write (errno and file name only in the text)."""
    text = (
        f"Can't write unprocessed chunk data (file write failed: time = Wed Nov 25 00:59:28 2026\n, filename = "
        f"'{path}', file descriptor = 3, errno = {code}, error message = '{os.strerror(code)}', buf = 0x1, "
        "total write size = 14400, bytes this sub-write = 14400, offset = 65536)"
    )
    return cls(code, text) if cls is OSError else cls(text)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    path = tmp_path_factory.mktemp("faults") / "d.h5"
    write_dataset(
        ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=40), n_frames=6, seed=1), path
    )
    return path


SOLVE = ("--method", "linear", "--weights", "estimate", "--select", "0:6")


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """test_cli's noisy dataset, solved here as there (``SOLVE``): the compiled kernels are reused."""
    import ineid
    from ineid.data import Combination, DatasetSpec, NoiseModel, write_dataset

    path = tmp_path_factory.mktemp("small") / "d.h5"
    noise = NoiseModel.create(4, force=0.3, moment=0.03)
    write_dataset(
        ineid.load_robot("sweaty-arm"),
        DatasetSpec(Combination("random", n_configs=12), n_frames=30, seed=2, noise=noise),
        path,
    )
    return path


@pytest.fixture(scope="module")
def results(small) -> Path:
    """Physically consistent estimates of configurations 2 and 5 (as test_cli makes them): exportable."""
    out = small.parent / "r.h5"
    r = run(
        "-q",
        "solve",
        small,
        "--method",
        "consistent",
        "--select",
        "2,5",
        "--fit-frames",
        30,
        "--workers",
        1,
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    return out


# test_cli's training run (same data and settings: its compiled kernels are reused)
TRAIN = (
    "--arch",
    "net1",
    "--sample-frames",
    3,
    "--siamese",
    "--loss",
    "physics",
    "--beta",
    2,
    "--epochs",
    3,
    "--batch",
    16,
    "--train-configs",
    24,
    "--val-configs",
    8,
)


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "run"
    r = run("-q", "train", data, *TRAIN, "--out", out)
    assert r.exit_code == 0, r.output
    return out


# -- the wording -------------------------------------------------------------------------------


def test_faults_are_recognised_in_python_and_h5py_forms(tmp_path):
    out = tmp_path / "r.h5"
    tmp = temporary_path(out, ".h5")
    assert describe_fault(OSError(errno.ENOSPC, "No space left on device", str(tmp))) == (
        f"no space left on device writing {out}; free some space or choose another --out"
    )
    # h5py's RuntimeError from a dataset's dealloc carries the errno only in its text
    assert describe_fault(h5py_error(errno.ENOSPC, tmp, RuntimeError)).startswith(
        f"no space left on device writing {out}"
    )
    assert fault_path(h5py_error(errno.EROFS, tmp)) == str(out)
    assert "read-only file system; choose another --out" in describe_fault(h5py_error(errno.EROFS, tmp))
    assert "permission denied" in describe_fault(PermissionError(errno.EACCES, "Permission denied", str(out)))
    assert "file name too long" in describe_fault(OSError(errno.ENAMETOOLONG, "File name too long", "x" * 300))
    assert "disk quota exceeded" in describe_fault(OSError(errno.EDQUOT, "Disk quota exceeded"))
    assert "out of memory" in describe_fault(MemoryError("Unable to allocate 72.0 GiB"))
    assert describe_fault(OSError(errno.ENOENT, "No such file")) is None  # not a fault to word: a bug
    assert describe_fault(RuntimeError("something else")) is None and describe_fault(ValueError("x")) is None


def test_a_bug_keeps_its_traceback(monkeypatch, tmp_path, results):
    import ineid.identify

    def broken(*a, **k):
        raise RuntimeError("an internal error")

    monkeypatch.setattr(ineid.identify, "load_results", broken)
    with pytest.raises(RuntimeError, match="an internal error"):
        run("results", "info", results)


def test_atomic_cleanup_never_hides_the_first_error(monkeypatch, tmp_path):
    from ineid._atomic import atomic_write

    def refuse(self, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "write_text", refuse)
    monkeypatch.setattr(Path, "unlink", refuse)  # a read-only folder refuses the cleanup too
    with pytest.raises(OSError) as e:
        atomic_write(tmp_path / "x.txt", "data")
    assert e.value.errno == errno.EROFS and e.value.__context__ is None


# -- full disk -----------------------------------------------------------------------------------


def test_full_disk_on_the_results_write(monkeypatch, tmp_path, small):
    out = tmp_path / "r.h5"
    real = Path.write_bytes

    def fill_up(self, payload):  # the disk fills halfway through the file, as a real one does
        real(self, payload[: len(payload) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", fill_up)
    line = one_line(run("-q", "solve", small, *SOLVE, "--out", out))
    assert line == f"Error: no space left on device writing {out}; free some space or choose another --out"
    assert leftovers(tmp_path) == []


def test_results_that_cannot_fit_are_refused_before_writing(monkeypatch, tmp_path, small):
    import ineid._faults

    monkeypatch.setattr(ineid._faults, "free_disk", lambda path: 1000)
    line = one_line(run("-q", "solve", small, *SOLVE, "--out", tmp_path / "r.h5"))
    assert "needs about" in line and "its disk has 1000 bytes free" in line and "--select" in line
    assert leftovers(tmp_path) == []


def test_full_disk_on_data_generate(monkeypatch, tmp_path):
    """ENOSPC where HDF5 stores a chunk (h5py's OSError, errno and temporary name in its text)."""
    from ineid.data.dataset import write

    out = tmp_path / "d.h5"

    def full(self, name, nbytes, rows):
        raise h5py_error(errno.ENOSPC, temporary_path(out))

    monkeypatch.setattr(write._SpaceWatch, "check", full)
    line = one_line(run("-q", "data", "generate", "--n-configs", 40, "--n-frames", 6, "--seed", 1, "--out", out))
    assert line == f"Error: no space left on device writing {out}; free some space or choose another --out"
    assert leftovers(tmp_path) == []


def test_a_dataset_too_big_for_the_disk_stops_at_its_first_chunks(monkeypatch, tmp_path):
    from ineid.data.dataset import write

    monkeypatch.setattr(write, "free_disk", lambda path: 50_000)
    # chunks of 192 configurations x 100 frames, as test_cli's SIGTERM test writes (its kernel is compiled)
    line = one_line(run("-q", "data", "generate", "--n-configs", 400, "--n-frames", 100, "--out", tmp_path / "d.h5"))
    assert "would be about" in line and "measured on its first 192 configurations" in line and "48.8 KiB free" in line
    assert leftovers(tmp_path) == []


def test_file_size_limit_in_hdf5_is_one_line(tmp_path):
    """HDF5's own failure (no injection): a process whose files may not exceed 64 KiB (``ulimit -f``)."""
    out = tmp_path / "d.h5"
    code = (
        "import resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
        "resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536)); from ineid.cli import main; "
        f"main(['-q', 'data', 'generate', '--n-configs', '300', '--n-frames', '20', '--out', {str(out)!r}])"
    )
    env = dict(os.environ, INEID_XLA_CACHE="0", PYTHONDONTWRITEBYTECODE="1")  # only the dataset meets the limit
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, check=False)
    assert p.returncode == 1, p.stderr
    expected = (
        f"Error: file too large for the file system (or the limit of `ulimit -f`) writing {out}; make a "
        "smaller output or choose another --out"
    )
    assert p.stderr.strip().splitlines() == [expected], p.stderr
    assert leftovers(tmp_path) == []


def _can_mount() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("mount") is not None


@pytest.mark.skipif(not _can_mount(), reason="needs root to mount a small tmpfs")
def test_real_full_and_read_only_disks(tmp_path, small):
    """A 256 KiB tmpfs filled by a real solve (a subprocess: HDF5 crashed there, exit 139) and data generate,
    and a read-only tmpfs."""
    full, ro = tmp_path / "full", tmp_path / "ro"
    full.mkdir(), ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(full)], check=False).returncode:
        pytest.skip("mount failed")
    try:
        if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], check=False).returncode:
            pytest.skip("mount failed")
        try:
            (full / "fill").write_bytes(b"\0" * 240_000)
            disk_full = ("no space left on device writing", "needs about", "would be about")
            p = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "ineid.cli",
                    "-q",
                    "solve",
                    str(small),
                    *map(str, SOLVE),
                    "--out",
                    str(full / "r.h5"),
                ],
                capture_output=True,
                text=True,
                timeout=120,
                check=False,
            )
            lines = p.stderr.strip().splitlines()
            assert p.returncode == 1 and len(lines) == 1 and any(w in lines[0] for w in disk_full), p.stderr
            line = one_line(run("-q", "data", "generate", "--n-configs", 400, "--n-frames", 20, "--out", full / "d.h5"))
            assert any(w in line for w in disk_full) and str(full / "d.h5") in line
            line = one_line(run("-q", "solve", small, *SOLVE, "--out", ro / "r.h5"))
            assert line == f"Error: {ro / 'r.h5'} is on a read-only file system; choose another --out"
            line = one_line(run("-q", "data", "generate", "--n-configs", 2, "--n-frames", 2, "--out", ro / "d.h5"))
            assert line == f"Error: {ro / 'd.h5'} is on a read-only file system; choose another --out"
            assert leftovers(full) == ["fill"] and leftovers(ro) == []
        finally:
            subprocess.run(["umount", str(ro)], check=False)
    finally:
        subprocess.run(["umount", str(full)], check=False)


# -- read-only and forbidden folders ---------------------------------------------------------------


def test_read_only_output_folder(monkeypatch, tmp_path, results):
    """EROFS where the temporary file is created (export-urdf) and from HDF5's file creation (data generate)."""
    import ineid._atomic

    out = tmp_path / "x.urdf"

    def refuse(path, suffix=""):
        raise OSError(errno.EROFS, "Read-only file system", str(temporary_path(path, suffix)))

    monkeypatch.setattr(ineid._atomic, "create_temporary", refuse)
    line = one_line(run("export-urdf", results, "--config", 2, "--out", out))
    assert line == f"Error: {out} is on a read-only file system; choose another --out"
    monkeypatch.undo()

    def h5_refuse(name, *a, **k):
        raise OSError(
            errno.EROFS,
            f"Unable to synchronously create file (unable to open file: name = '{name}', "
            "errno = 30, error message = 'Read-only file system', flags = 13, o_flags = 242)",
        )

    monkeypatch.setattr(h5py, "File", h5_refuse)
    out = tmp_path / "d.h5"
    line = one_line(run("-q", "data", "generate", "--n-configs", 2, "--n-frames", 2, "--out", out))
    assert line == f"Error: {out} is on a read-only file system; choose another --out"
    assert leftovers(tmp_path) == []


def test_permission_denied_output_folder(monkeypatch, tmp_path, results):
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        if os.geteuid() == 0:  # root ignores the mode: inject what a user would get

            def refuse(self, *a, **k):
                raise PermissionError(errno.EACCES, "Permission denied", str(self))

            monkeypatch.setattr(Path, "write_text", refuse)
        line = one_line(run("export-urdf", results, "--config", 2, "--out", folder / "x.urdf"))
        assert line.startswith(f"Error: permission denied: {folder / 'x.urdf'}") and "choose another --out" in line
        assert leftovers(folder) == []
    finally:
        folder.chmod(0o700)


def test_unreadable_input_names_the_file(monkeypatch, tmp_path, data):
    def refuse(name, *a, **k):
        raise PermissionError(
            errno.EACCES,
            f"Unable to synchronously open file (unable to open file: name = "
            f"'{name}', errno = 13, error message = 'Permission denied')",
        )

    monkeypatch.setattr(h5py, "File", refuse)
    line = one_line(run("data", "info", data))
    assert line.startswith(f"Error: permission denied: {data}")


# -- absurd option values ----------------------------------------------------------------------------


def test_noise_is_bounded_and_a_dataset_never_holds_inf(tmp_path, model):
    from ineid.data import Combination, DatasetSpec, NoiseModel, write_dataset
    from ineid.errors import DatasetError

    line = one_line(
        run("data", "generate", "--n-configs", 2, "--noise", "force=1e308", "--out", tmp_path / "d.h5"), code=2
    )
    assert "STD <= 1e+06" in line
    out = tmp_path / "lib.h5"  # the library, asked directly: refuses at the first chunk, writes nothing
    # about 7 % of the draws exceed 1.8 sigma (1.8e308 overflows): certain among 720
    spec = DatasetSpec(Combination("random", n_configs=40), n_frames=6, seed=1, noise=NoiseModel.create(4, force=1e308))
    with np.errstate(over="ignore"), pytest.raises(DatasetError, match="wrench would hold an infinite value"):
        write_dataset(model, spec, out)
    assert leftovers(tmp_path) == []


@pytest.fixture
def recording(tmp_path) -> Path:
    t = np.arange(0, 3, 0.01)
    q = 0.3 * np.sin(np.outer(t, [1.0, 1.3, 0.7, 2.0]))
    w = np.column_stack([np.sin(k * t) for k in range(1, 7)])
    rows = ["time,q1,q2,q3,q4,fx,fy,fz,mx,my,mz"] + [
        ",".join(f"{v:.6g}" for v in (t[i], *q[i], *w[i])) for i in range(len(t))
    ]
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def test_import_rate_and_delay_are_bounded(tmp_path, recording):
    out = tmp_path / "r.h5"
    line = one_line(run("data", "import", recording, "--robot", "sweaty-arm", "--rate", "1e9", "--out", out))
    assert "--rate 1e+09 Hz is more than 100 x the faster stream's rate (100 Hz)" in line and "at most 10000 Hz" in line
    line = one_line(run("data", "import", recording, "--robot", "sweaty-arm", "--delay", "1e300", "--out", out))
    assert "longer than the whole recording" in line
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "code", "words"),
    [
        (
            (
                "data",
                "generate",
                "--n-configs",
                2,
                "--frame-mode",
                "fourier",
                "--base-frequency",
                "inf",
                "--out",
                "OUT",
            ),
            2,
            "finite",
        ),
        (("data", "generate", "--n-configs", 2, "--com-box", "nan", "--out", "OUT"), 2, "finite"),
        (("data", "generate", "--n-configs", 2, "--harmonics", 10**6, "--out", "OUT"), 2, "1<=x<=1000"),
        (("data", "generate", "--n-configs", 10**12, "--out", "OUT"), 1, "configurations needs about"),
        (("data", "generate", "--n-configs", 100, "--n-frames", 10**7, "--out", "OUT"), 1, "use fewer frames"),
        (("excite", "sweaty-arm", "--duration", 10, "--rate", "1e9", "--out", "OUT"), 1, "10,000,000,000 samples"),
        (("excite", "sweaty-arm", "--duration", 10, "--starts", 10**9, "--out", "OUT"), 2, "--starts"),
        (("identifiability", "sweaty-arm", "--n-frames", 10**12), 1, "analysing 1,000,000,000,000 frames needs"),
        (("study", "noise", "--levels", "0,1e308", "--out", "OUT"), 2, "--levels"),
        (("train", "DATA", "--arch", "mlp", "--depth", 2, "--width", 10**9, "--out", "OUT"), 2, "too large"),
        (("train", "DATA", "--lr", "inf", "--out", "OUT"), 2, "finite"),
        (("solve", "DATA", "--workers", 10**6, "--out", "OUT"), 2, "--workers"),
        *[
            (("solve", "DATA", "--weights", "noise", "--sigma", v, 1, 1, 1, 1, 1, "--out", "OUT"), 2, "'--sigma'")
            for v in ("0", "-1", "nan", "inf")
        ],
        *[
            (("robot", "show", FIXTURES / "mixed_chain.urdf", "--lock", f"j2={v}"), 2, f"finite position, got 'j2={v}'")
            for v in ("nan", "inf", "-inf")
        ],
        (("train", "DATA", "--seed", 10**27, "--out", "OUT"), 2, "--seed"),
    ],
)
def test_absurd_values_are_refused(tmp_path, data, args, code, words):
    args = [data if a == "DATA" else tmp_path / "out" if a == "OUT" else a for a in args]
    line = one_line(run(*args), code=code)
    assert words in line, line
    assert leftovers(tmp_path) == []


def test_a_dataset_that_does_not_fit_in_memory(monkeypatch, data):
    import ineid._faults

    monkeypatch.setattr(ineid._faults, "available_memory", lambda: 10_000)
    line = one_line(run("-q", "solve", data, "--out", data.parent / "never.h5"))
    assert f"reading 40 configurations of {data} needs about" in line and "select fewer (--select)" in line


# -- damaged files -----------------------------------------------------------------------------------


def _copy_run(trained: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(trained, tmp_path / "run"))


def test_damaged_checkpoint_on_resume(tmp_path, data, trained):
    run_dir = _copy_run(trained, tmp_path)
    (run_dir / "checkpoint.msgpack").write_bytes((trained / "checkpoint.msgpack").read_bytes()[:100])
    line = one_line(run("-q", "train", data, *TRAIN, "--out", run_dir, "--resume"))
    assert line.startswith(f"Error: {run_dir / 'checkpoint.msgpack'} is damaged (truncated, corrupt")
    assert "--overwrite) or restore the file" in line


@pytest.mark.parametrize("text", ["{garbage", "", "[1, 2]", '{"train": {}}'])
def test_damaged_config_on_resume_and_evaluate(tmp_path, data, trained, text):
    run_dir = _copy_run(trained, tmp_path)
    (run_dir / "config.json").write_text(text)
    for args in (("train", data, *TRAIN, "--out", run_dir, "--resume"), ("evaluate", run_dir, data, "--overwrite")):
        line = one_line(run("-q", *args))
        assert line.startswith(f"Error: {run_dir / 'config.json'} is damaged ("), line


def test_damaged_model_scalers_and_metrics(tmp_path, data, trained):
    run_dir = _copy_run(trained, tmp_path)
    (run_dir / "model.msgpack").write_bytes(b"\x00" * 10)
    assert "model.msgpack is damaged" in one_line(run("-q", "evaluate", run_dir, data, "--overwrite"))
    shutil.copy(trained / "model.msgpack", run_dir / "model.msgpack")
    (run_dir / "scalers.json").write_text('{"x": 1}')
    assert "scalers.json is damaged (it needs the objects x and y)" in one_line(
        run("-q", "evaluate", run_dir, data, "--overwrite")
    )
    shutil.copy(trained / "scalers.json", run_dir / "scalers.json")
    with (run_dir / "metrics.jsonl").open("a") as fh:
        fh.write('{"epoch": \n')
    line = one_line(run("-q", "train", data, *TRAIN, "--out", run_dir, "--resume"))
    assert "metrics.jsonl is damaged (line 4 is not a JSON record with an epoch)" in line


def _damage(src: Path, dst: Path, fn) -> Path:
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as f:
        fn(f)
    return dst


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda f: f.__delitem__("theta_hat"), "dataset 'theta_hat' is missing"),
        (lambda f: f.attrs.__delitem__("settings"), "attribute 'settings' is missing"),
        (lambda f: f.attrs.__setitem__("settings", "{nope"), "attribute 'settings' is not JSON"),
        (lambda f: f.attrs.__setitem__("version", "x"), "attribute 'version' is not an integer"),
        (
            lambda f: (f.__delitem__("theta_std"), f.__setitem__("theta_std", np.zeros((3, 5)))),
            "dataset 'theta_std' is float64 of shape (3, 5), expected numbers of shape (2 x 20)",
        ),
        (
            lambda f: (
                f.__delitem__("base_hat"),
                f.__setitem__("base_hat", np.full((2, 17), "a", h5py.string_dtype())),
            ),
            "dataset 'base_hat' is text",
        ),
    ],
)
def test_damaged_results_file(tmp_path, results, damage, words):
    path = _damage(results, tmp_path / "r.h5", damage)
    for args in (("results", "info", path), ("export-urdf", path, "--config", 2, "--out", tmp_path / "x.urdf")):
        line = one_line(run(*args))
        assert line.startswith(f"Error: {path}: ") and words in line and "solve again" in line, line
    assert leftovers(tmp_path) == ["r.h5"]


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda f, q: f.__setitem__("q", q.astype(str).astype(object).astype(h5py.string_dtype())), "q holds text"),
        (lambda f, q: f.__setitem__("q", q.astype("S8")), "q holds text (bytes)"),
        (lambda f, q: f.__setitem__("q", (1000 * q).astype(np.int32)), "q holds integers"),
        (lambda f, q: f.__setitem__("q", q.astype(np.complex128)), "q holds complex numbers"),
        (lambda f, q: f.create_group("q"), "'q' is a group, not an array"),
    ],
)
def test_dataset_of_wrong_types(tmp_path, data, damage, words):
    def rewrite(f):
        q = f["q"][()]
        del f["q"]
        damage(f, q)

    path = _damage(data, tmp_path / "d.h5", rewrite)
    for args in (("data", "info", path), ("solve", path, "--out", tmp_path / "r.h5")):
        line = one_line(run("-q", *args))
        assert line.startswith(f"Error: {path}: ") and words in line, line
    assert leftovers(tmp_path) == ["d.h5"]


def test_truncated_dataset_and_results(tmp_path, data, results):
    for src, commands in ((data, (("data", "info"), ("solve",))), (results, (("results", "info"), ("export-urdf",)))):
        path = tmp_path / src.name
        path.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
        for command in commands:
            extra = ("--config", 2) if command == ("export-urdf",) else ()
            outs = () if "info" in command else ("--out", tmp_path / "out")
            assert "is not a readable HDF5 file" in one_line(run("-q", *command, path, *extra, *outs))


def test_damaged_parsed_urdf_in_the_cache_is_parsed_again():
    import json

    from ineid.robots.urdf import parse_chain
    from ineid.robots.urdf_cache import chain_file, chain_key

    data = (FIXTURES / "mixed_chain.urdf").read_bytes()
    good = parse_chain(data, "m.urdf")
    path = chain_file(chain_key(data, "m.urdf", None))
    doc = json.loads(path.read_text())
    for bad in ({**doc, "joints": []}, {**doc, "joints": [{**doc["joints"][0], "theta": [1, 2]}]}, {**doc, "name": 5}):
        path.write_text(json.dumps(bad))
        again = parse_chain(data, "m.urdf")
        assert [j.name for j in again.joints] == [j.name for j in good.joints]
        assert json.loads(path.read_text()) == doc  # rewritten whole
