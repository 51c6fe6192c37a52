"""The paper's section 4, reproduced: its classical solvers on its own data layout, per parameter.

The paper generates 100 parameter sets per unknown link around the CAD values, combines them
full-factorially into 10,000 configurations of 100 random frames each (noise-free), fits every
configuration with MATLAB's ``lsqlin`` and ``lsqnonlin`` and reports: the masses and centres of
mass identified by both, the linear problem identifying everything, and the nonlinear solver's
inertia entries at "between approximately 50 % and 95 %" accuracy, depending on the configuration
and the frames. This study runs the same layout (:class:`PaperSize`; ``quick``: 20 random
configurations, for CI) through ``lsqlin``, ``lsqnonlin`` (:mod:`ineid.identify.classical`), and
ineid's ``linear`` and ``consistent``, fitting the first 4, 10 and 100 frames of each
configuration, and reports, per method, frames and parameter, the paper's measures: the
accuracy ``1 - |estimate - truth| / |truth|`` (:func:`ineid.identify.results.relative_error`),
as the share of configurations within 5 % (accuracy >= 95 %), the share in the 50-95 % band, and
the median error, with the identifiability reason beside each parameter (:func:`reasons`).

The parameters are the paper's 20: per link the mass, the centre of mass and the inertia about it
(``x`` of :func:`ineid.identify.classical.x_from_theta`), computed from each method's standard
parameters. A parameter is identifiable when every standard parameter it is computed from is
(:attr:`ineid.identify.identifiability.BaseParameters.identifiable`); otherwise the reason names
the base parameters those appear in: the data fix the sum, each solver splits it its own way.
:func:`check_claims` sets the paper's statements against the rows.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ineid._atomic import save_figure, write_csv
from ineid.data.synthesis.generate import DatasetSpec, generate_dataset
from ineid.data.synthesis.sampling import Combination
from ineid.identify.classical import x_from_theta
from ineid.identify.identifiability import BaseParameters, base_parameters, frame_minimum
from ineid.identify.results import relative_error
from ineid.identify.solve import SolveResults, SolveSettings, solve_dataset
from ineid.params import N_PARAMS_PER_LINK, PARAM_NAMES
from ineid.robots.model import SMALL_JOB_FRAMES

METHODS = {name: {"method": name, "weights": "none"} for name in ("lsqlin", "lsqnonlin", "linear", "consistent")}
"""Each method's :class:`ineid.identify.SolveSettings` fields: the paper's plain objective for all four (clean data:
every weighting fits the frames exactly; one weighting compiles one kernel per number of frames)."""
PARAMETERS = ("paper", "standard")
"""The parameters reported: the paper's (mass, centre of mass, inertia about it) or ineid's standard ones."""
PAPER_FRAMES = (4, 10, 100)
"""Frames fitted per configuration: the fewest that can work, a few, and all of the paper's."""
X_NAMES = ("m", "cx", "cy", "cz", "Icxx", "Icxy", "Icyy", "Icxz", "Icyz", "Iczz")
"""The paper's parameters per link: mass (kg), centre of mass (m, link frame), inertia about it (kg m^2)."""
WITHIN = 0.05
"""The paper's "identified": accuracy of at least 95 %, a relative error of at most 5 %."""
BAND = (0.05, 0.5)
"""The paper's 50-95 % accuracy band, as relative errors."""
CLAIM_SHARE = 0.95
"""A claim about "the" parameter holds when this share of the configurations bears it out."""


@dataclass(frozen=True)
class PaperSize:
    """The study's size: configurations (full factorial of ``per_link`` sets per link, or ``n_configs`` random) and
    frames generated per configuration."""

    per_link: int | None = 100
    n_configs: int | None = None
    n_frames: int = 100

    def combination(self) -> Combination:
        if self.n_configs is not None:
            return Combination("random", n_configs=self.n_configs)
        return Combination("factorial", per_link=self.per_link)


SIZES = {"full": PaperSize(), "quick": PaperSize(per_link=None, n_configs=20)}
"""The paper's 100 x 100 configurations of 100 frames, and the CI size."""


@dataclass(frozen=True)
class PaperRow:
    """One parameter under one method and number of frames, over the configurations solved."""

    method: str
    frames: int
    parameter: str
    identifiable: bool
    within_5: float
    band_50_95: float
    below_50: float
    median_error: float
    p95_error: float
    solved: float
    seconds: float
    reason: str


