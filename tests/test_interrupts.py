"""Ctrl-C and SIGTERM inside a solver (a cross-cutting feature test): IPOPT through CasADi catches what its
Python callbacks raise and CasADi's own ``KeyboardInterruptException``; ineid still stops within an
iteration, exits 130 / 143 with one line and leaves the previous output as it was."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ineid._interrupts import Terminated, terminate_on_sigterm

REPO = Path(__file__).resolve().parents[1]

SIGNALS = [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)]


@pytest.fixture
def ineid_handlers():
    """ineid's SIGTERM and SIGINT handlers, as the command installs them; the test process's put back after."""
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    hook = sys.unraisablehook
    terminate_on_sigterm()
    yield
    for s, handler in old.items():
        signal.signal(s, handler)
    sys.unraisablehook = hook


def callback_problem(n: int = 20, signal_at: int | None = None, signum: int = signal.SIGTERM):
    """An IPOPT problem whose objective is a Python :class:`casadi.Callback` (as the excitation design's):
    ``(solver, calls)``; the callback sends ``signum`` to this process on evaluation ``signal_at``."""
    import casadi as ca

    from ineid.identify.ipopt import nlpsol

    calls = []

    class Objective(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("objective", {"enable_fd": True})

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(n, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(1, 1)

        def eval(self, arg):
            calls.append(1)
            if len(calls) == signal_at:
                signal.raise_signal(signum)  # to this (main) thread: the handler runs here, inside IPOPT's evaluation
            x = np.asarray(arg[0]).ravel()
            return [float(np.sum((x - 1.0) ** 4) + np.sum(x[:-1] * x[1:]) ** 2)]

    objective = Objective()
    x = ca.MX.sym("x", n)
    opts = {
        "print_time": False,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.hessian_approximation": "limited-memory",
        "ipopt.max_iter": 200,
    }
    return nlpsol("callback", {"x": x, "f": objective(x)}, opts, keep=(objective,)), calls


@pytest.mark.parametrize(("signum", "raised"), SIGNALS, ids=["SIGTERM", "SIGINT"])
def test_a_signal_in_a_python_callback_stops_ipopt(ineid_handlers, capfd, signum, raised):
    solver, calls = callback_problem()
    solver(x0=np.zeros(20))
    full_iterations, full_calls = solver.stats()["iter_count"], len(calls)
    assert full_iterations > 10
    capfd.readouterr()

    per_iteration = full_calls / full_iterations  # finite differences: some 90 evaluations
    solver, calls = callback_problem(signal_at=100, signum=signum)
    with pytest.raises(raised):
        for _ in range(3):  # further starts are never begun
            solver(x0=np.zeros(20))
    stats = solver.stats()
    assert stats["return_status"] == "User_Requested_Stop"
    assert stats["iter_count"] < 5 < full_iterations
    assert len(calls) < 100 + 2 * per_iteration  # the rest of the iteration it was in, at most
    out, err = capfd.readouterr()
    assert out + err == ""  # no CasADi warning, no traceback: the exception was never raised inside IPOPT


def test_ctrl_c_in_a_library_call_stops_ipopt(capfd):
    """Without ineid's handlers (a script calling the library), Python's own SIGINT handler is stood in for
    during the solve, and put back."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)  # (a command run in this process set ineid's)
    try:
        solver, _ = callback_problem(signal_at=21, signum=signal.SIGINT)
        with pytest.raises(KeyboardInterrupt):
            solver(x0=np.zeros(20))
        assert solver.stats()["return_status"] == "User_Requested_Stop"
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, old)
    assert capfd.readouterr().err == ""


