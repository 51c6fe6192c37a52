"""Measurement noise: zero-mean Gaussian on the wrench and on the kinematics.

The wrench is computed from the clean kinematics and the true parameters; then
independent Gaussian noise is added to each wrench axis (a force/torque sensor) and to
``q`` (encoders), ``qd`` and ``qdd`` (as a gyroscope and its derivative, or an observer,
would see them). The clean values are kept beside the noisy ones in a dataset, so a
study can separate the two error sources.

**Glitches.** A sensor that now and then misreads (a loose connector, an impact, a
saturating strain gauge) is modelled by ``glitch_rate`` and ``glitch_scale``: each frame,
independently with probability ``glitch_rate``, gets force noise ``glitch_scale`` times
the force axes' standard deviations (``fx, fy, fz``; the moments keep theirs). The noise
of frame ``j`` on force axis ``a`` is then ``sigma_a * g_j * z_ja`` with ``g_j`` =
``glitch_scale`` on a glitched frame and 1 otherwise, ``z`` standard normal. Which frames
glitch is drawn after the Gaussian noise from the same stream, so data without glitches
are bit-identical to those made before glitches existed.

**Other channels** (joint torques ``tau``, motor currents, a wrench at a link): ``channels``
holds each one's standard deviations under its key (one number, or one per axis), recorded
under the same key in the dataset's ``noise``. Their draws come after all of the above,
channel by channel in the order of their keys, so the wrench's and the kinematics' noise
(and every file made before these channels existed) are unchanged by them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

WRENCH_AXES = ("fx", "fy", "fz", "mx", "my", "mz")
STATE_KEYS = ("q", "qd", "qdd")
_OWN_KEYS = frozenset({*STATE_KEYS, "wrench", "glitch_rate", "glitch_scale"})


def _std(value, size: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,):
        raise ValueError(f"{name} noise must be one number or {size} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} noise standard deviations must be finite and >= 0, got {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class NoiseModel:
    """Standard deviations of additive Gaussian measurement noise (SI units).

    Attributes:
        wrench: (6,) per axis: N for ``fx, fy, fz``, N*m for ``mx, my, mz``.
        q: (n_dof,) rad (m for prismatic joints); ``qd`` rad/s; ``qdd`` rad/s^2.
        glitch_rate: share of frames, in [0, 1), whose force noise is ``glitch_scale``
            times larger (see the module doc); 0: no glitches.
        glitch_scale: the factor on a glitched frame's force noise, >= 1 (default 20).
        channels: ``{key: std}`` for the measurement channels other than the base wrench
            ``wrench`` (``{"tau": 0.02}``: N*m on every joint), one number or one per axis,
            in the channel's units.
    """

    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))
    q: np.ndarray | float = 0.0
    qd: np.ndarray | float = 0.0
    qdd: np.ndarray | float = 0.0
    glitch_rate: float = 0.0
    glitch_scale: float = 20.0
    channels: Mapping[str, np.ndarray | float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        stds = {}
        for key, value in dict(self.channels).items():
            if key in _OWN_KEYS:
                raise ValueError(f"channel noise key {key!r} is the noise model's own; give it as {key}=...")
            arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
            if arr.ndim != 1 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"{key} noise must be one finite number >= 0 or one per axis, got {arr.tolist()}")
            stds[key] = arr
        object.__setattr__(self, "channels", stds)
        if not 0.0 <= float(self.glitch_rate) < 1.0:
            raise ValueError(f"glitch_rate must be in [0, 1), got {self.glitch_rate}")
        if not 1.0 <= float(self.glitch_scale) < float("inf"):
            raise ValueError(f"glitch_scale must be >= 1 and finite, got {self.glitch_scale}")
        if self.glitch_rate > 0 and not np.any(np.asarray(self.wrench)[:3] > 0):
            raise ValueError("glitches scale the force noise: give a force noise (force=...) with glitch_rate > 0")

    @classmethod
    def create(
        cls,
        n_dof: int,
        *,
        force: float | Sequence[float] = 0.0,
        moment: float | Sequence[float] = 0.0,
        q: float | Sequence[float] = 0.0,
        qd: float | Sequence[float] = 0.0,
        qdd: float | Sequence[float] = 0.0,
        glitch_rate: float = 0.0,
        glitch_scale: float = 20.0,
        channels: Mapping[str, float | Sequence[float]] | None = None,
    ) -> NoiseModel:
        """A noise model from per-group standard deviations (a number, or one per axis/joint); ``channels``
        ``{key: std}`` for other measurement channels (``{"tau": 0.02}``)."""
        wrench = np.concatenate([_std(force, 3, "force"), _std(moment, 3, "moment")])
        return cls(
            wrench=wrench,
            q=_std(q, n_dof, "q"),
            qd=_std(qd, n_dof, "qd"),
            qdd=_std(qdd, n_dof, "qdd"),
            glitch_rate=float(glitch_rate),
            glitch_scale=float(glitch_scale),
            channels=dict(channels or {}),
        )

    @classmethod
    def from_dict(cls, d: Mapping, n_dof: int) -> NoiseModel:
        """Inverse of :meth:`to_dict`."""
        return cls(
            wrench=_std(d.get("wrench", 0.0), 6, "wrench"),
            q=_std(d.get("q", 0.0), n_dof, "q"),
            qd=_std(d.get("qd", 0.0), n_dof, "qd"),
            qdd=_std(d.get("qdd", 0.0), n_dof, "qdd"),
            glitch_rate=float(d.get("glitch_rate", 0.0)),
            glitch_scale=float(d.get("glitch_scale", 20.0)),
            channels={k: v for k, v in d.items() if k not in _OWN_KEYS},
        )

    def to_dict(self) -> dict:
        """The standard deviations as lists; ``glitch_rate`` and ``glitch_scale`` only when glitching
        (so the records, and the fingerprints, of data without glitches are unchanged)."""
        d = {k: np.atleast_1d(np.asarray(getattr(self, k), dtype=float)).tolist() for k in ("wrench", "q", "qd", "qdd")}
        if self.glitch_rate > 0:
            d.update(glitch_rate=float(self.glitch_rate), glitch_scale=float(self.glitch_scale))
        d.update({k: v.tolist() for k, v in self.channels.items()})
        return d

    def noisy_keys(self) -> tuple[str, ...]:
        """Which arrays this model perturbs, among ``q, qd, qdd, wrench`` and the keys of :attr:`channels`."""
        own = tuple(k for k in (*STATE_KEYS, "wrench") if np.any(np.asarray(getattr(self, k)) > 0))
        return own + tuple(k for k in sorted(self.channels) if np.any(self.channels[k] > 0))

    def apply(self, arrays: Mapping[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Noisy copies of ``arrays["q" | "qd" | "qdd" | "wrench"]`` (..., dim) and of ``arrays[key]`` for every
        key of :attr:`channels` with noise.

        One draw of all channels per frame, in a fixed order, so a configuration's noise
        depends only on its random stream; with glitches, then one uniform draw per frame
        picks the glitched frames; then one draw per frame for each other channel, in the
        order of their keys.

        Raises:
            ValueError: a channel's standard deviations that are neither one number nor one per axis.
        """
        keys = (*STATE_KEYS, "wrench")
        widths = [arrays[k].shape[-1] for k in keys]
        batch = arrays["wrench"].shape[:-1]
        z = rng.standard_normal(batch + (sum(widths),))
        out, start = {}, 0
        for k, width in zip(keys, widths, strict=True):
            std = np.asarray(getattr(self, k), dtype=np.float64)
            out[k] = arrays[k] + std * z[..., start : start + width] if np.any(std > 0) else arrays[k]
            start += width
        if self.glitch_rate > 0:
            glitched = rng.random(batch) < self.glitch_rate
            extra = np.where(glitched, self.glitch_scale - 1.0, 0.0)[..., None]  # (..., 1)
            zw = z[..., start - 6 : start - 3]  # the force axes' draws
            out["wrench"] = out["wrench"].copy()
            out["wrench"][..., :3] += extra * np.asarray(self.wrench)[:3] * zw
        for key in sorted(self.channels):
            std = self.channels[key]
            if not np.any(std > 0):
                continue
            values = arrays[key]
            if std.shape not in ((1,), values.shape[-1:]):
                raise ValueError(
                    f"{key} noise has {std.size} standard deviations for {values.shape[-1]} axes; "
                    "give one number or one per axis"
                )
            out[key] = values + std * rng.standard_normal(values.shape)
        return out