def _depends(link: int, k: int) -> list[int]:
    """The standard parameters (indices in ``theta_u``) the paper's parameter ``k`` of ``link`` is computed from."""
    o = N_PARAMS_PER_LINK * link
    if k == 0:
        return [o]
    if k < 4:
        return [o, o + k]
    pairs = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
    a, b = pairs[k - 4]
    mc = [o + 1 + j for j in range(3) if j != a] if a == b else [o + 1 + a, o + 1 + b]
    return [o, *mc, o + k]


def reasons(base: BaseParameters, links, parameters: str = "paper") -> list[tuple[bool, str]]:
    """``(identifiable, reason)`` of each parameter reported (``len(links) * 10``, link by link): the paper's
    (``parameters="paper"``, each computed from a few standard parameters, :func:`_depends`) or the standard ones."""
    out = []
    for i, _ in enumerate(links):
        for k in range(N_PARAMS_PER_LINK):
            dep = _depends(i, k) if parameters == "paper" else [N_PARAMS_PER_LINK * i + k]
            hidden = [j for j in dep if not base.identifiable[j]]
            if not hidden:
                out.append((True, "identifiable"))
                continue
            rows = [r for r in range(base.rank) if np.any(base.B[r, hidden] != 0)]
            nulls = [n + 1 for n in range(base.null_basis.shape[1]) if np.any(base.null_basis[hidden, n] != 0)]
            shown = "; ".join(base.names[r] for r in rows[:2]) + ("; ..." if len(rows) > 2 else "")
            what = f"via {', '.join(base.param_names[j] for j in hidden)}: " if parameters == "paper" else ""
            out.append((False, f"{what}only in {shown} (null direction {', '.join(map(str, nulls))})"))
    return out


def reported(theta_u: np.ndarray, n_links: int, parameters: str = "paper") -> np.ndarray:
    """(C, 10 n_u) the parameters reported of standard ones (C, >= 10 n_u): the paper's (mass, centre of mass,
    inertia about it; :func:`ineid.identify.classical.x_from_theta`) or the standard ones themselves."""
    theta = theta_u[:, : N_PARAMS_PER_LINK * n_links]
    return x_from_theta(theta, n_links) if parameters == "paper" else theta


def paper_rows(
    res: SolveResults, method: str, frames: int, base: BaseParameters, links, parameters: str = "paper"
) -> list[PaperRow]:
    """The :class:`PaperRow` of each parameter reported (:data:`PARAMETERS`) for one solve."""
    n = len(links)
    ok = res.success
    err = relative_error(reported(res.theta_links[ok], n, parameters), reported(res.theta_true[ok], n, parameters))
    names = [f"{link}.{p}" for link in links for p in (X_NAMES if parameters == "paper" else PARAM_NAMES)]
    rows = []
    for k, (name, (ident, why)) in enumerate(zip(names, reasons(base, links, parameters), strict=True)):
        e = err[:, k]
        e = e[np.isfinite(e)]

        def share(mask, e=e):
            return float(np.mean(mask)) if e.size else float("nan")

        rows.append(
            PaperRow(
                method,
                frames,
                name,
                ident,
                share(e <= WITHIN),
                share((e > BAND[0]) & (e <= BAND[1])),
                share(e > BAND[1]),
                float(np.median(e)) if e.size else float("nan"),
                float(np.percentile(e, 95)) if e.size else float("nan"),
                float(np.mean(ok)),
                float(np.sum(res.seconds)),
                why,
            )
        )
    return rows


def paper_study(
    model,
    size: PaperSize = SIZES["quick"],
    frames=PAPER_FRAMES,
    methods=tuple(METHODS),
    seed: int = 0,
    workers: int = 1,
    parameters: str = "paper",
    progress=None,
) -> tuple[list[PaperRow], dict]:
    """Generate the paper's layout for ``model`` (clean data) and solve it with every method and number of frames.

    Returns:
        the rows (method, frames, parameter; in that order) and the results ``{(method, frames): SolveResults}``.

    Raises:
        IdentificationError: a number of frames below the fewest that can work (:func:`frame_minimum`).
    """
    if parameters not in PARAMETERS:
        raise ValueError(f"parameters must be one of {', '.join(PARAMETERS)}, got {parameters!r}")
    frames = tuple(int(f) for f in frames)
    for f in frames:
        frame_minimum(model).require(f)
    spec = DatasetSpec(size.combination(), n_frames=max(max(frames), size.n_frames), seed=seed)
    ds_all = generate_dataset(model, spec)
    base = base_parameters(model)
    links = tuple(model.unknown_links)
    rows: list[PaperRow] = []
    results = {}
    total, done = len(frames) * len(methods), 0
    # a small study (the quick size) fits through CasADi: no kernel compiled for each number of frames
    backend = "casadi" if ds_all.n_configs * max(frames) <= SMALL_JOB_FRAMES else "jax"
    for f in frames:
        ds = ds_all.select(frames=slice(0, f))
        for name in methods:
            t0 = time.perf_counter()
            res = solve_dataset(
                ds, SolveSettings(frames=f, workers=workers, backend=backend, **METHODS[name]), model=model
            )
            res.seconds = np.full(res.n, (time.perf_counter() - t0) / max(res.n, 1))
            results[(name, f)] = res
            rows += paper_rows(res, name, f, base, links, parameters)
            done += 1
            if progress is not None:
                progress(done, total)
    return rows, results