def test_sigterm_while_ipopt_runs_in_c(ineid_handlers, capfd):
    """A problem all in CasADi's SX (as the consistent solver's): the signal reaches Python at CasADi's own
    check between iterations, which would raise KeyboardInterruptException inside IPOPT and fail only that solve."""
    import casadi as ca

    from ineid.identify.ipopt import nlpsol

    n = 200
    x = ca.SX.sym("x", n)
    f = ca.sum1(100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2)  # Rosenbrock's: L-BFGS takes ~1,000 iterations
    solver = nlpsol(
        "rosenbrock",
        {"x": x, "f": f},
        {
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.hessian_approximation": "limited-memory",
            "ipopt.max_iter": 3000,
            "ipopt.tol": 1e-14,
        },
    )
    timer = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(Terminated):
            for _ in range(3):
                solver(x0=np.tile([-1.2, 1.0], n // 2))
    finally:
        timer.cancel()
    assert time.perf_counter() - t0 < 1.5  # stopped within an iteration of the signal, not after ~1 s per solve
    assert solver.stats()["return_status"] == "User_Requested_Stop"
    assert capfd.readouterr().err == ""


def test_nested_blocks_raise_once_at_the_outermost_end(ineid_handlers):
    from ineid._interrupts import interruptible, stop_requested

    with pytest.raises(KeyboardInterrupt):
        with interruptible():
            with interruptible():
                signal.raise_signal(signal.SIGINT)  # to this (main) thread
                time.sleep(0.01)  # the handler runs, records
                assert stop_requested()
            assert stop_requested()  # the inner block's end raised nothing
    assert not stop_requested()
    with interruptible():  # nothing stale is left for the next block
        pass


def test_a_sigint_taken_by_a_c_library_is_taken_back(ineid_handlers):
    """A C library that installs its own SIGINT handler (sigaction, behind Python's back: Python still reports its
    own) would swallow Ctrl-C; ineid's blocks install Python's again, so the signal is recorded and raised."""
    import ctypes

    from ineid._interrupts import interruptible, stop_requested

    libc = ctypes.CDLL(None)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = (ctypes.c_int, ctypes.c_void_p)
    libc.signal(signal.SIGINT, 1)  # SIG_IGN, where Python's handler is still reported
    with pytest.raises(KeyboardInterrupt):
        with interruptible():
            signal.raise_signal(signal.SIGINT)  # to this (main) thread
            time.sleep(0.01)
            assert stop_requested()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # blocked in this thread: it would stay pending
    try:
        with pytest.raises(KeyboardInterrupt):
            with interruptible():
                signal.raise_signal(signal.SIGINT)  # to this (main) thread
                time.sleep(0.01)
                assert stop_requested()
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


# -- the command, in a real process --------------------------------------------------------------------------


def child(args, cwd):
    """``ineid -v ARGS`` in a process group of its own (the session's cache: compiled kernels are reused)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.Popen(
        [sys.executable, "-m", "ineid.cli", "-v", *map(str, args)],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def interrupt_in_ipopt(args, cwd, signum, outputs, after=0.3, group=False, before_signal=None):
    """Run ``args``, send ``signum`` ``after`` seconds into its IPOPT solves (the ``-v`` line ``IPOPT: ...``;
    to its whole process group with ``group``, as a terminal's Ctrl-C), and check that it stops with the one
    line and exit status, ``outputs`` byte for byte as before and no temporary file beside them. Returns the
    seconds from the signal to the exit."""
    before = {p: p.read_bytes() for p in outputs}
    proc = child(args, cwd)
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if line.startswith("ineid: IPOPT:"):
            break
    else:
        pytest.fail(f"the solver never started: {proc.communicate()}\n{''.join(seen)}")
    time.sleep(after)
    if before_signal is not None:
        before_signal(proc.pid)
    if group:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    t0 = time.perf_counter()
    out, err = proc.communicate(timeout=60)
    seconds = time.perf_counter() - t0
    code, line = {
        signal.SIGTERM: (143, "ineid: terminated (SIGTERM); no partial output file was left"),
        signal.SIGINT: (130, "ineid: interrupted; no partial output file was left"),
    }[signum]
    assert proc.returncode == code, out + err
    assert err.strip().splitlines()[-1] == line, err
    assert not any(w in err for w in ("Traceback", "CasADi", "WARNING", "Exception ignored")), err
    assert "wrote" not in out
    assert {p: p.read_bytes() for p in outputs} == before
    assert sorted(p.name for p in cwd.iterdir()) == sorted(p.name for p in cwd.iterdir() if not p.name.startswith("."))
    return seconds


def previous(folder: Path, *names: str) -> list[Path]:
    """Files standing for a previous run's outputs."""
    paths = [folder / name for name in names]
    for p in paths:
        p.write_bytes(b"the previous output of " + p.name.encode())
    return paths


EXCITE = ("excite", "sweaty-arm", "--duration", 4, "--harmonics", 3, "--starts", 4, "--out", "t.csv", "--overwrite")


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (Linux /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text()
        except (OSError, ValueError):
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_excite_interrupted_in_ipopt_keeps_the_previous_design_and_stops_its_workers(tmp_path, signum):
    """Interrupted while its starts run here and in a worker process (Ctrl-C reaches the whole process group, SIGTERM
    only the command): the previous design stays, and the worker is gone with the command."""
    lanes = []
    seconds = interrupt_in_ipopt(
        (*EXCITE, "--workers", 2),
        tmp_path,
        signum,
        previous(tmp_path, "t.csv", "t.json"),
        group=signum == signal.SIGINT,
        before_signal=lambda pid: lanes.extend(_children(pid)),
    )
    assert seconds < 10  # within an iteration (plus the exit), not after every start
    assert lanes, "no worker process was running"
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in lanes) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in lanes)


@pytest.fixture(scope="module")
def many(tmp_path_factory):
    """200 configurations x 10 frames of sweaty-arm: seconds of consistent IPOPT solves (interrupted early)."""
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    path = tmp_path_factory.mktemp("interrupts") / "many.h5"
    write_dataset(
        ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=200), n_frames=10, seed=3), path
    )
    return path


