"""The ``ineid`` command: parse arguments, call the library, print or write the result.

One module per verb group (:mod:`.robot`: robot, generate; :mod:`.data`; :mod:`.excite`;
:mod:`.identify`: identifiability, solve, export-urdf, study, results; :mod:`.export_mjcf`; :mod:`.learn`: train,
evaluate, sweep),
shared options in :mod:`.options`, console output in :mod:`.output`. Heavy libraries (JAX,
CasADi, h5py, yourdfpy) are imported inside the commands, so ``ineid --help`` imports none
of them. Any :class:`ineid.IneidError` becomes a one-line message and exit status 1, and so
does a fault the user can fix (a full disk, a read-only or forbidden folder, a name too
long, memory run out: :func:`ineid._faults.describe_fault`); any other exception is a bug
and keeps its traceback. Bad arguments exit with status 2 (click's usage error); Ctrl-C
(130) and SIGTERM (143) leave no partial output file and say so in one line (or say what they left on purpose, such
as a run
to continue with ``--resume``). The table of
exit statuses is in ``README.md`` (The command line).
"""

from __future__ import annotations

import logging
import os
import sys
import warnings

import click

from ineid._faults import describe_fault
from ineid._interrupts import Terminated, terminate_on_sigterm
from ineid.errors import IneidError


class IneidGroup(click.Group):
    """A group whose commands turn library errors and interruptions into one clear line."""

    def main(self, args=None, *rest, **kwargs):
        try:
            return super().main(args, *rest, **kwargs)
        except SystemExit as e:
            if args is None and e.code in (130, 143):  # run as a program (arguments from sys.argv), interrupted
                # JAX may still be compiling on a thread of its own; tearing the interpreter down under it
                # crashes (SIGSEGV, exit 139) after the line was printed. Everything ineid cleans up is done.
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(e.code)
            raise

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except IneidError as e:
            raise click.ClickException(str(e)) from None
        except (OSError, RuntimeError, MemoryError) as e:
            fault = describe_fault(e)
            if fault is None:
                raise  # not the user's to fix: a bug, keep the traceback
            raise click.ClickException(fault) from None
        except Terminated as e:
            click.echo(f"ineid: terminated (SIGTERM); {_left_behind(e)}", err=True)
            ctx.exit(143)
        except KeyboardInterrupt as e:
            click.echo(f"ineid: interrupted; {_left_behind(e)}", err=True)
            ctx.exit(130)


def _left_behind(e: BaseException) -> str:
    """What an interrupted command left on purpose (``output_files.on_interrupt``), else the usual promise."""
    return getattr(e, "ineid_left_behind", None) or "no partial output file was left"


def _version() -> str:
    from ineid._version import __version__  # package metadata; imports no JAX

    return __version__


def configure_logging(verbosity: int) -> None:
    """``-v`` INFO (files read, cache hits, code generation), ``-vv`` DEBUG, JAX's compile log and
    XLA's own C++ log lines (silenced below ``-vv``)."""
    from ineid.cli.output import show_derivation_progress

    level = max(logging.DEBUG, min(logging.CRITICAL, logging.WARNING - 10 * verbosity))
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("ineid: %(message)s"))
    handler.setLevel(level)  # also for records of a child logger set lower (derivation steps)
    root = logging.getLogger("ineid")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False
    show_derivation_progress(verbosity == 0)  # -v logs each step anyway; -q shows nothing
    if verbosity >= 2:
        os.environ.setdefault("JAX_LOG_COMPILES", "1")
    elif "jax" not in sys.modules:
        # XLA's C++ log (``E... slow_operation_alarm.cc] Constant folding an instruction is taking
        # > 1s``, ...) writes raw lines to stderr at ERROR level: only FATAL below -vv. XLA reads
        # the level when JAX is first imported (JAX itself sets 1, warnings and errors); a value
        # the user set wins.
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")


@click.group(cls=IneidGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="ineid", prog_name="ineid", message="%(prog)s %(version)s")
@click.option("-v", "--verbose", count=True, help="More output (repeatable): files read, caches, compilation.")
@click.option("-q", "--quiet", count=True, help="Less output: no progress bars, errors only in the log.")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: int) -> None:
    """Identify a robot arm's inertial parameters from its base force/torque sensor.

    ROBOT is a built-in name (sweaty-arm) or a path to a URDF or MJCF (.xml, needs ineid[mujoco]) file of a serial
    arm or a kinematic tree on a fixed base.
    """
    ctx.obj = {"verbosity": verbose - quiet}
    configure_logging(verbose - quiet)
    if verbose - quiet < 1:
        # a full or read-only disk under the cache: JAX warns for every kernel it cannot store
        # (the kernel still runs, only the next run compiles it again); -v shows them
        warnings.filterwarnings("ignore", message="Error writing persistent compilation cache entry")
    terminate_on_sigterm()
    from ineid.cache import enable_compilation_cache

    if ctx.invoked_subcommand != "cache":  # `cache info|clear` inspect the folder: never create it
        enable_compilation_cache()  # JAX not imported yet: sets the environment variables JAX reads


from ineid.cli import cache, data, excite, export_mjcf, identify, learn, report, robot, solve, study, sweep  # noqa: E402  (commands register on main)

for _module in (robot, data, excite, identify, solve, export_mjcf, report, learn, sweep, study, cache):
    _module.register(main)

__all__ = ["IneidGroup", "main"]
