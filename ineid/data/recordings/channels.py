"""Which measurement channels a recording holds: the F/T sensor's wrench (where it sits), and what rides on
the joints' clock (joint torques, motor currents).

:func:`ineid.data.recordings.pipeline.recording_dataset` asks here for the channel records and checks;
the streams themselves are :class:`ineid.data.recordings.streams.Streams`.
"""

from __future__ import annotations

import numpy as np

from ineid.channels import BaseWrench, Channel
from ineid.channels.pose import SensorPose, parse_sensor_pose
from ineid.errors import DatasetError

RIDER_NAMES = {"tau": "joint torques", "current": "motor currents"}
"""The channels a recording carries on the joints' clock, by dataset key (:class:`Streams` fields)."""


def joint_channels(streams, model, n_samples: int, settings=None) -> dict[str, np.ndarray]:
    """``{key: (Nq, n_dof)}`` of the recorded joint torques (``tau``) and motor currents (``current``).

    Raises:
        DatasetError: an array that is not one column per joint and one row per joint sample;
            motor currents without the drives' torque constants and gear ratios (``settings``).
    """
    out = {}
    for key, what in RIDER_NAMES.items():
        a = getattr(streams, key, None)
        if a is None:
            continue
        a = np.asarray(a, dtype=np.float64)
        if a.ndim != 2 or a.shape != (n_samples, model.n_dof):
            raise DatasetError(
                f"{streams.source}: {what} of shape {a.shape} for {n_samples} joint samples; {model.name} has "
                f"{model.n_dof} joints ({', '.join(model.joint_names)}): give one column per joint"
            )
        out[key] = a
    drives = settings is not None and (settings.torque_constant is not None or settings.gear_ratio is not None)
    if drives and "current" not in out:
        raise DatasetError(
            f"{streams.source}: --torque-constant and --gear-ratio are the motor currents' drives, "
            "and the recording has no currents (i1..in); drop them"
        )
    if "current" in out and (settings is None or settings.torque_constant is None or settings.gear_ratio is None):
        raise DatasetError(
            f"{streams.source}: motor currents are read through the drives: give their torque constants and gear "
            "ratios (--torque-constant K, --gear-ratio G: one number, or one per joint), or the joint torques "
            "instead (tau1..tauN)"
        )
    return out


def _per_joint(values, model, what: str) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if len(values) == 1:
        values *= model.n_dof
    if len(values) != model.n_dof:
        raise DatasetError(
            f"{len(values)} {what} for {model.n_dof} joints ({', '.join(model.joint_names)}); give one "
            "number, or one per joint"
        )
    return values


def rider_channels(riders, model=None, settings=None) -> list[Channel]:
    """The channels of :func:`joint_channels`' keys, as measured (no actuation model: that is identification's):
    the joint torques ``tau``, the motor currents ``current`` with ``settings``' drives."""
    from ineid.channels.torque import JointTorque

    out: list[Channel] = []
    for key in riders:
        if key == "tau":
            out.append(JointTorque())
        elif key == "current":
            from ineid.channels.torque import MotorCurrent

            out.append(
                MotorCurrent(
                    torque_constant=_per_joint(settings.torque_constant, model, "torque constants"),
                    gear_ratio=_per_joint(settings.gear_ratio, model, "gear ratios"),
                )
            )
    if out and getattr(settings, "coupling", None):
        import dataclasses

        from ineid.channels.transmission import read_coupling

        matrix, motors = read_coupling(settings.coupling, model.joint_names)
        out = [dataclasses.replace(c, coupling=matrix, motors=motors) for c in out]
    return out


def resolve_wrench_channel(pose_text: str | None, frame_id: str | None, model) -> tuple[Channel, str]:
    """The channel of a recording's wrench, and where its sensor pose is given (for the summary).

    The sensor sits under the base (a :class:`ineid.channels.BaseWrench` at :func:`resolve_sensor`'s
    pose) unless ``pose_text`` (or, without it, the messages' ``frame_id``) names a sensor on a
    moving link, as :func:`ineid.channels.link_wrench.sensor_channel` reads it (``LINK``,
    ``LINK:x,y,z,roll,pitch,yaw``, or a URDF frame welded to a moving link): then the channel
    is the wrench at that link (kind ``link_wrench``, key ``wrench_<link>``), its pose in the
    link's frame. The messages' ``frame_id`` is recorded with the pose.

    Raises:
        DatasetError: a link that is not in the model, a pose that does not parse (and
            :func:`resolve_sensor`'s errors).
    """
    from dataclasses import replace

    from ineid.channels.link_wrench import LinkWrench, sensor_channel

    text = None if pose_text is None else pose_text.strip()
    if text:
        name = text.partition(":")[0].strip()
        on_link = ":" in text or name in model.chain.body_links
    else:
        on_link = bool(frame_id) and frame_id in model.chain.body_links  # a bag's frame on a moving link
    if on_link:
        channel = sensor_channel(text or frame_id, model)
        if isinstance(channel, LinkWrench):
            if frame_id is not None:
                channel = replace(channel, sensor=replace(channel.sensor or SensorPose(), frame_id=frame_id))
            return channel, f"link {channel.link!r}'s frame"
    return BaseWrench(sensor=resolve_sensor(pose_text, frame_id, model)), "the base frame"


def resolve_sensor(pose_text: str | None, frame_id: str | None, model) -> SensorPose:
    """The sensor pose from ``--sensor-pose``, else from the messages' ``frame_id``, else the base frame.

    Raises:
        DatasetError, RobotModelError: a pose that does not parse, a frame the URDF does
            not have or that moves with the arm.
    """
    from dataclasses import replace

    from ineid.robots.urdf import fixed_frame_pose

    source = f"the URDF of {model.name}"
    if pose_text is not None:
        pose = parse_sensor_pose(pose_text, model.urdf_text, model.locked_joints or None, source)
    elif frame_id:
        if frame_id == model.chain.root_link:
            pose = SensorPose(frame=frame_id)
        else:
            try:
                r, p = fixed_frame_pose(model.urdf_text, frame_id, source, model.locked_joints or None)
            except Exception as e:  # re-raised below with the fix
                raise DatasetError(
                    f"the wrench messages are in frame {frame_id!r}: {e}; give the sensor's pose in the base frame "
                    "with --sensor-pose x,y,z,roll,pitch,yaw (0,0,0,0,0,0 if it is the base frame)"
                ) from None
            pose = SensorPose.from_matrix(r, p, frame=frame_id)
    else:
        pose = SensorPose()
    return replace(pose, frame_id=frame_id)
