"""Evaluation of a trained run on held-out configurations, with the floor the null space sets
and the linear least-squares estimate on the same configurations and frames.

A configuration's estimate is the mean of the network's predictions over the disjoint
groups ``[0, K), [K, 2K), ...`` of its frames (K = 1: every frame); the linear least
squares of :mod:`ineid.identify` uses the same frames. Errors are reported twice:

* on the standard parameters (the paper's measure, ``|theta_hat - theta| / |theta|``);
* on the base parameters ``beta = B theta``, the combinations the wrench determines.

**The floor.** With two unknown links, three directions of the 20 parameters never reach
the base wrench, so even an estimator that knew ``beta`` exactly could only guess them from
their correlation with ``beta`` over the sampled configurations. ineid fits that guess,
the linear minimum-mean-square-error estimator
``theta_hat = mu_theta + C_theta,beta C_beta,beta^-1 (beta - mu_beta)``, on the training
configurations' true parameters (for another dataset, out of fold: 5-fold on the evaluated
configurations), and reports its error per parameter. It is zero on the individually
identifiable parameters. It is the best estimator linear in ``beta`` (the conditional
mean, so the best of all, where the sampling is Gaussian; ineid's uniform bands are close
to that); a network whose error is near it has nothing left to gain from the data.

**The Gaussian-prior estimate** is the classical answer to noise with a known population:
the posterior mean of ``beta`` under a Gaussian prior fitted on the training
configurations' true parameters (their mean and covariance) and a per-axis noise model
(the RMS of the wrench residual at the truth over the training frames), mapped to
``theta`` by the floor's rule (:func:`ineid.learn.wls.prior_estimate`; out of fold on
another dataset, like the floor). It is what an untrained ``wls`` network outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ineid.errors import TrainingError
from ineid.learn.data import fixed_groups, frame_features
from ineid.learn.runs import Run

if TYPE_CHECKING:
    from ineid.data import Dataset
    from ineid.robots import RobotModel


PREDICT_CHUNK_FRAMES = 100_000
"""Frames per chunk of configurations in :func:`predict` (bounds a wls run's regressor memory)."""


def predict(
    run: Run, ds: Dataset, configs: np.ndarray, batch: int = 1024, model: RobotModel | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Per-configuration estimates (C, n_u), per-sample estimates (C, G, n_u), frames used.

    A configuration's groups ``[0, K), [K, 2K), ...`` are its samples; a ``wls`` run also
    gets each frame's regressor and wrench (the generated JAX regressor of ``model``,
    default the dataset's), computed a chunk of configurations at a time.
    """
    import jax

    k = run.config.model.frames
    configs = np.asarray(configs)
    if ds.n_frames < k:
        raise TrainingError(f"the run takes {k} frames per sample but the dataset has {ds.n_frames} per configuration")
    groups = ds.n_frames // k
    structured = run.config.model.uses_regressor
    if structured:
        from ineid.identify.systems import stack

        model = model or ds.model()
    apply = jax.jit(run.net.apply)
    per_chunk = max(1, PREDICT_CHUNK_FRAMES // ds.n_frames)
    out = []
    for c0 in range(0, len(configs), per_chunk):
        sub = ds.select(configs[c0 : c0 + per_chunk], slice(0, groups * k))
        x = run.x_scaler.transform(frame_features(sub))
        pos, frames = fixed_groups(sub.n_configs, sub.n_frames, k)
        arrays = [x]
        if structured:
            channels = ds.meta.channels
            n_axes = channels.n_axes(model)
            w, y = stack(model, sub.q, sub.qd, sub.qdd, sub.measured(channels), sub.theta_known, channels)
            arrays += [
                w.reshape(sub.n_configs, sub.n_frames, n_axes, -1),
                y.reshape(sub.n_configs, sub.n_frames, n_axes),
            ]
        for start in range(0, len(pos), batch):
            parts = [a[pos[start : start + batch, None], frames[start : start + batch]] for a in arrays]
            n = len(parts[0])
            if n < batch:  # pad to one compiled shape
                parts = [np.concatenate([a, np.repeat(a[-1:], batch - n, axis=0)]) for a in parts]
            out.append(np.asarray(apply(run.params, *parts))[:n])
    z = np.concatenate(out).reshape(len(configs), groups, -1)
    per_sample = run.y_scaler.inverse(z)
    return per_sample.mean(axis=1), per_sample, groups * k


def floor_estimator(theta_fit: np.ndarray, b: np.ndarray):
    """The linear MMSE estimate of ``theta`` from exact ``beta = B theta`` (see module doc)."""
    from ineid.learn.wls import null_space_map

    mu_t, mu_b, gain = null_space_map(theta_fit, b)

    def estimate(theta_true: np.ndarray) -> np.ndarray:
        return mu_t + (theta_true @ b.T - mu_b) @ gain.T

    return estimate


def _stats(est, truth, names):
    import warnings

    from ineid.identify.results import relative_error

    err = relative_error(est, truth)
    ss_res = np.sum((est - truth) ** 2, axis=0)
    ss_tot = np.sum((truth - truth.mean(axis=0)) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column (no floor) stays NaN
        r2 = 1.0 - ss_res / ss_tot
        return {
            "names": list(names),
            "median": np.nanmedian(err, axis=0).tolist(),
            "p95": np.nanpercentile(err, 95, axis=0).tolist(),
            "r2": r2.tolist(),
            "overall_median": float(np.nanmedian(err)),
        }


@dataclass
class Evaluation:
    """Everything ``ineid evaluate`` reports, JSON-able via :meth:`to_dict`."""

    n_configs: int
    frames_used: int
    network: dict
    network_base: dict
    floor: dict
    per_sample_median: float
    wrench_rms: list
    wrench_normalized: float
    physical_share: float
    identifiable: list
    linear: dict | None = None
    linear_base: dict | None = None
    linear_physical_share: float | None = None
    gaussian: dict | None = None
    gaussian_base: dict | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def evaluate(
    run: Run, ds: Dataset, configs: np.ndarray | None = None, model: RobotModel | None = None, linear: bool = True
) -> Evaluation:
    """Evaluate ``run`` on configurations of ``ds`` (default: the run's test split when ``ds``
    is its dataset, else every configuration).

    Args:
        run: a loaded run.
        ds: a dataset with the truth.
        configs: dataset indices to evaluate.
        model: the robot model (default: rebuilt from the dataset).
        linear: also compute the classical references on the same configurations and
            frames: the linear least squares and the Gaussian-prior estimate.
    """
    from ineid.identify import SolveSettings, base_parameters, frame_minimum, solve_dataset
    from ineid.identify.results import relative_error
    from ineid.identify.systems import predict_wrench
    from ineid.params import all_links_physical

    ds.require_truth("evaluating a network")
    if list(ds.meta.unknown_param_names) != list(run.meta["param_names"]):
        raise TrainingError(
            f"the run predicts {', '.join(run.meta['param_names'][:3])}, ...; the dataset's unknown parameters differ"
        )
    same = _same_dataset(run, ds)
    configs_given = configs is not None
    if configs is None:
        configs = run.split.test if same else np.arange(ds.n_configs)
    configs = np.asarray(configs, dtype=np.int64)
    model = model or ds.model()
    channels = ds.meta.channels
    base = base_parameters(model, channels=channels)
    theta_hat, per_sample, f_used = predict(run, ds, configs, model=model)
    truth = ds.theta_unknown[configs]
    names = run.meta["param_names"]
    floor = _floor(ds.theta_unknown, run.split.train if same else None, configs, base.B)
    sub = ds.select(configs, slice(0, f_used))
    full = model.full_theta(theta_hat, ds.theta_known)
    resid = sub.measured(channels) - predict_wrench(model, sub.q, sub.qd, sub.qdd, full, channels)
    scale = np.asarray(run.meta["wrench_scale"])
    ev = Evaluation(
        n_configs=len(configs),
        frames_used=f_used,
        network=_stats(theta_hat, truth, names),
        network_base=_stats(theta_hat @ base.B.T, truth @ base.B.T, base.names),
        floor=_stats(floor, truth, names),
        per_sample_median=float(np.nanmedian(relative_error(per_sample, truth[:, None, :]))),
        wrench_rms=np.sqrt(np.mean(resid**2, axis=(0, 1))).tolist(),
        wrench_normalized=float(np.mean((resid / scale) ** 2)),
        physical_share=float(all_links_physical(theta_hat).mean()),
        identifiable=base.identifiable.tolist(),
    )
    if linear and f_used >= frame_minimum(model, channels=channels).frames:  # what solve_dataset accepts
        res = solve_dataset(sub, SolveSettings(frames=f_used), model=model)
        ok = res.success
        ev.linear = _stats(res.theta_hat[ok], truth[ok], names)
        ev.linear_base = _stats(res.base_hat[ok], truth[ok] @ base.B.T, base.names)
        ev.linear_physical_share = float(all_links_physical(res.theta_hat[ok]).mean())
    if linear:
        gp = gaussian_prior_estimates(run, ds, configs, f_used, model, same)
        if gp is not None:
            ev.gaussian = _stats(gp[0], truth, names)
            ev.gaussian_base = _stats(gp[1], truth @ base.B.T, base.names)
    given = "given" if configs_given else "all"
    ev.extra = {"configs": "test split" if same and not configs_given else given, "same_dataset": same}
    return ev


def _same_dataset(run: Run, ds) -> bool:
    return run.meta.get("dataset", {}).get("fingerprint") == ds.fingerprint()


def gaussian_prior_estimates(run: Run, ds, configs: np.ndarray, f_used: int, model, same: bool):
    """Gaussian-prior estimates ``(theta (C, n_u), beta (C, r))`` of ``configs`` on their first
    ``f_used`` frames (see the module doc).

    Args:
        run: a loaded run; its training split (``same``) gives the prior and the noise model
            (a wls run's own constants, which are exactly those).
        ds, configs: the dataset (with the truth) and the dataset indices to estimate.
        f_used: frames per configuration.
        model: the robot model.
        same: ``ds`` is the run's dataset; otherwise the fit is 5-fold out of fold over
            ``configs`` (None when there are fewer than ``5 (r + 2)`` of them).
    """
    from ineid.identify import base_parameters
    from ineid.learn.train import wls_context
    from ineid.learn.wls import WlsContext, iter_systems, prior_estimate

    scale = np.asarray(run.meta["wrench_scale"])
    n = len(configs)
    if same:
        contexts = [
            WlsContext.from_dict(run.meta["wls"])
            if "wls" in run.meta
            else wls_context(ds, run.split.train, model, run.y_scaler, scale)
        ]
        fold = np.zeros(n, dtype=np.int64)
    else:
        if n < 5 * (base_parameters(model, channels=ds.meta.channels).rank + 2):
            return None
        fold = np.arange(n) % 5
        contexts = [wls_context(ds, configs[fold != k], model, run.y_scaler, scale) for k in range(5)]
    sub = ds.select(configs, slice(0, f_used))
    theta = np.empty((n, len(run.meta["param_names"])))
    beta = np.empty((n, contexts[0].rank))
    for sl, w, y in iter_systems(
        model, sub.q, sub.qd, sub.qdd, sub.measured(), sub.theta_known, channels=ds.meta.channels
    ):
        for k, ctx in enumerate(contexts):
            rows = np.flatnonzero(fold[sl] == k)
            if rows.size:
                theta[sl.start + rows], beta[sl.start + rows] = prior_estimate(ctx, w[rows], y[rows])
    return theta, beta


def _floor(theta_all: np.ndarray, train_rows, configs: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Floor estimates of ``configs``: fitted on ``train_rows``, or 5-fold out of fold."""
    truth = theta_all[configs]
    if train_rows is not None:
        return floor_estimator(theta_all[train_rows], b)(truth)
    n = len(configs)
    if n < 5 * (b.shape[0] + 2):  # too few to fit 17 + 1 numbers per parameter out of fold
        return np.full_like(truth, np.nan)
    out = np.empty_like(truth)
    folds = np.arange(n) % 5
    for k in range(5):
        out[folds == k] = floor_estimator(truth[folds != k], b)(truth[folds == k])
    return out
