"""Options and parsing shared by the ``ineid`` commands: each defined once, here.

Flag names carry one meaning across commands:

=====================  ====================================================================
``ROBOT``              positional where the robot is the command's subject: a built-in name
                       (sweaty-arm), a URDF path or an MJCF path (``.xml``, ``ineid[mujoco]``); ``data import``
                       (whose subject is the
                       recording) takes ``--robot`` (required)
``--unknown-links``    comma-separated links to identify
``--lock JOINT=POS``   treat a URDF joint as fixed (repeatable)
``--gravity``          GX GY GZ, m/s^2, base frame; or ``standard`` (0 0 -9.80665)
``--n-configs N``      how many configurations to make
``--n-frames N``       how many frames to make or sample per configuration
``--fit-frames K``     frames fitted per configuration (the first K; the rest validate)
``--sample-frames K``  frames per network sample
``--select SEL``       which configurations of a file: ``all``, ``A:B[:STEP]``, ``1,5,9``
``--config N``         one configuration of a file, by its index
``--out``              the file or folder to write; never replaced without ``--overwrite``
=====================  ====================================================================

The deprecated spellings (``--configs``, ``--frames``, ``--frames-list``, ``--robot`` on
``data generate``/``study noise``) keep working, with a deprecation message, until ineid
:data:`DEPRECATED_UNTIL`.
Defaults live in the library's dataclasses and constants; options read them from there.
"""

from __future__ import annotations

import functools
import importlib
import math
import os
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import click

DEPRECATED_UNTIL = "0.3"


# -- values from the library, looked up when needed (``ineid --help`` imports nothing heavy) --


def _resolve(ref: str):
    """``"package.module:Name.attr"`` -> the object."""
    module, _, attr = ref.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def library_default(ref: str):
    """The default of a dataclass field, ``"module:Class.field"``."""
    module_cls, _, name = ref.rpartition(".")
    cls = _resolve(module_cls)
    for f in fields(cls):
        if f.name == name:
            if f.default is not MISSING:
                return f.default
            if f.default_factory is not MISSING:
                return f.default_factory()
    raise AttributeError(f"{ref} has no default")


class LibraryOption(click.Option):
    """An option whose default is a library dataclass field's (``default_from="module:Class.field"``)."""

    def __init__(self, *args, default_from: str, **kwargs) -> None:
        super().__init__(*args, show_default=True, **kwargs)
        self.default_from = default_from

    def get_default(self, ctx: click.Context, call: bool = True):
        return library_default(self.default_from)


class LibraryChoice(click.ParamType):
    """``click.Choice`` over a library constant (a tuple or dict of names), imported on first use."""

    def __init__(self, ref: str) -> None:
        self.ref = ref
        self._choice: click.Choice | None = None

    @property
    def choice(self) -> click.Choice:
        if self._choice is None:
            self._choice = click.Choice(list(_resolve(self.ref)))
        return self._choice

    @property
    def name(self) -> str:  # click shows it in errors
        return "choice"

    def get_metavar(self, param, *args, **kwargs):  # click >= 8.2 passes ctx= by keyword
        return self.choice.get_metavar(param, *args, **kwargs)

    def convert(self, value, param, ctx):
        return self.choice.convert(value, param, ctx)

    def shell_complete(self, ctx, param, incomplete):
        return self.choice.shell_complete(ctx, param, incomplete)


class FiniteFloatRange(click.FloatRange):
    """``click.FloatRange`` that also refuses NaN and infinity (which pass click's range checks).

    Every float option of ineid uses it: a NaN or infinite setting never reaches the library
    (where it would write NaN into a dataset or allocate without bound).
    """

    def convert(self, value, param, ctx):
        rv = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return super().convert(rv, param, ctx)

    def _describe_range(self) -> str:
        """The range shown in ``--help`` (``[x>=0]``); none for an unbounded one (click would show ``x<=None``)."""
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


FINITE = FiniteFloatRange()
"""Any finite float (``--gravity``)."""


