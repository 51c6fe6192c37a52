"""ROS bags in: ``sensor_msgs/JointState`` and ``geometry_msgs/WrenchStamped``, no ROS needed.

Read with ``rosbags`` (pure Python): a ROS 1 ``.bag``, a ROS 2 bag folder (sqlite3 or MCAP
storage, with its ``metadata.yaml``), or a bare ``.mcap`` file. Message definitions come
from the bag itself.

* Joint states: the topic ``joint_topic`` (default ``/joint_states``). Joints are matched
  to the model's by name, in any order (each message may order them differently); extra
  joints (a gripper, a head) are ignored; a model joint missing from a message is an error
  naming it. Positions are read (velocities and accelerations are derived consistently
  from them, :mod:`ineid.data.recordings.pipeline`), and ``effort`` as the joint torques when the
  messages carry it (every message, one per name; empty in all: no torques), matched by
  name like the positions.
* Wrench: the one ``WrenchStamped`` topic of the bag, or ``wrench_topic`` when there are
  several. Its ``header.frame_id`` is recorded (and names the sensor frame when the URDF
  has that link). A bag without one is read when its joint states carry efforts (a lab
  with joint torque sensors only).
* Link IMUs: each ``sensor_msgs/Imu`` topic of ``imu_topics``, on its own clock: its
  ``angular_velocity`` (a gyroscope, rad/s) and ``linear_acceleration`` (an accelerometer's
  specific force, m/s^2), both in the message's frame, each left out when its covariance's first
  element is -1 (ROS's "not measured"); the IMU's name is the messages' ``header.frame_id`` (a
  link, a URDF frame on a link, or the name of an ``--imu NAME=LINK:pose``). Angular acceleration
  (the paper's sensor; ROS has no message for it) is a ``geometry_msgs/Vector3Stamped`` on
  ``<imu topic>/angular_acceleration`` (rad/s^2, sensor frame), read as a stream of its own clock
  when the bag has that topic.
* Time: each message's ``header.stamp`` (the measurement time); a zero stamp falls back
  to the time the bag logged the message. Times are seconds from the earliest message of
  the two topics; the absolute start is recorded in the dataset's origin.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ineid._faults import require_memory
from ineid.data.recordings.bag_reader import bag_kind, open_bag
from ineid.data.recordings.streams import VALUE_LIMIT, Streams, first_beyond
from ineid.errors import DatasetError

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
IMU = "sensor_msgs/msg/Imu"
VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
ANGULAR_ACCELERATION = "/angular_acceleration"
"""The suffix of an IMU topic's angular-acceleration topic (``geometry_msgs/Vector3Stamped``, rad/s^2)."""
MAX_MESSAGES = 100_000_000
"""The most messages ineid reads from a bag's topics (joint states, wrench, IMUs together), as many as the
rows of a CSV (:data:`ineid.data.recordings.csv_rows.MAX_ROWS`); the memory they need is checked too, before reading."""


def _stamp_ns(msg, log_ns: int) -> int:
    stamp = msg.header.stamp
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns > 0 else int(log_ns)


