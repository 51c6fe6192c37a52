"""Noise study: how wrench and kinematic noise and the number of frames affect each method.

For every noise level and frame count, the same configurations (same parameters, same
clean frames: the random streams do not depend on the noise) are identified by

* ``linear``: ordinary least squares;
* ``weighted``: least squares weighted per wrench axis, noise estimated from residuals;
* ``consistent``: log-Cholesky IPOPT with the CAD prior (always a rigid body);

and the median relative errors of the base parameters (what the data determine) and of
the standard parameters, and the share of physically invalid estimates, are tabulated.
A noise level ``k`` scales the reference standard deviations: wrench
``force``/``moment``, and ``qd``/``qdd`` of a gyroscope-type measurement.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ineid._atomic import save_figure, write_csv
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify.results import relative_error
from ineid.identify.solve import SolveSettings, solve_dataset
from ineid.params import all_links_physical

REFERENCE_NOISE = {"force": 0.5, "moment": 0.05, "q": 0.0, "qd": 0.01, "qdd": 0.1}
"""Standard deviations at noise level 1 (N, N*m, rad, rad/s, rad/s^2)."""

STUDY_METHODS = {
    "linear": SolveSettings(method="linear", weights="none"),
    "weighted": SolveSettings(method="linear", weights="estimate"),
    "consistent": SolveSettings(method="consistent", weights="estimate"),
}


@dataclass(frozen=True)
class StudyRow:
    """One line of the noise study: a method at one noise level and frame count, over its configurations.

    Errors are relative (``|estimate - truth| / |truth|``), medians and 95th percentiles over
    the successful configurations; shares are fractions in [0, 1]; ``seconds`` wall-clock.
    """

    level: float
    frames: int
    method: str
    base_error_median: float
    base_error_p95: float
    standard_error_median: float
    identifiable_error_median: float
    invalid_share: float
    failed_share: float
    seconds: float


def noise_study(
    model,
    levels=(0.0, 0.5, 1.0, 2.0, 4.0),
    frames=(10, 50, 200),
    n_configs: int = 200,
    seed: int = 0,
    methods=tuple(STUDY_METHODS),
    workers: int = 1,
    progress=None,
) -> list[StudyRow]:
    """Run the sweep; one :class:`StudyRow` per (level, frames, method)."""
    import time

    from ineid.identify.identifiability import frame_minimum

    for k in frames:
        frame_minimum(model).require(int(k))
    # compile the regressor shapes once, so the first row's time is solving, not compiling
    warm = generate_dataset(model, DatasetSpec(Combination("random", n_configs=2), n_frames=max(frames), seed=seed))
    solve_dataset(warm, SolveSettings(frames=max(frames)), model=model)
    rows: list[StudyRow] = []
    total = len(levels) * len(frames) * len(methods)
    done = 0
    for level in levels:
        ref = {k: level * v for k, v in REFERENCE_NOISE.items()}
        noise = NoiseModel.create(model.n_dof, **ref) if level > 0 else None
        spec = DatasetSpec(Combination("random", n_configs=n_configs), n_frames=max(frames), seed=seed, noise=noise)
        ds_all = generate_dataset(model, spec)
        for k in frames:
            ds = ds_all.select(frames=slice(0, k))
            for name in methods:
                settings = STUDY_METHODS[name]
                settings = SolveSettings(**{**settings.to_dict(), "frames": k, "workers": workers, "axis_sigma": None})
                t0 = time.perf_counter()
                res = solve_dataset(ds, settings, model=model)
                seconds = time.perf_counter() - t0
                ok = res.success
                b_err = relative_error(res.base_hat[ok], res.base_true[ok])
                t_err = relative_error(res.theta_hat[ok], res.theta_true[ok])
                valid = all_links_physical(np.nan_to_num(res.theta_hat[ok]))
                rows.append(
                    StudyRow(
                        level=float(level),
                        frames=int(k),
                        method=name,
                        base_error_median=float(np.nanmedian(b_err)) if ok.any() else np.nan,
                        base_error_p95=float(np.nanpercentile(b_err, 95)) if ok.any() else np.nan,
                        standard_error_median=float(np.nanmedian(t_err)) if ok.any() else np.nan,
                        identifiable_error_median=float(np.nanmedian(t_err[:, res.base.identifiable]))
                        if ok.any()
                        else np.nan,
                        invalid_share=float(1.0 - valid.mean()) if ok.any() else np.nan,
                        failed_share=float(1.0 - ok.mean()),
                        seconds=seconds,
                    )
                )
                done += 1
                if progress is not None:
                    progress(done, total)
    return rows


def write_rows(rows: list[StudyRow], path: str | Path) -> Path:
    """The study's table as CSV (atomically), one row per method, frame count and level."""
    return write_csv(path, list(asdict(rows[0])), [asdict(r) for r in rows])


def plot(rows: list[StudyRow], path: str | Path) -> Path:
    """Errors and invalid share against the noise level, one line per method and frame count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), constrained_layout=True)
    methods = sorted({r.method for r in rows}, key=list(STUDY_METHODS).index)
    frames = sorted({r.frames for r in rows})
    styles = ["-", "--", ":", "-."]
    for mi, method in enumerate(methods):
        for fi, k in enumerate(frames):
            sel = sorted((r for r in rows if r.method == method and r.frames == k), key=lambda r: r.level)
            x = [r.level for r in sel]
            kw = {
                "color": f"C{mi}",
                "linestyle": styles[fi % len(styles)],
                "marker": "o",
                "label": f"{method}, {k} frames",
            }
            axes[0].plot(x, [r.base_error_median for r in sel], **kw)
            axes[1].plot(x, [r.standard_error_median for r in sel], **kw)
            axes[2].plot(x, [100 * r.invalid_share for r in sel], **kw)
    axes[0].set_title("base parameters: median relative error")
    axes[1].set_title("standard parameters: median relative error")
    axes[2].set_title("physically invalid estimates (%)")
    for ax in axes[:2]:
        ax.set_yscale("log")
    for ax in axes:
        ax.set_xlabel("noise level (x reference)")
        ax.grid(True, alpha=0.3)
    for text in axes[2].legend(fontsize=7).get_texts():
        text.set_parse_math(False)  # labels are names, never mathtext
    path = Path(path)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
