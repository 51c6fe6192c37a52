"""What a solve returns: :class:`SolveResults`, assembled the same way by every solver (:func:`dataset_results`).

The estimates of the selected configurations of one dataset, their residuals on the fitted and
held-out frames (:func:`residual_summary` of :func:`ineid.identify.steps.estimate_residual_sums`), the
prior, the truth of synthetic data (:func:`truth_with_extras`), and what a results file records of
the dataset and the channels fitted (:func:`results_meta`). The methods of :mod:`ineid.identify.solve`,
the two steps (:mod:`ineid.identify.two_step`), several recordings (:mod:`ineid.identify.joint`) and a
trained network (:mod:`ineid.learn.amortized`) all return one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ineid.channels import ChannelSet
from ineid.identify.identifiability import BaseParameters
from ineid.identify.settings import SolveSettings


@dataclass
class SolveResults:
    """Estimates of the selected configurations of one dataset (see ``docs/identification.md``).

    Arrays have one row per solved configuration, in selection order. Per-axis arrays
    (``fit_rms``, ``validation_rms``; ``bias_hat`` and ``bias_std``, the sensor offsets with
    ``bias="estimate"``) are (C, A) over the fitted channels' stacked axes, named in
    :attr:`axes` (the base wrench: fx..mz, N and N*m, sensor frame).
    """

    settings: SolveSettings
    base: BaseParameters
    param_names: tuple[str, ...]
    config_index: np.ndarray
    theta_hat: np.ndarray
    theta_std: np.ndarray
    base_hat: np.ndarray
    base_std: np.ndarray
    success: np.ndarray
    status: np.ndarray
    seconds: np.ndarray
    fit_rms: np.ndarray
    validation_rms: np.ndarray
    validation_rel: np.ndarray
    n_frames_fit: int
    n_frames_validation: int
    theta_prior: np.ndarray
    theta_true: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    bias_hat: np.ndarray | None = None
    bias_std: np.ndarray | None = None
    payload: dict | None = None
    """Per payload link (:mod:`ineid.identify.payload`): mass, centre of mass, inertia about it, with std."""

    @property
    def axes(self) -> tuple[str, ...]:
        """The names of the per-axis arrays' columns (``meta["axes"]``; a file of ineid 0.1: the base wrench's)."""
        return tuple(self.meta.get("axes") or ("fx", "fy", "fz", "mx", "my", "mz"))

    @property
    def units(self) -> tuple[str, ...]:
        """The units of the per-axis arrays' columns."""
        return tuple(self.meta.get("units") or ("N", "N", "N", "N*m", "N*m", "N*m"))

    @property
    def base_true(self) -> np.ndarray | None:
        """``B theta_true``; NaN in the base parameters that involve an extra parameter whose truth is unknown."""
        if self.theta_true is None:
            return None
        unknown = np.isnan(self.theta_true)
        out = np.nan_to_num(self.theta_true) @ self.base.B.T
        out[(unknown.astype(np.float64) @ (self.base.B != 0).T.astype(np.float64)) > 0] = np.nan
        return out

    @property
    def n_extra(self) -> int:
        """The channels' extra parameters among :attr:`param_names` (the last ones; :mod:`ineid.identify.extras`)."""
        return self.base.n_extra

    @property
    def theta_links(self) -> np.ndarray:
        """(C, 10 n_u) the unknown links' estimates: :attr:`theta_hat` without the extra parameters."""
        return self.theta_hat[:, : self.theta_hat.shape[1] - self.n_extra]

    @property
    def n(self) -> int:
        return len(self.config_index)


