"""Write recordings as a lab's logger does: ROS 1 and ROS 2 bags (with rosbags) and CSV files."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def _time(typestore, ns: int):
    return typestore.types["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def write_bag(
    path: Path,
    kind: str,
    joint_names: Sequence[str],
    joint_time: np.ndarray,
    q: np.ndarray,
    wrench_time: np.ndarray | None,
    wrench: np.ndarray | None,
    frame_id: str = "ft_sensor",
    joint_topic: str = "/joint_states",
    wrench_topic: str = "/ft_sensor/wrench",
    start_ns: int = 1_700_000_000 * 10**9,
    extra_topics: Sequence[str] = (),
    effort: Sequence[np.ndarray] | np.ndarray | None = None,
) -> Path:
    """Write a bag with JointState and WrenchStamped messages.

    Args:
        kind: ``"ros1"`` (a ``.bag`` file), ``"sqlite3"`` or ``"mcap"`` (ROS 2 bag folders).
        joint_names: names in the messages, in message order (``q``'s columns).
        joint_time, wrench_time: s from ``start_ns``; header stamps and log times.
        wrench: None: no wrench topic (``wrench_time`` None too).
        extra_topics: further WrenchStamped topics carrying the same data (for ambiguity tests).
        effort: per joint state message its ``effort`` array (message order; rows of an array,
            or a list of arrays of any length); None: empty efforts.
    """
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    t = store.types
    js, ws = "sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    events = [(int(start_ns + round(s * 1e9)), 0, k) for k, s in enumerate(joint_time)]
    events += [(int(start_ns + round(s * 1e9)), 1, k) for k, s in enumerate(() if wrench is None else wrench_time)]
    events.sort()
    empty = np.zeros(0)
    with writer:
        cj = writer.add_connection(joint_topic, js, typestore=store)
        cw = (
            []
            if wrench is None
            else [writer.add_connection(topic, ws, typestore=store) for topic in (wrench_topic, *extra_topics)]
        )
        for ns, which, k in events:
            if which == 0:
                header = t["std_msgs/msg/Header"](stamp=_time(store, ns), frame_id="", **({"seq": k} if ros1 else {}))
                eff = empty if effort is None else np.ascontiguousarray(effort[k], dtype=np.float64)
                msg = t[js](
                    header=header,
                    name=list(joint_names),
                    position=np.ascontiguousarray(q[k], dtype=np.float64),
                    velocity=empty,
                    effort=eff,
                )
                writer.write(cj, ns, serialize(msg, js))
            else:
                header = t["std_msgs/msg/Header"](
                    stamp=_time(store, ns), frame_id=frame_id, **({"seq": k} if ros1 else {})
                )
                v = t["geometry_msgs/msg/Vector3"]
                f, m = wrench[k, :3], wrench[k, 3:]
                msg = t[ws](
                    header=header,
                    wrench=t["geometry_msgs/msg/Wrench"](
                        force=v(x=f[0], y=f[1], z=f[2]), torque=v(x=m[0], y=m[1], z=m[2])
                    ),
                )
                data = serialize(msg, ws)
                for c in cw:
                    writer.write(c, ns, data)
    return path


def write_angles_csv(path: Path, time: np.ndarray, q: np.ndarray, wrench: np.ndarray) -> Path:
    """A CSV with time, q1..qn and the wrench: an encoder-only recording on one clock."""
    n = q.shape[1]
    header = ",".join(["time", *(f"q{i}" for i in range(1, n + 1)), "fx", "fy", "fz", "mx", "my", "mz"])
    np.savetxt(path, np.column_stack([time, q, wrench]), delimiter=",", header=header, comments="", fmt="%.17g")
    return Path(path)
