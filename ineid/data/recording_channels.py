"""Which measurement channels a recording holds: the F/T sensor's wrench (where it sits), and what rides on
the joints' clock (joint torques, motor currents).

:func:`ineid.data.recording.recording_dataset` asks here for the channel records and checks;
the streams themselves are :class:`ineid.data.streams.Streams`.
"""

from __future__ import annotations

import numpy as np

from ineid.channels import BaseWrench, Channel
from ineid.channels.pose import SensorPose, parse_sensor_pose
from ineid.errors import DatasetError

RIDER_NAMES = {"tau": "joint torques", "current": "motor currents"}
"""The channels a recording carries on the joints' clock, by dataset key (:class:`Streams` fields)."""


def joint_channels(streams, model, n_samples: int) -> dict[str, np.ndarray]:
    """``{key: (Nq, n_dof)}`` of the recorded joint torques (``tau``) and motor currents (``current``).

    Raises:
        DatasetError: an array that is not one column per joint and one row per joint sample;
            motor currents, which need a motor-current channel this ineid does not have yet.
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
                f"{model.n_dof} joints ({', '.join(model.joint_names)}): give one {what[6:-1]} per joint"
            )
        out[key] = a
    if "current" in out:
        raise DatasetError(
            f"{streams.source}: motor currents need the motor-current channel (gear ratio, torque constant), which "
            "this ineid does not have yet; give the joint torques instead (tau = k * gear * i, columns tau1..tauN)"
        )
    return out


def rider_channels(riders) -> list[Channel]:
    """The channels of :func:`joint_channels`' keys, as measured (no actuation model: that is identification's)."""
    from ineid.channels.torque import JointTorque  # noqa: PLC0415

    return [JointTorque() for key in riders if key == "tau"]


def resolve_wrench_channel(pose_text: str | None, frame_id: str | None, model) -> tuple[Channel, str]:
    """The channel of a recording's wrench and where its sensor pose is given (for the summary).

    Today the base wrench at :func:`resolve_sensor`'s pose.
    """
    return BaseWrench(sensor=resolve_sensor(pose_text, frame_id, model)), "the base frame"


def resolve_sensor(pose_text: str | None, frame_id: str | None, model) -> SensorPose:
    """The sensor pose from ``--sensor-pose``, else from the messages' ``frame_id``, else the base frame.

    Raises:
        DatasetError, RobotModelError: a pose that does not parse, a frame the URDF does
            not have or that moves with the arm.
    """
    from dataclasses import replace  # noqa: PLC0415

    from ineid.robots.urdf import fixed_frame_pose  # noqa: PLC0415

    source = f"the URDF of {model.name}"
    if pose_text is not None:
        pose = parse_sensor_pose(pose_text, model.urdf_text, model.locked_joints or None, source)
    elif frame_id:
        if frame_id == model.chain.root_link:
            pose = SensorPose(frame=frame_id)
        else:
            try:
                r, p = fixed_frame_pose(model.urdf_text, frame_id, source, model.locked_joints or None)
            except Exception as e:  # noqa: BLE001 - re-raised below with the fix
                raise DatasetError(
                    f"the wrench messages are in frame {frame_id!r}: {e}; give the sensor's pose in the base frame "
                    "with --sensor-pose x,y,z,roll,pitch,yaw (0,0,0,0,0,0 if it is the base frame)"
                ) from None
            pose = SensorPose.from_matrix(r, p, frame=frame_id)
    else:
        pose = SensorPose()
    return replace(pose, frame_id=frame_id)
