"""Import a recording from a real arm (a CSV file) as a one-configuration dataset.

Columns (a header row is required; names are case-insensitive, any order, extra columns
are ignored; units SI):

    time                 s, increasing within each stream (see below)
    q1 .. qn             joint positions, rad (m for prismatic joints), URDF chain order
    qd1 .. qn            joint velocities, rad/s        } optional, together: without them
    qdd1 .. qn           joint accelerations, rad/s^2   } they are derived from q1 .. qn
    tau1 .. taun         joint torques, N*m (N), optional; or tau_<joint> by joint name
    i1 .. in             motor currents, A, optional; or i_<joint> (not identified yet: refused)
    fx fy fz             force, N         } what the sensor reads: the load of the robot on
    mx my mz             moment, N*m      } it, sensor frame, moment about the sensor origin;
                                            optional when joint torques are given
    imu_<NAME>_wx,_wy,_wz      a link IMU's gyroscope, rad/s            } sensor frame; any of the
    imu_<NAME>_ax,_ay,_az      its accelerometer (specific force), m/s^2 } three kinds per IMU, all
    imu_<NAME>_alx,_aly,_alz   its angular acceleration, rad/s^2         } three axes of a kind

Joint torques (and currents) are on the joints' clock: their cells belong to the joint
sample of their row.

Several streams may share the file: a row whose joint cells are all empty holds a wrench
sample only, a row whose wrench cells are all empty a joint sample only (a merged log of
two clocks); each IMU (all its columns) is a stream of its own the same way. The processing (filter, derivatives, one time base, the sensor pose) is
:mod:`ineid.data.recording`'s. A sensor that reports the wrench the fixture exerts on the
robot (the opposite sign) is imported with ``flip_wrench=True``. The truth is unknown, so
the file has no ``theta_unknown``; ``theta_known`` holds the model's CAD values of the
known links.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_output
from ineid.data.schema import Dataset
from ineid.data.streams import ImuStream, Streams
from ineid.errors import DatasetError

WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")


def read_csv_rows(path: str | Path) -> list[tuple[int, list[str]]]:
    """``(physical line number, cells)`` of every row of a CSV file; blank and ``#`` comment lines skipped.

    Raises:
        DatasetError: the file does not exist or is not CSV text.
    """
    path = Path(path)
    try:
        # utf-8-sig: a byte-order mark (spreadsheet exports write one) is not part of the first column's name.
        with path.open(newline="", encoding="utf-8-sig") as fh:
            return [
                (k, cells)
                for k, line in enumerate(fh, start=1)
                if line.strip() and not line.lstrip().startswith("#")
                for cells in csv.reader([line])
            ]
    except FileNotFoundError:
        raise DatasetError(f"{path} does not exist") from None
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DatasetError(f"{path}: cannot be read as CSV text ({e})") from None


def csv_columns(n_dof: int, derivatives: bool = True) -> list[str]:
    """The columns of an arm with ``n_dof`` joints in the documented order (``qd``, ``qdd`` if ``derivatives``)."""
    joints = [f"q{i}" for i in range(1, n_dof + 1)]
    if derivatives:
        joints += [f"qd{i}" for i in range(1, n_dof + 1)] + [f"qdd{i}" for i in range(1, n_dof + 1)]
    return ["time", *joints, *WRENCH_COLUMNS]


def _channel_columns(header: list[str], prefix: str, what: str, model, path: Path) -> list[str]:
    """The header's columns of a per-joint channel (``tau``: ``tau1..tauN`` or ``tau_<joint>``), in chain order;
    [] when it has none.

    Raises:
        DatasetError: columns for another number of joints, a joint the robot does not have,
            some joints missing, or both spellings.
    """
    n = model.n_dof
    numbered = sorted(int(h[len(prefix):]) for h in header if h.startswith(prefix) and h[len(prefix):].isdigit())
    named = [h for h in header if h.startswith(f"{prefix}_")]
    if not numbered and not named:
        return []
    joints = [j.lower() for j in model.joint_names]
    spelled = f"{prefix}1..{prefix}{n} or {prefix}_<joint> ({', '.join(f'{prefix}_{j}' for j in joints)})"
    if numbered and named:
        raise DatasetError(f"{path}: the {what} columns mix {prefix}<k> and {prefix}_<joint>; use one spelling: "
                           f"{spelled}")
    if named:
        unknown = [h for h in named if h[len(prefix) + 1:] not in joints]
        if unknown:
            raise DatasetError(f"{path}: column {unknown[0]!r} names no joint of {model.name}; its {what} columns are "
                               f"{spelled}")
        wanted = [f"{prefix}_{j}" for j in joints]
    else:
        if min(numbered) < 1:
            raise DatasetError(f"{path}: {what} columns count from 1 ({prefix}1), found {prefix}0")
        if max(numbered) != n or len(numbered) != n:
            found = max(numbered)
            raise DatasetError(
                f"{path}: the {what} columns are for {len(numbered)} joint{'s' if len(numbered) != 1 else ''} (up to "
                f"{prefix}{found}), but {model.name} has {n} ({', '.join(model.joint_names)}); give {spelled}"
            )
        wanted = [f"{prefix}{i}" for i in range(1, n + 1)]
    missing = [c for c in wanted if c not in header]
    if missing:
        raise DatasetError(f"{path}: missing {what} column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
                           f"give one per joint: {spelled}")
    return wanted


def read_csv_streams(path: str | Path, model, progress=None):
    """Read a recording CSV into :class:`ineid.data.streams.Streams` (no processing yet).

    Raises:
        DatasetError: the file missing, unreadable or empty; a repeated column; joint
            columns for another number of joints; torque columns for another number of
            joints or naming another joint; missing columns (all named); ``qd`` without
            ``qdd`` or the reverse; neither a wrench nor torques; no data rows; a ragged row;
            a cell that is not a number; a row with only some of a stream's cells; NaN or
            infinite values; time not increasing within a stream. Cell errors name the line.
    """
    path = Path(path)
    n = model.n_dof
    numbered = read_csv_rows(path)
    rows = [cells for _, cells in numbered]
    line_of = [k for k, _ in numbered]
    if not rows:
        raise DatasetError(f"{path}: the file is empty; expected a header row {','.join(csv_columns(n, False))}")
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
    tau_cols = _channel_columns(header, "tau", "joint torque", model, path)
    current_cols = _channel_columns(header, "i", "motor current", model, path)
    has_wrench_cols = any(c in header for c in WRENCH_COLUMNS) or not (tau_cols or current_cols)
    required = ["time", *(f"q{i}" for i in range(1, n + 1)), *(WRENCH_COLUMNS if has_wrench_cols else ())]
    missing = [c for c in required if c not in header]
    if missing:
        raise DatasetError(
            f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
            f"a recording of {model.name} needs {','.join(required)} (and optionally qd1..qd{n}, qdd1..qdd{n}; "
            f"the wrench columns may be left out when joint torques tau1..tau{n} are given)"
        )
    from ineid.data.recording_imu import imu_column_kinds  # noqa: PLC0415

    imu_kinds = imu_column_kinds(header, path)
    deriv = [f"{p}{i}" for p in ("qd", "qdd") for i in range(1, n + 1)]
    present = [c for c in deriv if c in header]
    if present and len(present) != len(deriv):
        absent = [c for c in deriv if c not in header]
        raise DatasetError(
            f"{path}: missing column{'s' if len(absent) > 1 else ''} {', '.join(absent)}; give all of "
            f"qd1..qd{n} and qdd1..qdd{n}, or none (then they are derived from the joint angles)"
        )
    joint_names = csv_columns(n, derivatives=bool(present))[1:-6] + tau_cols + current_cols
    names = ["time", *joint_names, *(WRENCH_COLUMNS if has_wrench_cols else ())]
    imu_cols = {name: [c for cols in kinds.values() for c in cols] for name, kinds in imu_kinds.items()}
    names += [c for cols in imu_cols.values() for c in cols]
    col = [header.index(c) for c in names]
    body = rows[1:]
    if not body:
        raise DatasetError(f"{path}: the header has no data rows below it")
    n_joint = len(joint_names)  # q (and qd, qdd, tau, i) columns: the joints' stream
    data = np.full((len(body), len(names)), np.nan)
    has_joint = np.ones(len(body), dtype=bool)
    has_wrench = np.full(len(body), has_wrench_cols)
    k0 = 1 + n_joint + (6 if has_wrench_cols else 0)
    streams = [(1, 1 + n_joint, has_joint)] + ([(1 + n_joint, k0, has_wrench)] if has_wrench_cols else [])
    has_imu = {}
    for name, cols in imu_cols.items():
        has_imu[name] = np.ones(len(body), dtype=bool)
        streams.append((k0, k0 + len(cols), has_imu[name]))
        k0 += len(cols)
    for i, row in enumerate(body):
        line = line_of[i + 1]
        if len(row) != len(header):
            raise DatasetError(f"{path}: line {line} has {len(row)} cells, the header has {len(header)}")
        cells = [row[c].strip() for c in col]
        empty = [not c for c in cells]
        for lo, hi, flag in streams:
            if all(empty[lo:hi]):
                flag[i] = False
            elif any(empty[lo:hi]):
                k = lo + empty[lo:hi].index(True)
                raise DatasetError(
                    f"{path}: line {line}, column {names[k]!r} is empty while others of its stream are not; "
                    "a row holds all the cells of each of its streams (the joints, the wrench, an IMU) or none"
                )
        if empty[0]:
            raise DatasetError(f"{path}: line {line}, column 'time' is empty")
        if not (has_joint[i] or has_wrench[i] or any(f[i] for f in has_imu.values())):
            raise DatasetError(f"{path}: line {line} holds a time but no joint, wrench or IMU values")
        for k, cell in enumerate(cells):
            if cell:
                try:
                    data[i, k] = float(cell)
                except ValueError:
                    raise DatasetError(f"{path}: line {line}, column {names[k]!r}: {cell!r} is not a number") from None
                if not np.isfinite(data[i, k]):
                    raise DatasetError(
                        f"{path}: line {line}, column {names[k]!r} is {cell}; values must be finite: drop or "
                        "repair those rows"
                    )
        if progress is not None and (i + 1) % 10000 == 0:
            progress(i + 1, len(body))
    checked = [("joint", has_joint), ("wrench", has_wrench)][: 1 + has_wrench_cols]
    for name, mask in [*checked, *((f"IMU {k!r}", f) for k, f in has_imu.items())]:
        rows_k = np.flatnonzero(mask)
        t = data[rows_k, 0]
        if len(rows_k) < 2:
            raise DatasetError(f"{path}: {len(rows_k)} {name} sample{'s' if len(rows_k) != 1 else ''}; a recording needs many more")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise DatasetError(
                f"{path}: time does not increase at line {line_of[rows_k[bad[0] + 1] + 1]} ({name} samples); "
                "sort the rows or fix the time column"
            )
    jr, wr = data[has_joint], data[has_wrench]
    q = jr[:, 1 : 1 + n]
    qd = jr[:, 1 + n : 1 + 2 * n] if present else None
    qdd = jr[:, 1 + 2 * n : 1 + 3 * n] if present else None
    k0 = 1 + (3 * n if present else n)
    tau = jr[:, k0 : k0 + n] if tau_cols else None
    k0 += n if tau_cols else 0
    current = jr[:, k0 : k0 + n] if current_cols else None
    if progress is not None:
        progress(len(body), len(body))
    imus = []
    for name, kinds in imu_kinds.items():
        rows_k = data[has_imu[name]]
        imus.append(ImuStream(name, rows_k[:, 0], {k: rows_k[:, [names.index(c) for c in cols]]
                                                   for k, cols in kinds.items()}, f"columns imu_{name}_*"))
    return Streams(
        joint_time=jr[:, 0], q=q, qd=qd, qdd=qdd, wrench_time=wr[:, 0] if has_wrench_cols else None,
        wrench=wr[:, 1 + n_joint : 7 + n_joint] if has_wrench_cols else None, tau=tau, current=current,
        imus=tuple(imus),
        source=str(path), origin={"format": "csv", "file": path.name, "rows": int(len(body))},
    )  # fmt: skip


def _joint_column(name: str) -> tuple[str, int] | None:
    for prefix in ("qdd", "qd", "q"):
        rest = name[len(prefix) :]
        if name.startswith(prefix) and rest.isdigit():
            return prefix, int(rest)
    return None


def write_recording_csv(path: str | Path, dataset: Dataset, config: int = 0, flip_wrench: bool = False,
                        derivatives: bool = True) -> Path:
    """Write one configuration of a dataset as a recording CSV (the inverse of the import).

    ``derivatives=False`` leaves out ``qd``/``qdd``, as an encoder-only recording has them.
    The CSV holds the base wrench (the channel ``wrench``, in its sensor's frame) and the joint
    torques ``tau1..taun`` (the channel ``tau``) that the dataset has.
    """
    tau = dataset.channel_values.get("tau")
    if dataset.wrench is None and tau is None:
        raise DatasetError(f"a recording CSV holds the wrench or joint torques, and this dataset measures "
                           f"{dataset.meta.channels.describe()}: write another dataset")
    n = dataset.n_dof
    t = dataset.time[config] if dataset.time is not None else np.arange(dataset.n_frames) * 0.01
    sign = -1.0 if flip_wrench else 1.0
    joints = [dataset.q[config], dataset.qd[config], dataset.qdd[config]] if derivatives else [dataset.q[config]]
    columns = csv_columns(n, derivatives)[:-6]
    if tau is not None:
        joints.append(tau[config])
        columns += [f"tau{i}" for i in range(1, n + 1)]
    if dataset.wrench is not None:
        joints.append(sign * dataset.wrench[config])
        columns += list(WRENCH_COLUMNS)
    table = np.concatenate([t[:, None], *joints], axis=1)
    path = Path(path)
    with atomic_output(path) as tmp, tmp.open("w", newline="") as fh:
        fh.write(",".join(columns) + "\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.17g")
    return path
