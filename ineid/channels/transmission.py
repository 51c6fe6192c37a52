"""Coupled transmissions: the matrix between motor and joint quantities, and the files it is read from.

A transmission couples the ``n`` motors to the ``n`` joints (an industrial wrist whose last motor drives
two joints, a differential, a gear)::

    qd_joint = C qd_motor,    tau_motor = C^T tau_joint    (the power tau_motor . qd_motor = tau_joint . qd_joint)

``C`` (joints x motors, square and invertible) is the *coupling*; a joint-torque or motor-current channel
with a coupling reads per motor (its axes are the motors, in the coupling's order), its regressor rows are
``C^T Y_tau`` and its friction, armature and offsets act on each motor's velocity ``C^-1 qd_joint``
(:mod:`ineid.channels.torque`). Identity coupling: the motors are the joints.

Files (:func:`read_coupling`, ``ineid solve --coupling FILE``):

* **JSON**: ``{"joints": [names], "motors": [names], "matrix": [[...], ...]}``, one row per joint, one
  column per motor (``qd_joint = C qd_motor``); joints left out are driven one-to-one by a motor of their name;
* **CSV**: a header ``joint,<motor>,<motor>,...``, then one row per joint: its name and its coefficients;
* **URDF** (``.urdf``, ``.xml``): the ros_control ``<transmission>`` elements.
  ``SimpleTransmission`` (``mechanicalReduction`` ``r``: ``q_joint = q_motor / r``) and
  ``DifferentialTransmission`` (``q_j1 = (q_a1 / r_a1 + q_a2 / r_a2) / (2 r_j1)``,
  ``q_j2 = (q_a1 / r_a1 - q_a2 / r_a2) / (2 r_j2)``, as ros_control's ``transmission_interface``);
  a joint with no transmission is driven one-to-one by a motor of its name. Mimic joints are not read
  (a joint that follows another is a locked or a separate joint of the model).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from ineid.errors import DatasetError


def check_coupling(matrix, motors, where: str = "coupling") -> tuple[tuple[tuple[float, ...], ...], tuple[str, ...]]:
    """``(matrix, motors)`` as hashable tuples, checked: square, finite, invertible, one distinct name per motor.

    Raises:
        DatasetError: one line naming ``where`` and what is wrong.
    """
    try:
        c = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: the coupling matrix must be rows of numbers, got {matrix!r}") from None
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.size == 0:
        raise DatasetError(f"{where}: the coupling matrix must be square (joints x motors), got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise DatasetError(f"{where}: the coupling matrix has non-finite entries")
    if np.linalg.matrix_rank(c) < c.shape[0]:
        raise DatasetError(f"{where}: the coupling matrix is singular (every motor must move the joints its own way)")
    motors = tuple(str(m) for m in motors)
    if len(motors) != c.shape[1] or len(set(motors)) != len(motors) or not all(motors):
        raise DatasetError(
            f"{where}: name each of the {c.shape[1]} motors once (got {', '.join(motors) or 'no names'})"
        )
    return tuple(tuple(float(v) for v in row) for row in c), motors


def _ordered(joint_names, rows: dict[str, dict[str, float]], motors: list[str], where: str):
    """The coupling over the model's joints from ``rows`` (joint -> motor -> coefficient): joints left out are
    driven one-to-one by a motor of their name."""
    unknown = sorted(set(rows) - set(joint_names))
    if unknown:
        raise DatasetError(f"{where}: joints {', '.join(unknown)} are not the model's ({', '.join(joint_names)})")
    motors = list(motors)
    for j in joint_names:
        if j not in rows:
            if j in motors:
                raise DatasetError(f"{where}: motor {j!r} has the name of a joint the file does not couple")
            motors.append(j)
            rows[j] = {j: 1.0}
    matrix = [[rows[j].get(m, 0.0) for m in motors] for j in joint_names]
    return check_coupling(matrix, motors, where)


def read_coupling(path, joint_names) -> tuple[tuple[tuple[float, ...], ...], tuple[str, ...]]:
    """``(C, motors)`` from a JSON, CSV or URDF file (module doc), over ``joint_names`` in their order.

    Raises:
        DatasetError: an unreadable file, an unknown joint, a singular or malformed matrix (one line).
    """
    path = Path(path)
    where = f"coupling file {path}"
    try:
        text = path.read_text()
    except OSError as e:
        raise DatasetError(f"{where}: cannot be read ({e.strerror or e})") from None
    suffix = path.suffix.lower()
    if suffix in (".urdf", ".xml"):
        rows, motors = _urdf_rows(text, where)
    elif suffix == ".csv":
        rows, motors = _csv_rows(text, where)
    elif suffix == ".json":
        rows, motors = _json_rows(text, where)
    else:
        raise DatasetError(f"{where}: give a .json, .csv or .urdf file (the format follows the suffix)")
    return _ordered(tuple(joint_names), rows, motors, where)


def _json_rows(text: str, where: str):
    try:
        d = json.loads(text)
        joints, motors, matrix = list(d["joints"]), list(d["motors"]), d["matrix"]
    except (ValueError, KeyError, TypeError):
        raise DatasetError(f"{where}: expected a JSON object with joints, motors and matrix (rows: joints)") from None
    if not isinstance(matrix, list) or len(matrix) != len(joints):
        raise DatasetError(f"{where}: the matrix needs one row per joint ({len(joints)})")
    rows = {}
    for j, row in zip(joints, matrix, strict=True):
        if not isinstance(row, list) or len(row) != len(motors):
            raise DatasetError(f"{where}: the row of joint {j!r} needs one number per motor ({len(motors)})")
        rows[str(j)] = dict(zip(map(str, motors), _numbers(row, where), strict=True))
    return rows, [str(m) for m in motors]


def _csv_rows(text: str, where: str):
    table = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
    if len(table) < 2 or len(table[0]) < 2:
        raise DatasetError(f"{where}: expected a header joint,<motor>,... and one row per joint")
    motors = [m.strip() for m in table[0][1:]]
    rows = {}
    for r in table[1:]:
        if len(r) != len(motors) + 1:
            raise DatasetError(f"{where}: the row of {r[0]!r} needs one number per motor ({len(motors)})")
        rows[r[0].strip()] = dict(zip(motors, _numbers(r[1:], where), strict=True))
    return rows, motors


def _numbers(values, where: str) -> list[float]:
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: coupling coefficients must be numbers, got {values!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise DatasetError(f"{where}: coupling coefficients must be finite, got {values!r}")
    return out


def _reduction(element, where: str) -> float:
    node = element.find("mechanicalReduction")
    if node is None:
        return 1.0
    (r,) = _numbers([node.text], where)
    if r == 0:
        raise DatasetError(f"{where}: a mechanicalReduction of 0")
    return r


def _urdf_rows(text: str, where: str):
    """``(rows, motors)`` of the ros_control ``<transmission>`` elements of a URDF (module doc)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise DatasetError(f"{where}: not XML ({e})") from None
    rows: dict[str, dict[str, float]] = {}
    motors: list[str] = []
    for t in root.iter("transmission"):
        kind = (t.findtext("type") or t.get("type") or "").rsplit("/", 1)[-1]
        joints, actuators = t.findall("joint"), t.findall("actuator")
        if kind == "SimpleTransmission" and len(joints) == 1 and len(actuators) == 1:
            r = _reduction(actuators[0], where) * _reduction(joints[0], where) * _reduction(t, where)
            a = actuators[0].get("name")
            rows[joints[0].get("name")] = {a: 1.0 / r}
            motors.append(a)
        elif kind == "DifferentialTransmission" and len(joints) == 2 and len(actuators) == 2:
            (a1, a2), (j1, j2) = (sorted(x, key=lambda e: e.findtext("role") or "") for x in (actuators, joints))
            ra1, ra2, rj1, rj2 = (_reduction(e, where) for e in (a1, a2, j1, j2))
            n1, n2 = a1.get("name"), a2.get("name")
            rows[j1.get("name")] = {n1: 1.0 / (2 * rj1 * ra1), n2: 1.0 / (2 * rj1 * ra2)}
            rows[j2.get("name")] = {n1: 1.0 / (2 * rj2 * ra1), n2: -1.0 / (2 * rj2 * ra2)}
            motors += [n1, n2]
        else:
            raise DatasetError(
                f"{where}: transmission {t.get('name')!r} of type {kind or 'none'!r}: ineid reads "
                "SimpleTransmission (one joint, one actuator) and DifferentialTransmission (two of each)"
            )
    if not rows:
        raise DatasetError(f"{where}: the URDF has no <transmission> element")
    return rows, motors
