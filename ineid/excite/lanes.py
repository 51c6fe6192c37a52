"""The starts of an excitation search in worker processes beside the calling one.

IPOPT starts are independent: each begins at its own candidate and shares nothing with the
others but the problem. On a machine with more than one core, :func:`ineid.excite.design_excitation`
therefore runs them in ``workers - 1`` *lanes*, worker processes started (a fresh interpreter,
nothing inherited but what is sent) as the design begins, so that each builds its copy of the
problem while the calling process checks the bounds and draws the candidates. A lane receives the
model (pickled by reference to its generated code, :meth:`ineid.RobotModel.__reduce__`), the
settings, the noise and the timing, builds the same problem (:func:`ineid.excite.design._problem_setup`
is deterministic), and then solves each start it is sent with the same solver options and sends
back its outcome. The design is therefore the same, start for start and bit for bit, whatever ran
where; the calling process solves starts too, and gives a lane a start only while more than one is
left, so a lane never holds up the last start.

A lane runs in a session of its own, so a terminal's Ctrl-C reaches only the calling process, which
decides; the lane is terminated when the calling process stops the search, interrupted or not. (Killed
outright, the calling process leaves its lanes to finish the start they solve; they exit when they find
its socket closed.) Lanes are for Linux, where a lane (``python -c``, :data:`_BOOT`) takes about a
second to import ineid and build its problem; elsewhere, and with ``workers=1``, every start runs in
the calling process.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

import numpy as np

from ineid.errors import ExcitationError

JOIN_SECONDS = 2.0
"""How long a lane may take to exit once told to, before it is terminated."""


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity where the system tells, else the CPU count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def default_workers(starts: int) -> int:
    """Processes for ``starts`` starts: one per usable CPU, at most one per start; one off Linux (or where this
    Python cannot start itself: no ``sys.executable``)."""
    if not sys.platform.startswith("linux") or not sys.executable:
        return 1
    return max(1, min(starts, usable_cpus()))


class LanesUnavailable(RuntimeError):
    """The lanes cannot run here (the problem does not pickle, or no process starts): the starts run in the calling
    process instead."""


_BOOT = (
    "import sys\n"
    "from multiprocessing.connection import Connection\n"
    "conn = Connection(int(sys.argv[1]))\n"
    "sys.path[:] = conn.recv()\n"
    "from ineid.excite.lanes import _lane_main\n"
    "_lane_main(conn)\n"
)
"""A lane's program: the calling process's import path, then :func:`_lane_main` on the socket it was given."""


class Lanes:
    """``count`` worker processes, each with its copy of the problem ``build(*args)`` (``build`` a module-level
    function, pickled by name, returning ``(problem, safety, max_iter, tol)``: :mod:`module doc
    <ineid.excite.lanes>`); a context manager that terminates them on leaving.

    Each is ``python -c`` :data:`_BOOT` with a socket to this process (not :mod:`multiprocessing`'s spawn,
    which would import the caller's main script again: a script without an ``if __name__ == "__main__"``
    guard would run twice). :meth:`submit` sends a start to an idle lane, :meth:`collect` returns the
    outcomes that came back.
    """

    def __init__(self, build: Callable, args: tuple, count: int) -> None:
        import pickle
        import socket
        import subprocess
        from multiprocessing.connection import Connection

        self._lanes = []
        try:
            job = pickle.dumps((build, args))
        except Exception as e:  # a model whose generated code ineid did not load itself, say: no lanes
            raise LanesUnavailable(f"the problem cannot be sent to a worker process ({type(e).__name__}: {e})") from e
        try:
            for _ in range(count):
                mine, theirs = socket.socketpair()
                proc = subprocess.Popen(
                    [sys.executable, "-c", _BOOT, str(theirs.fileno())],
                    pass_fds=(theirs.fileno(),),
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,  # IPOPT and CasADi print nothing there; the caller's output is its own
                    stderr=subprocess.PIPE,  # empty unless the lane dies: then its last line names why (collect)
                    start_new_session=True,  # a terminal's Ctrl-C is the caller's to handle, even while Python starts
                )
                theirs.close()
                conn = Connection(mine.detach())
                self._lanes.append([proc, conn, None])  # process, connection, the start it solves (None: idle)
                conn.send(list(sys.path))
                conn.send_bytes(job)
        except OSError as e:  # no process could be started (resources, no executable)
            self.close()
            raise LanesUnavailable(f"no worker process could be started ({e})") from e
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Lanes:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self._lanes)

    def idle(self) -> int:
        """How many lanes wait for a start."""
        return sum(1 for lane in self._lanes if lane[2] is None)

    def busy(self) -> int:
        return len(self._lanes) - self.idle()

    def submit(self, k: int, x0: np.ndarray, sigma: np.ndarray) -> None:
        """Send start ``k`` from ``x0`` (the axes weighed by ``sigma``) to an idle lane."""
        lane = next(lane for lane in self._lanes if lane[2] is None)
        lane[2] = k
        try:
            lane[1].send((k, np.asarray(x0, dtype=np.float64), np.asarray(sigma, dtype=np.float64)))
        except OSError:  # the lane is gone: :meth:`collect` finds its socket closed and says why
            pass

    def collect(self, timeout: float) -> list[tuple]:
        """The outcomes that came back, waiting at most ``timeout`` s for one, as ``(start, outcome)``.

        Raises:
            ExcitationError: a lane failed (its error named) or exited without an answer (``reason`` "workers").
        """
        from multiprocessing.connection import wait

        waiting = [lane[1] for lane in self._lanes if lane[2] is not None]
        if not waiting:
            return []
        ready = wait(waiting, timeout=timeout)
        out = []
        for lane in self._lanes:
            if lane[1] not in ready:
                continue
            try:
                kind, payload = lane[1].recv()
            except (EOFError, OSError):
                raise ExcitationError(
                    f"an excitation worker process exited (status {lane[0].wait()}{_last_words(lane[0])}) while "
                    f"solving start {lane[2] + 1}; rerun with --workers 1",
                    reason="workers",
                ) from None
            if kind == "error":
                raise ExcitationError(
                    f"an excitation worker process failed on start {lane[2] + 1}: {payload}; rerun with --workers 1",
                    reason="workers",
                )
            out.append((lane[2], payload))
            lane[2] = None
        return out

    def close(self) -> None:
        """Tell every lane to exit; terminate those solving a start (nobody will read it) and those that do not
        exit within :data:`JOIN_SECONDS`."""
        import subprocess

        for proc, conn, k in self._lanes:
            if k is not None:
                proc.terminate()
                continue
            try:
                conn.send(None)
            except OSError:
                pass
        for proc, conn, _ in self._lanes:
            try:
                proc.wait(JOIN_SECONDS)
            except subprocess.TimeoutExpired:
                proc.terminate()
                proc.wait()
            conn.close()
            proc.stderr.close()
        self._lanes = []


def _last_words(proc) -> str:
    """``": <the last line>"`` of a lane's stderr once it has exited (a traceback's last line names the error), or
    nothing."""
    try:
        lines = proc.stderr.read().decode(errors="replace").strip().splitlines()
    except (OSError, ValueError):
        return ""
    return f": {lines[-1]}" if lines else ""


def _lane_main(conn) -> None:
    """A lane (:data:`_BOOT`): build the problem it is sent, then solve each start sent until told to stop (None)."""
    import logging
    import signal
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the calling process decides what Ctrl-C does
    logging.getLogger().addHandler(logging.NullHandler())  # its lines are the calling process's to print
    warnings.simplefilter("ignore")
    setup_error = None
    try:
        from ineid.excite.search import start_solver

        build, args = conn.recv()
        problem, safety, max_iter, tol = build(*args)
        solve = start_solver(problem, safety, max_iter, tol)
    except (EOFError, OSError):
        return
    except Exception as e:  # sent when the first start comes: the calling process names it
        setup_error = f"{type(e).__name__}: {e}"
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):  # the calling process is gone
            return
        if message is None:
            return
        k, x0, sigma = message
        if setup_error is not None:
            conn.send(("error", setup_error))
            continue
        try:
            if not np.array_equal(sigma, problem.sigma):
                problem.reweigh(sigma)
            conn.send(("ok", solve(k, x0)))
        except Exception as e:
            conn.send(("error", f"{type(e).__name__}: {e}"))
