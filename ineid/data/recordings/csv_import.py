"""Import a recording from a real arm (a CSV file) as a one-configuration dataset.

Columns (a header row is required; names are case-insensitive, any order, extra columns
are ignored; units SI):

    time                 s, increasing within each stream (see below)
    q1 .. qn             joint positions, rad (m for prismatic joints), URDF chain order
    qd1 .. qn            joint velocities, rad/s        } optional, together: without them
    qdd1 .. qn           joint accelerations, rad/s^2   } they are derived from q1 .. qn
    tau1 .. taun         joint torques, N*m (N), optional; or tau_<joint> by joint name
    i1 .. in             motor currents, A, optional; or i_<joint>
                         (with a coupling, per motor: tau_<motor>, i_<motor>, or numbered in the motors' order)
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
two clocks); each IMU (all its columns) is a stream of its own the same way. The processing (filter, derivatives,
one time base, the sensor pose) is
:mod:`ineid.data.recordings.pipeline`'s. A sensor that reports the wrench the fixture exerts on the
robot (the opposite sign) is imported with ``flip_wrench=True``. The truth is unknown, so
the file has no ``theta_unknown``; ``theta_known`` holds the model's CAD values of the
known links.

The file is read within stated limits and streamed (:mod:`ineid.data.recordings.csv_rows`: a regular file of at most
64 GiB, 10,000 columns, 10^8 rows, lines of 2^20 characters, values within
:data:`ineid.data.recordings.streams.VALUE_LIMIT`); memory holds the numbers of the columns read, not the text.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_output
from ineid._inputs import regular_file
from ineid.data.dataset.schema import Dataset
from ineid.data.recordings.csv_rows import MAX_CSV_BYTES, Layout, Table, csv_lines, parse_header, read_rows
from ineid.data.recordings.streams import ImuStream, Streams
from ineid.errors import DatasetError

WRENCH_COLUMNS = ("fx", "fy", "fz", "mx", "my", "mz")


def read_csv_rows(path: str | Path) -> list[tuple[int, list[str]]]:
    """``(physical line number, cells)`` of every row of a CSV file; blank and ``#`` comment lines skipped.

    Within the limits of a recording CSV (:mod:`ineid.data.recordings.csv_rows`: a regular file of at most
    :data:`MAX_CSV_BYTES`, lines of at most ``MAX_LINE_CHARS``).

    Raises:
        InputFileError: the file does not exist, is not a regular file (a FIFO, a device) or is too large.
        DatasetError: it is not CSV text, or a line is too long.
    """
    path = regular_file(
        path, "the CSV file", max_bytes=MAX_CSV_BYTES, limit_name="ineid.data.recordings.csv_rows.MAX_CSV_BYTES"
    )
    rows = []
    with csv_lines(path) as blocks:
        for numbers, lines in blocks:
            for k, line in zip(numbers, lines, strict=True):
                try:
                    rows.append((k, next(csv.reader([line]))))
                except csv.Error as e:
                    raise DatasetError(f"{path}: line {k} cannot be read as CSV ({e})") from None
    return rows


def csv_columns(n_dof: int, derivatives: bool = True) -> list[str]:
    """The columns of an arm with ``n_dof`` joints in the documented order (``qd``, ``qdd`` if ``derivatives``)."""
    joints = [f"q{i}" for i in range(1, n_dof + 1)]
    if derivatives:
        joints += [f"qd{i}" for i in range(1, n_dof + 1)] + [f"qdd{i}" for i in range(1, n_dof + 1)]
    return ["time", *joints, *WRENCH_COLUMNS]


def _channel_columns(header: list[str], prefix: str, what: str, model, path: Path, motors=()) -> list[str]:
    """The header's columns of a per-joint channel (``tau``: ``tau1..tauN`` or ``tau_<joint>``), in chain order;
    [] when it has none. With ``motors`` (a coupling's motors, :mod:`ineid.channels.transmission`) the channel
    reads per motor: ``tau1..tauN`` in the motors' order or ``tau_<motor>``, in the motors' order.

    Raises:
        DatasetError: columns for another number of joints, a joint (motor) the robot (coupling) does not
            have, some joints (motors) missing, or both spellings.
    """
    n = model.n_dof
    numbered = sorted(int(h[len(prefix) :]) for h in header if h.startswith(prefix) and h[len(prefix) :].isdigit())
    named = [h for h in header if h.startswith(f"{prefix}_")]
    if not numbered and not named:
        return []
    axes = [a.lower() for a in (motors or model.joint_names)]
    noun = "motor" if motors else "joint"
    spelled = f"{prefix}1..{prefix}{n} or {prefix}_<{noun}> ({', '.join(f'{prefix}_{a}' for a in axes)})"
    if numbered and named:
        raise DatasetError(
            f"{path}: the {what} columns mix {prefix}<k> and {prefix}_<{noun}>; use one spelling: {spelled}"
        )
    if named:
        unknown = [h for h in named if h[len(prefix) + 1 :] not in axes]
        if unknown:
            owner = "the coupling (--coupling)" if motors else model.name
            raise DatasetError(
                f"{path}: column {unknown[0]!r} names no {noun} of {owner}; its {what} columns are {spelled}"
            )
        wanted = [f"{prefix}_{a}" for a in axes]
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
        raise DatasetError(
            f"{path}: missing {what} column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
            f"give one per {noun}: {spelled}"
        )
    return wanted


def read_csv_streams(path: str | Path, model, progress=None, imus: tuple[str, ...] = (), motors: tuple[str, ...] = ()):
    """Read a recording CSV into :class:`ineid.data.recordings.streams.Streams` (no processing yet).

    A link IMU's columns ``imu_<NAME>_...`` become a stream only when ``imus`` (the ``--imu`` texts) names
    ``NAME``; the others are listed in the streams' ``origin["imu_unused"]`` (the import says so in one line:
    :func:`ineid.data.recordings.imus.unused_imu_lines`). With ``motors`` (the motors of a coupling,
    ``--coupling``) the torque and current columns may be named after them: ``tau_<motor>``, ``i_<motor>``.

    The file is read within the limits of :mod:`ineid.data.recordings.csv_rows` (size, columns, rows, line
    length; values within :data:`ineid.data.recordings.streams.VALUE_LIMIT`), streamed: memory holds the
    numbers of the columns read, not the text.

    Raises:
        InputFileError: the file does not exist, is not a regular file (a FIFO, a device, a folder),
            or is larger than :data:`ineid.data.recordings.csv_rows.MAX_CSV_BYTES`.
        DatasetError: the file not UTF-8 text or empty; more columns or rows than the limits, a line
            too long; a repeated column; joint columns for another number of joints; torque columns for
            another number of joints or naming another joint; missing columns (all named); ``qd``
            without ``qdd`` or the reverse; neither a wrench nor torques; no data rows; a ragged row;
            a cell that is not a number; a row with only some of a stream's cells; NaN or infinite
            values, or values beyond the limit; time not increasing within a stream. Cell errors
            name the line.
        ResourceError: the rows would not fit in the memory available.
    """
    path = regular_file(
        path, "the CSV recording", max_bytes=MAX_CSV_BYTES, limit_name="ineid.data.recordings.csv_rows.MAX_CSV_BYTES"
    )
    with csv_lines(path) as blocks:
        first = next((b for b in blocks if b[1]), None)
        if first is None:
            raise DatasetError(
                f"{path}: the file is empty; expected a header row {','.join(csv_columns(model.n_dof, False))}"
            )
        numbers, lines = first
        header = parse_header(lines[0], numbers[0], path)
        columns = _recording_columns(header, model, path, imus, motors)
        index = {h: k for k, h in enumerate(header)}
        layout = Layout(
            path, len(header), tuple(index[c] for c in columns.names), tuple(columns.names), columns.streams
        )
        rest = [(numbers[1:], lines[1:])]
        table = read_rows((b for part in (rest, blocks) for b in part), layout, path.stat().st_size, progress)
    if not len(table.values):
        raise DatasetError(f"{path}: the header has no data rows below it")
    return _streams(table, columns, model, path)


class _Columns:
    """The columns a recording CSV's header holds, in the order they are read (:func:`_recording_columns`)."""

    def __init__(
        self,
        joint_names: list[str],
        measured: bool,
        tau: list[str],
        current: list[str],
        wrench: bool,
        imu_kinds: dict[str, dict[str, list[str]]],
    ) -> None:
        self.joint_names, self.measured, self.tau, self.current = joint_names, measured, tau, current
        self.wrench, self.imu_kinds = wrench, imu_kinds
        self.unused_imus: dict[str, list[str]] = {}
        self.imu_cols = {name: [c for cols in kinds.values() for c in cols] for name, kinds in imu_kinds.items()}
        self.names = [
            "time",
            *joint_names,
            *(WRENCH_COLUMNS if wrench else ()),
            *(c for cols in self.imu_cols.values() for c in cols),
        ]
        k0 = 1 + len(joint_names) + (6 if wrench else 0)
        spans = [(1, 1 + len(joint_names))] + ([(1 + len(joint_names), k0)] if wrench else [])
        for cols in self.imu_cols.values():
            spans.append((k0, k0 + len(cols)))
            k0 += len(cols)
        self.streams = tuple(spans)