def read_bag_streams(
    path: str | Path,
    joint_names: Sequence[str],
    joint_topic: str = "/joint_states",
    wrench_topic: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    imu_topics: Sequence[str] = (),
):
    """Read joint angles and the sensor wrench from a ROS bag into :class:`ineid.data.recordings.streams.Streams`.

    Args:
        path: ROS 1 ``.bag``, ROS 2 bag folder, or ``.mcap`` file.
        joint_names: the model's joints in chain order (``RobotModel.joint_names``).
        joint_topic: the ``sensor_msgs/JointState`` topic.
        wrench_topic: the ``geometry_msgs/WrenchStamped`` topic; None: the only one in the bag.
        progress: ``progress(done, total)`` over messages read.
        imu_topics: ``sensor_msgs/Imu`` topics of link IMUs (with ``<topic>/angular_acceleration``
            when the bag has it).

    Raises:
        DatasetError: the bag cannot be read; a topic is missing or of another type (the
            message lists what the bag has); several wrench topics and none chosen; a
            model joint missing from the joint states (named); positions or efforts not
            matching names (efforts in some messages only); the wrench ``frame_id``
            changing within the recording; neither a wrench topic nor efforts.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    joint_names = list(joint_names)
    with open_bag(path) as (connections, messages, deserialize):
        topics = _chosen_topics(path, connections, joint_topic, wrench_topic, imu_topics)
        conns = topics.joint + topics.wrench + topics.imu
        total = sum(c.msgcount for c in conns)
        _check_messages(path, total, len(joint_names))
        read = _Messages(path, topics, joint_topic, joint_names)
        done = 0
        for conn, log_ns, raw in messages(conns):
            read.add(conn, log_ns, deserialize(raw, conn.msgtype))
            done += 1
            if progress is not None and done % 5000 == 0:
                progress(done, total)
        if progress is not None:
            progress(done, total)
    return _bag_streams(path, joint_topic, topics, read)


@dataclass
class _Topics:
    """The bag's connections to read, each topic checked for its message type.

    Attributes:
        joint: the joint states' connections.
        wrench: the wrench's connections (none without a wrench topic).
        imu: the IMU topics' connections and their angular-acceleration topics'.
        imu_of: the IMU topic of each topic in ``imu``.
        wrench_topic: the wrench topic read, None when the bag has none (the efforts are the measurement).
        available: the bag's topics and their types, for messages.
    """

    joint: list
    wrench: list
    imu: list
    imu_of: dict[str, str]
    wrench_topic: str | None
    available: str
    unused_imu: tuple[str, ...] = ()


def _chosen_topics(
    path: Path, connections, joint_topic: str, wrench_topic: str | None, imu_topics: Sequence[str]
) -> _Topics:
    """The connections of the joint-state topic, the wrench topic (given, or the bag's only one) and the IMU
    topics, each of the right message type.

    Raises:
        DatasetError: a topic missing or of another type (naming the bag's topics), several wrench topics and
            none chosen.
    """
    by_topic: dict[str, list] = {}
    for c in connections:
        by_topic.setdefault(c.topic, []).append(c)
    available = ", ".join(f"{t} ({cs[0].msgtype})" for t, cs in sorted(by_topic.items())) or "none"
    jconns = by_topic.get(joint_topic)
    if not jconns:
        states = [t for t, cs in by_topic.items() if cs[0].msgtype == JOINT_STATE]
        hint = f"; its JointState topics: {', '.join(states)}: pass --joint-topic" if states else ""
        raise DatasetError(f"{path}: the bag has no topic {joint_topic!r}{hint} (topics: {available})")
    if jconns[0].msgtype != JOINT_STATE:
        raise DatasetError(f"{path}: topic {joint_topic!r} holds {jconns[0].msgtype}, not {JOINT_STATE}")
    wrenches = sorted(t for t, cs in by_topic.items() if cs[0].msgtype == WRENCH_STAMPED)
    if wrench_topic is None:
        if len(wrenches) > 1:
            raise DatasetError(
                f"{path}: the bag has {len(wrenches)} wrench topics ({', '.join(wrenches)}); "
                "choose one with --wrench-topic"
            )
        wrench_topic = wrenches[0] if wrenches else None  # none: the joint states' efforts must be there
    wconns = by_topic.get(wrench_topic) if wrench_topic is not None else []
    if wrench_topic is not None and not wconns:
        hint = f"; its wrench topics: {', '.join(wrenches)}" if wrenches else ""
        raise DatasetError(f"{path}: the bag has no topic {wrench_topic!r}{hint} (topics: {available})")
    if wconns and wconns[0].msgtype != WRENCH_STAMPED:
        raise DatasetError(f"{path}: topic {wrench_topic!r} holds {wconns[0].msgtype}, not {WRENCH_STAMPED}")
    iconns, imu_of = _imu_connections(path, by_topic, imu_topics, available)
    unused = tuple(sorted(t for t, cs in by_topic.items() if cs[0].msgtype == IMU and t not in imu_topics))
    return _Topics(jconns, wconns, iconns, imu_of, wrench_topic, available, unused)


class _Messages:
    """The messages of the chosen topics, gathered as they are read: joint states, wrenches, IMU readings."""

    def __init__(self, path: Path, topics: _Topics, joint_topic: str, joint_names: list[str]) -> None:
        self.joints = _JointStates(path, joint_topic, joint_names, sum(c.msgcount for c in topics.joint))
        n_w = sum(c.msgcount for c in topics.wrench)
        self.tw, self.w = _Rows(1, n_w, np.int64), _Rows(6, n_w)  # ns stamps; N and Nm
        self.frame_ids: set[str] = set()  # the wrench messages' frame_id
        self.imu_data: dict[str, tuple[list, list, set]] = {c.topic: ([], [], set()) for c in topics.imu}
        self._joint_ids = {c.id for c in topics.joint}

    def add(self, conn, log_ns: int, msg) -> None:
        """Gather one deserialized message of connection ``conn``, logged at ``log_ns``."""
        if conn.topic in self.imu_data:
            stamps, values, frames = self.imu_data[conn.topic]
            stamps.append(_stamp_ns(msg, log_ns))
            frames.add(str(msg.header.frame_id))
            values.append(_imu_values(msg))
        elif conn.id in self._joint_ids:
            self.joints.add(msg, log_ns)
        else:
            f, m = msg.wrench.force, msg.wrench.torque
            self.tw.append(_stamp_ns(msg, log_ns))
            self.w.append((f.x, f.y, f.z, m.x, m.y, m.z))
            self.frame_ids.add(str(msg.header.frame_id))


def _bag_streams(path: Path, joint_topic: str, topics: _Topics, read: _Messages) -> Streams:
    """The streams of the messages read, times in s from the earliest message, checked.

    Raises:
        DatasetError: no messages on a topic read, neither a wrench nor efforts, several wrench frames, a
            value beyond :data:`ineid.data.recordings.streams.VALUE_LIMIT`.
    """
    joints, wrench_topic, frame_ids, imu_data = read.joints, topics.wrench_topic, read.frame_ids, read.imu_data
    tq, q, effort = joints.stamps.array()[:, 0], joints.q.array(), joints.effort.array() if joints.effort.n else None
    tw, w = read.tw.array()[:, 0], read.w.array()
    if not len(tq) or (wrench_topic is not None and not len(w)):
        raise DatasetError(f"{path}: no messages on {joint_topic if not len(tq) else wrench_topic}")
    if wrench_topic is None and effort is None:
        raise DatasetError(
            f"{path}: the bag has no {WRENCH_STAMPED} topic and its joint states carry no effort "
            f"(joint torques): nothing to identify from (topics: {topics.available})"
        )
    if len(frame_ids) > 1:
        raise DatasetError(
            f"{path}: the wrench messages on {wrench_topic} name several frames "
            f"({', '.join(map(repr, sorted(frame_ids)))}); a recording needs one sensor frame"
        )
    for topic, what, values in (
        (joint_topic, "positions", q),
        (joint_topic, "efforts", effort),
        (wrench_topic, "wrench values", w),
    ):
        _check_values(path, topic, what, values)
    t0 = min([int(tq.min()), *([int(tw.min())] if len(tw) else []), *(v[0][0] for v in imu_data.values() if v[0])])
    frame_id = (frame_ids.pop() or None) if frame_ids else None
    origin = {
        "format": bag_kind(path),
        "file": path.name,
        "joint_topic": joint_topic,
        "wrench_topic": wrench_topic,
        "joint_messages": len(tq),
        "wrench_messages": len(w),
        "start_ns": int(t0),
        "frame_id": frame_id,
    }
    if effort is not None:
        origin["effort"] = True
    imus = _imu_streams(path, imu_data, topics.imu_of, t0)
    if imus:
        origin["imu_topics"] = {s.where: len(s.time) for s in imus}
    if topics.unused_imu:
        origin["imu_unused"] = {"topics": list(topics.unused_imu)}
    return Streams(
        joint_time=(tq - t0) * 1e-9,
        q=q,
        qd=None,
        qdd=None,
        wrench_time=(tw - t0) * 1e-9 if len(w) else None,
        wrench=w if len(w) else None,
        source=str(path),
        frame_id=frame_id,
        origin=origin,
        tau=effort,
        imus=imus,
    )


def _check_messages(path: Path, total: int, n_joints: int) -> None:
    """At most :data:`MAX_MESSAGES` messages, and memory for them, before any is read."""
    if total > MAX_MESSAGES:
        raise DatasetError(
            f"{path}: the topics to read hold {total:,} messages, more than the {MAX_MESSAGES:,} ineid "
            "reads (ineid.data.recordings.bags.MAX_MESSAGES); import a shorter part of the recording"
        )
    # a joint state's stamp, positions and efforts (a wrench's are fewer), then the arrays of the streams
    require_memory(
        2 * total * 8 * (1 + 2 * n_joints),
        f"reading {total:,} messages of {path}",
        "import a shorter part of the recording",
    )


def _check_values(path: Path, topic: str | None, what: str, values: np.ndarray | None) -> None:
    """No value beyond :data:`ineid.data.recordings.streams.VALUE_LIMIT` (NaN and infinity are the import's to name)."""
    k = None if values is None else first_beyond(values, VALUE_LIMIT)
    if k is not None:
        row = values.reshape(len(values), -1)[k]
        v = row[np.isfinite(row) & (np.abs(row) > VALUE_LIMIT)][0]
        raise DatasetError(
            f"{path}: message {k} on {topic}: its {what} hold {v:g}, beyond {VALUE_LIMIT:g} in "
            "magnitude (ineid.data.recordings.streams.VALUE_LIMIT), more than any sensor gives; a corrupt message: "
            "cut it from the recording"
        )


class _Rows:
    """Rows appended a message at a time into one array that doubles when full: no Python object per message."""

    def __init__(self, width: int, capacity: int, dtype=np.float64) -> None:
        self._a = np.empty((max(1, min(int(capacity), MAX_MESSAGES)), width), dtype=dtype)
        self.n = 0

    def append(self, row) -> None:
        if self.n == len(self._a):  # the metadata's message count was low
            self._a = np.concatenate([self._a, np.empty_like(self._a)])
        self._a[self.n] = row
        self.n += 1

    def array(self) -> np.ndarray:
        return self._a[: self.n]


class _JointStates:
    """The joint states of a bag, matched to the model's joints by name, message by message."""

    def __init__(self, path: Path, topic: str, joint_names: list[str], capacity: int) -> None:
        self.path, self.topic, self.joint_names = path, topic, joint_names
        self.stamps = _Rows(1, capacity, np.int64)
        self.q = _Rows(len(joint_names), capacity)
        self.effort = _Rows(len(joint_names), 0)  # grows when the messages carry efforts
        self._order: dict[tuple, np.ndarray] = {}

    def add(self, msg, log_ns: int) -> None:
        """Append one ``sensor_msgs/JointState``.

        Raises:
            DatasetError: a model joint missing, positions or efforts not matching the names, efforts in
                some messages only.
        """
        k, names = self.stamps.n, tuple(msg.name)
        idx = self._order.get(names)
        if idx is None:
            missing = [j for j in self.joint_names if j not in names]
            if missing:
                raise DatasetError(
                    f"{self.path}: joint state message {k} on {self.topic} lacks joint"
                    f"{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} "
                    f"(it names {', '.join(map(repr, names)) or 'none'}); "
                    "the recording is of another arm, or the URDF's joint names differ"
                )
            idx = self._order[names] = np.array([names.index(j) for j in self.joint_names])
        pos = np.asarray(msg.position, dtype=np.float64)
        if len(pos) != len(names):
            raise DatasetError(
                f"{self.path}: joint state message {k} on {self.topic} has {len(names)} names but {len(pos)} positions"
            )
        eff = np.asarray(msg.effort, dtype=np.float64)
        if len(eff) not in (0, len(names)) or (k and bool(len(eff)) != bool(self.effort.n)):
            raise DatasetError(
                f"{self.path}: joint state message {k} on {self.topic} has {len(eff)} efforts for "
                f"{len(names)} names"
                + (
                    ""
                    if len(eff) not in (0, len(names))
                    else f" where message 0 had {len(names) if self.effort.n else 0}"
                )
                + "; the joint torques (effort) must come with every joint state, one per name, or never"
            )
        self.stamps.append(_stamp_ns(msg, log_ns))
        self.q.append(pos[idx])
        if len(eff):
            self.effort.append(eff[idx])


def _imu_connections(path: Path, by_topic: dict, imu_topics: Sequence[str], available: str) -> tuple[list, dict]:
    """The connections of the IMU topics (and their angular-acceleration topics), and each one's IMU topic."""
    conns, imu_of = [], {}
    imus = sorted(t for t, cs in by_topic.items() if cs[0].msgtype == IMU)
    for topic in imu_topics:
        cs = by_topic.get(topic)
        if not cs:
            hint = f"; its Imu topics: {', '.join(imus)}" if imus else ""
            raise DatasetError(f"{path}: the bag has no topic {topic!r}{hint} (topics: {available})")
        if cs[0].msgtype != IMU:
            raise DatasetError(f"{path}: topic {topic!r} holds {cs[0].msgtype}, not {IMU}")
        conns += cs
        imu_of[topic] = topic
        alpha = by_topic.get(topic + ANGULAR_ACCELERATION)
        if alpha:
            if alpha[0].msgtype != VECTOR3_STAMPED:
                raise DatasetError(
                    f"{path}: topic {topic + ANGULAR_ACCELERATION!r} holds {alpha[0].msgtype}; an IMU's "
                    f"angular acceleration is a {VECTOR3_STAMPED} (rad/s^2, sensor frame)"
                )
            conns += alpha
            imu_of[topic + ANGULAR_ACCELERATION] = topic
    return conns, imu_of


def _imu_values(msg) -> tuple:
    """``(gyro or None, accel or None)`` of a ``sensor_msgs/Imu``, or ``(alpha,)`` of a ``Vector3Stamped``."""
    if hasattr(msg, "vector"):
        v = msg.vector
        return ((v.x, v.y, v.z),)
    w, a = msg.angular_velocity, msg.linear_acceleration
    gyro = None if float(msg.angular_velocity_covariance[0]) == -1 else (w.x, w.y, w.z)
    accel = None if float(msg.linear_acceleration_covariance[0]) == -1 else (a.x, a.y, a.z)
    return gyro, accel


def _imu_streams(path: Path, imu_data: dict, imu_of: dict, t0: int) -> tuple:
    """One :class:`ImuStream` per IMU topic and per angular-acceleration topic, named by the ``frame_id``."""
    from ineid.data.recordings.streams import ImuStream

    names: dict[str, str] = {}
    out = []
    for topic in sorted(imu_data, key=lambda t: (imu_of[t], t)):
        stamps, values, frames = imu_data[topic]
        if not stamps:
            raise DatasetError(f"{path}: no messages on {topic}")
        if len(frames) > 1:
            raise DatasetError(
                f"{path}: the IMU messages on {topic} name several frames "
                f"({', '.join(map(repr, sorted(frames)))}); one topic is one IMU"
            )
        frame = frames.pop()
        owner = imu_of[topic]
        if owner != topic:
            frame = frame or names.get(owner, "")
            if owner in names and frame != names[owner]:
                raise DatasetError(
                    f"{path}: {topic} names frame {frame!r} and {owner} frame {names[owner]!r}; an "
                    "IMU's angular acceleration is in its own frame"
                )
        if not frame:
            raise DatasetError(
                f"{path}: the messages on {topic} have an empty frame_id; it names the IMU's link (or a "
                "URDF frame on it, or an --imu NAME=LINK:pose)"
            )
        names[owner] = frame
        t = (np.asarray(stamps, dtype=np.int64) - t0) * 1e-9
        readings = {}
        if owner != topic:
            readings["alpha"] = np.asarray([v[0] for v in values], dtype=np.float64).reshape(-1, 3)
        else:
            for i, kind in enumerate(("gyro", "accel")):
                present = [v[i] is not None for v in values]
                if any(present) and not all(present):
                    raise DatasetError(
                        f"{path}: the {kind} of {topic} is measured in some messages only (its "
                        "covariance[0] is -1 in the others); one topic is one IMU, measured alike"
                    )
                if all(present):
                    readings[kind] = np.asarray([v[i] for v in values], dtype=np.float64).reshape(-1, 3)
            if not readings:
                raise DatasetError(
                    f"{path}: the messages on {topic} mark both the angular velocity and the linear "
                    "acceleration as not measured (covariance[0] = -1)"
                )
        for kind, values in readings.items():
            _check_values(
                path,
                topic,
                {"gyro": "angular velocities", "accel": "linear accelerations", "alpha": "angular accelerations"}[kind],
                values,
            )
        out.append(ImuStream(frame, t, readings, topic))
    return tuple(out)
