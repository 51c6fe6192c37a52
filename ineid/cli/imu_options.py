"""The link IMUs' options of ``ineid data import`` and ``ineid data generate`` (issue 22)."""

from __future__ import annotations

import math

import click

IMU_NOISE_KEYS = ("gyro", "accel", "alpha")
"""``--noise``/``--imu-noise`` keys of the IMUs: white-noise std of the gyroscopes (rad/s), accelerometers (m/s^2)
and angular-acceleration sensors (rad/s^2) at the frames' rate."""

imu_option = click.option(
    "--imu", "imus", multiple=True, metavar="[NAME=]LINK[:X,Y,Z,R,P,Y]|FRAME",
    help="A link IMU (repeatable): on moving link LINK at a pose in its frame (m, rad, URDF rpy; default its "
         "origin), or at a URDF frame welded to a moving link. NAME: the <NAME> of its columns imu_<NAME>_wx... "
         "or its bag messages' frame_id, when neither the link's nor the frame's name.",
)  # fmt: skip


def _seconds(ctx, param, value: float) -> float:
    if not math.isfinite(value):
        raise click.BadParameter(f"{value} is not a finite number of seconds")
    return value


imu_import_options = [
    imu_option,
    click.option("--imu-topic", "imu_topics", multiple=True, metavar="TOPIC",
                 help="Bags: a sensor_msgs/Imu topic of a link IMU (repeatable); its frame_id names the link, a URDF "
                      "frame on it or an --imu NAME; angular acceleration on TOPIC/angular_acceleration "
                      "(geometry_msgs/Vector3Stamped, rad/s^2)."),
    click.option("--imu-delay", type=float, default=0.0, show_default=True, metavar="S", callback=_seconds,
                 help="How late the IMU time stamps are against the joints' (s)."),
    click.option("--imu-noise", default=None, metavar="KEY=STD,...",
                 callback=lambda ctx, p, v: parse_imu_noise(v, "--imu-noise"),
                 help="The fusion's weights: white-noise std of gyro (rad/s), accel (m/s^2), alpha (rad/s^2) at the "
                      "frames' rate (default: gyro=0.005,accel=0.05,alpha=0.17)."),
]


def imu_import(f):
    """Decorate ``ineid data import`` with the IMU options."""
    for option in reversed(imu_import_options):
        f = option(f)
    return f


def parse_imu_noise(value: str | None, hint: str) -> dict[str, float] | None:
    """``gyro=0.005,accel=0.05,alpha=0.17`` (any subset) -> ``{key: std}``."""
    if not value:
        return None
    out = {}
    for item in value.split(","):
        key, sep, val = item.strip().partition("=")
        try:
            if not sep or key.strip().lower() not in IMU_NOISE_KEYS:
                raise ValueError
            out[key.strip().lower()] = float(val)
            if not 0 < out[key.strip().lower()] < 1e6:
                raise ValueError
        except ValueError:
            raise click.BadParameter(f"expected KEY=STD with KEY in {', '.join(IMU_NOISE_KEYS)} and 0 < STD < 1e6, got "
                                     f"{item.strip()!r}", param_hint=hint) from None
    return out


def estimation_settings(imu_noise: dict[str, float] | None):
    """The :class:`ineid.data.state_estimation.EstimationSettings` of a parsed ``--imu-noise`` (None: defaults)."""
    if not imu_noise:
        return None
    from ineid.data.state_estimation import EstimationSettings, ImuNoise  # noqa: PLC0415

    return EstimationSettings(noise=ImuNoise(**imu_noise))
