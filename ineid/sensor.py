"""Moved: a sensor's pose and the wrench transform are a measurement channel's geometry, in :mod:`ineid.channels.pose`.

This module re-exports its names for one release (``from ineid.channels import SensorPose,
parse_sensor_pose, wrench_transform, ...``); it is removed in ineid 0.3.
"""

from __future__ import annotations

import warnings

from ineid.channels.pose import (
    SensorPose,
    matrix_rpy,
    parse_sensor_pose,
    regressor_in_sensor,
    rpy_matrix,
    wrench_in_sensor,
    wrench_transform,
)

warnings.warn(
    "ineid.sensor moved to ineid.channels.pose (import its names from ineid.channels); "
    "ineid.sensor is removed in ineid 0.3",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = [
    "SensorPose",
    "matrix_rpy",
    "parse_sensor_pose",
    "regressor_in_sensor",
    "rpy_matrix",
    "wrench_in_sensor",
    "wrench_transform",
]
