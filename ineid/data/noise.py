"""Measurement noise: zero-mean Gaussian on the wrench and on the kinematics.

The wrench is computed from the clean kinematics and the true parameters; then
independent Gaussian noise is added to each wrench axis (a force/torque sensor) and to
``q`` (encoders), ``qd`` and ``qdd`` (as a gyroscope and its derivative, or an observer,
would see them). The clean values are kept beside the noisy ones in a dataset, so a
study can separate the two error sources.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

WRENCH_AXES = ("fx", "fy", "fz", "mx", "my", "mz")
STATE_KEYS = ("q", "qd", "qdd")


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
    """

    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))
    q: np.ndarray | float = 0.0
    qd: np.ndarray | float = 0.0
    qdd: np.ndarray | float = 0.0

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
    ) -> NoiseModel:
        """A noise model from per-group standard deviations (a number, or one per axis/joint)."""
        wrench = np.concatenate([_std(force, 3, "force"), _std(moment, 3, "moment")])
        return cls(wrench=wrench, q=_std(q, n_dof, "q"), qd=_std(qd, n_dof, "qd"), qdd=_std(qdd, n_dof, "qdd"))

    @classmethod
    def from_dict(cls, d: Mapping, n_dof: int) -> NoiseModel:
        """Inverse of :meth:`to_dict`."""
        return cls(
            wrench=_std(d.get("wrench", 0.0), 6, "wrench"),
            q=_std(d.get("q", 0.0), n_dof, "q"),
            qd=_std(d.get("qd", 0.0), n_dof, "qd"),
            qdd=_std(d.get("qdd", 0.0), n_dof, "qdd"),
        )

    def to_dict(self) -> dict:
        return {k: np.atleast_1d(np.asarray(getattr(self, k), dtype=float)).tolist() for k in ("wrench", "q", "qd", "qdd")}

    def noisy_keys(self) -> tuple[str, ...]:
        """Which arrays this model perturbs, among ``q, qd, qdd, wrench``."""
        return tuple(k for k in (*STATE_KEYS, "wrench") if np.any(np.asarray(getattr(self, k)) > 0))

    def apply(self, arrays: Mapping[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Noisy copies of ``arrays["q" | "qd" | "qdd" | "wrench"]`` (..., dim).

        One draw of all channels per frame, in a fixed order, so a configuration's noise
        depends only on its random stream.
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
        return out
