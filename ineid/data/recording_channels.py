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
                f"{model.n_dof} joints ({', '.join(model.joint_names)}): give one column per joint"
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
    """The channel of a recording's wrench, and where its sensor pose is given (for the summary).

    The sensor sits under the base (a :class:`ineid.channels.BaseWrench` at :func:`resolve_sensor`'s
    pose) unless ``pose_text`` (or, without it, the messages' ``frame_id``) names a frame on a
    moving link: ``LINK:x,y,z,roll,pitch,yaw`` (the pose in URDF link ``LINK``'s frame; a link
    welded to the base gives the base wrench), or a URDF link welded to a moving link. Then
    the channel is a wrench at that link (kind ``link_wrench``, key ``wrench_<link>``), the
    sensor's pose in the moving link's frame.

    Raises:
        DatasetError: a link that is not in the model, a pose that does not parse (and
            :func:`resolve_sensor`'s errors).
    """
    text = None if pose_text is None else pose_text.strip()
    if text and ":" in text:
        link, _, numbers = text.partition(":")
        link = link.strip()
        if not numbers.strip() or not link:
            raise DatasetError(f"sensor pose {pose_text!r}: expected LINK:x,y,z,roll,pitch,yaw (m, rad, URDF rpy)")
        local = parse_sensor_pose(numbers)
        body = _moving_body(link, model)
        if body is None:
            if not _welded_to_root(link, model):
                raise DatasetError(
                    f"sensor pose {pose_text!r}: {link!r} is not a link of {model.name}; its links: "
                    f"{', '.join(_link_names(model))}"
                )
            base = parse_sensor_pose(link, model.urdf_text, model.locked_joints or None, f"the URDF of {model.name}")
            pose = _compose(base, local, frame=None)
            return BaseWrench(sensor=_with_frame_id(pose, frame_id)), "the base frame"
        pose = _compose(_in_body(link, model), local, frame=None)
        return _link_wrench(body, _with_frame_id(pose, frame_id)), f"link {body!r}'s frame"
    name = text if text and _is_name(text) else (frame_id if text is None else None)
    body = None if name is None else _moving_body(name, model)
    if body is not None:
        return _link_wrench(body, _with_frame_id(_in_body(name, model), frame_id)), f"link {body!r}'s frame"
    return BaseWrench(sensor=resolve_sensor(pose_text, frame_id, model)), "the base frame"


def _is_name(text: str) -> bool:
    try:
        float(text.replace(" ", ",").split(",")[0])
    except ValueError:
        return True
    return False


def _link_names(model) -> list[str]:
    return [model.chain.root_link, *(n for n in model.chain.body_links if n != model.chain.root_link)]


def _moving_body(link: str, model) -> str | None:
    """The moving link that URDF link ``link`` is (or is welded to), or None (the root's, or no such link)."""
    info = model.chain.body_links.get(link)
    return None if info is None else info.body


def _welded_to_root(link: str, model) -> bool:
    return link == model.chain.root_link or link in model.chain.merged_links.get(model.chain.root_link, ())


def _in_body(link: str, model) -> SensorPose:
    """The pose of URDF link ``link`` in its moving body's frame (the identity for the body itself)."""
    info = model.chain.body_links[link]
    return SensorPose.from_matrix(np.asarray(info.body_R_link), np.asarray(info.body_p_link), frame=link)


def _compose(outer: SensorPose, inner: SensorPose, frame: str | None) -> SensorPose:
    """``outer @ inner``: the pose ``inner`` (given in ``outer``'s frame) in the frame ``outer`` is given in."""
    if outer.is_identity:  # the numbers as given, not a round trip through a rotation matrix
        from dataclasses import replace  # noqa: PLC0415

        return replace(inner, frame=frame if frame is not None else inner.frame)
    r = outer.base_R_sensor @ inner.base_R_sensor
    p = outer.base_R_sensor @ np.asarray(inner.base_p_sensor) + np.asarray(outer.base_p_sensor)
    return SensorPose.from_matrix(r, p, frame=frame if frame is not None else inner.frame)


def _with_frame_id(pose: SensorPose, frame_id: str | None) -> SensorPose:
    from dataclasses import replace  # noqa: PLC0415

    return replace(pose, frame_id=frame_id)


def link_wrench_key(link: str) -> str:
    """``wrench_<link>``: a valid channel key (lower case, ``_`` for other characters, at most 32)."""
    import re  # noqa: PLC0415

    return ("wrench_" + re.sub(r"[^a-z0-9_]", "_", link.lower()))[:32]


def _link_wrench(body: str, pose: SensorPose) -> Channel:
    from ineid.channels.link_wrench import LinkWrench  # noqa: PLC0415

    return LinkWrench(key=link_wrench_key(body), link=body, sensor=pose)


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
