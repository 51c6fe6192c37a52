"""The base wrench: what an F/T sensor under the base reads, the paper's measurement.

``[F; M] = Psi(q, qd, qdd; g) theta``: the wrench the moving links exert on the fixture,
base frame, moment about the base origin (:class:`ineid.RobotModel`). A sensor mounted at
pose ``(R, p)`` in the base frame reads ``X [F; M]`` with the 6x6 wrench transform ``X``
(:func:`ineid.channels.pose.wrench_transform`), constant, so the channel's ``T = X`` and
its rows are ``X Psi``. An untared sensor adds six constant offsets (``offsets=True``),
which also take the weight of whatever sits between the sensor and the first joint.

Every evaluator here is the robot model's own (the generated code, compiled once per
robot, chunked), with ``X`` applied after, exactly as identification applied it before
channels existed: ``X @ Psi`` for rows, ``w @ X^T`` for predictions, so results stay the same
to the last bit. The prediction uses the generated ``base_wrench``, which never forms ``Psi``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from ineid.channels.base import Channel, register
from ineid.channels.channelset import ChannelSet
from ineid.channels.pose import SensorPose, regressor_in_sensor, wrench_in_sensor
from ineid.errors import DatasetError

WRENCH_AXES = ("fx", "fy", "fz", "mx", "my", "mz")
WRENCH_UNITS = ("N", "N", "N", "N*m", "N*m", "N*m")


@dataclass(frozen=True, kw_only=True)
class WrenchSensor(Channel):
    """What every six-axis F/T sensor channel shares (not a kind of its own): axes ``fx..mz`` in N and
    N*m, the mount pose ``sensor`` whose wrench transform is ``T`` (None: the model's frame), six offsets,
    and the pose in the record. :class:`BaseWrench` (under the base) and
    :class:`ineid.channels.link_wrench.LinkWrench` (on a link) differ only in ``Phi``.

    Attributes:
        sensor: the sensor's pose in the model's frame of ``Phi``; None (or the identity pose): that frame.
    """

    sensor: SensorPose | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.sensor is not None and not isinstance(self.sensor, SensorPose):
            raise TypeError(f"sensor must be a SensorPose or None, got {type(self.sensor).__name__}")

    def axes(self, model=None) -> tuple[str, ...]:
        return WRENCH_AXES

    def units(self, model=None) -> tuple[str, ...]:
        return WRENCH_UNITS

    def n_axes(self, model=None) -> int:
        return 6

    def frame_text(self, own: str) -> str:
        """``own`` (the model's frame) or ``sensor frame xyz=... rpy=...``, for :meth:`describe`."""
        return own if self.transform() is None else f"sensor frame {self.sensor.describe()}"

    def with_sensor(self, sensor: SensorPose | None) -> WrenchSensor:
        return replace(self, sensor=sensor)

    def transform(self) -> np.ndarray | None:
        """``X`` (6, 6) of the sensor pose, or None for the model's frame (no sensor, or the identity pose)."""
        return None if self.sensor is None or self.sensor.is_identity else self.sensor.transform()

    def _record(self) -> dict:
        return {"sensor": None if self.sensor is None else self.sensor.to_dict()}

    @classmethod
    def _parse_record(cls, d: Mapping, where: str) -> dict:
        sensor = d.get("sensor")
        if sensor is not None and not isinstance(sensor, Mapping):
            raise DatasetError(
                f"{where}: the {cls.kind} channel's sensor must be a pose record or null, got {sensor!r}"
            )
        return {"sensor": None if sensor is None else SensorPose.from_dict(sensor, f"{where}: sensor")}


@register
@dataclass(frozen=True, kw_only=True)
class BaseWrench(WrenchSensor):
    """The wrench under the base, in the base frame or a sensor's (see the module docstring).

    Attributes:
        key: where its values are stored (default ``"wrench"``, the dataset's ``wrench``).
        sensor: the sensor's pose in the base frame; None (or the identity pose): the
            wrench is in the base frame, moment about the base origin.
        offsets: six constant offsets (N, N*m, sensor axes) are identified with the parameters.
    """

    key: str = "wrench"

    kind = "wrench"
    RECORD_FIELDS = ("sensor",)

    def describe(self) -> str:
        return f"base wrench '{self.key}' ({self.frame_text('base frame')})" + (
            ", six offsets identified" if self.offsets else ""
        )

    # -- the model ------------------------------------------------------------------------
    def entries_function(self, model):
        return model.jax_regressor_entries

    def nonzero(self, model) -> tuple[tuple[int, ...], ...]:
        return model.regressor_nonzero

    def casadi_function(self, model):
        return model.casadi_regressor

    def phi_function(self, model):
        """The generated ``base_wrench_regressor``."""
        return model.jax_regressor

    def phi_theta_function(self, model):
        """The generated ``base_wrench`` (``Psi theta`` without forming ``Psi``)."""
        return model.jax_base_wrench

    # -- eager: the robot model's chunked evaluators, X applied as identification always did
    def rows(self, model, q, qd, qdd) -> np.ndarray:
        return regressor_in_sensor(self.transform(), model.regressor(q, qd, qdd))

    def rows_split(self, model, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
        x = self.transform()
        psi_u, psi_k = model.regressor_split(q, qd, qdd)
        return regressor_in_sensor(x, psi_u), regressor_in_sensor(x, psi_k)

    def predict(self, model, q, qd, qdd, theta) -> np.ndarray:
        return wrench_in_sensor(self.transform(), model.base_wrench(q, qd, qdd, theta))


BASE_WRENCH = ChannelSet.of(BaseWrench())
"""The measurement of versions 1 and 2 of the dataset format, and of every function given no channels:
the base wrench under ``wrench``, in the base frame."""
