"""The data of training runs, held once for every trial trained on it.

Two trials on one dataset differ in which configurations they train and validate on (their split)
and in the constants fitted on those (the feature and target scalers, the physics term's per-axis
normalization); the dataset's numbers are the same. So the numbers are held once, raw, for every
configuration any trial uses (:class:`SharedData`, on the device), and each trial brings its
constants (:class:`TrialData`), applied as a batch is gathered (:func:`gather`): ``x = (features -
center) / scale``, the very divisions that scaling the whole arrays first would make, so a trial
gets the same numbers whichever trials it shares the data with.

:func:`prepare` is the one-trial form with the arrays scaled up front (what the tests of the
physics loss and the step benchmark read).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ineid.errors import DatasetError
from ineid.learn.config import DTYPES
from ineid.learn.data import Split, frame_features
from ineid.learn.losses import PHYSICS_MODES, CompactRegressor, Physics
from ineid.learn.scalers import Scaler
from ineid.learn.steps import Prepared

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.learn.config import TrainConfig
    from ineid.robots import RobotModel

CACHE_LIMIT_BYTES = 6 * 2**30
"""A cached physics term larger than this falls back to the inline regressor."""


@dataclass
class SharedData:
    """The raw numbers of configurations ``rows`` of a dataset, on the device.

    Attributes:
        rows: (C,) sorted dataset indices held; :meth:`local` maps dataset indices to positions.
        arrays: device arrays, positions first: ``feats`` (C, F, 3 n_dof + A) raw features; the
            physics term's ``compact`` (C, F, width) rows unscaled (a cached loss of a network that does not
            read the regressor), ``psi``/``yres`` (cached, full) or ``q``/``qd``/``qdd``/``wrench`` (inline).
        physics: the physics term of the data (its per-trial fields, the scalers and the wrench
            scale, are placeholders a trial's replace: :meth:`TrialData.physics`).
        feats, values, theta_unknown: the host copies the trials fit their constants on.
        n_frames: frames per configuration.
        dtype: of the device arrays.
    """

    rows: np.ndarray
    arrays: dict
    physics: Physics
    feats: np.ndarray
    values: np.ndarray
    theta_unknown: np.ndarray
    n_frames: int
    dtype: str = "float64"
    programs: dict = field(default_factory=dict)
    """The compiled epochs of the populations trained on these data (by :func:`ineid.learn.population.program_key`)."""

    def local(self, dataset_indices: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.rows, dataset_indices)

    @property
    def n_out(self) -> int:
        return self.theta_unknown.shape[1]

    def holds(self, dataset_indices: np.ndarray) -> bool:
        """Whether every configuration of ``dataset_indices`` is held."""
        return bool(np.isin(dataset_indices, self.rows).all())


def build_shared(
    ds: Dataset,
    model: RobotModel,
    rows: np.ndarray,
    *,
    physics_mode: str = "cached",
    full_regressor: bool = False,
    dtype: str = "float64",
) -> SharedData:
    """Hold configurations ``rows`` of ``ds`` for training (see :class:`SharedData`).

    Args:
        ds: the dataset (with the truth).
        model: the robot model.
        rows: dataset indices (sorted, unique).
        physics_mode: ``"cached"`` or ``"inline"`` (:class:`ineid.learn.losses.Physics`); a cache
            over :data:`CACHE_LIMIT_BYTES` falls back to inline.
        full_regressor: the networks read the regressor themselves (``wls``): the full cached form.
        dtype: of the device arrays (:data:`DTYPES`).
    """
    import jax.numpy as jnp

    ds.require_truth("training")
    if physics_mode not in PHYSICS_MODES:
        raise ValueError(f"physics_mode must be one of {', '.join(PHYSICS_MODES)}, got {physics_mode!r}")
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    rows = np.asarray(rows, dtype=np.int64)
    sub = ds.select(rows)
    channels = ds.meta.channels
    n_axes = channels.n_axes(model)
    values = sub.measured(channels)  # (C, F, A): the wrench itself for one base wrench
    feats = frame_features(sub)
    n_u = sub.theta_unknown.shape[1]
    if physics_mode == "cached" and sub.n_configs * sub.n_frames * n_axes * (n_u + 1) * 8 > CACHE_LIMIT_BYTES:
        physics_mode = "inline"
    compact, arrays = None, {}
    if physics_mode == "cached":
        compact, arrays = _cached_physics(model, sub, values, full_regressor)
    else:
        arrays = {"q": sub.q, "qd": sub.qd, "qdd": sub.qdd, "wrench": values}
    physics = Physics(
        mode=physics_mode,
        regressor=channels.jax_rows_function(model),  # the base wrench: the generated regressor itself
        gravity=np.asarray(model.gravity),
        unknown_index=np.asarray(model.unknown_index),
        known_index=np.asarray(model.known_index),
        theta_known=np.asarray(sub.theta_known),
        wrench_scale=np.ones(n_axes),
        y_center=np.zeros(n_u),
        y_scale=np.ones(n_u),
        compact=compact,
    )
    arrays["feats"] = feats
    if dtype != "float64":  # the term's constants in the training dtype, so nothing promotes back to float64
        cast = {f: np.asarray(getattr(physics, f), dtype=dtype) for f in ("gravity", "theta_known")}
        if compact is not None:
            cast["compact"] = dataclasses.replace(compact, base_map=np.asarray(compact.base_map, dtype=dtype))
        physics = dataclasses.replace(physics, **cast)
    on_device = {k: jnp.asarray(v, dtype=dtype) for k, v in arrays.items()}
    return SharedData(rows, on_device, physics, feats, values, np.asarray(sub.theta_unknown), sub.n_frames, dtype)


def _cached_physics(model, sub, values: np.ndarray, full: bool):
    """The physics term's numbers of configurations ``sub``, computed once (the ``"cached"`` mode), unscaled.

    Returns:
        ``(compact, arrays)``: unless ``full``, the :class:`ineid.learn.losses.CompactRegressor` and
        ``{"compact": its rows, one a frame, with the per-axis scale 1}``; else None and ``{"psi": (C, F, A,
        n_u) the unknown links' rows, "yres": (C, F, A) the values less the known links' part}``.
    """
    from ineid.identify.systems import stack

    channels = sub.meta.channels
    n_axes, n_u = channels.n_axes(model), sub.theta_unknown.shape[1]
    w, y = stack(model, sub.q, sub.qd, sub.qdd, values, sub.theta_known, channels)  # (C, AF, n_u), (C, AF)
    w = w.reshape(sub.n_configs, sub.n_frames, n_axes, n_u)
    y = y.reshape(sub.n_configs, sub.n_frames, n_axes)
    if full:
        return None, {"psi": w, "yres": y}
    from ineid.identify.identifiability import base_parameters

    compact, rows = CompactRegressor.from_frames(w, y, base_parameters(model, channels=channels), np.ones(n_axes))
    return compact, {"compact": rows}


@dataclass
class TrialData:
    """One trial's share of :class:`SharedData`: its split and its fitted constants.

    Attributes:
        split: the trial's configurations.
        x_scaler, y_scaler: the feature and target scalers (fitted on the training split).
        wrench_scale: (A,) the physics term's per-axis normalization.
        z: (C, n_u) the targets of every held configuration, scaled (a wls network's: their
            identifiable part).
        context: a wls network's constants (:class:`ineid.learn.wls.WlsContext`), else None.
    """

    split: Split
    x_scaler: Scaler
    y_scaler: Scaler
    wrench_scale: np.ndarray
    z: np.ndarray
    context: object = None

    def constants(self, shared: SharedData) -> dict:
        """The numbers a compiled step reads of this trial (NumPy; the dtype of the shared data)."""
        dt = np.dtype(shared.dtype)
        c = {
            "x_center": self.x_scaler.center,
            "x_scale": self.x_scaler.scale,
            "y_center": self.y_scaler.center,
            "y_scale": self.y_scaler.scale,
            "wrench_scale": self.wrench_scale,
            "z": self.z,
        }
        if shared.physics.compact is not None:
            c["entry_scale"] = entry_scale(shared.physics.compact, self.wrench_scale)
        return {k: np.asarray(v, dtype=dt) for k, v in c.items()}


def entry_scale(compact: CompactRegressor, wrench_scale: np.ndarray) -> np.ndarray:
    """(width,) the divisor of each number of a compact row: ``s_a`` of the axis it belongs to."""
    s = np.asarray(wrench_scale, dtype=np.float64)
    parts = [s[compact.axis_order]] + [np.repeat(s[list(axes)], len(cols)) for cols, axes in compact.groups]
    return np.concatenate(parts)


def fit_trial(
    shared: SharedData, cfg: TrainConfig, split: Split, saved: tuple | None = None, targets: np.ndarray | None = None
) -> TrialData:
    """The constants of a trial with ``split``: fitted on its training configurations, or ``saved``
    (``(x_scaler, y_scaler, wrench_scale)`` of an existing run).

    ``targets``: (C, n_u) the unscaled targets of the held configurations (default: the truth).
    """
    if not shared.holds(np.union1d(split.train, split.val)):
        raise ValueError("the shared data do not hold every configuration of the trial's split")
    if saved is None:
        fit = shared.local(split.train)
        feats = shared.feats[fit]
        x_scaler = Scaler.fit(cfg.scaler, feats.reshape(-1, feats.shape[-1]))
        y_scaler = Scaler.fit(cfg.scaler, shared.theta_unknown[fit])
        ws = shared.values[fit].reshape(-1, shared.values.shape[-1]).std(axis=0)
        wrench_scale = np.where(ws > 0, ws, 1.0)
    else:
        x_scaler, y_scaler, wrench_scale = saved
    truth = shared.theta_unknown if targets is None else targets
    return TrialData(split, x_scaler, y_scaler, np.asarray(wrench_scale, dtype=np.float64), y_scaler.transform(truth))


def trial_physics(physics: Physics, consts: dict) -> Physics:
    """``physics`` with a trial's scalers and wrench scale (arrays, traced inside a compiled step)."""
    return dataclasses.replace(
        physics, y_center=consts["y_center"], y_scale=consts["y_scale"], wrench_scale=consts["wrench_scale"]
    )


def gather(arrays: dict, consts: dict, mode: str, rows, frames, n_axes: int):
    """A trial's batch: positions (B,) and frames (B, K) -> ``(x, z, physics inputs)``, scaled by its constants.

    Per-frame arrays are gathered by one flat index ``row * n_frames + frame`` along their first
    axis: a single-axis ``take``, much cheaper on the CPU than a two-axis gather.
    """
    import jax.numpy as jnp

    n_frames = arrays["feats"].shape[1]
    flat = rows[:, None] * n_frames + frames

    def take(a):
        return jnp.take(a.reshape((-1,) + a.shape[2:]), flat, axis=0)

    x = (take(arrays["feats"]) - consts["x_center"]) / consts["x_scale"]
    z = consts["z"][rows]
    if "compact" in arrays:  # y / s and the kept entries in one gather
        row = take(arrays["compact"]) / consts["entry_scale"]
        return x, z, (row[..., n_axes:], row[..., :n_axes])
    if mode == "cached":
        return x, z, (take(arrays["psi"]), take(arrays["yres"]))
    return x, z, tuple(take(arrays[k]) for k in ("q", "qd", "qdd", "wrench"))


def prepare(
    ds: Dataset,
    cfg: TrainConfig,
    rows: np.ndarray,
    model: RobotModel,
    scalers=None,
    fit_rows: np.ndarray | None = None,
    wrench_scale: np.ndarray | None = None,
    physics_mode: str = "cached",
) -> Prepared:
    """Scalers (fitted on ``fit_rows`` unless given) and device arrays of configurations ``rows``, scaled.

    Args:
        ds: the dataset (with the truth).
        cfg: the run's settings.
        rows: sorted dataset indices of the configurations to hold.
        model: the robot model.
        scalers: ``(x_scaler, y_scaler)`` of an existing run, or None to fit.
        fit_rows: configurations to fit the scalers and the wrench scale on (the training split).
        wrench_scale: the physics term's per-axis normalization of an existing run.
        physics_mode: ``"cached"`` or ``"inline"`` (see :class:`ineid.learn.losses.Physics`).
    """
    import jax.numpy as jnp

    if ds.n_frames < cfg.model.frames:
        raise DatasetError(
            f"{cfg.model.frames} frames per sample but the dataset has {ds.n_frames} frames per configuration"
        )
    shared = build_shared(ds, model, rows, physics_mode=physics_mode, full_regressor=cfg.model.uses_regressor)
    fit = np.asarray(fit_rows if fit_rows is not None else rows)
    split = Split(fit, np.asarray(rows), np.zeros(0, dtype=np.int64))
    saved = None if scalers is None else (*scalers, wrench_scale)
    trial = fit_trial(shared, cfg, split, saved)
    c = trial.constants(shared)
    arrays = {"x": (shared.arrays["feats"] - c["x_center"]) / c["x_scale"], "z": jnp.asarray(c["z"])}
    if "compact" in shared.arrays:
        arrays["compact"] = shared.arrays["compact"] / c["entry_scale"]
    else:
        arrays.update({k: v for k, v in shared.arrays.items() if k != "feats"})
    physics = dataclasses.replace(
        shared.physics, y_center=trial.y_scaler.center, y_scale=trial.y_scaler.scale, wrench_scale=trial.wrench_scale
    )
    return Prepared(shared.rows, trial.x_scaler, trial.y_scaler, arrays, physics, shared.n_out, shared.n_frames)


def float32_resolution(
    ds: Dataset, model: RobotModel, rows: np.ndarray, wrench_scale: np.ndarray
) -> tuple[float, float]:
    """How well float32 resolves the physics term's residual at the true parameters, on up to 200 of ``rows``.

    Returns:
        ``(residual, rounding)``: the RMS of the normalized residual ``(R - Psi theta) / s`` at the true parameters
        in float64, and the RMS of what computing it in float32 changes. A residual not well above the rounding
        (clean data: round-off) is one float32 cannot fit: its physics term stops improving at the rounding.
    """
    from ineid.identify.systems import stack

    sub = ds.select(np.sort(np.asarray(rows))[:200])
    channels = ds.meta.channels
    w, y = stack(model, sub.q, sub.qd, sub.qdd, sub.measured(channels), sub.theta_known, channels)
    n_axes = channels.n_axes(model)
    s = np.tile(np.asarray(wrench_scale, dtype=np.float64), w.shape[1] // n_axes)  # frame-major rows, A per frame
    theta = np.asarray(sub.theta_unknown)
    r64 = (y - np.einsum("cnp,cp->cn", w, theta)) / s
    f32 = np.float32
    r32 = (y.astype(f32) - np.einsum("cnp,cp->cn", w.astype(f32), theta.astype(f32))) / s.astype(f32)
    return float(np.sqrt(np.mean(r64**2))), float(np.sqrt(np.mean((r32 - r64) ** 2)))
