"""What a fit used, in words: the channels fitted, the name of its held-out error, its held-out RMS per axis.

A results file records the channels it fitted (``meta["channels"]``: one record per channel, its
``kind`` and ``key``) and names the per-axis arrays' columns (``axes``, ``units``: one channel's axes
by their own names, several channels' as ``<key>.<axis>``). The summary of ``ineid solve``,
``ineid results info`` and the report say from these what was fitted (the base wrench, joint
torques, motor currents, a link's wrench) and print the held-out RMS of every axis in its unit, so
a torque-only fit is never reported as a wrench fit.
"""

from __future__ import annotations

import numpy as np

KIND_WORDS = {
    "wrench": "base wrench",
    "link_wrench": "wrench at a link",
    "joint_torque": "joint torques",
    "motor_current": "motor currents",
}
"""A channel kind in words; a kind not listed is shown with its underscores as spaces."""

WRENCH_RECORD = {"kind": "wrench", "key": "wrench"}
"""What a results file of ineid 0.1 fitted (it records no channels): the base wrench."""


def channel_records(meta) -> list[dict]:
    """The channels' records of a results ``meta`` (a file that records none: the base wrench's)."""
    records = [r for r in meta.get("channels") or () if isinstance(r, dict)]
    return records or [dict(WRENCH_RECORD)]


def channel_name(record: dict) -> str:
    """One channel in words: ``"joint torques 'tau'"``, ``"base wrench 'wrench'"``, ``"wrench at link
    'hand' 'wrench_hand'"``."""
    kind, key = str(record.get("kind")), str(record.get("key"))
    words = KIND_WORDS.get(kind, kind.replace("_", " "))
    if kind == "link_wrench" and record.get("link"):
        words = f"wrench at link '{record['link']}'"
    return f"{words} '{key}'"


def fitted_channels(meta) -> str:
    """The channels a results ``meta`` fitted, in words (``"joint torques 'tau' and base wrench 'wrench'"``)."""
    names = [channel_name(r) for r in channel_records(meta)]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def is_wrench_only(meta) -> bool:
    """The fit used the base wrench alone (the paper's setting)."""
    return [r.get("kind") for r in channel_records(meta)] == ["wrench"]


def axis_groups(meta, axes, units) -> list[tuple[str, list[int], list[str]]]:
    """``(channel in words, column indices, axis names without the key)`` per fitted channel, in order.

    ``axes`` and ``units``: the per-axis columns' names and units (``SolveResults.axes``, ``.units``).
    Columns no record claims (a file whose records and axes disagree) form a last group, ``"other axes"``.
    """
    records = channel_records(meta)
    if len(records) == 1:
        return [(channel_name(records[0]), list(range(len(axes))), list(axes))]
    groups, claimed = [], set()
    for r in records:
        prefix = f"{r.get('key')}."
        cols = [k for k, a in enumerate(axes) if a.startswith(prefix) and k not in claimed]
        claimed.update(cols)
        if cols:
            groups.append((channel_name(r), cols, [axes[k][len(prefix) :] for k in cols]))
    rest = [k for k in range(len(axes)) if k not in claimed]
    if rest:
        groups.append(("other axes", rest, [axes[k] for k in rest]))
    return groups


def rms_lines(meta, axes, units, rms) -> list[str]:
    """One line per fitted channel: its name, then each axis's RMS in the axis's unit.

    ``"joint torques 'tau' (N*m): shoulder_pitch 0.0158, elbow 0.0111"``; a channel whose axes
    differ in unit (the wrench: N and N*m) gives each value its unit. NaN is shown as ``-``.
    """
    lines = []
    for name, cols, names in axis_groups(meta, axes, units):
        own = {units[k] for k in cols}
        one = len(own) == 1
        values = ", ".join(
            f"{a} {_number(rms[k])}" + ("" if one or not np.isfinite(rms[k]) else f" {units[k]}")
            for a, k in zip(names, cols, strict=True)
        )
        lines.append(f"{name}{f' ({own.pop()})' if one else ''}: {values}")
    return lines


def held_out_rms(res) -> tuple[np.ndarray, str] | None:
    """``(rms (A,), what)``: the held-out RMS per axis of ``res`` (a :class:`ineid.identify.SolveResults`), the
    median over its identified configurations, and which frames it is of, in words; None when nothing was held
    out or identified."""
    ok = np.asarray(res.success, dtype=bool)
    if not res.n_frames_validation or not ok.any():
        return None
    import warnings

    rms = np.asarray(res.validation_rms, dtype=np.float64)[ok]
    with warnings.catch_warnings():  # an axis NaN in every configuration: NaN, shown as "-"
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(rms, axis=0)
    v = res.meta.get("validation")
    frames = (
        f"{res.n_frames_validation} frames of the validation recording"
        if v
        else f"{res.n_frames_validation} held-out frames"
    )
    n = int(ok.sum())
    return median, frames + ("" if n == 1 else f", median over {n} configurations")


def held_out_error_name(meta) -> str:
    """The held-out relative error's name: ``"relative wrench error ||w - Psi theta_hat|| / ||w||"`` for the base
    wrench alone, else ``"relative error of joint torques 'tau' ||y - y_hat|| / ||y||"``."""
    if is_wrench_only(meta):
        return "relative wrench error ||w - Psi theta_hat|| / ||w||"
    return f"relative error of {fitted_channels(meta)} ||y - y_hat|| / ||y||"


def _number(x) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.3g}"
