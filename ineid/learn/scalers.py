"""Feature and target scalers, fitted on the training split only and saved with a run.

``transform(x) = (x - center) / scale`` per column; ``inverse(z) = z * scale + center``.

* ``standard``: center = mean, scale = standard deviation;
* ``robust``: center = median, scale = interquartile range (25th to 75th percentile);
* ``minmax``: maps the training range onto [0, 1] (center = min, scale = max - min).

A column with zero spread keeps scale 1, so constant features pass through shifted only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCALERS = ("standard", "robust", "minmax")


@dataclass(frozen=True)
class Scaler:
    """A fitted per-column affine scaler (see module doc).

    Attributes:
        kind: one of :data:`SCALERS`.
        center, scale: (n_columns,) in the data's units.
    """

    kind: str
    center: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, kind: str, x: np.ndarray) -> Scaler:
        """Fit on ``x`` (n_samples, n_columns)."""
        if kind not in SCALERS:
            raise ValueError(f"scaler must be one of {', '.join(SCALERS)}, got {kind!r}")
        x = np.asarray(x, dtype=np.float64).reshape(-1, np.shape(x)[-1])
        if kind == "standard":
            center, scale = x.mean(axis=0), x.std(axis=0)
        elif kind == "robust":
            q25, q50, q75 = np.percentile(x, [25, 50, 75], axis=0)
            center, scale = q50, q75 - q25
        else:
            center, scale = x.min(axis=0), x.max(axis=0) - x.min(axis=0)
        scale = np.where(scale > 1e-12 * np.maximum(np.abs(center), 1.0), scale, 1.0)
        return cls(kind, center, scale)

    def transform(self, x):
        return (x - self.center) / self.scale

    def inverse(self, z):
        return z * self.scale + self.center

    def to_dict(self) -> dict:
        return {"kind": self.kind, "center": self.center.tolist(), "scale": self.scale.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Scaler:
        return cls(d["kind"], np.asarray(d["center"], dtype=np.float64), np.asarray(d["scale"], dtype=np.float64))
