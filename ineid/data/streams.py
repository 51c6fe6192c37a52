"""What a lab records, as read from a file: joint angles and the sensor wrench, each on its own clock.

The file readers (:mod:`ineid.data.csv_import`, :mod:`ineid.data.bags`) produce
:class:`Streams`; :func:`ineid.data.recording.recording_dataset` turns them into frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Streams:
    """A recording as read from a file: two streams, each on its own clock.

    Attributes:
        joint_time: (Nq,) s, increasing.
        q: (Nq, n_dof) joint angles (rad; m for prismatic joints), chain order.
        qd, qdd: (Nq, n_dof) measured velocities and accelerations, or None (derived).
        wrench_time: (Nw,) s, increasing, on the wrench's clock.
        wrench: (Nw, 6) what the sensor reads: the load of the robot on it, in its frame,
            moment about its origin (N, N*m).
        source: the file, for messages.
        frame_id: the frame the wrench messages name (ROS bags), or None.
        origin: provenance recorded in the dataset (format, topics, message counts...).
    """

    joint_time: np.ndarray
    q: np.ndarray
    qd: np.ndarray | None
    qdd: np.ndarray | None
    wrench_time: np.ndarray
    wrench: np.ndarray
    source: str
    frame_id: str | None = None
    origin: dict = field(default_factory=dict)
