"""Link IMUs: what they read (:mod:`.readings`) and the joint states estimated from them and the
encoders (:mod:`.estimation`, with the gyro biases of :mod:`.gyro_bias` and the priors' weights of
:mod:`.prior_weights`).

The names of :mod:`.readings` are re-exported here (``from ineid.data.imu import ImuMount``).
"""

from __future__ import annotations

from ineid.data.imu.readings import (
    AXES,
    KINDS,
    UNITS,
    ImuJacobians,
    ImuMount,
    imu_jacobians,
    imu_readings,
    jacobians_from,
    link_jacobians,
    link_motion,
    moving_index,
    parse_imu,
    readings_from_motion,
)

__all__ = [
    "AXES",
    "KINDS",
    "UNITS",
    "ImuJacobians",
    "ImuMount",
    "imu_jacobians",
    "imu_readings",
    "jacobians_from",
    "link_jacobians",
    "link_motion",
    "moving_index",
    "parse_imu",
    "readings_from_motion",
]