class SeedRange(click.IntRange):
    """``--seed``: 0 <= seed < 2^63 (NumPy's and JAX's generators take 64-bit seeds; a larger one would be an
    OverflowError), its range shown as ``0<=x<2^63`` in ``--help``."""

    name = "seed"

    def __init__(self) -> None:
        super().__init__(0, 2**63 - 1)

    def _describe_range(self) -> str:
        return "0<=x<2^63"


SEED = SeedRange()
"""``--seed``: an integer in ``[0, 2^63)``."""
MAX_WORKERS = 4 * (os.cpu_count() or 1)
WORKERS = click.IntRange(1, MAX_WORKERS)
"""``--workers``: each process loads CasADi and the generated code (about 200 MB); more than four per
CPU only costs memory (a million would exhaust it)."""


class PlotFile(click.Path):
    """A file a figure is written to (``--plot``): its suffix a format matplotlib writes here, PNG without one.

    Checked as the option is parsed, before any work: ``solve --plot r.xyz`` stops at once (exit 2) naming
    the formats, not after solving.
    """

    name = "plot file"

    def __init__(self) -> None:
        super().__init__(dir_okay=False, path_type=Path)

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        suffix = Path(path).suffix.lower().lstrip(".")
        formats = plot_formats()
        if suffix and suffix not in formats:
            self.fail(
                f"{str(value)!r}: matplotlib writes no .{suffix} files here; end the name with one of "
                f".{', .'.join(formats)} (none: PNG)",
                param,
                ctx,
            )
        return path


def plot_formats() -> tuple[str, ...]:
    """The suffixes (lower case, no dot) of the formats matplotlib writes figures in here (``pgf`` only where its
    TeX system is on the PATH)."""
    import shutil

    import matplotlib
    from matplotlib.backend_bases import FigureCanvasBase

    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    if "pgf" in formats and shutil.which(str(matplotlib.rcParams["pgf.texsystem"])) is None:
        formats.remove("pgf")
    return tuple(formats)


def names_in(ref: str, hint: str):
    """Callback: comma-separated names, each one of the library constant ``ref`` -> tuple."""

    def callback(ctx, param, value):
        if value is None:
            return None
        allowed = list(_resolve(ref))
        vals = tuple(v.strip() for v in value.split(",") if v.strip())
        bad = [v for v in vals if v not in allowed]
        if bad or not vals:
            raise click.BadParameter(f"choose from {', '.join(allowed)}; got {value!r}", param_hint=hint)
        return vals

    return callback


def numbers(cast: type, hint: str, minimum: float = 0, maximum: float = math.inf):
    """Callback: comma-separated finite numbers, each in ``[minimum, maximum]`` -> tuple."""

    def callback(ctx, param, value):
        if value is None:
            return None
        try:
            vals = tuple(cast(v) for v in value.split(",") if v.strip())
            if not vals or not all(minimum <= v <= maximum and math.isfinite(v) for v in vals):
                raise ValueError
        except ValueError:
            bound = f"in [{minimum:g}, {maximum:g}]" if math.isfinite(maximum) else f">= {minimum:g}"
            raise click.BadParameter(
                f"expected comma-separated numbers {bound}, got {value!r}", param_hint=hint
            ) from None
        return vals

    return callback


# -- the robot -------------------------------------------------------------------------------


@dataclass(frozen=True)
class RobotChoice:
    """What the robot options chose; :meth:`load` builds the :class:`ineid.RobotModel`."""

    robot: str
    unknown_links: tuple[str, ...] | None = None
    locked_joints: dict[str, float] | None = None
    gravity: tuple[float, float, float] | None = None

    def load(self):
        from ineid.robots.load import load_robot

        kwargs = {"unknown_links": self.unknown_links, "locked_joints": self.locked_joints}
        if self.gravity is not None:
            kwargs["gravity"] = self.gravity
        return load_robot(self.robot, **kwargs)


