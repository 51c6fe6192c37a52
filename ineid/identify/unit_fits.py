"""Refits of a dataset under other units: the evidence of the unit checks in :mod:`ineid.identify.plausibility`.

Joint angles in the other unit (degrees read as radians, radians imported with ``--angle-unit
deg``) or moments 1000x off the forces (N*mm next to N) leave a dataset that solves without an
error and gives garbage: with little motion nothing in the numbers looks wrong. The fit tells:
under the right units the model explains the measurements, under wrong ones it cannot, whatever
the size of the motion. :func:`refit_units` refits a subsample of the frames (at most
:data:`HYPOTHESIS_FRAMES` of each of at most :data:`HYPOTHESIS_CONFIGS` configurations, evenly
spaced) once per hypothesis, by linear least squares on the regressor from CasADi (nothing
compiled), and :func:`relative_error` says how much of the measurements each fit leaves
unexplained, axis by axis (so that moments scaled by 1000 do not outweigh the forces).

The refit frees one more column than the solve: the known links' contribution, with a factor of
its own. A wrench scaled as a whole (kN read as N) is then fitted exactly under its true angles
and moments (the unknown links' parameters and that factor scale with it), so the hypotheses
compare the angles and the moments alone, and the factor is the wrench's scale.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ineid.channels import BaseWrench, ChannelSet
from ineid.identify.systems import stack_casadi

HYPOTHESIS_FRAMES = 200
"""Frames per configuration refitted under each hypothesis: far more equations than parameters (a 7-joint arm
has at most 70), and a refit of 200 frames takes some milliseconds."""
HYPOTHESIS_CONFIGS = 3
"""Configurations refitted (evenly spread): a unit mistake is the dataset's, not one configuration's."""


@dataclass(frozen=True)
class UnitFit:
    """The least squares of the subsample under one hypothesis (medians over its configurations).

    Attributes:
        angle: the factor on the revolute joints' ``q``, ``qd``, ``qdd`` (1: as stored).
        moment: the factor on the base wrenches' moments (1: as stored).
        error: :func:`relative_error` of the fit (inf where no configuration could be fitted).
        scale: the fitted factor on the known links' contribution: the measurements' scale against SI
            (1000 for a wrench in mN and N*mm); NaN without known links.
        mass: the unknown links' fitted total mass, kg.
        n_frames: frames fitted per configuration.
    """

    angle: float
    moment: float
    error: float
    scale: float
    mass: float
    n_frames: int


def fitted_channels(res, ds) -> ChannelSet:
    """The measurement channels ``res`` was fitted on (its records; a results file of ineid 0.1: the dataset's)."""
    records = res.meta.get("channels")
    return ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")


def relative_error(rss: np.ndarray, ss: np.ndarray) -> float:
    """The RMS over the axes of each axis's relative error ``sqrt(rss_a / ss_a)``, the median over configurations.

    Args:
        rss: (C, A) residual sums of squares per configuration and measured axis (NaN: not fitted).
        ss: (C, A) the measured values' sums of squares (about their means where offsets are fitted); axes
            whose values never change (``ss_a = 0``) are left out.

    Returns:
        0 (a perfect fit) to about 1 (nothing explained) and beyond; inf where no configuration was fitted.
    """
    ok = np.all(np.isfinite(rss), axis=1) & np.any(ss > 0, axis=1)
    if not ok.any():
        return np.inf
    moving = ss[ok] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        per_config = np.sqrt(np.where(moving, rss[ok] / ss[ok], 0).sum(axis=1) / moving.sum(axis=1))
    return float(np.median(per_config))


def fit_error(res, ds) -> float:
    """:func:`relative_error` of a solve's fitted frames (``res`` a :class:`ineid.identify.SolveResults` of ``ds``)."""
    w = np.asarray(ds.measured(fitted_channels(res, ds))[:, : res.n_frames_fit], dtype=np.float64)
    if res.bias_hat is not None:
        w = w - w.mean(axis=1, keepdims=True)
    rss = np.asarray(res.fit_rms, dtype=np.float64) ** 2 * res.n_frames_fit
    rss[~np.asarray(res.success, dtype=bool)] = np.nan
    return relative_error(rss, np.sum(w**2, axis=1))


def with_units(ds, model, angle: float = 1.0, moment: float = 1.0):
    """``ds`` with its revolute joints' ``q``, ``qd``, ``qdd`` times ``angle`` and its base wrenches' moments times
    ``moment`` (what the import would have made of the same file with the other unit)."""
    factor = np.array([angle if kind == "revolute" else 1.0 for kind in model.joint_types])
    scale = np.repeat([1.0, moment], 3)
    values = {
        c.key: np.asarray(ds.measurements[c.key]) * scale
        for c in ds.meta.channels
        if isinstance(c, BaseWrench) and moment != 1.0
    }
    return dataclasses.replace(
        ds,
        q=ds.q * factor,
        qd=ds.qd * factor,
        qdd=ds.qdd * factor,
        wrench=values.pop("wrench", ds.wrench),
        channel_values={**ds.channel_values, **values},
    )


def subsample(ds):
    """At most :data:`HYPOTHESIS_CONFIGS` configurations of ``ds`` and :data:`HYPOTHESIS_FRAMES` of their frames,
    evenly spaced."""
    configs = np.unique(np.linspace(0, ds.n_configs - 1, min(HYPOTHESIS_CONFIGS, ds.n_configs)).round().astype(int))
    frames = np.unique(np.linspace(0, ds.n_frames - 1, min(HYPOTHESIS_FRAMES, ds.n_frames)).round().astype(int))
    return ds.select(configs, frames)


def _least_squares(ds, i: int, model, channels: ChannelSet, offsets: np.ndarray | None):
    """Configuration ``i``'s fit with the known links' contribution scaled freely: ``(rss (A,), ss (A,), scale,
    mass)``."""
    n_axes = channels.n_axes(model)
    args = (model, ds.q[i], ds.qd[i], ds.qdd[i], ds.measured(channels)[i])
    w, rest = stack_casadi(*args, ds.theta_known, channels)
    _, y = stack_casadi(*args, np.zeros_like(ds.theta_known), channels)
    a = np.column_stack([w, y - rest])  # the unknown links' (and extra) columns, the known links' contribution
    a, y = a.reshape(-1, n_axes, a.shape[1]), y.reshape(-1, n_axes)
    if offsets is not None:  # a constant per offset axis, as the solve's offsets
        a = a - a.mean(axis=0) * offsets[:, None]
        y = y - y.mean(axis=0) * offsets
    a, y = a.reshape(-1, a.shape[2]), y.reshape(-1)
    norms = np.linalg.norm(a, axis=0)
    known = norms[-1] > 0
    norms[norms == 0] = 1.0  # a column of zeros: its parameter stays 0
    x = np.linalg.lstsq(a / norms, y, rcond=None)[0] / norms
    rss = np.sum((y - a @ x).reshape(-1, n_axes) ** 2, axis=0)
    mass = float(np.sum(x[: 10 * len(model.unknown_links)][0::10]))
    return rss, np.sum(y.reshape(-1, n_axes) ** 2, axis=0), float(x[-1]) if known else np.nan, mass


def refit_units(ds, channels: ChannelSet, offsets: bool, model, hypotheses) -> list[UnitFit]:
    """The least squares of :func:`subsample` of ``ds`` under each ``(angle, moment)`` factor pair of ``hypotheses``.

    Args:
        ds: the solved :class:`ineid.data.Dataset`.
        channels: the measurement channels the solve fitted (:func:`fitted_channels`).
        offsets: whether the solve estimated the channels' constant offsets.
        model: its :class:`ineid.RobotModel`.
        hypotheses: ``(angle, moment)`` pairs, :func:`with_units`'s factors.

    Returns:
        One :class:`UnitFit` per hypothesis, in order.
    """
    sub = subsample(ds)
    mask = channels.with_offsets(True).offset_mask(model).astype(np.float64) if offsets else None
    fits = []
    for angle, moment in hypotheses:
        scaled = with_units(sub, model, angle, moment)
        parts = [_least_squares(scaled, i, model, channels, mask) for i in range(sub.n_configs)]
        rss, ss = np.array([p[0] for p in parts]), np.array([p[1] for p in parts])
        fits.append(
            UnitFit(
                angle,
                moment,
                relative_error(rss, ss),
                float(np.median([p[2] for p in parts])),
                float(np.median([p[3] for p in parts])),
                sub.n_frames,
            )
        )
    return fits