def _recording_columns(header: list[str], model, path: Path, imus: tuple[str, ...] = (), motors=()) -> _Columns:
    """Which of the header's columns a recording of ``model`` reads (the IMUs' of those ``imus``, the ``--imu``
    texts, names); the header's mistakes, named."""
    n = model.n_dof
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
    names = set(header)
    tau_cols = _channel_columns(header, "tau", "joint torque", model, path, motors)
    current_cols = _channel_columns(header, "i", "motor current", model, path, motors)
    has_wrench_cols = any(c in names for c in WRENCH_COLUMNS) or not (tau_cols or current_cols)
    required = ["time", *(f"q{i}" for i in range(1, n + 1)), *(WRENCH_COLUMNS if has_wrench_cols else ())]
    missing = [c for c in required if c not in names]
    if missing:
        raise DatasetError(
            f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
            f"a recording of {model.name} needs {','.join(required)} (and optionally qd1..qd{n}, qdd1..qdd{n}; "
            f"the wrench columns may be left out when joint torques tau1..tau{n} are given)"
        )
    from ineid.data.recordings.imus import imu_column_kinds, named_imus

    found = imu_column_kinds(header, path)
    named = named_imus(imus, model)
    absent = sorted(named - set(found))
    if absent:
        raise DatasetError(
            f"{path}: --imu {absent[0]!r} has no readings in the recording (its IMUs: {', '.join(found) or 'none'}); "
            f"name its columns imu_{absent[0]}_wx... after it, or drop the --imu"
        )

    deriv = [f"{p}{i}" for p in ("qd", "qdd") for i in range(1, n + 1)]
    present = [c for c in deriv if c in names]
    if present and len(present) != len(deriv):
        absent = [c for c in deriv if c not in names]
        raise DatasetError(
            f"{path}: missing column{'s' if len(absent) > 1 else ''} {', '.join(absent)}; give all of "
            f"qd1..qd{n} and qdd1..qdd{n}, or none (then they are derived from the joint angles)"
        )
    joint_names = csv_columns(n, derivatives=bool(present))[1:-6] + tau_cols + current_cols
    columns = _Columns(joint_names, bool(present), tau_cols, current_cols, has_wrench_cols, found)
    columns.unused_imus = {name: list(kinds) for name, kinds in found.items() if name not in named}
    return columns


