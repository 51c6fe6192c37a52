"""IPOPT through CasADi that stops on Ctrl-C and SIGTERM like the rest of ineid.

CasADi catches what the Python code inside a solve raises: the exception of a
:class:`casadi.Callback` (the excitation criterion, the workspace constraints) becomes a
printed warning and a failed evaluation, and a signal seen by CasADi's own check becomes a
``KeyboardInterruptException`` warning and a failed start; either way the caller's loop would
go on to the next start or configuration and finish as if never interrupted.

:func:`nlpsol` builds the solver with an iteration callback that asks IPOPT to stop
(``User_Requested_Stop``) once :func:`ineid._interrupts.stop_requested`, and runs every solve
inside :func:`ineid._interrupts.interruptible`: the signal is recorded while IPOPT runs, IPOPT
stops at the end of the iteration it is in, and ``KeyboardInterrupt`` or
:class:`ineid._interrupts.Terminated` is raised when the call returns. The callback reads
none of the iterate (empty inputs, CasADi's buffer interface): some 10 microseconds an iteration.
"""

from __future__ import annotations

from ineid._interrupts import interruptible, stop_requested


def _stop_callback():
    """A CasADi function of the solver's outputs that returns 1 (stop) once an interruption is recorded."""
    import casadi as ca

    class StopOnInterrupt(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("stop_on_interrupt", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "stop"

        def get_sparsity_in(self, i):
            return ca.Sparsity(0, 0)  # nothing of the iterate is copied for Python

        def has_eval_buffer(self):
            return True

        def eval_buffer(self, arg, res):
            memoryview(res[0]).cast("d")[0] = 1.0 if stop_requested() else 0.0
            return 0

    return StopOnInterrupt()


class InterruptibleSolver:
    """A CasADi ``nlpsol`` whose calls stop on SIGINT / SIGTERM and raise their exception (module doc).

    Called like the CasADi function (``solver(x0=..., lbx=...)``); ``stats()`` is CasADi's.
    """

    def __init__(self, solver, keep: tuple = ()):
        self.solver = solver
        self._keep = keep  # CasADi does not own Python callbacks: they live as long as the solver

    def __call__(self, **kwargs):
        with interruptible():
            return self.solver(**kwargs)

    def stats(self) -> dict:
        return self.solver.stats()


def nlpsol(name: str, nlp: dict, opts: dict, keep: tuple = ()) -> InterruptibleSolver:
    """``casadi.nlpsol(name, "ipopt", nlp, opts)``, stopped by SIGINT and SIGTERM (module doc).

    Args:
        name: the solver's name.
        nlp: CasADi's problem (``{"x": ..., "f": ..., "g": ..., "p": ...}``).
        opts: CasADi and IPOPT options (``"ipopt.max_iter"``); they may not set ``iteration_callback``.
        keep: Python objects the problem's functions call (:class:`casadi.Callback` instances),
            kept alive with the solver.

    Raises:
        ValueError: ``opts`` sets its own ``iteration_callback``.
    """
    import casadi as ca

    if "iteration_callback" in opts:
        raise ValueError("opts may not set iteration_callback: it stops IPOPT on SIGINT and SIGTERM")
    stop = _stop_callback()
    solver = ca.nlpsol(name, "ipopt", nlp, dict(opts, iteration_callback=stop))
    return InterruptibleSolver(solver, (stop, *keep))