def test_solve_sigterm_in_ipopt_keeps_the_previous_results_and_report(many, tmp_path):
    args = (
        "solve",
        many,
        "--method",
        "consistent",
        "--workers",
        1,
        "--out",
        "o.h5",
        "--report",
        "o.html",
        "--overwrite",
    )
    seconds = interrupt_in_ipopt(args, tmp_path, signal.SIGTERM, previous(tmp_path, "o.h5", "o.html"), after=0.2)
    assert seconds < 10  # within an iteration (plus the exit), not after every configuration


@pytest.mark.slow  # 2,000 configurations and worker processes started (~15 s)
@pytest.mark.parametrize(
    ("signum", "group"), [(signal.SIGTERM, False), (signal.SIGINT, True)], ids=["SIGTERM", "SIGINT-to-the-group"]
)
def test_solve_workers_stop_at_once(tmp_path, signum, group):
    """With worker processes the main process stops them: the queued blocks are dropped and the running ones
    end at their next configuration, instead of the pool solving every block first (seconds here); a Ctrl-C
    that reaches the workers too is left to the main process (no worker's traceback, no CasADi warning)."""
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    data = tmp_path / "data" / "many.h5"
    data.parent.mkdir()
    write_dataset(
        ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=2000), n_frames=10, seed=3), data
    )
    args = ("solve", data, "--method", "consistent", "--workers", 2, "--out", "o.h5", "--overwrite")
    seconds = interrupt_in_ipopt(args, tmp_path, signum, previous(tmp_path, "o.h5"), after=1.0, group=group)
    assert seconds < 3


def test_a_local_ray_cluster_leaves_ineids_sigterm_handler(ineid_handlers, tmp_path, monkeypatch):
    """Ray's head node, started in this process by ``ray.init``, installs a SIGTERM handler that exits 1 without a
    line; the ray engine puts ineid's back (and stops the cluster on the way out)."""
    import types

    from ineid.learn import ModelSpec, TrainConfig, ray_engine

    ours = signal.getsignal(signal.SIGTERM)
    seen = []

    def init(**_):
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))

    def get(ref):
        raise RuntimeError("the trial failed")

    task = types.SimpleNamespace(options=lambda **_: task, remote=lambda *args: object())
    fake = types.SimpleNamespace(
        is_initialized=lambda: False,
        init=init,
        shutdown=lambda: seen.append("shutdown"),
        remote=lambda fn: task,
        put=lambda x: x,
        get=get,
        wait=lambda refs, num_returns: seen.append(signal.getsignal(signal.SIGTERM)) or ([refs[0]], refs[1:]),
        exceptions=types.SimpleNamespace(RayError=RuntimeError),
    )
    monkeypatch.setitem(sys.modules, "ray", fake)
    rows = ray_engine.ray_trials(
        None, [TrainConfig(model=ModelSpec("simple"))], tmp_path / "sweep", ray_init={"num_cpus": 1}
    )
    assert rows[0].status.startswith("failed")
    assert seen == [ours, "shutdown"]
