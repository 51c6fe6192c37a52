"""The tests' lab recording: MuJoCo simulates ``sweaty-arm`` the way a lab records it.

The simulator itself (the arm as MJCF on a force/torque sensor, the computed-torque
reference tracking, joint friction and armature) is :mod:`ineid.studies.mujoco_sim`; this module
draws the simulated parameters and writes the files a lab would bring (CSV, bags). A lab's
recording is the sensor wrench plus a constant bias, and the joint angles only, at 1 kHz.
"""

from __future__ import annotations

import numpy as np

from ineid.channels.pose import SensorPose
from ineid.studies.mujoco_sim import simulate

SENSOR_POSE = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
"""The test sensor: 3-5 cm off the base origin and turned nearly upside down (roll 3.1 rad)."""
OFFSETS = np.array([1.5, -2.0, 3.0, 0.1, -0.2, 0.05])
"""The test sensor's own offsets (N, N*m, sensor frame), on top of the root body's weight."""


class LabRecording:
    """A MuJoCo run of ``sweaty-arm`` recorded like a lab records it, and the files it makes.

    The simulated arm's unknown links (``upper_arm``, ``forearm``) carry parameters drawn
    around the CAD values (so the prior is not the truth).

    Attributes:
        model: the :class:`ineid.RobotModel` (CAD values as prior).
        theta: (10 n_links,) the simulated parameters; ``theta_unknown`` those of the unknown links.
        sim: the :class:`Simulation`.
        reading: (F, 6) what the untared sensor reads: the load in its frame plus the root
            body's weight plus :data:`OFFSETS`.
        tared: (F, 6) what a sensor tared before the arm was mounted reads: no offset.
        bias: (6,) ``reading - tared``, the offsets ``--bias estimate`` must find (up to the
            weight of mass that never moves, which it cannot tell from an offset).
    """

    def __init__(self, folder, duration: float = 10.0, seed: int = 11) -> None:
        import ineid
        from ineid.data.synthesis.sampling import sample_link_parameters

        self.folder = folder
        self.model = ineid.load_robot("sweaty-arm")
        rng = np.random.default_rng(seed)
        theta = self.model.theta_cad.copy()
        for link in self.model.unknown_links:
            idx = _link_columns(self.model, link)
            theta[idx] = sample_link_parameters(self.model.theta_cad[idx], 1, rng)[0]
        self.theta = theta
        self.theta_unknown = theta[self.model.unknown_index]
        self.pose = SENSOR_POSE
        self.sim = simulate(self.model, theta, self.pose, duration)
        x = self.pose.transform()
        rt, g = self.sim.root_theta, self.model.gravity
        root = x @ np.concatenate([rt[0] * g, np.cross(rt[1:4], g)])
        self.tared = self.sim.wrench_sensor - root
        self.bias = root + OFFSETS
        self.reading = self.tared + self.bias
        self._files: dict[str, object] = {}

    def file(self, kind: str):
        """The recording as ``csv`` (angles only, untared), ``csv-tared``, ``ros1``, ``sqlite3``, ``mcap``
        (ROS 2 folders) or ``bare-mcap``; written once. Bags list the joints in reverse order with an
        extra joint ``head_pan``; the wrench's ``frame_id`` is ``ft_sensor``."""
        if kind in self._files:
            return self._files[kind]
        from tests.bag_files import write_angles_csv, write_bag

        t, q = self.sim.time, self.sim.q
        if kind in ("csv", "csv-tared"):
            path = write_angles_csv(self.folder / f"{kind}.csv", t, q, self.reading if kind == "csv" else self.tared)
        elif kind == "bare-mcap":
            import shutil

            folder = self.file("mcap")
            path = self.folder / "bare.mcap"
            shutil.copy(next(folder.glob("*.mcap")), path)
        else:
            names = [*reversed(self.model.joint_names), "head_pan"]
            q_msg = np.column_stack([q[:, ::-1], np.zeros(len(q))])
            path = self.folder / ("rec.bag" if kind == "ros1" else f"rec_{kind}")
            write_bag(path, kind, names, t, q_msg, t, self.reading)
        self._files[kind] = path
        return path


def _link_columns(model, link: str) -> np.ndarray:
    i = model.link_names.index(link)
    return np.arange(10 * i, 10 * i + 10)
