"""Which measurement channels a solve fits, and the actuation models of its joint torques.

A dataset stores each channel as measured (:mod:`ineid.channels`): a joint-torque channel
with every actuation model off. Identification chooses:

* **the channels** (``SolveSettings.use``, ``ineid solve --use wrench,torque``): names of the
  dataset's channels, each matching a channel's key (``wrench``, ``tau``), its kind
  (``wrench``, ``joint_torque``) or its kind without the ``joint_`` prefix (``torque``);
  None (the default): every channel the file has;
* **the actuation models** of the joint-torque channels among them (every channel whose
  record has the fields ``friction``, ``armature`` and ``torque_offset``, the
  ``JointTorque`` contract): ``friction`` (``"viscous"``, ``"coulomb"``), ``coulomb_zone``
  (rad/s: 0 for ``sign(qd)``, else ``tanh(qd / zone)``), ``asymmetric`` friction,
  ``armature`` and ``torque_offset``, each set by ``dataclasses.replace`` on the channel, so
  its extra kept columns (``<joint>.fv``, ...) are identified with the links' parameters
  (:mod:`ineid.identify.extras`).

Asking for an actuation model without a joint-torque channel among those fitted, or for a
channel the file does not have, is one :class:`ineid.errors.IdentificationError` naming the fix.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from ineid.channels import BaseWrench, ChannelSet, LinkWrench
from ineid.channels.link_wrench import refuse_nothing_beyond
from ineid.errors import IdentificationError

FRICTION_MODELS = ("viscous", "coulomb")
"""The friction terms of a joint-torque channel, in the order its extra columns take them."""
ACTUATION_FIELDS = ("friction", "armature", "torque_offset")
"""The record fields that make a channel a joint-torque channel whose actuation can be modelled."""


def is_actuated(channel) -> bool:
    """Whether ``channel`` takes actuation models (its record has :data:`ACTUATION_FIELDS`)."""
    names = {f.name for f in dataclasses.fields(channel)}
    return set(ACTUATION_FIELDS) <= names


def channel_names(channel) -> tuple[str, ...]:
    """The names ``--use`` knows ``channel`` by: its key, its kind, the kind without ``joint_``."""
    kind = channel.kind
    return tuple(dict.fromkeys((channel.key, kind, kind.removeprefix("joint_"))))


def _label(channel) -> str:
    short = channel.kind.removeprefix("joint_")
    return channel.key if short == channel.key else f"{short} ({channel.key})"


def select_channels(channels: ChannelSet, use: Sequence[str] | None) -> ChannelSet:
    """The channels of ``channels`` named in ``use`` (:func:`channel_names`), in the set's order; all when None.

    Raises:
        IdentificationError: a name no channel has (naming those there are), or no name at all.
    """
    if use is None:
        return channels
    use = [str(u) for u in use]
    have = ", ".join(_label(c) for c in channels)
    if not use:
        raise IdentificationError(f"--use names no channel; choose among {have}", status="unknown_channel")
    for name in use:
        if not any(name in channel_names(c) for c in channels):
            what = "joint torques" if name in ("torque", "tau", "joint_torque") else f"channel named {name!r}"
            raise IdentificationError(
                f"--use {name}: this dataset has no {what} (it measures {have}); choose among {have}",
                status="unknown_channel",
            )
    return ChannelSet(tuple(c for c in channels if any(n in channel_names(c) for n in use)))


def actuation_requested(settings) -> bool:
    """Whether ``settings`` (a :class:`ineid.identify.solve.SolveSettings`) asks for any actuation model."""
    return bool(
        settings.friction
        or settings.armature
        or settings.torque_offset
        or settings.asymmetric_friction
        or settings.coulomb_zone
        or settings.torque_constant_unknown
    )


def check_actuation(settings) -> None:
    """Refuse inconsistent actuation settings (``ValueError``, one line each)."""
    bad = [f for f in settings.friction if f not in FRICTION_MODELS]
    if bad or len(set(settings.friction)) != len(settings.friction):
        raise ValueError(
            f"friction must be none or any of {', '.join(FRICTION_MODELS)} (each once), "
            f"got {','.join(settings.friction)}"
        )
    if not settings.coulomb_zone >= 0:
        raise ValueError(f"coulomb_zone must be >= 0 rad/s, got {settings.coulomb_zone}")
    if settings.coulomb_zone and "coulomb" not in settings.friction:
        raise ValueError("coulomb_zone smooths Coulomb friction: add friction 'coulomb' (--friction coulomb)")
    if settings.torque_constant_unknown and not settings.two_step:
        raise ValueError(
            "torque constants are identified in the second of two steps (the links from the wrench "
            "first): add --two-step"
        )
    if settings.asymmetric_friction and not settings.friction:
        raise ValueError(
            "asymmetric_friction splits the friction coefficients per direction: "
            "add a friction model (--friction viscous,coulomb)"
        )


def with_actuation(channels: ChannelSet, settings) -> ChannelSet:
    """``channels`` with each joint-torque channel's actuation models set from ``settings`` (module doc).

    Raises:
        IdentificationError: an actuation model asked for and no joint-torque channel among ``channels``.
    """
    actuated = [c for c in channels if is_actuated(c)]
    if not actuated:
        if actuation_requested(settings):
            raise IdentificationError(
                f"--friction, --armature and --torque-offset model joint torques, and the channels fitted "
                f"({', '.join(channels.keys)}) have none; fit a dataset with joint torques (--use torque) "
                "or leave them out",
                status="no_torque_channel",
            )
        return channels
    currents = [c for c in actuated if _has_torque_constant(c)]
    if settings.torque_constant_unknown and not currents:
        raise IdentificationError(
            f"--torque-constant-unknown identifies motor currents' torque constants, and the channels fitted "
            f"({', '.join(channels.keys)}) have no motor currents: fit a dataset with currents (--use current) "
            "or leave it out",
            status="no_current_channel",
        )
    out = channels
    for c in actuated:
        k = {"identify_k": bool(settings.torque_constant_unknown)} if _has_torque_constant(c) else {}
        out = out.replace(
            dataclasses.replace(
                c,
                friction=tuple(f for f in FRICTION_MODELS if f in settings.friction),
                coulomb_zone=float(settings.coulomb_zone),
                asymmetric=bool(settings.asymmetric_friction),
                armature=bool(settings.armature),
                torque_offset=bool(settings.torque_offset),
                **k,
            )
        )
    return out


def _has_torque_constant(channel) -> bool:
    """Whether ``channel`` reads torques through torque constants that can be identified (a motor current)."""
    return "identify_k" in {f.name for f in dataclasses.fields(channel)}


def solve_channels(ds, settings, model) -> ChannelSet:
    """The channels ``solve_dataset`` fits: the dataset's chosen by ``settings.use``, the joint torques'
    actuation models set (:func:`with_actuation`), each with offsets when ``settings.bias == "estimate"``.

    Raises:
        IdentificationError: an unknown ``use`` name, actuation models without joint torques, or channels
            ``casadi-c`` cannot fit (extra kept columns, anything but one base wrench in the base frame).
        DatasetError: a wrist sensor with nothing the model moves beyond it (it reads zeros).
    """
    channels = with_actuation(select_channels(ds.meta.channels, settings.use), settings)
    channels = channels.with_offsets(settings.bias == "estimate")
    for channel in channels:
        if isinstance(channel, LinkWrench):
            refuse_nothing_beyond(model, channel.link)
    if settings.backend == "casadi-c":
        check_no_extra_columns(channels, model)
        (first, *rest) = channels
        if rest or not isinstance(first, BaseWrench):
            raise IdentificationError(
                f"backend 'casadi-c' fits one base wrench; this dataset measures "
                f"{channels.describe()}: use backend 'jax' or 'casadi'",
                status="unsupported",
            )
        if first.transform() is not None:
            raise IdentificationError(
                "backend 'casadi-c' fits in the base frame only; this dataset's wrench is in a "
                "sensor frame: use backend 'jax' or 'casadi'",
                status="unsupported",
            )
    return channels


def channels_named(names: Sequence[str] | None) -> ChannelSet:
    """The channels ``names`` stand for without a dataset (``ineid identifiability --use`` on random frames):
    ``wrench`` the base wrench, ``torque`` (``tau``, ``joint_torque``) the joint torques; None: the base wrench.

    Raises:
        IdentificationError: a name that is neither, or joint torques this ineid has no channel for.
    """
    from ineid.channels import channel_from_dict, channel_kinds

    out = []
    for name in names or ("wrench",):
        if name in ("wrench", "base_wrench"):
            out.append(BaseWrench())
        elif name in ("torque", "tau", "joint_torque") and "joint_torque" in channel_kinds():
            out.append(channel_from_dict({"kind": "joint_torque", "key": "tau"}))
        elif name in ("torque", "tau", "joint_torque"):
            raise IdentificationError(
                "this ineid has no joint-torque channel yet; use --use wrench", status="unknown_channel"
            )
        else:
            raise IdentificationError(
                f"--use {name}: without --data the channels are wrench and torque; "
                "choose among them (or analyse a dataset's channels with --data)",
                status="unknown_channel",
            )
    return ChannelSet(tuple(dict.fromkeys(out)))


def check_no_extra_columns(channels: ChannelSet, model, what: str = "backend 'casadi-c'") -> None:
    """Refuse channels with extra kept columns where ``what`` does not identify them (the ``casadi-c`` blocks)."""
    extra = channels.extra_names(model)
    if extra:
        raise IdentificationError(
            f"{what} does not fit extra parameters ({', '.join(extra[:3])}"
            f"{', ...' if len(extra) > 3 else ''}); use backend 'jax' or 'casadi', or leave "
            "the friction, armature and torque-offset models out",
            status="unsupported",
        )
