"""The paper's claims about its networks, judged on a study's rows (:mod:`ineid.studies.paper_networks`).

A *cell* is a setting without its seed (architecture, frames, Siamese, activation, scaler,
optimizer, loss, epochs, training size); its values are the error ``metric`` of its seeds.
Two cells are compared by their means, and the difference counts only when it exceeds the
seed-to-seed spread: ``|mean_a - mean_b| > max(range_a, range_b)`` (``range`` = largest
minus smallest over the seeds), each cell with at least two seeds; otherwise the
comparison is *within spread* or has *too few seeds*.

A claim "X is best" is judged in every *context* (cells that differ only in the factor in
question, X among them and at least one alternative): *not held* where an alternative is
better beyond the spread, *held* where every alternative is worse beyond it, else *not
decidable*. Over the contexts: not held if any context says so, held if all do, else not
decidable (including when no context exists).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

HELD, NOT_HELD, UNDECIDABLE = "held", "not held", "not decidable"
METRICS = {"test_standard_median": "standard parameters", "test_base_median": "base parameters"}
CELL = ("arch", "frames", "siamese", "activation", "scaler", "optimizer", "loss", "epochs", "n_train")
"""What makes a cell (a row's settings without its seed)."""

FACTOR_CLAIMS = (  # (factor, the paper's best, the paper's words)
    ("activation", "tanh", "the tanh activation function ... produced the most promising results"),
    ("scaler", "robust", "the robust scaler ... produced the most promising results"),
    ("optimizer", "sgd", "the SGD optimizer produced the most promising results"),
)
SIAMESE_CLAIM = (
    "the most promising result was produced by the Siamese network with eight hidden layers and a width factor of eight"
)
CLASSICAL_CLAIM = "the AI-based methods struggled to achieve the precision of classical numerical optimization"


@dataclass(frozen=True)
class Verdict:
    """One claim judged: its words (and the metric), held / not held / not decidable, and why."""

    claim: str
    verdict: str
    why: str


def _get(row, key):
    return row[key] if isinstance(row, dict) else getattr(row, key)


def cells(rows, metric: str = "test_standard_median") -> dict[tuple, list[float]]:
    """``{cell: [metric of each seed]}`` over the rows that finished (``status == "ok"``, a finite metric)."""
    out: dict[tuple, list[float]] = defaultdict(list)
    for r in rows:
        value = float(_get(r, metric))
        if _get(r, "status") == "ok" and np.isfinite(value):
            out[tuple(_get(r, k) for k in CELL)].append(value)
    return dict(out)


def compare(a: list[float], b: list[float]) -> str:
    """``"better"`` (a lower beyond the spread), ``"worse"``, ``"within spread"`` or ``"too few seeds"``."""
    if len(a) < 2 or len(b) < 2:
        return "too few seeds"
    spread = max(np.ptp(a), np.ptp(b))
    d = float(np.mean(b) - np.mean(a))
    return "better" if d > spread else "worse" if -d > spread else "within spread"


def _show(values: list[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.4g} (1 seed)"
    return f"{np.mean(values):.4g} +- {np.ptp(values) / 2:.2g} ({len(values)} seeds)"


def _context_name(key: dict) -> str:
    frames = "" if key.get("frames", 1) == 1 else (" Siamese K" if key.get("siamese") else " K") + str(key["frames"])
    parts = [
        f"{key['arch']}{frames}" if "arch" in key else None,
        *(str(key[k]) for k in ("activation", "scaler", "optimizer") if k in key),
        f"{key['epochs']} epochs",
        f"{key['n_train']} training configurations",
    ]
    return ", ".join(p for p in parts if p)


def _judge(claimed: list[float], others: dict[str, list[float]]) -> tuple[str, str]:
    """One context: the verdict and its reason (claimed cell against each alternative)."""
    results = {name: compare(claimed, v) for name, v in others.items()}
    details = "; ".join(f"{name} {_show(v)}: {results[name]}" for name, v in others.items())
    if any(r == "worse" for r in results.values()):
        return NOT_HELD, details
    if all(r == "better" for r in results.values()):
        return HELD, details
    return UNDECIDABLE, details


def _combine(claim: str, judged: list[tuple[str, str]], missing: str) -> Verdict:
    if not judged:
        return Verdict(claim, UNDECIDABLE, missing)
    verdicts = [v for v, _ in judged]
    verdict = NOT_HELD if NOT_HELD in verdicts else HELD if all(v == HELD for v in verdicts) else UNDECIDABLE
    counts = ", ".join(f"{verdicts.count(v)} {v}" for v in (HELD, NOT_HELD, UNDECIDABLE) if verdicts.count(v))
    return Verdict(claim, verdict, f"{len(judged)} context(s): {counts}. " + " | ".join(w for _, w in judged))


def factor_claim(table: dict[tuple, list[float]], factor: str, best: str, claim: str) -> Verdict:
    """``best`` is the best ``factor`` (activation, scaler or optimizer) where only that factor differs."""
    i = CELL.index(factor)
    groups: dict[tuple, dict[str, list[float]]] = defaultdict(dict)
    for cell, values in table.items():
        groups[cell[:i] + cell[i + 1 :]][cell[i]] = values
    judged = []
    for rest, by_value in sorted(groups.items(), key=str):
        if best not in by_value or len(by_value) < 2:
            continue
        verdict, details = _judge(by_value[best], {f"{v}": by_value[v] for v in by_value if v != best})
        context = dict(zip([k for k in CELL if k != factor], rest, strict=True))
        judged.append((verdict, f"{_context_name(context)}: {best} {_show(by_value[best])} against {details}"))
    return _combine(claim, judged, f"no cells that differ only in the {factor} with {best} and another among them")


def siamese_claim(table: dict[tuple, list[float]], arch: str = "net6", claim: str = SIAMESE_CLAIM) -> Verdict:
    """The Siamese ``arch`` network is the best of the networks trained with the same other settings."""
    net = slice(0, 3)  # arch, frames, Siamese
    groups: dict[tuple, dict[tuple, list[float]]] = defaultdict(dict)
    for cell, values in table.items():
        groups[cell[3:]][cell[net]] = values
    judged = []
    for rest, by_net in sorted(groups.items(), key=str):
        mine = [n for n in by_net if n[0] == arch and n[2]]
        if len(mine) != 1 or len(by_net) < 2:
            continue

        def label(n):
            return f"{n[0]}" + (f" Siamese K{n[1]}" if n[2] else f" K{n[1]}" if n[1] > 1 else "")

        verdict, details = _judge(by_net[mine[0]], {label(n): v for n, v in by_net.items() if n != mine[0]})
        context = dict(zip(CELL[3:], rest, strict=True))
        judged.append(
            (verdict, f"{_context_name(context)}: {label(mine[0])} {_show(by_net[mine[0]])} against {details}")
        )
    return _combine(claim, judged, f"no Siamese {arch} network beside other networks of the same settings")


def classical_claim(rows, metric: str = "test_standard_median", claim: str = CLASSICAL_CLAIM) -> Verdict:
    """Every network's test error is above linear least squares' on the same test configurations and frames."""
    linear = "linear_standard_median" if metric == "test_standard_median" else "linear_base_median"
    pairs = [
        (float(_get(r, metric)), float(_get(r, linear)), _get(r, "name"))
        for r in rows
        if _get(r, "status") == "ok" and np.isfinite(float(_get(r, metric)))
    ]
    pairs = [p for p in pairs if np.isfinite(p[1])]
    if not pairs:
        return Verdict(claim, UNDECIDABLE, "no finished trial with a least-squares comparison")
    best = min(pairs)
    beaten = [p for p in pairs if p[0] <= p[1]]
    if beaten:
        return Verdict(
            claim,
            NOT_HELD,
            f"{len(beaten)} of {len(pairs)} trials at or below least squares, e.g. "
            f"{beaten[0][2]} {beaten[0][0]:.3g} against {beaten[0][1]:.3g}",
        )
    ratio = min(p[0] / p[1] for p in pairs) if all(p[1] > 0 for p in pairs) else float("inf")
    return Verdict(
        claim,
        HELD,
        f"all {len(pairs)} trials above linear least squares; the best network "
        f"({best[2]}) {best[0]:.3g} against {best[1]:.3g}, at least {ratio:.3g} x",
    )


def check_claims(rows, metrics: tuple[str, ...] = tuple(METRICS)) -> list[Verdict]:
    """The paper's claims about its networks judged on study rows (:class:`ineid.studies.paper_networks.StudyRow`
    or dicts of their fields), on each metric (median relative test error of the standard / base parameters)."""
    out = []
    for metric in metrics:
        what = f" [{METRICS[metric]}]"
        table = cells(rows, metric)
        out += [factor_claim(table, factor, best, words + what) for factor, best, words in FACTOR_CLAIMS]
        out.append(siamese_claim(table, claim=SIAMESE_CLAIM + what))
        out.append(classical_claim(rows, metric, CLASSICAL_CLAIM + what))
    return out


def write_claims(verdicts: list[Verdict], path) -> None:
    """``claims.csv``: claim, verdict, why (atomically)."""
    import dataclasses
    from pathlib import Path

    from ineid._atomic import write_csv

    write_csv(Path(path), ["claim", "verdict", "why"], [dataclasses.asdict(v) for v in verdicts])
