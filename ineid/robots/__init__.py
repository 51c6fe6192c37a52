"""Robots: their files (URDF, MJCF: read and written), the built-in arm, and the :class:`RobotModel` that
evaluates a robot's generated code.

Data flow: a robot file -> its format's reader (:mod:`.urdf`, :mod:`.mjcf`; picked by :mod:`.load`) ->
a :class:`ineid.chain.Chain` -> its generated modules, found or derived (:mod:`.codegen`) ->
:func:`load_robot` -> :class:`RobotModel`. Identified parameters go back into the files by the writers
(:mod:`.urdf_write`, :mod:`.mjcf_write`).
"""

from __future__ import annotations

from ineid.chain import Chain, JointSpec
from ineid.robots.builtin import BUILTIN_ROBOTS, BuiltinRobot
from ineid.robots.load import load_robot, robot_file_chain
from ineid.robots.model import DEFAULT_GRAVITY, RobotModel
from ineid.robots.urdf import load_chain

__all__ = [
    "BUILTIN_ROBOTS",
    "DEFAULT_GRAVITY",
    "BuiltinRobot",
    "Chain",
    "JointSpec",
    "RobotModel",
    "load_chain",
    "load_robot",
    "robot_file_chain",
]
