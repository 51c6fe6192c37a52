"""Plausibility checks on the data alone: unit and sign mistakes that no error catches.

A recording in degrees, or with its wrench's sign flipped, imports and solves without an
error and gives garbage. These checks look at what the arrays hold against what the URDF
says and return :class:`Finding` s: one line each, naming the likely mistake and the
option that fixes it. They never raise and never stop a run; ``ineid data import`` and
``ineid solve`` print them as warnings. The checks that need a fit (total mass, held-out
error, the fitted static force) are in :mod:`ineid.identify.plausibility`.

Thresholds (documented in ``docs/recordings.md``, "Plausibility checks"):

* angles in degrees: some revolute joint with limits has at least :data:`DEGREE_SHARE`
  of its samples beyond ``+-(2 pi + 1)`` rad and more than 1 rad outside its limits,
  while every limited revolute joint's angles divided by 57.3 stay within its limits
  (widened by 5 % of the range + 0.05 rad) for at least 99 % of the samples;
* static wrench against gravity: the mean force over all frames, in the base frame, has a
  component against gravity larger than half the moving links' URDF weight and points
  more than 120 degrees away from gravity;
* time stamps in another unit: the median step gives a rate outside :data:`RATE_RANGE`,
  and another unit of :data:`ineid.data.recordings.streams.TIME_UNITS` gives one inside it with the
  joints' speeds (99th percentile) below :data:`MAX_JOINT_SPEED` (the unit whose rate is
  nearest 1 kHz is named);
* gravity in another unit: ``|g|`` more than :data:`GRAVITY_FACTOR` times above or below
  Earth's, or within :data:`G_UNIT_TOLERANCE` of 1 (standard gravities); zero is allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.channels import BaseWrench
from ineid.data.recordings.streams import SI_UNITS, TIME_UNITS, in_si_units
from ineid.data.recordings.timing import timing_warnings
from ineid.errors import DatasetError

DEGREE_SHARE = 0.05
"""Share of a joint's samples beyond ``2 pi + 1`` rad (and its limits) that makes degrees likely."""
DEGREE_FIT_SHARE = 0.99
"""Share of every limited joint's samples that must fit its limits once read as degrees."""
STATIC_AGAINST = 0.5
"""The mean force's component against gravity, as a share of the arm's weight, that warns."""
STATIC_COS = -0.5
"""... and the cosine of its angle to gravity must be below this (more than 120 degrees off)."""
RATE_RANGE = (10.0, 1e5)
"""Hz, the sampling rates a robot recording has: below 10 Hz a robot's motion (a few Hz) leaves no usable
accelerations (the default cut-off alone, at least 1 Hz, needs 2.2 Hz), and no F/T sensor or encoder streams
faster than some tens of kHz."""
MAX_JOINT_SPEED = 50.0
"""rad/s (m/s): another time unit is named only where the joints' speeds under it stay below this (the fastest
arms' joints reach about 10 rad/s): a 5 Hz recording of a moving arm is not milliseconds."""
TYPICAL_RATE = 1e3
"""Hz: of two time units that both fit, the one whose rate is nearer this (in decades) is named."""
STANDARD_GRAVITY = 9.80665
"""m/s^2, Earth's standard gravity."""
GRAVITY_FACTOR = 10.0
"""A gravity more than this factor above or below Earth's warns: the Moon's (0.17x) and Jupiter's (2.5x) are
within it, a unit mistake is not (cm/s^2: 100x, mm/s^2: 1000x, km/s^2: 0.001x)."""
G_UNIT_TOLERANCE = 0.01
"""m/s^2: a gravity of 1 within this is taken as given in standard gravities (no body of the solar system
has 1 m/s^2 at its surface)."""
_GRAVITY_UNITS = {1e2: "cm/s^2", 1e3: "mm/s^2", 1e-3: "km/s^2"}
_TIME_NAMES = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}