def _split_names(ctx, param, value: str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    return tuple(v.strip() for v in value.split(",") if v.strip())


def _parse_locked(ctx, param, values: tuple[str, ...]) -> dict[str, float] | None:
    out = {}
    for item in values:
        name, sep, val = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(val)
            if not math.isfinite(out[name.strip()]):
                raise ValueError
        except ValueError:
            raise click.BadParameter(
                f"expected JOINT=POSITION with a finite position, got {item!r}", param_hint="--lock"
            ) from None
    return out or None


unknown_links_option = click.option(
    "--unknown-links",
    metavar="LINK,LINK",
    default=None,
    callback=_split_names,
    help="Comma-separated links to identify: moving links, or links welded to one (a payload, identified in its "
    "own frame; its body keeps its CAD). Default: the built-in's choice, or all moving links.",
)
lock_option = click.option(
    "--lock",
    "locked",
    multiple=True,
    metavar="JOINT=POS",
    callback=_parse_locked,
    help="Treat a URDF (or MJCF) joint as fixed at POS (repeatable).",
)


class GravityType(click.ParamType):
    """``--gravity``: three finite numbers (m/s^2, base frame) or a name of
    :data:`ineid.robots.gravity.GRAVITY_WORDS` (``standard``: 9.80665 down the base frame's z)."""

    name = "gravity"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple) and len(value) == 1:
            value = value[0]
        if isinstance(value, str):
            from ineid.robots.gravity import GRAVITY_WORDS

            if value.strip().lower() in GRAVITY_WORDS:
                return GRAVITY_WORDS[value.strip().lower()]
            self.fail(f"{value!r}: give GX GY GZ (three numbers, m/s^2) or {' or '.join(GRAVITY_WORDS)}", param, ctx)
        if not isinstance(value, (tuple, list)) or len(value) != 3:
            self.fail(f"{value!r}: give GX GY GZ (three numbers, m/s^2) or standard", param, ctx)
        return tuple(FINITE.convert(v, param, ctx) for v in value)


class GravityOption(click.Option):
    """``--gravity GX GY GZ`` or ``--gravity standard``: three values, or one word.

    click gives an option a fixed number of values; this one reads one, and two more after it unless
    the first is a word (its parser entry's ``process`` takes them from the arguments still to parse).
    """

    def add_to_parser(self, parser, ctx) -> None:
        super().add_to_parser(parser, ctx)
        for name in self.opts:
            entry = parser._long_opt.get(name) or parser._short_opt.get(name)
            if entry is None:
                continue
            process = entry.process

            def greedy(value, state, process=process):
                from ineid.robots.gravity import GRAVITY_WORDS

                if isinstance(value, str) and value.strip().lower() not in GRAVITY_WORDS:
                    if len(state.rargs) < 2:
                        raise click.BadOptionUsage(self.opts[0], f"{self.opts[0]} takes GX GY GZ or standard")
                    value = (value, state.rargs.pop(0), state.rargs.pop(0))
                process(value, state)

            entry.process = greedy