def check_claims(rows: list[PaperRow], minimum) -> list[tuple[str, str, str]]:
    """``(claim, verdict, evidence)`` of the paper's statements (section 4) against the rows.

    ``minimum``: the model's :class:`ineid.identify.frame_minimum.FrameMinimum`. The claims about the solvers
    are checked on the most frames studied.
    """
    out = []
    f_max = max(r.frames for r in rows)
    at = {(r.method, r.parameter): r for r in rows if r.frames == f_max}

    def verdict(method: str, keep) -> tuple[str, str]:
        chosen = [r for (m, _), r in at.items() if m == method and keep(r.parameter)]
        if not chosen:
            return "not run", f"{method} not in --methods"
        worst = min(chosen, key=lambda r: r.within_5)
        holds = worst.within_5 >= CLAIM_SHARE
        evidence = (
            f"{method}, {f_max} frames: worst {worst.parameter} within 5 % in {100 * worst.within_5:.0f} % "
            f"of configurations (median error {worst.median_error:.2g}; {worst.reason})"
        )
        return ("holds" if holds else "does not hold"), evidence

    mc = lambda p: p.rsplit(".", 1)[1] in ("m", "cx", "cy", "cz", "mx", "my", "mz")  # noqa: E731
    for method in ("lsqlin", "lsqnonlin"):
        out.append((f"{method} identifies the masses and centres of mass", *verdict(method, mc)))
    out.append(("lsqlin identifies every parameter", *verdict("lsqlin", lambda p: True)))
    inertia = [r for (m, _), r in at.items() if m == "lsqnonlin" and not mc(r.parameter)]
    if inertia:
        band = float(np.mean([r.band_50_95 for r in inertia]))
        within = float(np.mean([r.within_5 for r in inertia]))
        out.append(
            (
                "lsqnonlin's inertia entries lie between 50 % and 95 % accuracy",
                "partly" if 0 < band < 1 else ("holds" if band == 1 else "does not hold"),
                f"{f_max} frames: {100 * band:.0f} % of the inertia entries' estimates in the band, "
                f"{100 * within:.0f} % within 5 %",
            )
        )
    out.append(
        (
            "at least 4 frames are needed (20 unknowns, 6 equations a frame)",
            "holds, for another reason"
            if minimum.frames == 4 and minimum.reason
            else ("holds" if minimum.frames == 4 else f"does not hold: {minimum.frames}"),
            f"the {minimum.rank} identifiable combinations need {minimum.frames} frames"
            + (f": {minimum.reason}" if minimum.reason else ""),
        )
    )
    return out


def write_rows(rows: list[PaperRow], path) -> None:
    """The rows as CSV (one per method, frames and parameter), atomically."""
    write_csv(path, list(PaperRow.__dataclass_fields__), [asdict(r) for r in rows])


def plot(rows: list[PaperRow], path, title: str) -> None:
    """Share within 5 % per parameter, one panel per number of frames, one bar per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = sorted({r.frames for r in rows})
    methods = list(dict.fromkeys(r.method for r in rows))
    params = list(dict.fromkeys(r.parameter for r in rows))
    fig, axes = plt.subplots(len(frames), 1, figsize=(14, 3.2 * len(frames)), constrained_layout=True, squeeze=False)
    width = 0.8 / len(methods)
    x = np.arange(len(params))
    for ax, f in zip(axes[:, 0], frames, strict=True):
        for i, m in enumerate(methods):
            share = {r.parameter: r.within_5 for r in rows if r.frames == f and r.method == m}
            ax.bar(x + (i - (len(methods) - 1) / 2) * width, [100 * share[p] for p in params], width, label=m)
        ax.set_xticks(x)
        for t in ax.set_xticklabels(params, rotation=60, fontsize=7):
            t.set_parse_math(False)
        ax.set_ylabel("% within 5 %")
        ax.set_title(f"{f} frames")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0, 0].legend(fontsize=8, ncols=len(methods))
    fig.suptitle(title).set_parse_math(False)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