@dataclass(frozen=True)
class Finding:
    """One plausibility warning: a stable ``code`` and a one-line ``message`` that names the fix.

    Codes: ``gravity_unit``, ``time_unit``, ``timing_jitter``, ``timing_repeats``, ``timing_gaps``,
    ``angles_in_degrees``, ``angles_in_radians``, ``wrench_unit``,
    ``static_wrench_against_gravity``, ``total_mass_negative``, ``total_mass_scale``, ``held_out_error``;
    ``unmodelled_offsets``, ``residual_above_noise`` (:mod:`ineid.identify.noise_figures`);
    ``non_physical``, ``iteration_cap`` (:mod:`ineid.identify.physical_checks`).
    """

    code: str
    message: str

    def to_dict(self) -> dict:
        return {"code": self.code, "message": self.message}

    @classmethod
    def from_dict(cls, d) -> Finding:
        return cls(str(d["code"]), str(d["message"]))


def moving_mass(model) -> float:
    """The URDF's mass of every moving link (kg): what the sensor weighs besides the root body."""
    return float(np.sum(np.asarray(model.theta_cad, dtype=np.float64)[0::10]))


def check_angle_units(model, q) -> Finding | None:
    """Joint angles that look like degrees (see the module docstring for the rule).

    Args:
        model: the :class:`ineid.RobotModel` (joint types and limits).
        q: (..., n_dof) joint positions as stored (rad; m for prismatic joints).

    Returns:
        A :class:`Finding` (``angles_in_degrees``) naming the joint that shows it most, or None.
    """
    joints = model.chain.joints
    rev = [i for i, j in enumerate(joints) if j.type == "revolute" and not j.continuous]
    q = np.asarray(q, dtype=np.float64)
    if not rev or q.size == 0:
        return None
    q = q.reshape(-1, q.shape[-1])[:, rev]
    lo, hi = model.q_lower[rev], model.q_upper[rev]
    with np.errstate(invalid="ignore"):
        far = (np.abs(q) > 2 * math.pi + 1) & ((q < lo - 1) | (q > hi + 1))
        share = far.mean(axis=0)
        if share.max() < DEGREE_SHARE:
            return None
        r = np.radians(q)
        margin = 0.05 * (hi - lo) + 0.05
        fits = ((r >= lo - margin) & (r <= hi + margin)).mean(axis=0)
    if fits.min() < DEGREE_FIT_SHARE:
        return None
    k = int(np.argmax(share))
    name = joints[rev[k]].name
    worst = float(q[:, k][np.argmax(np.abs(q[:, k]))])
    return Finding(
        "angles_in_degrees",
        f"the joint angles look like degrees: {name} reaches {worst:.4g} rad ({100 * share[k]:.0f} % of its "
        f"samples beyond 2 pi + 1 and outside its limits {lo[k]:.3g}..{hi[k]:.3g} rad), while every angle / 57.3 "
        "fits the limits: import the recording with data import --angle-unit deg",
    )


def mean_force_in_base(wrench, sensor_pose=None) -> np.ndarray:
    """The mean force (3,) over every frame of ``wrench`` (..., 6), turned into the base frame (N).

    Args:
        wrench: the dataset's wrench, in the sensor frame when ``sensor_pose`` is given.
        sensor_pose: the :class:`ineid.channels.SensorPose` of the wrench, or None (base frame).
            A force is a free vector: ``F_base = base_R_sensor F_sensor`` (the sensor's offset
            from the base origin changes only the moment).
    """
    w = np.asarray(wrench, dtype=np.float64).reshape(-1, 6)
    f = w[:, :3].mean(axis=0) if len(w) else np.zeros(3)
    return f if sensor_pose is None else np.asarray(sensor_pose.base_R_sensor) @ f


