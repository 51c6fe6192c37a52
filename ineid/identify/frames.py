"""Identify from one set of frames (a recording) without a dataset file: :func:`identify_frames`."""

from __future__ import annotations

import numpy as np

from ineid.errors import IdentificationError
from ineid.identify.identifiability import base_parameters, frame_minimum
from ineid.identify.solve import SolveResults, SolveSettings, solve_dataset


def identify_frames(
    model,
    q,
    qd,
    qdd,
    wrench,
    method: str = "linear",
    weights: str = "estimate",
    axis_sigma=None,
    start: str = "prior",
    bias: str = "none",
    sensor_pose=None,
) -> SolveResults:
    """Identify the unknown links from one set of frames (a recording); all frames are fitted.

    Args:
        model: the :class:`ineid.RobotModel` (unknown links, gravity, CAD prior).
        q, qd, qdd: (F, n_dof); wrench: (F, 6), the sensor reading in ineid's convention.
        method, weights, axis_sigma, start, bias: as in :class:`SolveSettings`.
        sensor_pose: the :class:`ineid.channels.SensorPose` the wrench is read in (None: the base frame).

    Returns:
        One-row :class:`SolveResults` (``theta_hat[0]``, ``theta_std[0]``, ``base_hat[0]``, ...).

    Raises:
        IdentificationError: too few frames, frames that do not determine the base
            parameters (with what is missing), or an IPOPT failure (``.status`` holds
            IPOPT's return status).
    """
    from ineid.data.dataset.schema import Dataset, DatasetMeta
    from ineid.identify.identifiability import analyze_frames

    arrays = [np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench)]
    for label, a, width in zip(("q", "qd", "qdd", "wrench"), arrays, (model.n_dof,) * 3 + (6,), strict=True):
        if a.ndim != 2 or a.shape[1] != width or len(a) != len(arrays[0]):
            raise ValueError(f"{label} must have shape (n_frames, {width}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise IdentificationError(
                f"{label} holds NaN or infinite values; drop or repair those frames", status="non_finite"
            )
    base = base_parameters(model, bias=bias == "estimate")
    frame_minimum(model, bias == "estimate").require(len(arrays[0]))
    analysis = analyze_frames(model, *arrays[:3], base, bias=bias == "estimate")
    if not analysis.ok:
        raise IdentificationError(analysis.problem(), status="rank_deficient")
    meta = DatasetMeta.for_model(
        model, source="recording", sensor=None if sensor_pose is None else sensor_pose.to_dict()
    )
    ds = Dataset(meta, *(a[None] for a in arrays), theta_known=model.theta_cad[model.known_index])
    res = solve_dataset(
        ds,
        SolveSettings(
            method=method,
            frames=len(arrays[0]),
            weights=weights,
            axis_sigma=None if axis_sigma is None else tuple(axis_sigma),
            start=start,
            bias=bias,
        ),
        model=model,
    )
    if not res.success[0]:
        raise IdentificationError(
            f"the {method} solver failed ({res.status[0]}); try start='linear', more frames, or the linear method",
            status=str(res.status[0]),
        )
    return res
