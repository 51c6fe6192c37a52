"""Options of simulated measurements (``data generate``, ``excite``): ``--noise``, ``--channels``,
``--friction-truth``.

What a synthetic dataset measures (``--channels wrench,torque``), with which actuation
(``--friction-truth fv=0.05,fc=0.2``: the values that joint torques add to ``Phi theta``) and
which noise (``--noise force=0.5,tau=0.02``); the library's names are
:class:`ineid.data.NoiseModel` and :class:`ineid.data.DatasetSpec` (``channels``,
``extra_truth``).
"""

from __future__ import annotations

import math

import click

NOISE_MAX = 1e6
"""The largest ``--noise`` value (std in N, N*m, rad, rad/s, rad/s^2, or the glitch scale): far above any
sensor's, and low enough that noisy values, their squares and sums stay finite in float64."""
NOISE_KEYS = (
    "force",
    "moment",
    "fx",
    "fy",
    "fz",
    "mx",
    "my",
    "mz",
    "q",
    "qd",
    "qdd",
    "tau",
    "current",
    "glitch",
    "glitch_scale",
    "gyro",
    "accel",
    "alpha",
)
IMU_NOISE_KEYS = ("gyro", "accel", "alpha")
"""``--noise`` keys of the link IMUs (``data generate --imu``): rad/s, m/s^2, rad/s^2 at the frames' rate."""
CHANNEL_NOISE_KEYS = ("tau", "current")
"""``--noise`` keys that are measurement channels' own (their dataset keys): ``tau`` the joint torques,
``current`` the motor currents."""


def _parse_noise(ctx, param, value: str | None) -> dict[str, float] | None:
    """``force=0.5,moment=0.02,qd=0.01[,tau=0.02,glitch=0.02,glitch_scale=20]`` -> ``{key: value}`` (checked; see
    :func:`noise_model`)."""
    if not value:
        return None
    std = {}
    for item in value.split(","):
        key, sep, val = item.strip().partition("=")
        key = key.strip().lower()
        try:
            if not sep or key not in NOISE_KEYS:
                raise ValueError
            std[key] = float(val)
            if not 0 <= std[key] <= NOISE_MAX:  # NaN fails too
                raise ValueError
        except ValueError:
            raise click.BadParameter(
                f"expected KEY=STD with KEY in {', '.join(NOISE_KEYS)} and 0 <= STD <= {NOISE_MAX:g}, got "
                f"{item.strip()!r}",
                param_hint="--noise",
            ) from None
    return std


noise_option = click.option(
    "--noise",
    default=None,
    metavar="KEY=STD,...",
    callback=_parse_noise,
    help="Gaussian noise std: force, moment (or fx..mz) in N, N*m; q, qd, qdd in rad, rad/s, rad/s^2; tau (joint "
    "torques, with --channels ...,torque) in N*m; current (with --channels ...,current) in A; glitch=RATE: that "
    "share of frames gets glitch_scale "
    "(default 20) times the force noise; gyro, accel, alpha (with --imu) in rad/s, m/s^2, rad/s^2. Each at most 1e6.",
)


def noise_model(std: dict[str, float] | None, n_dof: int, wrench_key: str = "wrench"):
    """The :class:`ineid.data.NoiseModel` of a parsed ``--noise`` (None for clean data).

    ``wrench_key``: the channel of the F/T sensor whose force and moment noise this is (``"wrench"``,
    the base wrench; ``"wrench_<link>"``, a sensor on a link: its noise goes under that key).

    Raises:
        click.BadParameter: glitches without force noise, a glitch rate outside [0, 1) or a scale below 1,
            glitches of a sensor on a link.
    """
    if not std:
        return None
    from ineid.data import NoiseModel

    force = [std.get(a, std.get("force", 0.0)) for a in ("fx", "fy", "fz")]
    moment = [std.get(a, std.get("moment", 0.0)) for a in ("mx", "my", "mz")]
    glitch = {"glitch_rate": std.get("glitch", 0.0)}
    if "glitch_scale" in std:
        glitch["glitch_scale"] = std["glitch_scale"]
    channels = {k: std[k] for k in CHANNEL_NOISE_KEYS if k in std}
    if wrench_key != "wrench":  # a sensor on a link: its own key, no glitch model
        if glitch["glitch_rate"]:
            raise click.BadParameter(
                "glitches are modelled for the base wrench only; drop glitch= with a sensor on a link",
                param_hint="--noise",
            )
        if any(force + moment):
            channels[wrench_key] = force + moment
        force, moment = 0.0, 0.0
    try:
        return NoiseModel.create(
            n_dof,
            force=force,
            moment=moment,
            q=std.get("q", 0.0),
            qd=std.get("qd", 0.0),
            qdd=std.get("qdd", 0.0),
            channels=channels,
            **glitch,
        )
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--noise") from None


