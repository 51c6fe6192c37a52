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
  ``stribeck_velocity``, ``armature`` and ``torque_offset``, and a coupled transmission (``coupling``, a file
  read against the model's joints, :func:`with_coupling`), each set by ``dataclasses.replace`` on the channel, so
  its extra kept columns (``<joint>.fv``, ...) are identified with the links' parameters
  (:mod:`ineid.identify.extras`).

With ``weights="noise"``, the noise of each axis of the channels fitted: given, or recorded with the
data (:func:`noise_levels`). FloBaRoID's two steps (:mod:`ineid.identify.two_step`) fit the wrench
channels first (:func:`wrench_settings`), then the joint torques (:func:`two_step_channels`,
:func:`torque_noise_levels`).

Asking for an actuation model without a joint-torque channel among those fitted, or for a
channel the file does not have, is one :class:`ineid.errors.IdentificationError` naming the fix.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ineid.channels import BaseWrench, ChannelSet, LinkWrench
from ineid.channels.link_wrench import refuse_nothing_beyond
from ineid.errors import IdentificationError
from ineid.identify.settings import FRICTION_MODELS, IDENTIFY, SolveSettings

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


def with_actuation(channels: ChannelSet, settings: SolveSettings) -> ChannelSet:
    """``channels`` with each joint-torque channel's actuation models set from ``settings`` (module doc).

    Raises:
        IdentificationError: an actuation model asked for and no joint-torque channel among ``channels``.
    """
    actuated = [c for c in channels if is_actuated(c)]
    if not actuated:
        if settings.actuation_requested:
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
        if _has_field(c, "stribeck_velocity"):
            k.update(stribeck_velocity=_velocity(settings.stribeck_velocity, "stribeck_velocity"), identified=())
        elif settings.stribeck_velocity:
            raise IdentificationError(
                f"channel {c.key!r} has no Stribeck friction model; leave --stribeck-velocity out",
                status="no_torque_channel",
            )
        out = out.replace(
            dataclasses.replace(
                c,
                friction=tuple(f for f in FRICTION_MODELS if f in settings.friction),
                coulomb_zone=_velocity(settings.coulomb_zone, "coulomb_zone"),
                asymmetric=bool(settings.asymmetric_friction),
                armature=bool(settings.armature),
                torque_offset=bool(settings.torque_offset),
                **k,
            )
        )
    return out


def _velocity(value, name: str) -> float:
    """A friction velocity of the settings as the channel takes it.

    Raises:
        IdentificationError: ``"identify"``: the search of :mod:`ineid.identify.friction_search` sets it before
            the channels are chosen, for one dataset; anywhere else (an analysis, several recordings) it is given.
    """
    if value == IDENTIFY:
        option = "--" + name.replace("_", "-")
        raise IdentificationError(
            f"{option} identify is found by the solve of one dataset; here give it in rad/s", status="unsupported"
        )
    return float(value)


def with_coupling(channels: ChannelSet, settings: SolveSettings, model) -> ChannelSet:
    """``channels`` with ``settings.coupling`` (a file, :func:`ineid.channels.transmission.read_coupling`) set on
    each joint-torque channel; unchanged without one."""
    if not settings.coupling:
        return channels
    from ineid.channels.transmission import read_coupling

    matrix, motors = read_coupling(settings.coupling, model.joint_names)
    out = channels
    for c in channels:
        if is_actuated(c):
            if not _has_field(c, "coupling"):
                raise IdentificationError(
                    f"channel {c.key!r} reads no coupled transmission; leave --coupling out", status="unsupported"
                )
            out = out.replace(dataclasses.replace(c, coupling=matrix, motors=motors))
    return out


def _has_field(channel, name: str) -> bool:
    return name in {f.name for f in dataclasses.fields(channel)}


def _has_torque_constant(channel) -> bool:
    """Whether ``channel`` reads torques through torque constants that can be identified (a motor current)."""
    return "identify_k" in {f.name for f in dataclasses.fields(channel)}


def solve_channels(ds, settings: SolveSettings, model) -> ChannelSet:
    """The channels ``solve_dataset`` fits: the dataset's chosen by ``settings.use``, the joint torques'
    actuation models set (:func:`with_actuation`), each with offsets when ``settings.bias == "estimate"``.

    Raises:
        IdentificationError: an unknown ``use`` name, actuation models without joint torques, or channels
            ``casadi-c`` cannot fit (extra kept columns, anything but one base wrench in the base frame).
        DatasetError: a wrist sensor with nothing the model moves beyond it (it reads zeros).
    """
    channels = with_actuation(select_channels(ds.meta.channels, settings.use), settings)
    channels = with_coupling(channels, settings, model).with_offsets(settings.estimates_offsets)
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


def noise_levels(ds, settings: SolveSettings, channels: ChannelSet, model) -> np.ndarray | None:
    """The noise per measured axis of ``channels`` for ``weights="noise"`` (None for the other weights):
    ``settings.axis_sigma``, or recorded with the data (per channel).

    Raises:
        IdentificationError: ``axis_sigma`` of another length than the channels' axes, or none given and none
            recorded.
    """
    if settings.weights != "noise":
        return None
    n_axes = channels.n_axes(model)
    if settings.axis_sigma is not None:
        sigma = np.asarray(settings.axis_sigma, dtype=np.float64)
        if sigma.shape != (n_axes,):
            raise IdentificationError(
                f"axis_sigma holds {sigma.size} numbers; the channels measure {n_axes} axes "
                f"({', '.join(channels.axes(model))}): give one per axis",
                status="bad_noise_levels",
            )
        return sigma
    recorded = channels.noise_std(ds.meta.noise, model)
    if recorded is None:
        what = "the wrench noise" if channels.keys == ("wrench",) else "the noise of every channel"
        raise IdentificationError(
            f"weights='noise' needs {what} per axis: give axis_sigma (--sigma FX FY FZ MX MY MZ) "
            "or use weights='estimate'",
            status="no_noise_levels",
        )
    return recorded


def two_step_channels(channels: ChannelSet) -> tuple[ChannelSet, ChannelSet]:
    """``(wrench channels, joint-torque channels)`` of ``channels``: what each of the two steps fits
    (:mod:`ineid.identify.two_step`).

    Raises:
        IdentificationError: either is missing (status ``two_step_channels``).
    """
    wrench = tuple(c for c in channels if not is_actuated(c))
    torque = tuple(c for c in channels if is_actuated(c))
    if not wrench or not torque:
        raise IdentificationError(
            f"--two-step fits the links from the wrench, then the joint torques' friction; the channels fitted "
            f"({', '.join(channels.keys)}) lack {'a wrench' if not wrench else 'joint torques'}: use both "
            "(--use wrench,torque on a dataset with both) or leave --two-step out",
            status="two_step_channels",
        )
    return ChannelSet(wrench), ChannelSet(torque)


def _axis_slice(
    axis_sigma: tuple[float, ...] | None, channels: ChannelSet, part: ChannelSet, model
) -> tuple[float, ...] | None:
    """``axis_sigma`` (``SolveSettings.axis_sigma``, over ``channels``' stacked axes) at ``part``'s axes."""
    if axis_sigma is None:
        return None
    sigma = np.asarray(axis_sigma, dtype=np.float64)
    if sigma.shape != (channels.n_axes(model),):
        raise IdentificationError(
            f"axis_sigma holds {sigma.size} numbers; the channels measure "
            f"{channels.n_axes(model)} axes: give one per axis",
            status="bad_noise_levels",
        )
    parts = channels.split(sigma, model)
    return tuple(float(v) for c in part for v in parts[c.key])


def wrench_settings(ds, settings: SolveSettings, model) -> SolveSettings:
    """Step 1's settings: ``settings`` on the wrench channels alone, without actuation models.

    Raises:
        IdentificationError: no wrench or no joint-torque channel among those chosen, or no actuation model.
    """
    channels = select_channels(ds.meta.channels, settings.use)
    wrench, _ = two_step_channels(channels)
    if not settings.actuation_requested:
        raise IdentificationError(
            "--two-step fits the joint torques' friction, armature or offsets after the links: "
            "give at least one (--friction viscous,coulomb, --armature, --torque-offset)",
            status="two_step_nothing",
        )
    return dataclasses.replace(
        settings,
        use=wrench.keys,
        two_step=False,
        friction=(),
        coulomb_zone=0.0,
        stribeck_velocity=0.0,
        asymmetric_friction=False,
        armature=False,
        torque_offset=False,
        torque_constant_unknown=False,
        coupling=None,
        axis_sigma=_axis_slice(settings.axis_sigma, channels, wrench, model),
    )


def torque_noise_levels(ds, settings: SolveSettings, channels: ChannelSet, torque: ChannelSet, model):
    """The noise per axis of ``torque``, the joint-torque channels among ``channels``, for ``weights="noise"``
    (None otherwise): ``settings.axis_sigma`` (over ``channels``' axes) at theirs, or recorded with the data.

    Raises:
        IdentificationError: ``axis_sigma`` of another length than the channels' axes, or none given and none
            recorded.
    """
    if settings.weights != "noise":
        return None
    axis_sigma = _axis_slice(settings.axis_sigma, channels, torque, model) or torque.noise_std(ds.meta.noise, model)
    if axis_sigma is None:
        raise IdentificationError(
            "weights='noise' needs the joint torques' noise per axis: give axis_sigma or use weights='estimate'",
            status="no_noise_levels",
        )
    return axis_sigma
