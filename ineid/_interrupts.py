"""Ctrl-C and SIGTERM: the exceptions they raise, and how they get through a solver that catches exceptions.

Once :func:`terminate_on_sigterm` is installed (the ``ineid`` command does it first), SIGTERM
raises :class:`Terminated` and SIGINT ``KeyboardInterrupt`` in the main thread, at its next
Python instruction. Both are ``BaseException``: they unwind through every ``except Exception``,
the atomic writers (:mod:`ineid._atomic`) drop their temporary files and the previous output
stays as it was; the command line turns them into one line and exit status 143 / 130.

Two kinds of place would lose them:

- A solver that calls back into Python and catches what the callback raises. IPOPT through
  CasADi prints the exception of a :class:`casadi.Callback` (and CasADi's own
  ``KeyboardInterruptException``) as a warning, takes the evaluation as failed and goes on,
  so the command would run to the end and replace the output. Such a call runs inside
  :func:`interruptible`: there the signal is only recorded, the solver asks
  :func:`stop_requested` between iterations and stops (``ineid.identify.ipopt`` makes IPOPT do
  so), and the interruption is raised when the call returns, as if it had arrived there.
- Python itself, where it ignores exceptions (a garbage-collection callback, a ``__del__``):
  the signal is sent again a moment later (:func:`redeliver_ignored_interrupt`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager


class Terminated(BaseException):
    """Raised in the main thread by SIGTERM once :func:`terminate_on_sigterm` is installed.

    Named for the signal, like ``KeyboardInterrupt``, and like it a ``BaseException``, so it unwinds through every
    ``except Exception`` and the atomic writers' cleanup runs.
    """


_holding = 0
"""How many :func:`interruptible` blocks the main thread is in; while above zero, signals are recorded, not raised."""

_pending: int | None = None
"""The signal recorded inside :func:`interruptible` (the first one), raised when the outermost block ends."""


def interruption(signum: int) -> BaseException:
    """The exception a signal raises: :class:`Terminated` for SIGTERM, ``KeyboardInterrupt`` for SIGINT."""
    return Terminated(f"terminated by signal {signum}") if signum == signal.SIGTERM else KeyboardInterrupt()


def _on_signal(signum, frame) -> None:
    """The handler of SIGTERM and SIGINT: raise their exception, or record it inside :func:`interruptible`."""
    global _pending
    if _holding:
        if _pending is None:
            _pending = signum
        return
    raise interruption(signum)


def stop_requested() -> bool:
    """True once SIGINT or SIGTERM arrived inside :func:`interruptible`: a solver polls it and stops."""
    return _pending is not None


def _deliverable() -> None:
    """Unblock SIGINT and SIGTERM in the calling (main) thread: a C library that blocked them there (its threads
    inherit the mask) would leave them pending, never delivered, and Ctrl-C would do nothing."""
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


@contextmanager
def interruptible() -> Iterator[None]:
    """Run a solver that catches the exceptions of the Python code it calls: SIGINT and SIGTERM are recorded
    while the block runs (:func:`stop_requested` turns true) and raised when it ends.

    Guarantees: a signal that arrives inside the block raises its exception (:func:`interruption`)
    when the block ends, in place of whatever the block returned or raised, and never inside the
    block, where the solver would catch it. Nested blocks raise at the end of the outermost one.
    Ctrl-C is recorded too where Python's own SIGINT handler is in place (a library call, outside
    the ``ineid`` command); another handler the program installed is left alone. Outside the main
    thread nothing changes (Python runs signal handlers in the main thread only).
    """
    global _holding, _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _deliverable()
    previous = signal.getsignal(signal.SIGINT)
    own_sigint = previous is signal.default_int_handler or previous is _on_signal
    if own_sigint:  # installed again even when already ours: a C library may have taken SIGINT behind Python's back
        signal.signal(signal.SIGINT, _on_signal)
    if not _holding:
        _pending = None
    _holding += 1
    try:
        yield
    finally:
        _holding -= 1
        if own_sigint:
            signal.signal(signal.SIGINT, previous)
        if not _holding and _pending is not None:
            signum, _pending = _pending, None
            raise interruption(signum)


REDELIVER_SECONDS = 0.01
"""Delay before a signal whose exception Python ignored is sent again (:func:`redeliver_ignored_interrupt`)."""


def redeliver_ignored_interrupt(unraisable) -> None:
    """``sys.unraisablehook``: send SIGTERM (SIGINT) again when its :class:`Terminated`
    (``KeyboardInterrupt``) was raised where Python ignores exceptions.

    A signal's handler runs in the main thread at the next instruction, which can be inside
    a garbage-collection callback or a ``__del__`` (JAX registers one: ``_xla_gc_callback``);
    there the exception is printed as "Exception ignored" and dropped, and the command would
    run on as if never signalled. The signal is sent again a moment later (from a timer thread,
    so that the handler runs after this hook has returned, in ordinary code); anything else
    goes to the previous hook.
    """
    exc = getattr(unraisable, "exc_value", None)
    signum = (
        signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT if isinstance(exc, KeyboardInterrupt) else None
    )
    if signum is None:
        _PREVIOUS_UNRAISABLEHOOK(unraisable)
        return
    timer = threading.Timer(REDELIVER_SECONDS, os.kill, (os.getpid(), signum))
    timer.daemon = True
    timer.start()


_PREVIOUS_UNRAISABLEHOOK = sys.unraisablehook


def terminate_on_sigterm() -> None:
    """Turn SIGTERM into :class:`Terminated` and SIGINT into ``KeyboardInterrupt`` in the main thread (a no-op
    elsewhere), both held back inside :func:`interruptible`; a SIGTERM or SIGINT whose exception lands where
    Python ignores exceptions is delivered again (:func:`redeliver_ignored_interrupt`).

    SIGINT keeps a handler other than Python's own (ignored, as under ``nohup``, stays ignored).
    """
    try:
        signal.signal(signal.SIGTERM, _on_signal)
    except ValueError:  # not the main thread
        print("ineid: SIGTERM handler not installed (not the main thread)", file=sys.stderr)
        return
    _deliverable()
    if signal.getsignal(signal.SIGINT) in (signal.default_int_handler, _on_signal):  # again: see interruptible
        signal.signal(signal.SIGINT, _on_signal)
    sys.unraisablehook = redeliver_ignored_interrupt