# -- motor currents: the drives (data generate, data import) ---------------------------------------

torque_constant_option = click.option(
    "--torque-constant",
    default=None,
    metavar="K[,K...]",
    callback=lambda ctx, p, v: _numbers(v, "--torque-constant"),
    help="Motor currents (--channels ...,current; i1..in in a recording): the motors' torque constants, N*m/A "
    "(one, or one per joint).",
)
gear_ratio_option = click.option(
    "--gear-ratio",
    default=None,
    metavar="G[,G...]",
    callback=lambda ctx, p, v: _numbers(v, "--gear-ratio"),
    help="Motor currents: the gear ratios, motor turns per joint turn, signed (one, or one per joint).",
)


DRIVE_RANGE = (1e-6, 1e6)
"""``--torque-constant`` and ``--gear-ratio`` (N*m/A, motor turns per joint turn) are within it in magnitude:
wider than any drive, and far from the products that underflow or overflow (at 1e-308 the solver's
eigenvalue decomposition fails)."""


def _numbers(value: str | None, hint: str) -> tuple[float, ...] | None:
    """Comma-separated numbers of magnitude within :data:`DRIVE_RANGE` (signed)."""
    if value is None:
        return None
    lo, hi = DRIVE_RANGE
    try:
        out = tuple(float(v) for v in value.split(",") if v.strip())
        if not out or not all(lo <= abs(v) <= hi for v in out):
            raise ValueError
    except ValueError:
        raise click.BadParameter(
            f"expected comma-separated numbers of magnitude {lo:g} to {hi:g}, got {value!r}", param_hint=hint
        ) from None
    return out


# -- what a synthetic dataset measures -----------------------------------------------------------

CHANNEL_NAMES = ("wrench", "torque", "current")
"""``--channels`` names: ``wrench`` the base wrench (key ``wrench``), ``torque`` the joint torques (key ``tau``),
``current`` the motor currents (key ``current``; with the drives' torque constants and gear ratios)."""


