"""Cross-cutting: nothing lost; outputs that are inputs, replacement only when complete, one writer per output,
stale temporaries, interruptions (130 / 143 and what they leave), resumable sweeps."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from ineid._atomic import lock_path, output_lock, remove_stale_temporaries

TRAIN = ("--arch", "simple", "--batch", "16", "--train-configs", "12", "--val-configs", "4", "--patience", "0")


def last_line(result, code):
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    return [line for line in result.output.splitlines() if line.strip()][-1]


def dead_pid() -> int:
    """A process id no process has now."""
    for pid in range(999999, 900000, -1):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            continue
    raise AssertionError("no free pid")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """20 configurations x 4 frames of sweaty-arm: enough for a network of a few epochs."""
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    path = tmp_path_factory.mktemp("outputs") / "d.h5"
    write_dataset(
        ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=20), n_frames=4, seed=3), path
    )
    return path


def snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


# -- an output that is an input ------------------------------------------------------------------


def test_solve_refuses_to_replace_its_dataset(run, data, tmp_path):
    before = data.read_bytes()
    line = last_line(run("solve", data, "--out", data, "--overwrite"), 1)
    assert line == f"Error: --out {data} is the input dataset; choose another file"
    link = tmp_path / "link.h5"  # another name for the same file
    link.symlink_to(data)
    line = last_line(run("solve", data, "--out", link, "--overwrite"), 1)
    assert line == f"Error: --out {link} is the input dataset; choose another file"
    assert data.read_bytes() == before
    line = last_line(run("solve", data, "--out", tmp_path / "r.png", "--plot", tmp_path / "r.png"), 1)
    assert line == f"Error: --plot {tmp_path / 'r.png'} is the results file (--out); choose another file"


@pytest.mark.parametrize("case", ["import", "trajectory", "export", "evaluate", "excite", "train"])
def test_other_commands_refuse_an_input_as_output(run, tmp_path, case):
    src = tmp_path / "in.file"
    src.write_text("time,q1\n")
    (tmp_path / "run").mkdir()
    model = tmp_path / "run" / "model.msgpack"
    model.write_bytes(b"weights")
    urdf = tmp_path / "arm.urdf"
    from ineid.robots import BUILTIN_ROBOTS

    urdf.write_text(BUILTIN_ROBOTS["sweaty-arm"].urdf_path.read_text())
    args, out, what = {
        "import": (("data", "import", src, "--robot", "sweaty-arm", "--out", src), src, "the input recording"),
        "trajectory": (
            ("data", "generate", "--frame-mode", "trajectory", "--trajectory", src, "--out", src),
            src,
            "the trajectory file",
        ),
        "export": (("export-urdf", src, "--config", 0, "--out", src), src, "the input results file"),
        "evaluate": (("evaluate", tmp_path / "run", src, "--out", model), model, "the input run's model.msgpack"),
        "excite": (("excite", urdf, "--duration", 2, "--out", urdf), urdf, "the robot's URDF"),
        "train": (("train", tmp_path / "run" / "config.json", "--out", tmp_path / "run"), None, None),
    }[case]
    if case == "train":  # a dataset named like a file of the run folder that --out replaces
        data = tmp_path / "run" / "config.json"
        data.write_text("{}")
        line = last_line(run(*args, "--overwrite"), 1)
        assert line == (
            f"Error: --out {tmp_path / 'run'} would replace {data}, the input dataset; choose another folder"
        )
        return
    before = out.read_bytes()
    line = last_line(run(*args, "--overwrite"), 1)
    assert line == f"Error: --out {out} is {what}; choose another file"
    assert out.read_bytes() == before


# -- one writer per output ---------------------------------------------------------------------------


def hold_lock(path, pid: int = 4242):
    """Lock ``path`` as another process would (a separate open file: flock excludes it even in this process)."""
    fd = os.open(lock_path(path), os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.write(fd, f"{pid}\n".encode())
    return fd


def test_a_second_writer_gets_one_line(run, data, tmp_path):
    out = tmp_path / "same.h5"
    out.write_bytes(b"the first writer's result")
    fd = hold_lock(out)
    try:
        line = last_line(run("data", "generate", "--n-configs", 2, "--n-frames", 2, "--out", out, "--overwrite"), 1)
        assert line == f"Error: another ineid process (pid 4242) is writing {out}; wait for it or choose another --out"
        line = last_line(run("solve", data, "--out", out, "--overwrite"), 1)
        assert "another ineid process (pid 4242) is writing" in line
    finally:
        os.close(fd)
    assert out.read_bytes() == b"the first writer's result"
    fd = hold_lock(tmp_path / "run", 77)
    try:
        line = last_line(run("train", data, *TRAIN, "--epochs", 1, "--out", tmp_path / "run"), 1)
        assert line == (
            f"Error: another ineid process (pid 77) is writing {tmp_path / 'run'}; wait for it or choose another --out"
        )
    finally:
        os.close(fd)
    assert not (tmp_path / "run").exists()
    # released: the lock file goes with its holder, and the library takes the lock again
    with output_lock(out):
        assert lock_path(out).read_text().strip() == str(os.getpid())
        with output_lock(out):  # re-entrant in one process
            pass
    assert not lock_path(out).exists()


def test_two_processes_writing_one_file(tmp_path):
    """Real processes: the second stops at once with the line, the first finishes its file."""
    out = tmp_path / "same.h5"
    code = (
        "import sys; from ineid._atomic import output_lock, atomic_write\n"
        "with output_lock(sys.argv[1]):\n    print('locked', flush=True); sys.stdin.readline()\n"
        "    atomic_write(sys.argv[1], 'first')\n"
    )
    first = subprocess.Popen(
        [sys.executable, "-c", code, out], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert first.stdout.readline().strip() == "locked"
        second = subprocess.run(
            [
                sys.executable,
                "-m",
                "ineid.cli",
                "data",
                "generate",
                "--n-configs",
                "2",
                "--n-frames",
                "2",
                "--out",
                out,
            ],
            capture_output=True,
            text=True,
        )
    finally:
        first.communicate("go\n", timeout=30)
    assert second.returncode == 1
    assert second.stderr.strip() == (
        f"Error: another ineid process (pid {first.pid}) is writing {out}; wait for it or choose another --out"
    )
    assert out.read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["same.h5"]


# -- what killed runs left ------------------------------------------------------------------------------


def test_stale_temporaries_are_removed_by_the_next_write(run, tmp_path):
    pid = dead_pid()
    out = tmp_path / "x.h5"
    stale = tmp_path / f".x.h5.ineid-{pid}-0123abcd.tmp"
    stale.write_bytes(b"\0" * 2_500_000)
    (tmp_path / f".x.h5.ineid-{pid}-4567cdef.tmp.h5").write_bytes(b"h5")  # atomic_output's, with the output's suffix
    kept = [
        f".x.h5.ineid-{os.getppid()}-0123abcd.tmp",  # a live process's
        f".xx.h5.ineid-{pid}-0123abcd.tmp",  # another output's
        f".x.h5.ineid-{pid}-0123abcd.tmp.png",  # not a suffix ineid gives this output's temporaries
        ".x.h5.4000000.tmp.notes",  # the user's, named like a temporary of another scheme
        f".x.h5.{pid}.tmp",
    ]
    for name in kept:
        (tmp_path / name).write_bytes(b"mine")
    r = run("data", "generate", "--n-configs", 2, "--n-frames", 2, "--out", out)
    assert r.exit_code == 0, r.output
    assert (
        f"ineid: removed a stale temporary file {stale.name} (2.5 MB) left by an interrupted ineid run"
        in r.output.splitlines()
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["x.h5", *kept])
    assert all((tmp_path / name).read_bytes() == b"mine" for name in kept)
    # a folder killed between the two renames of a swap: the old one is moved back
    run_dir = tmp_path / "run"
    (tmp_path / f".run.ineid-{pid}-0123abcd.old").mkdir()
    (tmp_path / f".run.ineid-{pid}-0123abcd.old" / "model.msgpack").write_bytes(b"old")
    (tmp_path / f".run.ineid-{pid}-4567cdef.tmp").mkdir()
    assert len(remove_stale_temporaries(run_dir)) == 2
    assert (run_dir / "model.msgpack").read_bytes() == b"old"
    assert not any(p.name.startswith(".run.") for p in tmp_path.iterdir())


# -- runs: replaced only when complete; interruptions ---------------------------------------------------


def test_train_overwrite_interrupted_keeps_the_old_run(run, data, tmp_path, monkeypatch):
    import ineid.learn.runs as runs
    from ineid.data import load_dataset
    from ineid.learn import ModelSpec, TrainConfig, load_run, train

    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    cfg = TrainConfig(ModelSpec("simple"), batch=16, n_train=12, n_val=4, patience=0, epochs=2)
    train(load_dataset(data), cfg, out, overwrite=True)  # replaces the folder once finished, keeping notes.txt
    before = snapshot(out)
    assert set(before) == {
        "notes.txt",
        "config.json",
        "scalers.json",
        "metrics.jsonl",
        "checkpoint.msgpack",
        "model.msgpack",
    }
    save_state = runs.save_state

    def interrupted(run_dir, state, final=False):
        if int(state["epoch"]) == 2:
            raise KeyboardInterrupt
        save_state(run_dir, state, final)

    monkeypatch.setattr(sys.modules["ineid.learn.train"], "save_state", interrupted)
    line = last_line(run("train", data, *TRAIN, "--epochs", 3, "--out", out, "--overwrite"), 130)
    assert line == f"ineid: interrupted; {out} keeps its previous run, untouched (the new one was not finished)"
    assert snapshot(out) == before
    assert load_run(out).config.epochs == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no lock file, no half-trained folder
    # a new run interrupted after its first checkpoint is kept, and the line says how to continue
    line = last_line(run("train", data, *TRAIN, "--epochs", 3, "--out", tmp_path / "new"), 130)
    assert line == (
        f"ineid: interrupted; the run in {tmp_path / 'new'} can be continued with `ineid train {data} ... "
        f"--out {tmp_path / 'new'} --resume` (the same settings)"
    )
    assert (tmp_path / "new" / "checkpoint.msgpack").is_file()


def test_train_overwrite_interrupted_during_the_swap_ends_with_the_new_run(run, data, tmp_path, monkeypatch):
    """Ctrl-C while the finished run is swapped in is held back until the new run is in place; the line says so."""
    import ineid._atomic as atomic
    import ineid.learn

    out = tmp_path / "run"
    out.mkdir()
    (out / "model.msgpack").write_bytes(b"the previous run")
    evaluate = ineid.learn.evaluate  # without the least-squares comparisons: what is tested is the swap
    monkeypatch.setattr(ineid.learn, "evaluate", lambda r, ds, model=None: evaluate(r, ds, model=model, linear=False))
    make = atomic.create_temporary_folder

    def signalled(path, kind="tmp"):  # the folder the old run is set aside in is made inside the swap
        if kind == "old":
            signal.raise_signal(signal.SIGINT)  # to this (main) thread
        return make(path, kind)

    monkeypatch.setattr(atomic, "create_temporary_folder", signalled)
    line = last_line(run("-q", "train", data, *TRAIN, "--epochs", 1, "--out", out, "--overwrite"), 130)
    assert line == f"ineid: interrupted; {out} holds the new run, complete (it had replaced the previous one)"
    assert (out / "model.msgpack").read_bytes() != b"the previous run" and (out / "evaluation.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_train_sigterm_exits_143(data, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ineid.cli", "-q", "train", data, *TRAIN, "--epochs", "100000", "--out", out],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (out / "checkpoint.msgpack").is_file() and proc.poll() is None:
        time.sleep(0.1)
    assert (out / "checkpoint.msgpack").is_file(), proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == (
        f"ineid: terminated (SIGTERM); the run in {out} can be continued with "
        f"`ineid train {data} ... --out {out} --resume` (the same settings)"
    )


# -- sweeps ------------------------------------------------------------------------------------------------


def test_sweep_resumes(run, data, tmp_path, monkeypatch):
    import ineid.learn  # noqa: F401  (the modules patched below)

    sweep_module = sys.modules["ineid.learn.trials"]  # run_population's module (it calls train_population, evaluate)
    train_module = sys.modules["ineid.learn.train"]  # (ineid.learn.train is also the function's name)

    out = tmp_path / "sweep"
    args = (
        "sweep",
        data,
        "--archs",
        "simple",
        "--scalers",
        "robust,standard",
        "--epochs",
        3,
        "--batch",
        16,
        "--train-configs",
        12,
        "--val-configs",
        4,
        "--patience",
        0,
        "--out",
        out,
    )
    evaluate = sweep_module.evaluate  # without the least-squares comparisons: what is tested is which trials train
    monkeypatch.setattr(
        sweep_module, "evaluate", lambda run, ds, model=None: evaluate(run, ds, model=model, linear=False)
    )
    save_state = train_module.save_state

    def interrupted(run_dir, state, final=False):
        if "standard" in run_dir.name and int(state["epoch"]) == 2:
            raise KeyboardInterrupt
        save_state(run_dir, state, final)

    monkeypatch.setattr(train_module, "save_state", interrupted)
    line = last_line(run(*args), 130)
    # the two trials differ only in their scaler: they train together, so neither had finished
    assert line == (
        f"ineid: interrupted; 0 of 2 trials in {out} are finished; continue the sweep with `ineid sweep "
        f"{data} ... --out {out} --resume` (the same settings)"
    )
    monkeypatch.setattr(train_module, "save_state", save_state)
    assert "different run settings" in last_line(run(*args[:-2], "--lr", 0.01, "--out", out, "--resume"), 1)
    calls = []
    train_population = sweep_module.train_population

    def counted(ds, trials, **kw):
        calls.extend((t.run_dir.name, t.resume) for t in trials)
        return train_population(ds, trials, **kw)

    monkeypatch.setattr(sweep_module, "train_population", counted)
    r = run(*args, "--resume")
    assert r.exit_code == 0, r.output
    # both continued from their checkpoints (epoch 2 and epoch 1), together
    assert calls == [("simple-tanh-single-robust-adam-mse", True), ("simple-tanh-single-standard-adam-mse", True)]
    rows = (out / "sweep.csv").read_text().splitlines()
    assert len(rows) == 3 and all(",ok" in row for row in rows[1:])
    for scaler in ("robust", "standard"):
        metrics = (out / f"simple-tanh-single-{scaler}-adam-mse" / "metrics.jsonl").read_text().splitlines()
        assert [json.loads(m)["epoch"] for m in metrics] == [1, 2, 3]
    calls.clear()
    r = run(*args, "--resume")  # a finished sweep: every trial kept
    assert r.exit_code == 0 and calls == [], r.output


def test_a_signal_swallowed_by_a_gc_callback_is_delivered_again():
    """SIGTERM's exception raised inside a callback whose exceptions Python ignores (JAX's
    ``_xla_gc_callback``) used to be dropped, and the command ran on; the hook sends it again."""
    import signal
    import threading
    import types

    from ineid._atomic import Terminated, redeliver_ignored_interrupt

    got = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: got.set())
    try:
        redeliver_ignored_interrupt(types.SimpleNamespace(exc_value=Terminated("terminated by signal 15")))
        for _ in range(100):  # the handler runs in this (main) thread once the signal arrives
            if got.wait(0.01):
                break
        assert got.is_set()
    finally:
        signal.signal(signal.SIGTERM, old)


# -- names ineid makes up beside an output ----------------------------------------------------------------


def plant_links(out, victims):
    """A symbolic link at every name an older scheme gave the temporaries and the lock of ``out`` in this
    process (``.NAME.PID.tmp[.SUFFIX]``, ``.NAME.lock``), each to a file of its own in ``victims``."""
    names = [f".{out.name}.{os.getpid()}.tmp", f".{out.name}.{os.getpid()}.tmp{out.suffix}", f".{out.name}.lock"]
    for name in names:
        victim = victims / f"victim-of-{name}"
        victim.write_text("the user's data")
        (out.parent / name).symlink_to(victim)
    return [out.parent / name for name in names]


def test_links_planted_beside_an_output_are_never_followed(run, tmp_path):
    """data generate, solve, export-urdf and report, each with links planted at the names of its temporaries
    and lock: a link at the lock's name is refused in one line; the temporaries' are skipped; nothing they
    point at changes."""
    shared, victims = tmp_path / "shared", tmp_path / "victims"
    shared.mkdir(), victims.mkdir()
    data, results = shared / "d.h5", shared / "r.h5"
    commands = [
        ("data", "generate", "--factorial", 2, "--n-frames", 10, "--out", data),
        ("-q", "solve", data, "--out", results),
        ("export-urdf", results, "--config", 0, "--out", shared / "o.urdf"),
        ("report", results, "--out", shared / "o.html"),
    ]
    for args in commands:
        out = args[-1]
        links = plant_links(out, victims)
        refusal = f"Error: {links[-1]} is a symbolic link, not a lock file of ineid; remove it, or choose another --out"
        assert last_line(run(*args), 1) == refusal
        assert not out.exists()
        links[-1].unlink()
        r = run(*args)
        assert r.exit_code == 0, r.output
        assert out.is_file() and not out.is_symlink()
        assert all(link.is_symlink() for link in links[:-1])  # not ineid's: left as they were
        assert {p.read_text() for p in victims.iterdir()} == {"the user's data"}
    assert not [p.name for p in shared.iterdir() if ".ineid-" in p.name or p.name.endswith(".lock")]


def test_a_253_character_out_name_is_written(run, tmp_path):
    out = tmp_path / ("d" * 250 + ".h5")
    r = run("data", "generate", "--factorial", 2, "--n-frames", 10, "--out", out)
    assert r.exit_code == 0, r.output
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_report_refuses_to_replace_the_dataset_its_results_were_solved_on(run, tmp_path):
    data, results = tmp_path / "d.h5", tmp_path / "r.h5"  # as the test above makes them: its solver is compiled
    assert run("data", "generate", "--factorial", 2, "--n-frames", 10, "--out", data).exit_code == 0
    assert run("-q", "solve", data, "--out", results).exit_code == 0
    before = data.read_bytes()
    for command in (("report", results), ("export-urdf", results, "--config", 0)):
        line = last_line(run(*command, "--out", data, "--overwrite"), 1)
        assert line == f"Error: --out {data} is the dataset the results were solved on; choose another file"
    assert data.read_bytes() == before


def test_generate_refuses_to_replace_the_robot_file(run, tmp_path):
    from ineid.robots import BUILTIN_ROBOTS

    robot = tmp_path / "gen" / "sweaty_arm_jax.py"  # the name of a module generate writes for this robot
    robot.parent.mkdir()
    robot.write_text(BUILTIN_ROBOTS["sweaty-arm"].urdf_path.read_text())
    before = snapshot(robot.parent)
    line = last_line(run("generate", robot, "--out", robot.parent, "--overwrite"), 1)
    assert line == f"Error: --out {robot.parent} would replace {robot}, the robot file; choose another folder"
    assert snapshot(robot.parent) == before


def test_generate_interrupted_leaves_modules_that_match_their_manifest(run, tmp_path, monkeypatch):
    """Ctrl-C after generate's first module is written: exit 130 once all the modules and their
    manifest are written, never new modules beside the old manifest (which ineid would refuse to load)."""
    from ineid._trust import verified
    from ineid.generated import file_names
    from ineid.symbolic import emit

    gen, names = tmp_path / "gen", file_names("sweaty-arm")
    emit.write_files({name: f"# Generated by {emit.GENERATOR}: an older version\n" for name in names}, gen)
    write = emit.atomic_write

    def interrupted(path, data):
        write(path, data)
        signal.raise_signal(signal.SIGINT)  # to this (main) thread

    monkeypatch.setattr(emit, "atomic_write", interrupted)
    line = last_line(run("generate", "sweaty-arm", "--out", gen), 130)
    assert line == "ineid: interrupted; no partial output file was left"
    modules = verified(gen, names, private=False)  # the manifest matches every module
    assert all(b"an older version" not in text for text in modules.values())


def _can_mount() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("mount") is not None


@pytest.mark.skipif(not _can_mount(), reason="needs root to mount a small tmpfs")
def test_a_new_run_that_fills_the_disk_leaves_nothing(run, data, tmp_path):
    """A 56 KiB tmpfs holds the run's first checkpoint, not its second: the error is one line, and no
    folder is left (an interruption there would keep the run to resume; an error has nothing to resume)."""
    full = tmp_path / "full"
    full.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=56k", "tmpfs", str(full)], check=False).returncode:
        pytest.skip("mount failed")
    try:
        line = last_line(run("-q", "train", data, *TRAIN, "--epochs", 3, "--out", full / "run"), 1)
        assert line.startswith("Error: no space left on device writing ") and "choose another --out" in line
        assert os.listdir(full) == []
    finally:
        subprocess.run(["umount", str(full)], check=False)


def test_train_overwrite_terminated_after_its_last_epoch_keeps_the_old_run(data, tmp_path):
    """SIGTERM once the new run's model is written, while it is evaluated: the evaluation is part of the
    new run, built beside the old one, so the old run is untouched and nothing else is left."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.msgpack").write_bytes(b"the previous run")
    (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    args = [sys.executable, "-m", "ineid.cli", "-q", "train", data, *TRAIN, "--epochs", "2", "--out", out]
    proc = subprocess.Popen([*args, "--overwrite"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def new_model() -> bool:  # the new run's model, wherever the run is built
        models = [*tmp_path.glob(".run.*/model.msgpack"), out / "model.msgpack"]
        return any(m.is_file() and m.read_bytes() != b"the previous run" for m in models)

    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and not new_model():
        time.sleep(0.02)
    assert new_model(), proc.communicate()
    time.sleep(0.2)  # into the evaluation (a second or more), past the moment a run is swapped in right after training
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    left = f"ineid: terminated (SIGTERM); {out} keeps its previous run, untouched (the new one was not finished)"
    assert err.strip().splitlines()[-1] == left
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
