"""A run's configurations made ready, scaled up front (:class:`Prepared`), and its batches (:func:`gather_samples`).

What :func:`ineid.learn.shared.prepare` returns: the physics loss's tests and the step benchmark read it.
Training itself gathers from the raw shared data with each trial's constants
(:func:`ineid.learn.shared.gather`, the same numbers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ineid.learn.losses import Physics
    from ineid.learn.scalers import Scaler


@dataclass
class Prepared:
    """The configurations of a run made ready: scalers and device arrays.

    Arrays hold only the configurations in ``rows`` (dataset indices), in that order;
    ``local(indices)`` maps dataset indices to positions in them.
    """

    rows: np.ndarray
    x_scaler: Scaler
    y_scaler: Scaler
    arrays: dict
    physics: Physics
    n_out: int
    n_frames: int

    def local(self, dataset_indices: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.rows, dataset_indices)


def gather_samples(arrays, mode, rows, frames, n_axes: int = 6):
    """Batch of samples: positions (B,) and frame indices (B, K) -> (x, z, physics inputs).

    ``n_axes``: the measured axes of a frame (:attr:`ineid.learn.losses.Physics.n_axes`), the
    first numbers of a compact row.

    Per-frame arrays are gathered by one flat index ``row * n_frames + frame`` along their
    first axis: a single-axis ``take``, much cheaper on the CPU than a two-axis gather.
    """
    import jax.numpy as jnp

    n_frames = arrays["x"].shape[1]
    flat = rows[:, None] * n_frames + frames

    def take(a):
        return jnp.take(a.reshape((-1,) + a.shape[2:]), flat, axis=0)

    if "compact" in arrays:  # compact cached rows: y / s and the kept entries in one gather
        row = take(arrays["compact"])
        return take(arrays["x"]), arrays["z"][rows], (row[..., n_axes:], row[..., :n_axes])
    if mode == "cached":
        inputs = (take(arrays["psi"]), take(arrays["yres"]))
    else:
        inputs = tuple(take(arrays[k]) for k in ("q", "qd", "qdd", "wrench"))
    return take(arrays["x"]), arrays["z"][rows], inputs