def _parse_channels(ctx, param, value: str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    names = tuple(dict.fromkeys(n.strip().lower() for n in value.split(",") if n.strip()))
    bad = [n for n in names if n not in CHANNEL_NAMES]
    if bad or not names:
        raise click.BadParameter(
            f"expected a comma-separated list of {', '.join(CHANNEL_NAMES)}, got {value!r}", param_hint="--channels"
        )
    return names


channels_option = click.option(
    "--channels",
    default=None,
    metavar="LIST",
    callback=_parse_channels,
    help="What the synthetic arm measures: wrench (the base wrench, the default), torque (joint torques, "
    "the actuator's: Phi theta plus --friction-truth), current (motor currents, tau / (k G): with "
    "--torque-constant, --gear-ratio), or several: wrench,torque.",
)


def simulated_channels(names: tuple[str, ...] | None, drives: tuple | None = None, sensor=None):
    """The :class:`ineid.channels.ChannelSet` of a parsed ``--channels`` (None: the default base wrench);
    ``drives``: ``(torque constants, gear ratios)`` per joint, for ``current``; ``sensor``: the F/T
    sensor's channel for ``wrench`` (:func:`ineid.channels.sensor_channel` of ``--sensor-pose``;
    default the base wrench in the base frame)."""
    if names is None and sensor is None:
        return None
    from ineid.channels import BaseWrench, ChannelSet
    from ineid.channels.torque import JointTorque, MotorCurrent

    made = []
    for name in names or ("wrench",):
        if name == "wrench":
            made.append(sensor or BaseWrench())
        elif name == "torque":
            made.append(JointTorque())
        else:
            made.append(MotorCurrent(torque_constant=drives[0], gear_ratio=drives[1]))
    return ChannelSet(tuple(made))


def drives(names: tuple[str, ...] | None, torque_constant, gear_ratio, n_dof: int):
    """``(k, G)`` one per joint for ``--channels ...,current`` (None without currents).

    Raises:
        click.UsageError: currents without both, either without currents, or another count than one or ``n_dof``.
    """
    current = names is not None and "current" in names
    if not current:
        if torque_constant or gear_ratio:
            raise click.UsageError(
                "--torque-constant and --gear-ratio are the motor currents' drives: simulate "
                "currents with --channels ...,current"
            )
        return None
    if not torque_constant or not gear_ratio:
        raise click.UsageError("motor currents are read through the drives: give --torque-constant and --gear-ratio")
    out = []
    for values, flag in ((torque_constant, "--torque-constant"), (gear_ratio, "--gear-ratio")):
        values = tuple(values) * (n_dof if len(values) == 1 else 1)
        if len(values) != n_dof:
            raise click.BadParameter(
                f"{len(values)} numbers for {n_dof} joints; give one, or one per joint", param_hint=flag
            )
        out.append(values)
    return tuple(out)


FRICTION_TERMS = {
    "fv": "fv",
    "fc": "fc",
    "offset": "offset",
    "ia": "Ia",
    "fv+": "fv+",
    "fv-": "fv-",
    "fc+": "fc+",
    "fc-": "fc-",
    "fs": "fs",
    "vs": "stribeck_velocity",
}
"""``--friction-truth`` terms (case-insensitive) and their extra-parameter names (``<joint>.<term>``); ``vs``, the
Stribeck velocity, is one for every joint (``extra_truth["stribeck_velocity"]``)."""
TERM_SPELLING = ("fv", "fc", "offset", "Ia", "fv+", "fv-", "fc+", "fc-", "fs", "vs")
"""The ``--friction-truth`` terms as the help and the messages spell them."""


def _parse_friction_truth(ctx, param, value: str | None) -> dict[tuple[str | None, str], float] | None:
    """``fv=0.05,fc=0.2,elbow.Ia=0.01`` -> ``{(joint or None, term): value}`` (joints checked by
    :func:`friction_truth`)."""
    if not value:
        return None
    out: dict[tuple[str | None, str], float] = {}
    for item in value.split(","):
        key, sep, val = item.strip().partition("=")
        joint, dot, term = key.strip().rpartition(".")
        term = FRICTION_TERMS.get(term.strip().lower())
        try:
            number = float(val)
            if not sep or term is None or (dot and not joint) or not math.isfinite(number) or abs(number) > NOISE_MAX:
                raise ValueError
            if term == "stribeck_velocity" and (dot or not number > 0):
                raise click.BadParameter(
                    f"vs, the Stribeck velocity, is one positive value (rad/s) for every joint, got {item.strip()!r}",
                    param_hint="--friction-truth",
                )
        except ValueError:
            raise click.BadParameter(
                f"expected TERM=VALUE or JOINT.TERM=VALUE with TERM in {', '.join(TERM_SPELLING)} and a "
                f"finite VALUE of at most {NOISE_MAX:g} in size, got {item.strip()!r}",
                param_hint="--friction-truth",
            ) from None
        out[(joint or None, term)] = number
    return out


friction_truth_option = click.option(
    "--friction-truth",
    default=None,
    metavar="TERM=VALUE,...",
    callback=_parse_friction_truth,
    help="The simulated actuation that joint torques add: fv (viscous, N*m*s/rad), fc (Coulomb, N*m), offset "
    "(N*m), Ia (armature, kg*m^2); fv+, fv-, fc+, fc- per direction; fs (Stribeck, N*m: fs exp(-(qd/vs)^2) "
    "sign(qd)) with vs (its velocity, rad/s, one for every joint). TERM=VALUE sets every joint, "
    "JOINT.TERM=VALUE one joint (it wins). Needs --channels ...,torque.",
)


def friction_truth(parsed: dict[tuple[str | None, str], float] | None, joint_names) -> dict[str, float] | None:
    """``{"<joint>.<term>": value}`` (``DatasetSpec.extra_truth``) of a parsed ``--friction-truth``.

    Raises:
        click.BadParameter: a joint the robot does not have.
    """
    if not parsed:
        return None
    joints = list(joint_names)
    bad = [j for j, _ in parsed if j is not None and j not in joints]
    if bad:
        raise click.BadParameter(
            f"the robot has no moving joint {bad[0]!r}; its joints: {', '.join(joints)}", param_hint="--friction-truth"
        )
    vs = parsed.get((None, "stribeck_velocity"))
    parsed = {k: v for k, v in parsed.items() if k[1] != "stribeck_velocity"}
    out = {f"{j}.{term}": v for (joint, term), v in parsed.items() if joint is None for j in joints}
    out.update({f"{joint}.{term}": v for (joint, term), v in parsed.items() if joint is not None})
    out = {f"{j}.{t}": out[f"{j}.{t}"] for j in joints for t in FRICTION_TERMS.values() if f"{j}.{t}" in out}
    return out if vs is None else {**out, "stribeck_velocity": vs}