def _gravity(ctx, param, value: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
    """``--gravity`` as given; one warning line when it looks like another unit than m/s^2."""
    if value is not None:
        from ineid.cli.output import print_findings
        from ineid.data.recordings.plausibility import check_gravity

        found = check_gravity(value, "--gravity")
        print_findings([found] if found is not None else [])
    return value


gravity_option = click.option(
    "--gravity",
    cls=GravityOption,
    type=GravityType(),
    default=None,
    metavar="GX GY GZ|standard",
    callback=_gravity,
    help="m/s^2, base frame; standard: 0 0 -9.80665 (standard gravity). Default 0 0 -9.81 (ineid's, the paper's).",
)


def robot_options(positional: str = "required", with_gravity: bool = True) -> Callable:
    """ROBOT, --unknown-links, --lock (and --gravity), handed to the command as ``robot: RobotChoice``.

    ``positional``: ``"required"`` (ROBOT argument), ``"optional"`` (ROBOT argument that
    defaults to sweaty-arm; 0.1's ``--robot`` still accepted), or ``"option"`` (required ``--robot``).
    """

    def deco(f):
        @functools.wraps(f)
        def wrapper(*args, **kw):
            robot = kw.pop("robot")
            old = kw.pop("deprecated_robot", None)
            if old is not None:
                if robot is not None:
                    raise click.UsageError("give ROBOT or --robot, not both")
                warn_deprecated("--robot", "the ROBOT argument")
                robot = old
            kw["robot"] = RobotChoice(
                robot or "sweaty-arm",
                kw.pop("unknown_links"),
                kw.pop("locked"),
                kw.pop("gravity", None) if with_gravity else None,
            )
            return f(*args, **kw)

        g = wrapper
        if with_gravity:
            g = gravity_option(g)
        g = lock_option(unknown_links_option(g))
        if positional == "option":
            # Required: a silent default (sweaty-arm) imported another arm's recording as the built-in's.
            return click.option(
                "--robot",
                required=True,
                metavar="ROBOT",
                help="The recorded robot: a built-in name (sweaty-arm), a URDF or an MJCF path.",
            )(g)
        if positional == "optional":
            g = click.option("--robot", "deprecated_robot", default=None, hidden=True)(g)
        return click.argument(
            "robot", metavar="[ROBOT]" if positional == "optional" else "ROBOT", required=positional == "required"
        )(g)

    return deco


# -- deprecated spellings --------------------------------------------------------------------


def warn_deprecated(old: str, new: str) -> None:
    click.echo(f"ineid: {old} is deprecated; use {new} (the old spelling goes in ineid {DEPRECATED_UNTIL})", err=True)


def deprecated_alias(old: str, new_param: str, new_flag: str, **option_kwargs) -> Callable:
    """Accept the 0.1 spelling ``old`` of option ``new_flag`` (parameter ``new_param``) with a warning."""
    dest = "deprecated_" + old.lstrip("-").replace("-", "_")

    def deco(f):
        @functools.wraps(f)
        def wrapper(*args, **kw):
            value = kw.pop(dest)
            if value is not None:
                ctx = click.get_current_context()
                if ctx.get_parameter_source(new_param) is click.core.ParameterSource.COMMANDLINE:
                    raise click.UsageError(f"give {new_flag} or {old}, not both")
                warn_deprecated(old, new_flag)
                kw[new_param] = value
            return f(*args, **kw)

        return click.option(old, dest, default=None, hidden=True, **option_kwargs)(wrapper)

    return deco


# -- selections, noise -------------------------------------------------------------------------


def parse_selection(text: str | None, n: int, hint: str = "--select"):
    """``all``, ``A:B[:STEP]``, ``1,5,9`` or mixtures (``0:10,50``) -> sorted unique indices into ``n``."""
    import numpy as np

    if text is None or text.strip().lower() == "all":
        return np.arange(n)
    picked: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            if ":" in part:
                bits = [int(b) if b.strip() else None for b in part.split(":")]
                if len(bits) > 3:
                    raise ValueError
                picked += list(range(n))[slice(*bits)]
            else:
                k = int(part)
                if not -n <= k < n:
                    raise click.BadParameter(
                        f"configuration {k} is out of range (the file has {n}: 0..{n - 1})", param_hint=hint
                    )
                picked.append(k % n)
        except ValueError:
            raise click.BadParameter(
                f"expected 'all', A:B[:STEP] or comma-separated indices, got {part!r}", param_hint=hint
            ) from None
    idx = np.unique(np.asarray(picked, dtype=np.int64))
    if idx.size == 0:
        raise click.BadParameter(f"{text!r} selects no configuration of the {n} in the file", param_hint=hint)
    return idx


select_option = click.option(
    "--select",
    "selection",
    default=None,
    metavar="SEL",
    help="Configurations: all (default), A:B[:STEP], or 1,5,9.",
)
select_alias = deprecated_alias("--configs", "selection", "--select")

# ``--noise`` (with ``--channels``, ``--friction-truth``) lives in :mod:`ineid.cli.simulation`; re-exported here.
from ineid.cli.simulation import NOISE_KEYS, NOISE_MAX, noise_model, noise_option  # noqa: E402, F401


def verbosity(ctx: click.Context) -> int:
    """``-v`` count minus ``-q`` count (rio's convention)."""
    return int((ctx.find_root().obj or {}).get("verbosity", 0))


def quiet(ctx: click.Context) -> bool:
    return verbosity(ctx) < 0
