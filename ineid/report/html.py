"""One self-contained HTML report of an identification (``ineid report``, ``ineid solve --report``).

The page holds everything a lab notebook needs, and needs nothing beside it (figures inline as
PNG ``data:`` URIs, the style in the page, no script, no network): the robot, the data (files,
fingerprints, rates, filter and delay, channels and sensor poses), the method and its settings,
ineid's version; identifiability (rank, base parameters by name, null directions, what the
sensor offsets cost); the estimates beside the CAD values with standard deviations, physical
validity (pseudo-inertia eigenvalues, triangle inequalities), a payload's mass, centre of mass
and inertia; validation (measured against predicted and the residual per axis over the whole
validation span, its spectrum, its RMS beside the noise, the tests of
:mod:`ineid.report.residuals`); the excitation's quality.

Rendered with Jinja2 (the Python field's template engine: Sphinx, MkDocs, nbconvert, pandas'
Styler), autoescaping on: robot, link and joint names are data and may hold markup. The template
is the package file ``ineid/report/templates/report.html.j2``.

What cannot be shown (the dataset moved, a results file that records none) is
said in a box at the top with the fix (``--data NEW_PATH``), and the rest of the page is shown.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ineid.errors import DatasetError
from ineid.report import sections


@dataclass
class ReportInputs:
    """What a report is built from.

    Attributes:
        res: :class:`ineid.identify.SolveResults`.
        ds: the dataset solved (its configurations selected as solved), or None when it is missing.
        validate_ds: the separate validation recording (``ineid solve --validate``), or None.
        model: the robot model (from the dataset), or None.
        results_path: the results file, or None (in memory).
        missing: ``(what is missing, how to fix it)`` pairs, shown at the top.
    """

    res: object
    ds: object = None
    validate_ds: object = None
    model: object = None
    results_path: Path | None = None
    missing: list[tuple[str, str]] = field(default_factory=list)


def inputs_from_files(
    results_path: str | Path, data_path: str | Path | None = None, validate_path: str | Path | None = None
) -> ReportInputs:
    """Read the results file and find its dataset: ``data_path``, else the path the results record.

    A missing, moved or different dataset (its fingerprint not the recorded one) is recorded in
    :attr:`ReportInputs.missing`, never raised: the report shows the rest.

    Raises:
        DatasetError: the results file does not read (not ineid's, damaged, newer).
    """
    from ineid.identify.results import load_results

    res = load_results(results_path)
    out = ReportInputs(res, results_path=Path(results_path))
    m = res.meta
    recorded = m.get("dataset_path") or (m.get("recordings") or [{}])[0].get("path")
    out.ds = _dataset(
        out, data_path or recorded, m.get("dataset_fingerprint"), "the dataset", "--data", given=data_path is not None
    )
    v = m.get("validation")
    if v:
        out.validate_ds = _dataset(
            out,
            validate_path or v.get("path"),
            v.get("fingerprint"),
            "the validation recording",
            "--validate",
            given=validate_path is not None,
        )
    if out.ds is not None:
        try:
            out.model = out.ds.model()
        except DatasetError as e:  # an unparsable URDF in the dataset
            out.missing.append((f"the robot model of {out.ds.path} cannot be built ({e})", "regenerate the dataset"))
            out.ds = out.validate_ds = None
    return out


def _dataset(out: ReportInputs, path, fingerprint, what: str, option: str, given: bool):
    from ineid.data.dataset.read import load_dataset

    res = out.res
    fix = f"give it with {option} PATH (ineid report RESULTS {option} PATH --out report.html)"
    if not path:
        out.missing.append(
            (
                f"the results file records no path of {what} (written by an older ineid, or solved "
                "in memory): no validation plots, residual tests or excitation figures",
                fix,
            )
        )
        return None
    if not Path(path).exists():
        moved = "" if given else " (moved or deleted since the solve)"
        out.missing.append(
            (
                f"{what} {path} is not there{moved}: no validation plots, residual tests or excitation figures",
                fix.replace(" PATH", " NEW_PATH"),
            )
        )
        return None
    try:
        configs = np.asarray(res.config_index) if option == "--data" else None
        ds = load_dataset(path, configs=configs, clean=False)
    except DatasetError as e:
        out.missing.append((f"{what} {path} does not read: {e}", fix))
        return None
    found = ds.fingerprint()
    if fingerprint and found != fingerprint:
        out.missing.append(
            (
                f"{what} {path} is not the one these results were solved on (fingerprint {found}, "
                f"the results record {fingerprint})",
                fix,
            )
        )
        return None
    return ds


def _validation_part(inputs: ReportInputs, i: int, config: int) -> dict | None:
    from ineid.report.figures import data_uri, default_span, spectrum_figure, validation_figure
    from ineid.report.plot import validation, validation_on
    from ineid.report.residuals import check_residual, validation_noise

    res, ds = inputs.res, inputs.ds
    if ds is None or not res.success[i]:
        return None
    if res.meta.get("validation"):
        if inputs.validate_ds is None:
            return None
        v = validation_on(res, inputs.validate_ds, inputs.model, config=config)
        frames_of = inputs.validate_ds
    else:
        v = validation(res, ds, inputs.model, config=config)
        frames_of = ds
    noise, source = validation_noise(res, frames_of, inputs.model, i)
    check = check_residual(
        v.time if v.series else None,
        v.measured,
        v.predicted,
        v.axes,
        v.units,
        v.blocks,
        v.qd,
        noise,
        source,
        _delay(res, frames_of, inputs.model, i),
        v.couplings,
    )
    sigma = np.array([c.noise for c in check.axes])
    figures = [
        (
            "Measured against predicted, the residual under each axis (whole validation span)",
            data_uri(validation_figure(v, noise=sigma, span=(float(v.time[0]), float(v.time[-1])))),
        )
    ]
    zoom = default_span(v.time, v.series)
    if zoom is not None:
        figures.append(
            (f"The first {zoom[1] - zoom[0]:g} s, readable", data_uri(validation_figure(v, noise=sigma, span=zoom)))
        )
    if v.series and len(v.time) >= 8:
        figures.append(("Residual amplitude spectrum per axis", data_uri(spectrum_figure(v, noise=sigma))))
    rows = [
        {
            "axis": c.axis,
            "unit": c.unit,
            "rms": sections.fmt(c.rms, 3),
            "noise": sections.fmt(c.noise, 3),
            "ratio": sections.fmt(c.ratio, 3),
            "lag1": sections.fmt(c.lag1, 2),
            "peak": "-" if np.isnan(c.peak_hz) else f"{c.peak_hz:.3g} Hz ({c.peak_share:.0%})",
            "friction": "-" if np.isnan(c.friction_share) else f"{c.friction_share:.0%}",
        }
        for c in check.axes
    ]
    delay = [(f"{1e3 * d:.3g} ms", f"{s:.0%}") for d, s in check.delay.values()]
    return {
        "source": v.source,
        "frames": len(v.time),
        "frame": v.frame,
        "measured": v.measured_text(),
        "config": v.config,
        "figures": figures,
        "rows": rows,
        "noise_source": check.noise_source,
        "delay": delay,
        "tested": check.tested,
        "warnings": check.warnings,
    }


def _delay(res, ds, model, i: int):
    """:func:`ineid.report.residuals.delay_scan` on every frame of configuration row ``i`` of ``ds`` (None: no
    time series)."""
    from ineid.channels import ChannelSet
    from ineid.identify.systems import stack_casadi
    from ineid.report.residuals import MAX_SCAN_FRAMES, delay_scan

    if ds.time is None or ds.n_frames < 8:
        return None
    records = res.meta.get("channels")
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    one = ds.select(configs=[i], frames=slice(0, MAX_SCAN_FRAMES))
    # the CasADi route: a one-off evaluation needs no compilation
    w, y = stack_casadi(model, one.q[0], one.qd[0], one.qdd[0], one.measured(channels)[0], one.theta_known, channels)
    n_axes = channels.n_axes(model)
    return delay_scan(one.time[0], y.reshape(-1, n_axes), w.reshape(-1, n_axes, w.shape[-1]))


def report_context(inputs: ReportInputs, config: int | None = None) -> dict:
    """Everything the template shows (module doc), as plain values."""
    from ineid._version import __version__

    res, ds, model = inputs.res, inputs.ds, inputs.model
    missing = list(inputs.missing)
    i = sections.solved_index(res, config)
    if config is not None and i is None:
        raise DatasetError(
            f"configuration {config} is not in the results; they hold "
            f"{np.asarray(res.config_index)[:10].tolist()}{' ...' if res.n > 10 else ''}"
        )
    ctx = {
        "title": f"ineid identification report: {res.meta['robot']}",
        "generated": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "ineid_version": __version__,
        "results_path": str(inputs.results_path) if inputs.results_path else "in memory",
        "robot": sections.robot_section(res, model),
        "data": sections.data_section(res, ds, inputs.validate_ds),
        "method": sections.method_section(res),
        "param_order": sections.params_order(),
        "findings": list(res.meta.get("warnings") or []),
        "checked": res.meta.get("warnings") is not None,
        "config": None,
        "estimates": None,
        "validity": None,
        "payload": None,
        "validation": None,
        "excitation": None,
    }
    cost = None
    if i is not None and res.success[i]:
        ctx["config"] = int(res.config_index[i])
        ctx["estimates"] = sections.estimates_section(res, i)
        ctx["validity"] = sections.validity_section(res, i)
        ctx["payload"] = sections.payload_section(res, i)
        ctx["validation"] = _validation_part(inputs, i, ctx["config"])
        ctx["excitation"] = sections.excitation_section(res, ds, model, i)
        cost = _offset_cost(res, ds, model, i)
    elif i is None or not res.success[i]:
        missing.append(
            (
                "no configuration was identified, so there are no estimates to show",
                "see the solver status under Method; solve again with other settings",
            )
        )
    ctx["identifiability"] = sections.identifiability_section(res, cost)
    ctx["missing"] = missing
    ctx["residual_warnings"] = [] if ctx["validation"] is None else ctx["validation"]["warnings"]
    bad = sorted({r["link"] for r in ctx["validity"] or [] if r["which"] == "estimate" and r["problems"]})
    ctx["invalid"] = (
        [
            (
                f"the estimate of {', '.join(bad)} is not a rigid body (see Physical validity): the data or "
                "the method cannot pin it down; solve with --method consistent"
            )
        ]
        if bad
        else []
    )
    return ctx


def _offset_cost(res, ds, model, i: int):
    """What the sensor offsets cost on the fitted frames (:func:`ineid.identify.identifiability.bias_cost`),
    when they were estimated and the dataset is at hand."""
    if ds is None or model is None or res.settings.bias != "estimate":
        return None
    from ineid.channels import ChannelSet
    from ineid.identify.identifiability import bias_cost

    records = res.meta.get("channels")
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    if res.n_extra:  # the cost is of the links' columns; extra columns (friction) change the question
        return None
    n = min(res.n_frames_fit, ds.n_frames)
    return bias_cost(model, ds.q[i, :n], ds.qd[i, :n], ds.qdd[i, :n], channels)


def render(ctx: dict) -> str:
    """The page of :func:`report_context`'s ``ctx`` (Jinja2, autoescaped)."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("ineid.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    return env.get_template("report.html.j2").render(**ctx)


def build_report(inputs: ReportInputs, config: int | None = None) -> str:
    """The report's HTML (module doc) of ``inputs``; ``config`` the configuration detailed (default: the first
    identified one)."""
    return render(report_context(inputs, config))


def write_report(html: str, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``html`` to ``path`` atomically (UTF-8).

    Raises:
        OutputExistsError: ``path`` exists and ``overwrite`` is off.
        DatasetError: ``path`` is a folder or its folder does not exist.
    """
    from ineid._atomic import atomic_write, check_output_file

    path = check_output_file(path, overwrite, "report.html")
    return atomic_write(path, html.encode("utf-8"))
