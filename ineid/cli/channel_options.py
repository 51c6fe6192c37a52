"""The options that choose the measurement channels and the joint torques' actuation models.

Shared by ``ineid solve`` and ``ineid identifiability`` (defined once, here):

=========================  ================================================================
``--use NAMES``            the channels fitted, comma-separated: ``wrench``, ``torque`` (or a
                           channel's key, ``tau``); default every channel the file has
``--friction MODEL``       ``none``, or any of ``viscous``, ``coulomb``, ``stribeck`` (comma-separated)
``--coulomb-zone RAD/S``   smooth Coulomb friction: ``tanh(qd / zone)`` instead of ``sign(qd)``;
                           ``identify``: the zone found by a 1-D search, with its std
``--stribeck-velocity V``  ``vs`` of the Stribeck term ``fs exp(-(qd / vs)^2) c(qd)`` (rad/s), or
                           ``identify``
``--asymmetric-friction``  one friction coefficient per direction of motion
``--armature``             rotor inertia ``Ia qdd`` per joint
``--torque-offset``        a constant torque per joint, identified with its std
``--two-step``             (``solve``) the links from the wrench, then the friction from the
                           joint torques' residual (FloBaRoID)
``--torque-constant-unknown``  (``solve``, with ``--two-step``) the motor currents' torque
                           constants identified in step 2 (``<joint>.k``)
``--coupling FILE``        (``solve``) a coupled transmission (JSON, CSV or URDF
                           ``<transmission>``s): the torques or currents are per motor
=========================  ================================================================

They map onto :class:`ineid.identify.solve.SolveSettings` (``use``, ``friction``, ...), which
sets them on the dataset's joint-torque channels (:mod:`ineid.identify.choose`).
"""

from __future__ import annotations

from collections.abc import Callable

import click

FRICTION_CHOICES = ("none", "viscous", "coulomb", "stribeck")
"""``--friction`` takes ``none`` or any of the others, comma-separated (``viscous,coulomb,stribeck``)."""


def _names(ctx, param, value: str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    if not names:
        raise click.BadParameter("name at least one channel (wrench, torque)", param_hint="'--use'")
    return names


def _friction(ctx, param, value: str) -> tuple[str, ...]:
    terms = tuple(v.strip() for v in value.split(",") if v.strip())
    if terms in ((), ("none",)):
        return ()
    known = FRICTION_CHOICES[1:]
    if set(terms) - set(known) or len(set(terms)) != len(terms):
        raise click.BadParameter(
            f"{value!r} is not none nor any of {', '.join(known)} (comma-separated)", param_hint="'--friction'"
        )
    return tuple(t for t in known if t in terms)


def _velocity(ctx, param, value: str) -> float | str:
    """A friction velocity: a number >= 0 (rad/s) or ``identify``."""
    if value.strip().lower() == "identify":
        return "identify"
    try:
        v = float(value)
    except ValueError:
        v = -1.0
    if not (v >= 0 and v < float("inf")):
        raise click.BadParameter(f"{value!r} is neither a velocity >= 0 (rad/s) nor 'identify'")
    return v


def channel_options(two_step: bool = False, use_default: str = "every channel the file has") -> Callable:
    """Decorator: ``--use`` (its help ending "Default: ``use_default``.") and the actuation options (``--two-step``
    too when ``two_step``)."""

    def decorate(f: Callable) -> Callable:
        if two_step:
            f = click.option(
                "--two-step",
                "two_step",
                is_flag=True,
                help="FloBaRoID's two steps: the links from the wrench alone, then the friction "
                "(and armature, offsets) from the joint torques' residual; needs both.",
            )(f)
            f = click.option(
                "--torque-constant-unknown",
                "torque_constant_unknown",
                is_flag=True,
                help="Identify the motor currents' torque constants (<joint>.k, around the channel's "
                "nominal ones) in step 2 of --two-step.",
            )(f)
            f = click.option(
                "--coupling",
                "coupling",
                default=None,
                metavar="FILE",
                type=click.Path(dir_okay=False),
                help="A coupled transmission, qd_joint = C qd_motor (JSON {joints, motors, matrix}, CSV "
                "joint,<motor>,..., or a URDF's <transmission>s): the torques or currents are read per motor, "
                "tau_motor = C^T tau_joint, friction on the motors' velocities (<motor>.fv, ...).",
            )(f)
        for option in reversed(
            (
                click.option(
                    "--use",
                    "use",
                    default=None,
                    metavar="NAMES",
                    callback=_names,
                    help="Channels to fit, comma-separated: wrench, torque (or a channel's key). "
                    f"Default: {use_default}.",
                ),
                click.option(
                    "--friction",
                    "friction",
                    default="none",
                    show_default=True,
                    metavar="MODEL",
                    callback=_friction,
                    help="Joint friction of the joint torques: none, or any of viscous, coulomb, stribeck, "
                    "comma-separated (<joint>.fv, <joint>.fc, <joint>.fs identified with the links).",
                ),
                click.option(
                    "--coulomb-zone",
                    "coulomb_zone",
                    default="0",
                    callback=_velocity,
                    metavar="RAD_PER_S|identify",
                    help="Smooth Coulomb friction: tanh(qd / zone) instead of sign(qd) (0: sign); identify: the "
                    "zone minimising the residual (a 1-D search, its std from the residual's curvature).",
                ),
                click.option(
                    "--stribeck-velocity",
                    "stribeck_velocity",
                    default="0",
                    callback=_velocity,
                    metavar="RAD_PER_S|identify",
                    help="The Stribeck velocity vs of --friction ...,stribeck: fs exp(-(qd/vs)^2) c(qd), c the "
                    "Coulomb sign or tanh; identify: found like the zone.",
                ),
                click.option(
                    "--asymmetric-friction",
                    "asymmetric_friction",
                    is_flag=True,
                    help="One friction coefficient per direction of motion (<joint>.fv+, <joint>.fv-, ...).",
                ),
                click.option("--armature", is_flag=True, help="Rotor inertia Ia * qdd per joint (<joint>.Ia)."),
                click.option(
                    "--torque-offset",
                    "torque_offset",
                    is_flag=True,
                    help="A constant torque per joint (<joint>.offset), identified with its std.",
                ),
            )
        ):
            f = option(f)
        return f

    return decorate


def settings_flags(flags: dict) -> dict:
    """The :class:`ineid.identify.solve.SolveSettings` arguments of the options' values (by the option names)."""
    keys = (
        "use",
        "friction",
        "coulomb_zone",
        "stribeck_velocity",
        "asymmetric_friction",
        "armature",
        "torque_offset",
        "two_step",
        "torque_constant_unknown",
        "coupling",
    )
    return {k: flags[k] for k in keys if k in flags}


def given_flags(ctx: click.Context, flags: dict) -> list[str]:
    """The actuation options given on the command line (``--friction``, ...), as typed."""
    return [
        f"--{k.replace('_', '-')}"
        for k in flags
        if k != "use" and ctx.get_parameter_source(k) is click.core.ParameterSource.COMMANDLINE
    ]


def chosen_channels(channels, flags: dict):
    """The channels ``identifiability`` analyses and ``excite`` designs for: ``channels`` (a dataset's, or None:
    those named by --use) with the actuation options; None (the base wrench, as always) when no option is given."""
    from ineid.identify import SolveSettings
    from ineid.identify.choose import channels_named, select_channels, with_actuation

    try:
        settings = SolveSettings(**settings_flags(flags))
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    if channels is None:
        if settings.use is None and settings == SolveSettings():
            return None
        channels = channels_named(settings.use)
    return with_actuation(select_channels(channels, settings.use), settings)