def check_static_force(model, force_base, what: str = "the mean force over the frames") -> Finding | None:
    """A static force that points against gravity (see the module docstring for the rule).

    The load of a resting arm on its fixture is its weight, along gravity; motion with no net
    drift averages out, and sensor offsets are small next to the weight. A mean force that
    points up means the sensor reports the force on the robot, or the sensor frame is turned.

    Args:
        model: the :class:`ineid.RobotModel` (gravity, URDF masses).
        force_base: (3,) N, base frame.
        what: how the message names the force.

    Returns:
        A :class:`Finding` (``static_wrench_against_gravity``) or None; None without gravity.
    """
    g = np.asarray(model.gravity, dtype=np.float64)
    f = np.asarray(force_base, dtype=np.float64)
    gn, fn = float(np.linalg.norm(g)), float(np.linalg.norm(f))
    if gn == 0 or not np.all(np.isfinite(f)) or fn == 0:
        return None
    weight = moving_mass(model) * gn
    along = float(f @ g) / gn
    if not (along < -STATIC_AGAINST * weight and along < STATIC_COS * fn):
        return None
    return Finding(
        "static_wrench_against_gravity",
        f"{what} points against gravity ({-along:.4g} N up, {math.degrees(math.acos(max(-1.0, along / fn))):.0f} "
        f"degrees from gravity; the arm weighs {weight:.4g} N): the sensor reports the force on the robot "
        "(data import --flip-wrench) or its frame is turned (data import --sensor-pose)",
    )


def power_of_ten(factor: float) -> float | None:
    """The power of ten within 2x of ``factor`` (other than 1), or None."""
    if not (factor > 0 and math.isfinite(factor)):
        return None
    p = round(math.log10(factor))
    return 10.0**p if p != 0 and abs(math.log10(factor) - p) < math.log10(2) else None


def times(ratio: float) -> str:
    """``1330x``, ``5.2x``, ``0.0012x``: a ratio as a reader says it."""
    return f"{ratio:.0f}x" if ratio >= 100 else f"{ratio:.2g}x"


def _hz(rate: float) -> str:
    for scale, unit in ((1e6, "MHz"), (1e3, "kHz"), (1.0, "Hz")):
        if rate >= scale * (1 - 1e-9):  # time stamps x 1e9 round a 1 kHz rate down
            return f"{rate / scale:.3g} {unit}"
    return f"{rate:.3g} Hz"


def check_time_unit(time, q, time_unit: str = "s", rate: float | None = None) -> Finding | None:
    """Time stamps that look like another unit than ``time_unit`` (see the module docstring for the rule).

    Args:
        time: (..., n_frames) the time stamps, s (after ``time_unit``'s conversion).
        q: (..., n_frames, n_dof) the joint positions at them (rad; m).
        time_unit: the unit the time column was read in (``data import --time-unit``).
        rate: Hz, the joints' own sampling rate where the frames were resampled (``--rate``); None: the
            frames' (the median step of ``time``).

    Returns:
        A :class:`Finding` (``time_unit``) naming the likely unit and ``--time-unit``, or None.
    """
    t, q = np.asarray(time, dtype=np.float64), np.asarray(q, dtype=np.float64)
    if t.ndim == 0 or t.shape[-1] < 2 or q.shape[:-1] != t.shape:
        return None
    dt = np.diff(t, axis=-1).reshape(-1)
    dq = np.abs(np.diff(q, axis=-2)).reshape(len(dt), -1)
    ok = np.isfinite(dt) & (dt > 0)
    if not ok.any():
        return None
    rate = 1.0 / float(np.median(dt[ok])) if rate is None else float(rate)
    step = 1.0 / rate
    lo, hi = RATE_RANGE
    if lo <= rate <= hi:
        return None
    with np.errstate(invalid="ignore"):
        v = dq[ok] / dt[ok, None]
    # a non-finite angle (an import that failed on it) names no unit
    speed = float(np.max(np.percentile(np.where(np.isfinite(v), v, np.inf), 99, axis=0))) if v.shape[1] else 0.0
    fits = []
    for unit, seconds in TIME_UNITS.items():
        k = seconds / TIME_UNITS[time_unit]  # true seconds per stored second, were the column in `unit`
        if unit != time_unit and lo <= rate / k <= hi and speed / k <= MAX_JOINT_SPEED:
            fits.append((abs(math.log10(rate / k / TYPICAL_RATE)), unit, k))
    if not fits:
        return None
    _, unit, k = min(fits)
    given = f" after --time-unit {time_unit}" if time_unit != "s" else ""
    return Finding(
        "time_unit",
        f"the time stamps are {step:.3g} s apart{given} ({_hz(rate)}), {'slower' if rate < lo else 'faster'} than a "
        f"robot recording's {_hz(lo)}..{_hz(hi)}: the time column looks like {_TIME_NAMES[unit]} ({_hz(rate / k)}, "
        f"joints up to {speed / k:.2g} rad/s); import the recording with data import --time-unit {unit}",
    )


