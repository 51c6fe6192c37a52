"""The link IMUs' options of ``ineid data import`` and ``ineid data generate``."""

from __future__ import annotations

import math
from dataclasses import replace

import click

from ineid.cli.simulation import IMU_NOISE_KEYS

imu_option = click.option(
    "--imu",
    "imus",
    multiple=True,
    metavar="[NAME=]LINK[:X,Y,Z,R,P,Y]|FRAME",
    help="A link IMU (repeatable): on moving link LINK at a pose in its frame (m, rad, URDF rpy; default its "
    "origin), or at a URDF frame welded to a moving link. NAME: the <NAME> of its columns imu_<NAME>_wx... "
    "or its bag messages' frame_id, when neither the link's nor the frame's name. A CSV's IMU columns are used "
    "only when an --imu names them (the import lists those it leaves out).",
)


def _seconds(ctx, param, value: float) -> float:
    if not math.isfinite(value):
        raise click.BadParameter(f"{value} is not a finite number of seconds")
    return value


imu_import_options = [
    imu_option,
    click.option(
        "--imu-topic",
        "imu_topics",
        multiple=True,
        metavar="TOPIC",
        help="Bags: a sensor_msgs/Imu topic of a link IMU (repeatable); its frame_id names the link, a URDF "
        "frame on it or an --imu NAME; angular acceleration on TOPIC/angular_acceleration "
        "(geometry_msgs/Vector3Stamped, rad/s^2).",
    ),
    click.option(
        "--imu-delay",
        type=float,
        default=0.0,
        show_default=True,
        metavar="S",
        callback=_seconds,
        help="How late the IMU time stamps are against the joints' (s).",
    ),
    click.option(
        "--imu-noise",
        default=None,
        metavar="KEY=STD,...",
        callback=lambda ctx, p, v: parse_imu_noise(v, "--imu-noise"),
        help="The fusion's weights: white-noise std of gyro (rad/s), accel (m/s^2), alpha (rad/s^2) at the "
        "frames' rate (default: gyro=0.005,accel=0.05,alpha=0.17).",
    ),
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
            raise click.BadParameter(
                f"expected KEY=STD with KEY in {', '.join(IMU_NOISE_KEYS)} and 0 < STD < 1e6, got {item.strip()!r}",
                param_hint=hint,
            ) from None
    return out


imu_generate_options = [
    imu_option,
    click.option(
        "--gyro-bias",
        type=click.FloatRange(min=0, max=1e6),
        default=0.0,
        show_default=True,
        metavar="STD",
        help="With --imu: the std of each gyro axis's constant bias (rad/s), drawn per configuration.",
    ),
    click.option(
        "--encoder-bits",
        type=click.IntRange(1, 64),
        default=None,
        metavar="N",
        help="Rehearse the import (fourier, trajectory frame modes): encoders of N bits (steps of 2 pi / 2^N "
        "rad), filtered and differentiated as the import does, fused with any --imu.",
    ),
]


def imu_generate(f):
    """Decorate ``ineid data generate`` with the rehearsal's options."""
    for option in reversed(imu_generate_options):
        f = option(f)
    return f


def check_imu_generate(imus, gyro_bias: float, encoder_bits: int | None, noise: dict | None, frame_mode: str) -> None:
    """The rehearsal's options without ``--imu``, or ``--imu`` with independent frames: one line (exit 2)."""
    imu_noise = sorted(k for k in (noise or {}) if k in IMU_NOISE_KEYS)
    if not imus:
        given = [
            flag
            for flag, on in (("--gyro-bias", gyro_bias > 0), (f"--noise {','.join(imu_noise)}", bool(imu_noise)))
            if on
        ]
        if given:
            raise click.UsageError(f"{given[0]} is for the link IMUs of a rehearsal: add --imu LINK[:pose]")
        if encoder_bits is None:
            return
    if frame_mode not in ("fourier", "trajectory"):
        flag = "--imu" if imus else "--encoder-bits"
        raise click.UsageError(
            f"{flag} rehearses an import, which filters and differentiates time series: use "
            f"--frame-mode fourier or trajectory, not {frame_mode} (independent frames)"
        )
    if any((noise or {}).get(k, 0.0) > 0 for k in ("q", "qd", "qdd")):
        raise click.UsageError(
            "with --imu the states are estimated from the encoders and the IMUs: drop the q, qd, "
            "qdd noise (--encoder-bits N quantizes the angles)"
        )


def imu_rehearsal(imus, gyro_bias: float, encoder_bits: int | None, noise: dict | None, model):
    """The :class:`ineid.data.synthesis.imu_rehearsal.ImuRehearsal` of the options (None without ``--imu``)."""
    if not imus and encoder_bits is None:
        return None
    from ineid.data.recordings.imus import parse_imu_text
    from ineid.data.synthesis.imu_rehearsal import ImuRehearsal

    mounts = [parse_imu_text(text, model) for text in imus]
    names = [m.name for m in mounts]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise click.BadParameter(
            f"IMU {dup[0]!r} is given twice; give each once (NAME=LINK:pose names a second IMU on one link)",
            param_hint="--imu",
        )
    return ImuRehearsal(
        tuple(mounts), {k: v for k, v in (noise or {}).items() if k in IMU_NOISE_KEYS}, gyro_bias, encoder_bits
    )


imu_excite_options = [
    click.option(
        "--imu",
        "imus",
        multiple=True,
        metavar="[NAME=]LINK[:X,Y,Z,R,P,Y]|FRAME",
        help="Design for a link IMU (repeatable; gyro, accelerometer and angular acceleration) fused with the "
        "encoders as ineid data import does: on moving link LINK at a pose in its frame (m, rad, URDF "
        "rpy; default its origin), or at a URDF frame welded to a moving link. Noise: --noise gyro=, "
        "accel=, alpha= (default 0.005 rad/s, 0.05 m/s^2, 0.17 rad/s^2).",
    ),
    click.option(
        "--encoder-bits",
        type=click.IntRange(1, 64),
        default=None,
        metavar="N",
        help="Design for encoders of N bits (steps of 2 pi / 2^N rad), filtered and differentiated as the "
        "import does: their joint-state errors inflate the noise to first order.  [default: exact]",
    ),
]


def imu_excite(f):
    """Decorate ``ineid excite`` with the sensors it designs for."""
    for option in reversed(imu_excite_options):
        f = option(f)
    return f


def excite_sensors(imus, encoder_bits: int | None, noise: dict | None, model):
    """The :class:`ineid.data.synthesis.imu_rehearsal.ImuRehearsal` ``ineid excite`` designs for (None: joint
    states exact).

    The IMUs' noise not given in ``--noise`` is the import's default (:class:`ineid.data.imu.estimation.ImuNoise`):
    a design for noise-free IMUs would promise too much.

    Raises:
        click.UsageError: IMU noise without ``--imu``; q, qd, qdd noise beside the sensors.
        DatasetError: an IMU that does not parse or names no moving link (one line).
    """
    noise = noise or {}
    if not imus and any(k in noise for k in IMU_NOISE_KEYS):
        key = next(k for k in IMU_NOISE_KEYS if k in noise)
        raise click.UsageError(f"--noise {key}= is the noise of link IMUs: add --imu LINK[:pose], or drop it")
    if not imus and encoder_bits is None:
        return None
    if any(k in noise for k in ("q", "qd", "qdd")):
        raise click.UsageError(
            "with --encoder-bits or --imu the joint-state errors come from the sensors: drop the q, qd, qdd noise"
        )
    from ineid.data.imu.settings import ImuNoise

    default = ImuNoise()
    sensors = imu_rehearsal(imus, 0.0, encoder_bits, noise, model)
    return replace(sensors, noise={k: noise.get(k, getattr(default, k)) for k in IMU_NOISE_KEYS} if imus else {})
