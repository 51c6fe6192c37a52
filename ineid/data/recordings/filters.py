"""The filters recordings were imported with, compared before they are fitted or validated together.

A recording imported from its joint angles went through a zero-phase low-pass (its angles, joint torques and
wrench alike; a recording with measured ``qd``, ``qdd`` only when a cut-off was given), recorded in the
dataset's origin (``origin["import"]``: ``cutoff``, ``filter``, the wrench ``delay`` and whether it was
estimated). Recordings fitted together (``ineid solve A.h5 B.h5``) and the one they are validated on
(``--validate C.h5``) should share that filter: rows low-passed at different cut-offs carry different
distortion and noise, and a validation recording filtered otherwise measures the filters as much as the
parameters. :func:`check_filters` compares them: the cut-off (relative ``CUTOFF_RTOL``), the filter (kind and
order) and, where each recording's delay was estimated on its own, the delay (``DELAY_ATOL``); datasets that
are not filtered recordings (synthetic datasets, recordings with measured ``qd``, ``qdd`` and no cut-off)
take no part. ``ineid data import A.csv B.csv C.csv --out FOLDER`` imports an experiment's recordings with one
filter (:mod:`ineid.data.recordings.experiment`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ineid.data.recordings import signals
from ineid.data.recordings.plausibility import Finding
from ineid.errors import DatasetError

CUTOFF_RTOL = 1e-6
"""Cut-offs that differ by less than this (relative) are the same."""
DELAY_ATOL = 1e-6
"""s: estimated delays that differ by less than this are the same."""
DEFAULT_FILTER = f"zero-phase Butterworth, order {signals.FILTER_ORDER}"
"""The filter of a record that does not name one (the import's only filter)."""


@dataclass(frozen=True)
class ImportFilter:
    """The filter a recording's frames went through.

    Attributes:
        label: the file (or what names it in messages).
        cutoff: Hz.
        kind: the filter, in words (:data:`DEFAULT_FILTER`).
        delay: s, the wrench delay when it was estimated for this recording alone (None otherwise).
    """

    label: str
    cutoff: float
    kind: str
    delay: float | None

    def describe(self) -> str:
        text = f"{self.label} {self.cutoff:.4g} Hz"
        return text + ("" if self.delay is None else f" (delay {1e3 * self.delay:.4g} ms, estimated)")


def import_filter(ds, label: str) -> ImportFilter | None:
    """The filter of dataset ``ds`` (named ``label``), None when it is not a filtered recording."""
    origin = getattr(ds.meta, "origin", None) or {}
    record = origin.get("import") if isinstance(origin, dict) else None
    if ds.meta.source != "recording" or not isinstance(record, dict) or record.get("cutoff") is None:
        return None
    delay = record.get("delay") if record.get("delay_estimated") else None
    return ImportFilter(
        label,
        float(record["cutoff"]),
        str(record.get("filter") or DEFAULT_FILTER),
        None if delay is None else float(delay),
    )


def mixed_filters(labelled: Sequence[tuple[str, object]]) -> str | None:
    """What differs between the filters of the datasets ``labelled`` (``(label, dataset)`` pairs), in words; None
    when the filtered recordings among them share one filter (or fewer than two are filtered)."""
    filters = [f for label, ds in labelled if (f := import_filter(ds, label)) is not None]
    if len(filters) < 2:
        return None
    first = filters[0]
    what = []
    if any(abs(f.cutoff - first.cutoff) > CUTOFF_RTOL * first.cutoff for f in filters):
        what.append("cut-offs")
    if any(f.kind != first.kind for f in filters):
        what.append("filters (" + ", ".join(sorted({f.kind for f in filters})) + ")")
    delays = [f.delay for f in filters if f.delay is not None]
    if delays and max(delays) - min(delays) > DELAY_ATOL:
        what.append("wrench delays, each estimated on its own")
    if not what:
        return None
    return f"different {' and '.join(what)}: " + ", ".join(f.describe() for f in filters)


def check_filters(labelled: Sequence[tuple[str, object]], allow: bool = False) -> Finding | None:
    """Refuse, or with ``allow`` warn about, datasets fitted or validated together that were imported with
    different filters (:func:`mixed_filters`).

    Args:
        labelled: ``(label, dataset)`` of every dataset fitted together and of the validation recording.
        allow: fit them anyway (``ineid solve --mixed-filters``).

    Returns:
        The warning (code ``mixed_filters``) when they differ and ``allow``; None when they do not.

    Raises:
        DatasetError: they differ, and not ``allow``.
    """
    differ = mixed_filters(labelled)
    if differ is None:
        return None
    if not allow:
        raise DatasetError(
            f"the recordings fitted and validated together were imported with {differ}; import them together "
            "(ineid data import A.csv B.csv ... --out FOLDER: one cut-off and delay for all) or each with the same "
            "--cutoff (and --delay), or pass --mixed-filters to fit them anyway"
        )
    return Finding(
        "mixed_filters", f"the recordings fitted and validated together were imported with {differ} (--mixed-filters)"
    )
