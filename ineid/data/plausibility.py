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
  more than 120 degrees away from gravity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ineid.channels import BaseWrench

DEGREE_SHARE = 0.05
"""Share of a joint's samples beyond ``2 pi + 1`` rad (and its limits) that makes degrees likely."""
DEGREE_FIT_SHARE = 0.99
"""Share of every limited joint's samples that must fit its limits once read as degrees."""
STATIC_AGAINST = 0.5
"""The mean force's component against gravity, as a share of the arm's weight, that warns."""
STATIC_COS = -0.5
"""... and the cosine of its angle to gravity must be below this (more than 120 degrees off)."""


@dataclass(frozen=True)
class Finding:
    """One plausibility warning: a stable ``code`` and a one-line ``message`` that names the fix.

    Codes: ``angles_in_degrees``, ``static_wrench_against_gravity``, ``total_mass_negative``,
    ``total_mass_scale``, ``held_out_error``.
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


def check_dataset(ds, model) -> list[Finding]:
    """The data-only checks on a dataset: angles in degrees, the raw static force's direction
    (for each base-wrench channel, in the frame its sensor pose names).

    Args:
        ds: a :class:`ineid.data.Dataset`.
        model: its :class:`ineid.RobotModel`.
    """
    found = [check_angle_units(model, ds.q)]
    wrenches = [c for c in ds.meta.channels if isinstance(c, BaseWrench)]
    for c in wrenches:
        what = "the mean force over the frames" + (f" of {c.key}" if len(wrenches) > 1 else "")
        found.append(check_static_force(model, mean_force_in_base(ds.measurements[c.key], c.sensor), what))
    return [f for f in found if f is not None]
