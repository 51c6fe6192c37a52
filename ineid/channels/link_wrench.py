"""An F/T sensor on any link: the wrench that everything beyond it exerts on it, in its own frame.

A wrist sensor between link ``L`` and what follows (the next links, a tool or payload welded
to ``L`` and named as a payload) reads, in the sensor frame, moment about the sensor origin,

    w_s = X_s Y_L(q, qd, qdd) theta

where ``Y_L theta`` is the wrench the blocks beyond ``L`` exert on it in ``L``'s frame, moment
about ``L``'s origin (:meth:`ineid.RobotModel.link_wrench_regressor`: the backward pass of
Newton-Euler, the base wrench's twin at a cut inside the chain), and ``X_s`` the 6x6 wrench
transform of the sensor's pose in ``L`` (:func:`ineid.channels.pose.wrench_transform`), constant
because the sensor is fixed to ``L``: the channel's ``T``. Six offsets, as for the base wrench.

What is beyond: the moving links after ``L`` and the payload blocks welded to ``L``
(``--unknown-links``). A known link welded to ``L`` is part of ``L``'s body in the model, so a
sensor given as a URDF frame with a massive known link welded beyond it is refused in one line
(name that link as a payload to identify it).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ineid.channels.base import Channel, check_key, register
from ineid.channels.pose import SensorPose, parse_sensor_pose, regressor_in_sensor, wrench_in_sensor
from ineid.channels.wrench import BaseWrench, WrenchSensor
from ineid.errors import DatasetError


@register
@dataclass(frozen=True, kw_only=True)
class LinkWrench(WrenchSensor):
    """The wrench at an F/T sensor on moving link ``link`` (see the module docstring).

    Attributes:
        key: where its values are stored (default ``"wrench_link"``), (C, F, 6), N and N*m.
        link: the moving link the sensor is mounted on.
        sensor: the sensor's pose in the link's frame; None (or identity): the link frame.
        offsets: six constant offsets (an untared sensor) are identified with the parameters.
    """

    key: str = "wrench_link"
    link: str = ""

    kind = "link_wrench"
    RECORD_FIELDS = ("link", "sensor")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.link, str) or not self.link:
            raise DatasetError(f"link-wrench channel {self.key!r}: name the link the sensor is mounted on")

    def describe(self) -> str:
        return f"wrench at link {self.link!r} '{self.key}' ({self.frame_text('link frame')})" + (
            ", six offsets identified" if self.offsets else ""
        )

    # -- the model ------------------------------------------------------------------------
    def entries_function(self, model):
        return model.jax_link_wrench_functions(self.link).entries

    def nonzero(self, model) -> tuple[tuple[int, ...], ...]:
        return model.link_wrench_nonzero(self.link)

    def casadi_function(self, model):
        return model.casadi_link_wrench_regressor(self.link)

    def phi_function(self, model):
        return model.jax_link_wrench_functions(self.link).regressor

    def phi_theta_function(self, model):
        return model.jax_link_wrench_functions(self.link).wrench

    def rows(self, model, q, qd, qdd) -> np.ndarray:
        return regressor_in_sensor(self.transform(), model.link_wrench_regressor(q, qd, qdd, self.link))

    def predict(self, model, q, qd, qdd, theta) -> np.ndarray:
        return wrench_in_sensor(self.transform(), model.link_wrench(q, qd, qdd, self.link, theta))

    # -- record ---------------------------------------------------------------------------
    def _record(self) -> dict:
        return {"link": self.link, **super()._record()}

    @classmethod
    def _parse_record(cls, d: Mapping, where: str) -> dict:
        link = d.get("link")
        if not isinstance(link, str) or not link:
            raise DatasetError(f"{where}: the link-wrench channel must name its link, got {link!r}")
        return {"link": link, **super()._parse_record(d, where)}


LINK_KEY_PREFIX = "wrench_"


def link_key(link: str) -> str:
    """A dataset key for the wrench at ``link``: ``wrench_<link>`` lower-cased, other characters as ``_``."""
    import re
    import zlib

    key = LINK_KEY_PREFIX + re.sub(r"[^a-z0-9_]", "_", link.lower())
    return key if len(key) <= 32 else key[:23] + f"_{zlib.crc32(link.encode()) % 10**8:08d}"


def link_frame(
    text: str, model, what: str = "sensor pose", otherwise: str = ", or six numbers for a sensor under the base"
) -> tuple[str, SensorPose, bool] | None:
    """``(moving link, pose in its frame, from a URDF frame)`` that ``text`` names, or None when it names no link.

    ``text``: ``LINK`` or ``LINK:x,y,z,roll,pitch,yaw`` with a moving link of ``model`` (the pose in its
    frame; ``LINK`` alone: its origin), or a URDF link welded to a moving link (its pose in that
    link's frame, from the URDF; the third item True). Anything else without a ``:`` is None (the
    caller's other forms, such as six numbers for a sensor under the base).

    Raises:
        DatasetError: a ``:`` after a name that is no moving link, or a URDF frame given a pose
            (one line: ``what``, the text, the moving links to choose from, and ``otherwise``).
    """
    moving = [j.link for j in model.chain.joints]
    name, _, pose = text.strip().partition(":")
    name = name.strip()
    if not (pose.strip() or name in moving or name in model.chain.body_links):
        return None
    if name in moving:
        return name, parse_sensor_pose(pose) if pose.strip() else SensorPose(), False
    link = model.chain.body_links.get(name)
    if link is not None and pose.strip():  # a URDF frame welded to a moving link, given a pose
        raise DatasetError(
            f"{what} {text.strip()!r}: {name!r} is a URDF frame on {link.body!r} and takes no pose; "
            f"give {name} alone, or {link.body}:x,y,z,roll,pitch,yaw (the pose in {link.body}'s frame)"
        )
    if link is None:
        raise DatasetError(
            f"{what} {text.strip()!r}: {name!r} is not a moving link of {model.name} (choose from "
            f"{', '.join(moving)}, or give a URDF frame welded to one{otherwise})"
        )
    return link.body, SensorPose.from_matrix(link.body_R_link, link.body_p_link, frame=name), True


def sensor_channel(text: str | None, model, key: str | None = None, offsets: bool = False) -> Channel:
    """The wrench channel a ``--sensor-pose`` names, for ``model``.

    ``text``: ``x,y,z,roll,pitch,yaw`` (m, rad, URDF rpy) or a URDF frame welded to the root:
    the base wrench (:class:`BaseWrench`); ``LINK`` or ``LINK:x,y,z,roll,pitch,yaw`` with a moving
    link, or a URDF frame welded to a moving link: the wrench at that link (:class:`LinkWrench`,
    resolved by :func:`link_frame`).

    Raises:
        DatasetError: the text does not parse, names no link or frame of the model, or a frame
            has a massive known link welded beyond it (one line naming the fix).
    """
    text = (text or "").strip()
    on_link = link_frame(text, model)
    if on_link is not None:
        link, sensor, from_frame = on_link
        if from_frame:
            _refuse_known_beyond(model, sensor.frame)
        return LinkWrench(
            key=check_key(key or link_key(link)),
            link=link,
            offsets=offsets,
            sensor=None if sensor.is_identity else sensor,
        )
    base = parse_sensor_pose(text or None, model.urdf_text, model.locked_joints, source=f"{model.name}'s URDF")
    return BaseWrench(key=key or "wrench", offsets=offsets, sensor=None if base.is_identity else base)


def refuse_nothing_beyond(model, link: str) -> None:
    """One line when nothing the model moves is beyond ``link``: a sensor there would read zero at every frame."""
    if any(model.link_wrench_nonzero(link)):
        return
    moving = [j.link for j in model.chain.joints]
    earlier = [name for name in moving[: moving.index(link)] if any(model.link_wrench_nonzero(name))]
    raise DatasetError(
        f"a sensor on {link!r} reads nothing: no moving link or payload of {model.name} is beyond it; mount it on "
        f"{'an earlier link (' + ', '.join(earlier) + ')' if earlier else 'an earlier link'}, or name a payload "
        f"welded to {link} in --unknown-links"
    )


def _refuse_known_beyond(model, frame: str) -> None:
    """One line when a known link with mass is welded beyond ``frame`` (the model folds it into the body)."""
    beyond, grew = {frame}, True
    links = model.chain.body_links
    while grew:
        grew = False
        for b in links.values():
            if b.parent in beyond and b.name not in beyond:
                beyond.add(b.name)
                grew = True
    massive = [n for n in sorted(beyond - {frame}) if n not in model.unknown_links and links[n].theta[0] > 0]
    if massive:
        raise DatasetError(
            f"sensor frame {frame!r}: link {massive[0]!r} (mass {links[massive[0]].theta[0]:g} kg) is "
            f"welded beyond it but is part of {links[frame].body!r}'s CAD in the model; name it in "
            "--unknown-links to identify it as a payload beyond the sensor"
        )
