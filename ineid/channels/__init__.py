"""Measurement channels: each sensor as rows of a regressor linear in the parameters.

:mod:`.base` defines what a channel is (:class:`Channel`: ``y = T Phi theta + E x + b + e``
per frame) and :mod:`.channelset` how channels are identified together
(:class:`ChannelSet`: their axes stacked); each module beside them is one kind of sensor:
:mod:`.wrench` (the F/T sensor under the base), :mod:`.link_wrench` (an F/T sensor on any
link), :mod:`.torque` (joint torques and motor currents with their actuation model), with the
sensor-pose arithmetic in :mod:`.pose`. Layer: above ``robots``, ``generated`` and ``symbolic``, below ``data``,
``identify`` and ``learn``, which ask channels for rows, axes and values and never name a
sensor. Submodules import each other directly, never this package. How a new sensor is
added: ``docs/architecture.md``, "Measurement channels".

Importing this package is light (NumPy only): JAX and CasADi load when rows are evaluated.
"""

from __future__ import annotations

from ineid.channels.base import Channel, channel_from_dict, channel_kinds, register
from ineid.channels.channelset import AxisBlock, ChannelSet
from ineid.channels.link_wrench import LinkWrench, link_key, sensor_channel
from ineid.channels.pose import (
    SensorPose,
    matrix_rpy,
    parse_sensor_pose,
    regressor_in_sensor,
    rpy_matrix,
    wrench_in_sensor,
    wrench_transform,
)
from ineid.channels.torque import FRICTION_TERMS, JointTorque, MotorCurrent, extra_unit
from ineid.channels.wrench import BASE_WRENCH, WRENCH_AXES, WRENCH_UNITS, BaseWrench

__all__ = [
    "BASE_WRENCH",
    "FRICTION_TERMS",
    "WRENCH_AXES",
    "WRENCH_UNITS",
    "AxisBlock",
    "BaseWrench",
    "Channel",
    "ChannelSet",
    "JointTorque",
    "LinkWrench",
    "MotorCurrent",
    "SensorPose",
    "channel_from_dict",
    "channel_kinds",
    "extra_unit",
    "link_key",
    "matrix_rpy",
    "parse_sensor_pose",
    "register",
    "regressor_in_sensor",
    "rpy_matrix",
    "sensor_channel",
    "wrench_in_sensor",
    "wrench_transform",
]
