"""Amortized identification: a trained run as a solver (``ineid solve --method network --run RUN``).

A network trained on synthetic configurations identifies the configurations of any
dataset of the same robot and unknown links, a recording included, in batches and
without per-configuration optimization. Each configuration's first frames are cut into
the run's groups of K (the first ``K * (n_fit // K)`` frames, ``n_fit`` the fitted frames),
the group estimates are averaged (as :func:`ineid.learn.evaluate` does), and the frames
after the fitted ones validate: the results have the fields of every other method
(:class:`ineid.identify.SolveResults`). A network gives no standard deviations: those
fields are NaN.
"""

from __future__ import annotations

import time

import numpy as np

from ineid.channels import BASE_WRENCH, ChannelSet
from ineid.errors import IdentificationError, TrainingError

HOLDOUT_FRACTION = 0.2
"""Without ``frames``, about this share of each configuration's frames is held out (as for the other methods)."""


def network_frames(n_frames: int, k: int, frames: int | None) -> int:
    """Frames fed to a run of K frames per sample: a multiple of K, at most ``n_frames``.

    ``frames`` given: it must be a multiple of K. Otherwise the largest multiple of K that
    leaves :data:`HOLDOUT_FRACTION` of the frames for validation, or all usable frames
    when that leaves no group.

    Raises:
        IdentificationError: fewer frames than K, or ``frames`` not a multiple of K or too many.
    """
    if n_frames < k:
        raise IdentificationError(
            f"the run takes {k} frames per sample but the dataset has {n_frames} per configuration; "
            "use a run trained with fewer frames per sample (--sample-frames)",
            status="too_few_frames",
        )
    if frames is not None:
        if frames % k or frames > n_frames:
            raise IdentificationError(
                f"--fit-frames {frames} must be a multiple of the run's {k} frames per sample and at most {n_frames}",
                status="bad_frames",
            )
        return frames
    fit = (n_frames - int(HOLDOUT_FRACTION * n_frames)) // k * k
    return fit if fit >= k else n_frames // k * k


def trained_channels(run) -> ChannelSet:
    """The measurement channels a run was trained on (its dataset's; a config without channels: the base wrench)."""
    records = run.meta.get("dataset", {}).get("channels")
    return BASE_WRENCH if records is None else ChannelSet.from_list(records, f"{run.run_dir}: channels")


def _check_channels(trained: ChannelSet, measured: ChannelSet) -> None:
    """Refuse data a run cannot read: other channels, or the same in other frames (a transform it never saw).

    Raises:
        IdentificationError: naming what differs and the methods that can identify the data.
    """
    same = trained.keys == measured.keys and all(
        type(a) is type(b) and _same_transform(a.transform(), b.transform())
        for a, b in zip(trained, measured, strict=True)
    )
    if same:
        return
    if trained.keys == measured.keys and all(type(a) is type(b) for a, b in zip(trained, measured, strict=True)):
        raise IdentificationError(
            "a trained run reads wrenches in the base frame; this recording's wrench is in a sensor frame: "
            "identify it with --method linear, nonlinear or consistent",
            status="sensor_frame",
        )
    raise IdentificationError(
        f"the run was trained on {trained.describe()}; this dataset measures "
        f"{measured.describe()}: identify it with --method linear, nonlinear or consistent",
        status="channels",
    )


def _same_transform(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.allclose(a, b, rtol=0, atol=1e-12))


def solve_with_run(ds, settings, model=None, progress=None):
    """Identify every configuration of ``ds`` with the trained run ``settings.run``.

    Args:
        ds: a :class:`ineid.data.Dataset` of the run's robot and unknown links (a recording
            or synthetic; select configurations beforehand).
        settings: a :class:`ineid.identify.SolveSettings` with ``method="network"`` and ``run``;
            ``frames`` as in :func:`network_frames`.
        model: the dataset's robot model (default: rebuilt from the file).
        progress: ``progress(done, total)`` over configurations.

    Returns:
        :class:`ineid.identify.SolveResults`.

    Raises:
        TrainingError: the run folder is not a finished run, or it predicts other parameters
            than the dataset's unknown links.
        IdentificationError: too few frames for the run, or a wrench in a sensor frame.
    """
    from ineid.identify.identifiability import base_parameters
    from ineid.identify.solve import dataset_results, estimate_residual_sums
    from ineid.learn.evaluate import predict
    from ineid.learn.runs import load_run

    run = load_run(settings.run)
    if list(ds.meta.unknown_param_names) != list(run.meta["param_names"]):
        raise TrainingError(
            f"the run predicts {', '.join(run.meta['param_names'][:2])}, ... of {run.meta['dataset']['robot']}; "
            f"the dataset's unknown parameters ({', '.join(ds.meta.unknown_param_names[:2])}, ...) differ"
        )
    n_features = len(run.x_scaler.center)
    width = 3 * ds.q.shape[-1] + ds.meta.channels.n_axes(ds.meta)
    if width != n_features:
        raise TrainingError(
            f"the run takes {n_features} features per frame; the dataset's frames have {width}: it is another robot"
        )
    _check_channels(trained_channels(run), ds.meta.channels)
    model = model or ds.model()
    base = base_parameters(model, channels=ds.meta.channels)
    k = run.config.model.frames
    n_fit = network_frames(ds.n_frames, k, settings.frames)
    n_val = ds.n_frames - n_fit
    c = ds.n_configs
    t0 = time.perf_counter()
    theta, _, _ = predict(run, ds.select(None, slice(0, n_fit)), np.arange(c), model=model)
    seconds = np.full(c, (time.perf_counter() - t0) / max(c, 1))
    if progress is not None:
        progress(c, c)
    ok = np.all(np.isfinite(theta), axis=1)
    sums = estimate_residual_sums(model, ds, n_fit, n_val, theta)
    prior = np.asarray(model.theta_cad[model.unknown_index], dtype=np.float64)
    return dataset_results(
        ds,
        settings,
        base,
        prior,
        sums,
        n_fit,
        n_val,
        t0,
        theta_hat=theta,
        theta_std=np.full_like(theta, np.nan),
        base_hat=theta @ base.B.T,
        base_std=np.full((c, base.rank), np.nan),
        success=ok,
        status=np.where(ok, "ok", "non_finite").astype(object),
        seconds=seconds,
    )
