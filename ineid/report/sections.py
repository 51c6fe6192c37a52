"""The numbers of the HTML report (:mod:`ineid.report.html`), one function per section.

Each returns plain JSON-able values (text, numbers, lists of rows) that the template lays out;
none writes HTML (the template escapes every value: names are data). Numbers are formatted here,
so the template holds no arithmetic.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ineid._inputs import read_json
from ineid.errors import IneidError
from ineid.params import PARAM_NAMES, inertial_from_theta, physical_violations, pseudo_inertia


def fmt(x, digits: int = 4) -> str:
    """A number for a table: ``-`` for None, NaN shown as ``-``, else ``digits`` significant digits."""
    if x is None:
        return "-"
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(x):
        return "-"
    return f"{x:.{digits}g}"


def word(value, none: str = "none") -> str:
    """A record's value for people: ``none`` for None (and an empty list), ``yes``/``no`` for a flag, numbers with
    6 significant digits, text as it is (never Python's ``None``, ``False``)."""
    if value is None or (isinstance(value, (list, tuple, dict)) and not value):
        return none
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return fmt(value, 6)
    return str(value)


def flatten(record, prefix: str = "", none: str = "none") -> list[tuple[str, str]]:
    """``(key.path, value)`` rows of a JSON-able record (lists of numbers kept on one row), values in words
    (:func:`word`; None shown as ``none``)."""
    if isinstance(record, dict) and not record and not prefix:
        return []
    if isinstance(record, dict) and record:
        rows = []
        for k in sorted(record, key=str):
            rows += flatten(record[k], f"{prefix}{k}" if not prefix else f"{prefix}.{k}", none)
        return rows
    if isinstance(record, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in record):
        return [r for k, v in enumerate(record) for r in flatten(v, f"{prefix}[{k}]", none)]
    if isinstance(record, (list, tuple)) and record:
        return [(prefix, ", ".join(word(v, none) for v in record))]
    return [(prefix, word(record, none))]


def solved_index(res, config: int | None):
    """The row of ``res`` the report details: ``config``'s (index in the dataset) or the first solved one."""
    ok = np.flatnonzero(res.success)
    if config is not None:
        hits = np.flatnonzero(np.asarray(res.config_index) == config)
        return int(hits[0]) if hits.size else None
    return int(ok[0]) if ok.size else None


def method_section(res) -> dict:
    """The method, its settings in words, what it fitted, how many configurations it identified, the ineid that
    wrote the results; the held-out RMS per axis of each fitted channel."""
    from ineid.identify.constrained_std import std_note
    from ineid.report.fitted import fitted_channels, held_out_error_name, held_out_rms, rms_lines

    m = res.meta
    found = held_out_rms(res)
    held = None if found is None else {"frames": found[1], "lines": rms_lines(m, res.axes, res.units, found[0])}
    ok = int(res.success.sum())
    statuses = sorted({str(s) for s in res.status})
    return {
        "method": res.settings.method,
        "settings": flatten(res.settings.to_dict(), none="not set (the default)"),
        "solved": f"{ok} of {res.n} configurations identified in {fmt(m.get('total_seconds'), 3)} s",
        "statuses": ", ".join(statuses[:8]) + (", ..." if len(statuses) > 8 else ""),
        "frames": f"{res.n_frames_fit} frames fitted, {res.n_frames_validation} validated per configuration",
        "written_by": f"ineid {m['ineid_version']}" if m.get("ineid_version") else "an unrecorded ineid",
        "fitted": fitted_channels(m),
        "std": std_note(res.settings.method, m.get("std")),
        "error_name": held_out_error_name(m),
        "held_out": held,
    }


def robot_section(res, model) -> dict:
    from ineid.robots.gravity import gravity_words

    m = res.meta
    out = {
        "name": m["robot"],
        "source": m["source"],
        "unknown_links": list(m["unknown_links"]),
        "gravity": gravity_words(m["gravity"]),
        "locked": [f"{k} = {fmt(v)} rad" for k, v in sorted((m.get("locked_joints") or {}).items())],
        "joints": None,
        "known_links": None,
    }
    if model is not None:
        out["joints"] = list(model.joint_names)
        out["known_links"] = list(model.known_links)
    return out


def identifiability_section(res, cost=None) -> dict:
    """Rank, base parameters by name, null directions, standard parameters the data determine alone; the
    offsets' cost (:class:`ineid.identify.identifiability.BiasCost`) when given; the extra parameters."""
    base = res.base
    out = {
        "rank": base.rank,
        "n_params": base.n_params,
        "names": list(base.names),
        "null": base.null_directions(),
        "identifiable": [p for p, ok in zip(base.param_names, base.identifiable, strict=True) if ok],
        "extra": list(base.param_names[base.n_link_params :]),
        "cost": None,
    }
    if cost is not None:
        out["cost"] = {
            "rank": f"{cost.base.rank} without offsets, {cost.base_bias.rank} with",
            "lost": list(cost.lost),
            "null": list(cost.new_null_directions),
            "condition": f"{fmt(cost.condition[0])} without offsets, {fmt(cost.condition[1])} with",
            "inflation": [(n, fmt(x, 3)) for n, x in zip(cost.base_bias.names, cost.std_inflation, strict=True)],
        }
    return out


def estimates_section(res, i: int) -> dict:
    """Standard and base parameters of row ``i``: CAD (the prior), estimate, std, truth where known."""
    from ineid.report.roundoff import base_scale, is_round_off, parameter_scale, shown_value

    prior = res.theta_prior[i] if res.theta_prior.ndim == 2 else res.theta_prior
    truth = None if res.theta_true is None else res.theta_true[i]
    rows = []
    for k, name in enumerate(res.param_names):
        std, scale = res.theta_std[i, k], parameter_scale(res.base, k)
        rows.append(
            {
                "name": name,
                "cad": fmt(prior[k]),
                "estimate": shown_value(res.theta_hat[i, k], scale, std, 4),
                "std": shown_value(std, scale, digits=3) if np.isfinite(std) else "- (prior)",
                "identifiable": bool(res.base.identifiable[k]),
                "truth": None if truth is None else fmt(truth[k]),
            }
        )
    base_truth = None if res.theta_true is None else res.base_true[i]
    base_rows = []
    for k, name in enumerate(res.base.names):
        est, std, scale = res.base_hat[i, k], res.base_std[i, k], base_scale(res.base, k)
        zero = is_round_off(est, scale, std)
        rel = abs(std / est) if est != 0 and np.isfinite(std) and not zero else math.nan
        base_rows.append(
            {
                "name": name,
                "estimate": shown_value(est, scale, std, 4),
                "std": shown_value(std, scale, digits=3),
                "rel": "-" if math.isnan(rel) else f"{100 * rel:.2g} %",
                "truth": None if base_truth is None else fmt(base_truth[k]),
            }
        )
    offsets = None
    if res.bias_hat is not None:
        offsets = [
            (a, u, fmt(res.bias_hat[i, k]), fmt(res.bias_std[i, k], 3))
            for k, (a, u) in enumerate(zip(res.axes, res.units, strict=True))
        ]
    return {"rows": rows, "base": base_rows, "truth": truth is not None, "offsets": offsets}


def validity_section(res, i: int) -> list[dict]:
    """Per unknown link, of the estimate and of the CAD values: mass, centre of mass, principal moments about
    it, the pseudo-inertia's eigenvalues, the triangle inequality, what makes it non-physical."""
    prior = res.theta_prior[i] if res.theta_prior.ndim == 2 else res.theta_prior
    out = []
    for k, link in enumerate(res.meta["unknown_links"]):
        for which, theta in (
            ("estimate", res.theta_hat[i, 10 * k : 10 * k + 10]),
            ("CAD", prior[10 * k : 10 * k + 10]),
        ):
            row = {
                "link": link,
                "which": which,
                "mass": fmt(theta[0]),
                "com": "-",
                "moments": "-",
                "pseudo": "-",
                "triangle": "-",
                "problems": physical_violations(theta),
            }
            if np.all(np.isfinite(theta)):
                row["pseudo"] = ", ".join(fmt(e, 3) for e in np.linalg.eigvalsh(pseudo_inertia(theta)))
                if theta[0] > 0:
                    _, com, ic = inertial_from_theta(theta)
                    moments = np.linalg.eigvalsh(0.5 * (ic + ic.T))
                    row["com"] = ", ".join(fmt(c) for c in com)
                    row["moments"] = ", ".join(fmt(e, 3) for e in moments)
                    row["triangle"] = "holds" if moments[0] + moments[1] >= moments[2] else "violated"
            out.append(row)
    return out


def payload_section(res, i: int) -> list[dict] | None:
    """Per payload link: mass, centre of mass and inertia about it (link frame, SI), with std."""
    if not res.payload:
        return None
    from ineid.identify.payload import INERTIA_NAMES

    out = []
    for link, q in res.payload.items():
        rows = [("mass", "kg", fmt(q["mass"][i]), fmt(q["mass_std"][i], 3))]
        rows += [(f"com {a}", "m", fmt(q["com"][i, k]), fmt(q["com_std"][i, k], 3)) for k, a in enumerate("xyz")]
        rows += [
            (f"{n} about com", "kg*m^2", fmt(q["inertia"][i, k]), fmt(q["inertia_std"][i, k], 3))
            for k, n in enumerate(INERTIA_NAMES)
        ]
        out.append({"link": link, "rows": rows})
    return out


def data_section(res, ds, validate_ds=None) -> dict:
    """The dataset(s): paths, fingerprints (recorded and found), sizes, rate, origin, noise, channels."""
    m = res.meta
    out = {
        "path": m.get("dataset_path") or "-",
        "fingerprint": m.get("dataset_fingerprint") or "-",
        "recordings": [
            (r.get("path") or "in memory", r.get("fingerprint") or "-", r.get("n_frames"))
            for r in m.get("recordings") or []
        ],
        "validation": None,
        "loaded": None,
        "channels": [],
        "sensor": None,
    }
    v = m.get("validation")
    if v:
        out["validation"] = {
            "path": v.get("path") or "in memory",
            "fingerprint": v.get("fingerprint") or "-",
            "frames": v.get("n_frames"),
            "offsets": word(v.get("offsets")),
        }
    for rec in m.get("channels") or []:
        rest = {k: val for k, val in rec.items() if k not in ("kind", "key")}
        out["channels"].append(
            {
                "key": rec.get("key"),
                "kind": rec.get("kind"),
                "record": "; ".join(f"{k}: {v}" for k, v in flatten(rest)) or "-",
            }
        )
    if m.get("sensor"):
        out["sensor"] = _pose_words(m["sensor"])
    if ds is not None:
        meta = ds.meta
        loaded = {
            "path": str(ds.path) if ds.path is not None else "in memory",
            "fingerprint": ds.fingerprint(),
            "source": meta.source,
            "configs": ds.n_configs,
            "frames": ds.n_frames,
            "rate": "-",
            "span": "-",
            "written_by": meta.ineid_version or "-",
            "sampling": flatten(meta.sampling or {}),
            "noise": flatten(meta.noise) if meta.noise else [],
            "origin": flatten(meta.origin or {}),
        }
        if ds.time is not None and ds.n_frames > 1:
            t = np.asarray(ds.time[0], dtype=np.float64)
            loaded["rate"] = f"{fmt(1 / np.median(np.diff(t)), 5)} Hz"
            loaded["span"] = f"{fmt(t[-1] - t[0], 5)} s"
        out["loaded"] = loaded
    if validate_ds is not None and out["validation"] is not None:
        out["validation"]["found"] = validate_ds.fingerprint()
    return out


def _pose_words(record) -> str:
    """A sensor pose record in words (``xyz=(0, 0, 0.1) m, rpy=(0, 0, 0) rad (URDF frame 'ft')``); a record that
    does not read as a pose: its fields."""
    from ineid.channels.pose import SensorPose

    try:
        return SensorPose.from_dict(record).describe()
    except (IneidError, KeyError, TypeError, ValueError):
        return "; ".join(f"{k}: {v}" for k, v in flatten(record))


def excitation_section(res, ds, model, i: int) -> dict | None:
    """How well the fitted frames of row ``i`` excite the base parameters (condition number of the scaled
    regressor, rank), and, for data sampled on an ``ineid excite`` trajectory, its record and, where its
    design JSON lies beside the dataset, the design's condition number and expected std."""
    if ds is None or model is None:
        return None
    from ineid.channels import ChannelSet
    from ineid.identify.identifiability import analyze_frames

    records = res.meta.get("channels")
    channels = ds.meta.channels if records is None else ChannelSet.from_list(records, "the results' channels")
    n = min(res.n_frames_fit, ds.n_frames)
    bias = res.settings.bias == "estimate"
    fa = analyze_frames(model, ds.q[i, :n], ds.qd[i, :n], ds.qdd[i, :n], bias=bias, channels=channels)
    out = {
        "condition": fmt(fa.condition_number),
        "rank": f"{fa.rank} of {fa.structural_rank}",
        "min_frames": fa.min_frames,
        "problem": fa.problem(),
        "trajectory": None,
        "design": None,
    }
    frames = (ds.meta.sampling or {}).get("frames") or {}
    if frames.get("mode") == "trajectory":
        tr = frames.get("trajectory") or {}
        out["trajectory"] = flatten(tr)
        out["design"] = _design(res, ds, tr.get("source"))
    return out


def _design(res, ds, source) -> dict | None:
    """The ``design`` record of ``ineid excite``'s JSON beside the dataset (``<trajectory>.json``), if found."""
    if not source or ds.path is None:
        return None
    path = Path(ds.path).parent / Path(str(source)).with_suffix(".json").name
    try:
        design = read_json(path, "the design record")["design"]
        names, std = design["base_parameters"], design["optimized"]["std"]
    except (IneidError, OSError, ValueError, KeyError, TypeError):  # a FIFO there is not waited on
        return None
    std_of = dict(zip(names, std, strict=False))
    i = solved_index(res, None)
    rows = [
        (n, fmt(std_of.get(n), 3), fmt(res.base_std[i, k], 3) if i is not None else "-")
        for k, n in enumerate(res.base.names)
    ]
    return {
        "path": str(path),
        "criterion": design.get("criterion"),
        "condition": fmt(design["optimized"].get("condition_number")),
        "random": fmt((design.get("random_fourier") or {}).get("condition_number")),
        "noise": ", ".join(fmt(s) for s in design.get("wrench_noise_std") or []),
        "rows": rows,
    }


def params_order() -> str:
    return ", ".join(PARAM_NAMES)
