"""Import a recording from a real arm (a CSV file) as a one-configuration dataset.

Columns (a header row is required; names are case-insensitive, any order, extra columns
are ignored; units SI):

    time                 s, strictly increasing
    q1 .. qn             joint positions, rad (m for prismatic joints), URDF chain order
    qd1 .. qn            joint velocities, rad/s
    qdd1 .. qn           joint accelerations, rad/s^2
    fx fy fz             force, N         } the wrench the robot exerts on the sensor,
    mx my mz             moment, N*m      } base frame, moment about the base origin

A sensor that reports the wrench the fixture exerts on the robot (the opposite sign)
is imported with ``flip_wrench=True``. The truth is unknown, so the file has no
``theta_unknown``; ``theta_known`` holds the model's CAD values of the known links.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid._atomic import atomic_output
from ineid.data.schema import Dataset, DatasetMeta
from ineid.errors import DatasetError

if TYPE_CHECKING:
    from ineid.robots import RobotModel

WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")


def csv_columns(n_dof: int) -> list[str]:
    """The required columns for an arm with ``n_dof`` joints, in the documented order."""
    return (
        ["time"]
        + [f"q{i}" for i in range(1, n_dof + 1)]
        + [f"qd{i}" for i in range(1, n_dof + 1)]
        + [f"qdd{i}" for i in range(1, n_dof + 1)]
        + list(WRENCH_COLUMNS)
    )


def read_recording_csv(path: str | Path, model: RobotModel, flip_wrench: bool = False) -> Dataset:
    """Read a recording CSV into a :class:`Dataset` of one configuration.

    Args:
        path: the CSV file (comma-separated; ``#`` lines are comments).
        model: the :class:`ineid.RobotModel` the arm is.
        flip_wrench: the sensor reports the wrench on the robot; negate it.

    Raises:
        DatasetError: a missing column, a joint count that does not match the model, a
            cell that is not a number, a non-finite value, time not increasing, fewer
            than one data row.
    """
    path = Path(path)
    n = model.n_dof
    try:
        with path.open(newline="") as fh:
            # (physical line number, cells); comment and blank lines skipped
            numbered = [
                (k, cells)
                for k, line in enumerate(fh, start=1)
                if line.strip() and not line.lstrip().startswith("#")
                for cells in csv.reader([line])
            ]
    except FileNotFoundError:
        raise DatasetError(f"{path} does not exist") from None
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DatasetError(f"{path}: cannot be read as CSV text ({e})") from None
    rows = [cells for _, cells in numbered]
    line_of = [k for k, _ in numbered]
    if not rows:
        raise DatasetError(f"{path}: the file is empty; expected a header row {','.join(csv_columns(n))}")
    header = [h.strip().lower() for h in rows[0]]
    dup = sorted({h for h in header if header.count(h) > 1 and h})
    if dup:
        raise DatasetError(f"{path}: column {dup[0]!r} appears more than once in the header")
    joint_index = [j[1] for h in header if (j := _joint_column(h)) is not None]
    if joint_index and (max(joint_index) != n or min(joint_index) < 1):
        found = max(joint_index)
        raise DatasetError(
            f"{path}: the columns are for {found} joint{'s' if found != 1 else ''} (up to q{found}), but "
            f"{model.name} has {n} ({', '.join(model.joint_names)}); the recording is for another arm "
            "or its columns are misnamed"
            if min(joint_index) >= 1
            else f"{path}: joint columns count from 1 (q1, qd1, qdd1), found index 0"
        )
    required = csv_columns(n)
    missing = [c for c in required if c not in header]
    if missing:
        raise DatasetError(
            f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
            f"a recording of {model.name} needs {','.join(required)}"
        )
    col = [header.index(c) for c in required]
    body = rows[1:]
    if not body:
        raise DatasetError(f"{path}: the header has no data rows below it")
    data = np.empty((len(body), len(required)))
    for i, row in enumerate(body):
        line = line_of[i + 1]
        if len(row) != len(header):
            raise DatasetError(f"{path}: line {line} has {len(row)} cells, the header has {len(header)}")
        for k, c in enumerate(col):
            cell = row[c].strip()
            try:
                data[i, k] = float(cell)
            except ValueError:
                raise DatasetError(f"{path}: line {line}, column {required[k]!r}: {cell!r} is not a number") from None
    bad = ~np.isfinite(data)
    if bad.any():
        r, k = np.argwhere(bad)[0]
        raise DatasetError(
            f"{path}: line {line_of[r + 1]}, column {required[k]!r} is {data[r, k]}; values must be finite: "
            "drop or repair those rows"
        )
    t = data[:, 0]
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        r = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 2
        raise DatasetError(f"{path}: time does not increase at line {line_of[r]}; sort the rows or fix the time column")
    q, qd, qdd = data[:, 1 : 1 + n], data[:, 1 + n : 1 + 2 * n], data[:, 1 + 2 * n : 1 + 3 * n]
    wrench = data[:, 1 + 3 * n :]
    if flip_wrench:
        wrench = -wrench
    meta = DatasetMeta.for_model(
        model,
        source="recording",
        origin={"csv": path.name, "rows": int(len(body)), "flip_wrench": bool(flip_wrench)},
    )
    return Dataset(
        meta=meta,
        q=q[None],
        qd=qd[None],
        qdd=qdd[None],
        wrench=wrench[None],
        theta_known=np.asarray(model.theta_cad[model.known_index], dtype=np.float64),
        time=t[None],
    )


def _joint_column(name: str) -> tuple[str, int] | None:
    for prefix in ("qdd", "qd", "q"):
        rest = name[len(prefix) :]
        if name.startswith(prefix) and rest.isdigit():
            return prefix, int(rest)
    return None


def write_recording_csv(path: str | Path, dataset: Dataset, config: int = 0, flip_wrench: bool = False) -> Path:
    """Write one configuration of a dataset as a recording CSV (the inverse of the import)."""
    n = dataset.n_dof
    t = dataset.time[config] if dataset.time is not None else np.arange(dataset.n_frames) * 0.01
    sign = -1.0 if flip_wrench else 1.0
    cols = [t[:, None], dataset.q[config], dataset.qd[config], dataset.qdd[config], sign * dataset.wrench[config]]
    table = np.concatenate(cols, axis=1)
    path = Path(path)
    with atomic_output(path) as tmp, tmp.open("w", newline="") as fh:
        fh.write(",".join(csv_columns(n)) + "\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.17g")
    return path