def with_time_unit_hint(error: DatasetError, streams, model, settings) -> DatasetError:
    """``error`` of an import, led by :func:`check_time_unit`'s finding on the joints' time stamps when there
    is one (a time column in ms fails the cut-off rules first; their message alone names the wrong fix).

    Args:
        error: what :func:`ineid.data.recordings.pipeline.recording_dataset` raised.
        streams: the :class:`ineid.data.recordings.streams.Streams` it was given.
        model: the :class:`ineid.RobotModel`.
        settings: its :class:`ineid.data.recordings.pipeline.ImportSettings`.
    """
    si = in_si_units(streams, model, **{k: getattr(settings, k) for k in SI_UNITS})
    found = check_time_unit(si.joint_time, si.q, settings.time_unit)
    return error if found is None else DatasetError(f"{found.message} (the import stopped at: {error})")


def check_recording_time(ds) -> Finding | None:
    """:func:`check_time_unit` on a recording's frames, at the joints' own rate; None for synthetic data (its
    frames sample a trajectory, at no clock's rate)."""
    origin = ds.meta.origin or {}
    if ds.meta.source != "recording" or ds.time is None:
        return None
    return check_time_unit(ds.time, ds.q, origin.get("time_unit", "s"), (origin.get("import") or {}).get("joint_rate"))


def check_gravity(gravity, what: str = "--gravity", fix: str = "--gravity") -> Finding | None:
    """A gravity vector in another unit than m/s^2 (see the module docstring for the rule).

    Args:
        gravity: (3,) as given.
        what: how the message names it.
        fix: the option the message suggests (with the vector in m/s^2 after it).

    Returns:
        A :class:`Finding` (``gravity_unit``) or None; None for zero gravity.
    """
    g = np.asarray(gravity, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(g))
    if norm == 0 or not math.isfinite(norm):
        return None
    ratio = norm / STANDARD_GRAVITY
    if abs(norm - 1) <= G_UNIT_TOLERANCE:
        factor, unit = STANDARD_GRAVITY, "standard gravities (g)"
    elif 1 / GRAVITY_FACTOR <= ratio <= GRAVITY_FACTOR:
        return None
    else:
        p = power_of_ten(ratio)
        factor, unit = (1 / p, _GRAVITY_UNITS[p]) if p in _GRAVITY_UNITS else (STANDARD_GRAVITY / norm, None)
    shown = " ".join(f"{v:g}" for v in g)
    fixed = " ".join(f"{v * factor:.4g}" for v in g)
    return Finding(
        "gravity_unit",
        f"{what} {shown} has |g| = {norm:.4g}, {times(ratio)} Earth's {STANDARD_GRAVITY:.4g} m/s^2"
        + (f": it looks like {unit}" if unit else "")
        + f"; gravity is in m/s^2: {fix} {fixed}"
        + ("" if unit else " for Earth's"),
    )


def check_dataset(ds, model) -> list[Finding]:
    """The data-only checks on a dataset: time stamps in another unit, the import's timing warnings (jitter,
    held rows, gaps: :mod:`ineid.data.recordings.timing`), angles in degrees, the raw static force's direction
    (for each base-wrench channel, in the frame its sensor pose names).

    Args:
        ds: a :class:`ineid.data.Dataset`.
        model: its :class:`ineid.RobotModel`.
    """
    found = [check_recording_time(ds), check_angle_units(model, ds.q)]
    found += [Finding(code, message) for code, message in timing_warnings(ds.meta.origin)]
    wrenches = [c for c in ds.meta.channels if isinstance(c, BaseWrench)]
    for c in wrenches:
        what = "the mean force over the frames" + (f" of {c.key}" if len(wrenches) > 1 else "")
        found.append(check_static_force(model, mean_force_in_base(ds.measurements[c.key], c.sensor), what))
    return [f for f in found if f is not None]