def residual_summary(sums, n_fit: int, n_val: int, theta_unknown: np.ndarray):
    """``(fit_rms (C, A), validation_rms (C, A), validation_rel (C,))`` from :func:`estimate_residual_sums`.

    ``rms_a = sqrt(ssr_a / frames)`` per measured axis; ``rel = ||R - predicted|| / ||R||`` over the
    held-out frames; NaN where ``theta_unknown`` has a non-finite entry (a failed solve) and,
    for the held-out columns, when no frame is held out.
    """
    ssr_fit, ssr_held, ss_held = sums
    failed = ~np.all(np.isfinite(theta_unknown), axis=1)
    fit_rms = np.sqrt(ssr_fit / n_fit)
    fit_rms[failed] = np.nan
    c = len(theta_unknown)
    if not n_val:
        return fit_rms, np.full(ssr_fit.shape, np.nan), np.full(c, np.nan)
    val_rms = np.sqrt(ssr_held / n_val)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero wrench: inf (ineid solve warns)
        val_rel = np.sqrt(ssr_held.sum(axis=1)) / np.sqrt(ss_held)
    val_rms[failed] = np.nan
    val_rel[failed] = np.nan
    return fit_rms, val_rms, val_rel


def dataset_results(
    ds,
    settings: SolveSettings,
    base: BaseParameters,
    theta_prior: np.ndarray,
    sums,
    n_fit: int,
    n_val: int,
    t_start: float,
    channels: ChannelSet | None = None,
    model=None,
    **estimates,
) -> SolveResults:
    """:class:`SolveResults` of estimates on ``ds``, for every solver (the methods and a trained run).

    What every result records the same way: the configurations' file indices, the residual
    RMS on the fitted and held-out frames from ``sums`` (:func:`estimate_residual_sums`, see
    :func:`residual_summary`), the prior, the truth when the dataset has it, and
    :func:`results_meta` with the seconds since ``t_start`` (``time.perf_counter()``) and the
    channels fitted (default: the dataset's; ``model`` names their axes, default the dataset's
    metadata). ``estimates``: the remaining fields (``theta_hat, theta_std, base_hat, base_std,
    success, status, seconds``, optionally ``bias_hat, bias_std``).
    """
    fit_rms, val_rms, val_rel = residual_summary(sums, n_fit, n_val, estimates["theta_hat"])
    return SolveResults(
        settings=settings,
        base=base,
        param_names=tuple(base.param_names),
        config_index=np.asarray(ds.config_index, dtype=np.int64),
        fit_rms=fit_rms,
        validation_rms=val_rms,
        validation_rel=val_rel,
        n_frames_fit=n_fit,
        n_frames_validation=n_val,
        theta_prior=theta_prior,
        theta_true=truth_with_extras(ds, base),
        meta=results_meta(ds, time.perf_counter() - t_start, channels, model),
        **estimates,
    )


def truth_with_extras(ds, base: BaseParameters) -> np.ndarray | None:
    """The true ``[theta_u, x]`` of synthetic data (C, 10 n_u + n_extra): the links' from the dataset, the extra
    parameters' from its ``extra_truth`` record (NaN where it has none); None without the links' truth."""
    if ds.theta_unknown is None:
        return None
    theta = np.asarray(ds.theta_unknown, dtype=np.float64)
    if not base.n_extra:
        return theta
    truth = getattr(ds.meta, "extra_truth", None) or {}
    names = base.param_names[base.n_link_params :]
    extra = np.array([float(truth.get(n, np.nan)) for n in names])
    return np.concatenate([theta, np.broadcast_to(extra, (len(theta), len(names)))], axis=1)


def results_meta(ds, total_seconds: float, channels: ChannelSet | None = None, model=None) -> dict:
    """What a results file records of its dataset (robot, URDF, links, gravity, sensor, path and fingerprint)
    and of the channels fitted (their records, the stacked axes' names and units)."""
    from ineid._version import __version__

    channels = ds.meta.channels if channels is None else channels
    names = model or ds.meta
    return {
        "ineid_version": __version__,
        "robot": ds.meta.robot,
        "source": ds.meta.source,
        "urdf": ds.meta.urdf,
        "unknown_links": list(ds.meta.unknown_links),
        "gravity": np.asarray(ds.meta.gravity).tolist(),
        "locked_joints": ds.meta.locked_joints,
        "dataset_path": None if ds.path is None else str(ds.path),
        "dataset_fingerprint": ds.fingerprint(),
        "sensor": ds.meta.sensor,
        "channels": channels.to_list(),
        "axes": list(channels.axes(names)),
        "units": list(channels.units(names)),
        "total_seconds": total_seconds,
    }