def _streams(table: Table, columns: _Columns, model, path: Path) -> Streams:
    """The rows read, split into the streams (each on its own rows) and checked for increasing time."""
    n, data, names = model.n_dof, table.values, columns.names
    flags = {"joint": table.present[:, 0]}
    if columns.wrench:
        flags["wrench"] = table.present[:, 1]
    for k, name in enumerate(columns.imu_cols, start=len(flags)):
        flags[f"IMU {name!r}"] = table.present[:, k]
    rows = {}
    for name, mask in flags.items():
        rows[name] = data if mask.all() else data[mask]  # one clock (the usual file): views, no copies
        t = rows[name][:, 0]
        if len(t) < 2:
            raise DatasetError(
                f"{path}: {len(t)} {name} sample{'s' if len(t) != 1 else ''}; a recording needs many more"
            )
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            line, k = table.lines[np.flatnonzero(mask)[bad[0] + 1]], bad[0]
            how = f"goes back {float(t[k] - t[k + 1]):.6g} s" if t[k + 1] < t[k] else "repeats"
            raise DatasetError(
                f"{path}: time does not increase at line {line} ({name} samples: {float(t[k + 1])!r} s after "
                f"{float(t[k])!r} s, time {how}); sort the rows or fix the time column"
            )
    jr = rows["joint"]
    k0 = 1 + (3 * n if columns.measured else n)
    tau = jr[:, k0 : k0 + n] if columns.tau else None
    k0 += n if columns.tau else 0
    imus = []
    for name, kinds in columns.imu_kinds.items():
        if name in columns.unused_imus:  # read (its rows are the file's), not used
            continue
        r = rows[f"IMU {name!r}"]
        imus.append(
            ImuStream(
                name,
                r[:, 0],
                {k: r[:, [names.index(c) for c in cols]] for k, cols in kinds.items()},
                f"columns imu_{name}_*",
            )
        )
    n_joint = len(columns.joint_names)
    wr = rows.get("wrench")
    return Streams(
        joint_time=jr[:, 0],
        q=jr[:, 1 : 1 + n],
        qd=jr[:, 1 + n : 1 + 2 * n] if columns.measured else None,
        qdd=jr[:, 1 + 2 * n : 1 + 3 * n] if columns.measured else None,
        wrench_time=None if wr is None else wr[:, 0],
        wrench=None if wr is None else wr[:, 1 + n_joint : 7 + n_joint],
        tau=tau,
        current=jr[:, k0 : k0 + n] if columns.current else None,
        imus=tuple(imus),
        source=str(path),
        origin={
            "format": "csv",
            "file": path.name,
            "rows": int(len(data)),
            **({"imu_unused": {"columns": columns.unused_imus}} if columns.unused_imus else {}),
        },
    )


def _joint_column(name: str) -> tuple[str, int] | None:
    for prefix in ("qdd", "qd", "q"):
        rest = name[len(prefix) :]
        if name.startswith(prefix) and rest.isdigit():
            return prefix, int(rest)
    return None


def write_recording_csv(
    path: str | Path, dataset: Dataset, config: int = 0, flip_wrench: bool = False, derivatives: bool = True
) -> Path:
    """Write one configuration of a dataset as a recording CSV (the inverse of the import).

    ``derivatives=False`` leaves out ``qd``/``qdd``, as an encoder-only recording has them.
    The CSV holds the base wrench (the channel ``wrench``, in its sensor's frame) and the joint
    torques ``tau1..taun`` (the channel ``tau``) that the dataset has.
    """
    tau = dataset.channel_values.get("tau")
    if dataset.wrench is None and tau is None:
        raise DatasetError(
            f"a recording CSV holds the wrench or joint torques, and this dataset measures "
            f"{dataset.meta.channels.describe()}: write another dataset"
        )
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
