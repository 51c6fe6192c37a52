"""Finite-Fourier joint trajectories: exact evaluation, sampling, and their CSV and JSON files.

A periodic excitation trajectory (Swevers, Ganseman, Tukel, De Schutter & Van Brussel
1997) has, per joint ``j`` and harmonics ``l = 1..H``, with ``w = 2 pi f0``::

    q_j(t)   = q0_j + sum_l  a_jl / (w l) sin(w l t) - b_jl / (w l) cos(w l t)
    qd_j(t)  =        sum_l  a_jl cos(w l t) + b_jl sin(w l t)
    qdd_j(t) =        sum_l -a_jl w l sin(w l t) + b_jl w l cos(w l t)

``a, b`` in rad/s (m/s for prismatic joints), ``q0`` the mean position over a period.
It is at rest at ``t = 0`` (and so at every whole period) when ``sum_l a_jl = 0`` and
``sum_l l b_jl = 0``. The peaks obey the guaranteed bounds
``|q - q0| <= sum_l |c_l| / (w l)``, ``|qd| <= sum_l |c_l|``, ``|qdd| <= sum_l |c_l| w l``
with ``|c_l| = hypot(a_l, b_l)``.

Files:

* ``traj.json``: the coefficients (``format: ineid-fourier-trajectory``), so a controller
  evaluates the trajectory itself with the formula above, which the file repeats;
* ``traj.csv``: ``time, q1..qn, qd1..qn, qdd1..qn`` sampled at a rate, SI units, ``#``
  comment lines on top (the same column names as a recording, without the wrench).

Both are written atomically (:mod:`ineid._atomic`).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_write, check_output
from ineid._inputs import parse_json, read_json, regular_file
from ineid.errors import DatasetError, OutputExistsError

FORMAT = "ineid-fourier-trajectory"
VERSION = 1
FORMULA = (
    "q_j(t) = q0_j + sum_l a_jl/(w l) sin(w l t) - b_jl/(w l) cos(w l t); "
    "qd_j(t) = sum_l a_jl cos(w l t) + b_jl sin(w l t); "
    "qdd_j(t) = sum_l -a_jl w l sin(w l t) + b_jl w l cos(w l t); "
    "w = 2 pi base_frequency, l = 1..harmonics, t in s"
)
WHOLE_TOL = 1e-9
"""Relative tolerance when a duration must be a whole number of periods or of samples."""


def whole_count(value: float) -> int | None:
    """``round(value)`` when ``value`` is a whole number (relative tolerance WHOLE_TOL), else None."""
    k = round(value)
    return int(k) if k >= 1 and abs(value - k) <= WHOLE_TOL * max(1.0, abs(value)) else None


def state_matrices(t: np.ndarray, base_frequency: float, harmonics: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Pq, Pqd, Pqdd)``, each (len(t), 2H): the states are linear in ``c = [a; b]``.

    ``q(t) - q0 = Pq @ [a; b]``, ``qd(t) = Pqd @ [a; b]``, ``qdd(t) = Pqdd @ [a; b]`` for
    one joint's coefficients ``a, b`` (H,) each.
    """
    wl = 2.0 * np.pi * base_frequency * np.arange(1, harmonics + 1)
    phase = np.asarray(t, dtype=np.float64)[:, None] * wl[None, :]
    s, c = np.sin(phase), np.cos(phase)
    pq = np.concatenate([s / wl, -c / wl], axis=1)
    pqd = np.concatenate([c, s], axis=1)
    pqdd = np.concatenate([-s * wl, c * wl], axis=1)
    return pq, pqd, pqdd


@dataclass(frozen=True, eq=False)
class FourierTrajectory:
    """A finite-Fourier trajectory of every joint (see the module doc for the formula).

    Attributes:
        base_frequency: ``f0``, Hz; the period is ``1 / f0``.
        q0: (n_dof,) mean joint positions, rad (m for prismatic joints).
        a, b: (n_dof, H) coefficients, rad/s (m/s).
        duration: s, a whole number of periods (default: one period).
        joint_names: the joints, chain order (may be empty).
    """

    base_frequency: float
    q0: np.ndarray
    a: np.ndarray
    b: np.ndarray
    duration: float | None = None
    joint_names: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        f0 = float(self.base_frequency)
        if not (math.isfinite(f0) and f0 > 0):
            raise ValueError(f"base_frequency must be a positive number of Hz, got {self.base_frequency!r}")
        q0 = np.asarray(self.q0, dtype=np.float64).reshape(-1)
        a = np.atleast_2d(np.asarray(self.a, dtype=np.float64))
        b = np.atleast_2d(np.asarray(self.b, dtype=np.float64))
        if a.shape != b.shape or a.shape[0] != q0.shape[0] or a.shape[1] < 1:
            raise ValueError(
                f"a and b must have shape (n_dof, harmonics) with n_dof = len(q0) = {q0.shape[0]}, "
                f"got a {a.shape} and b {b.shape}"
            )
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ValueError("trajectory coefficients must be finite")
        duration = 1.0 / f0 if self.duration is None else float(self.duration)
        if whole_count(duration * f0) is None:
            raise ValueError(
                f"duration {duration:g} s is not a whole number of periods of {1 / f0:g} s (base frequency {f0:g} Hz)"
            )
        names = tuple(self.joint_names)
        if names and len(names) != q0.shape[0]:
            raise ValueError(f"joint_names has {len(names)} names for {q0.shape[0]} joints")
        object.__setattr__(self, "base_frequency", f0)
        object.__setattr__(self, "q0", q0)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "duration", duration)
        object.__setattr__(self, "joint_names", names)

    # -- structure -------------------------------------------------------------------
    @property
    def n_dof(self) -> int:
        return int(self.q0.shape[0])

    @property
    def harmonics(self) -> int:
        return int(self.a.shape[1])

    @property
    def period(self) -> float:
        return 1.0 / self.base_frequency

    @property
    def n_periods(self) -> int:
        return int(whole_count(self.duration * self.base_frequency))

    # -- evaluation ------------------------------------------------------------------
    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, qd, qdd)`` at times ``t`` (T,) s, each (T, n_dof), exact (the formula)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        pq, pqd, pqdd = state_matrices(t, self.base_frequency, self.harmonics)
        c = np.concatenate([self.a, self.b], axis=1).T  # (2H, n_dof)
        return self.q0[None, :] + pq @ c, pqd @ c, pqdd @ c

    def sample_times(self, rate: float) -> np.ndarray:
        """``t_k = k / rate`` for ``k = 0..K``, ``K = duration * rate`` (both ends included).

        Raises:
            ValueError: the duration is not a whole number of samples at ``rate``.
        """
        rate = float(rate)
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate must be a positive number of Hz, got {rate!r}")
        k = whole_count(self.duration * rate)
        if k is None:
            raise ValueError(
                f"duration {self.duration:g} s is not a whole number of samples at {rate:g} Hz; "
                f"choose a duration that is a multiple of 1/rate = {1 / rate:g} s"
            )
        return np.arange(k + 1) / rate

    def sample(self, rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, q, qd, qdd)`` at ``rate`` Hz over the duration, ends included (see :meth:`sample_times`)."""
        t = self.sample_times(rate)
        return (t, *self.evaluate(t))

    def amplitude_bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Guaranteed peaks ``(max |q - q0|, max |qd|, max |qdd|)``, (n_dof,) each, over all ``t``."""
        wl = 2.0 * np.pi * self.base_frequency * np.arange(1, self.harmonics + 1)
        amp = np.hypot(self.a, self.b)
        return (amp / wl).sum(-1), amp.sum(-1), (amp * wl).sum(-1)

    def rest_residual(self) -> tuple[np.ndarray, np.ndarray]:
        """``(qd(0), qdd(0))``: zero for a trajectory that starts (and ends) at rest."""
        wl = 2.0 * np.pi * self.base_frequency * np.arange(1, self.harmonics + 1)
        return self.a.sum(-1), (self.b * wl).sum(-1)

    # -- files -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-able record of the coefficients; :meth:`from_dict` reads it back."""
        return {
            "format": FORMAT,
            "version": VERSION,
            "formula": FORMULA,
            "units": "SI: s, Hz, rad (m for prismatic joints), rad/s, rad/s^2",
            "joint_names": list(self.joint_names),
            "base_frequency": self.base_frequency,
            "duration": self.duration,
            "harmonics": self.harmonics,
            "q0": self.q0.tolist(),
            "a": self.a.tolist(),
            "b": self.b.tolist(),
        }

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> FourierTrajectory:
        """Inverse of :meth:`to_dict`.

        Raises:
            DatasetError: not a trajectory record, or a field with the wrong shape or value.
        """
        if not isinstance(d, Mapping) or d.get("format") != FORMAT:
            raise DatasetError(f'{source}: not an ineid trajectory (expected "format": "{FORMAT}")')
        if int(d.get("version", 0)) > VERSION:
            raise DatasetError(
                f"{source}: trajectory format version {d.get('version')} is newer than this ineid reads ({VERSION}); "
                "upgrade ineid"
            )
        try:
            return cls(
                base_frequency=float(d["base_frequency"]),
                q0=np.asarray(d["q0"], dtype=np.float64),
                a=np.asarray(d["a"], dtype=np.float64),
                b=np.asarray(d["b"], dtype=np.float64),
                duration=None if d.get("duration") is None else float(d["duration"]),
                joint_names=tuple(d.get("joint_names") or ()),
            )
        except KeyError as e:
            raise DatasetError(f"{source}: missing field {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            raise DatasetError(f"{source}: {e}") from None


def _check_output(path: Path, overwrite: bool) -> None:
    if path.is_dir():
        raise OutputExistsError(f"{path} is a folder; give a file name")
    check_output(path, overwrite)


def trajectory_columns(n_dof: int) -> list[str]:
    """``time, q1..qn, qd1..qn, qdd1..qn``."""
    return ["time"] + [f"{p}{i}" for p in ("q", "qd", "qdd") for i in range(1, n_dof + 1)]


def trajectory_csv_text(t, q, qd, qdd, comments: Sequence[str] = ()) -> str:
    """The CSV text of sampled states: ``#`` comment lines, the header, one row per sample (``%.17g``).

    A comment's control characters (a newline in a robot name) are written escaped, so each
    comment stays one ``#`` line.
    """
    t = np.asarray(t, dtype=np.float64)
    q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
    buf = io.StringIO()
    for line in comments:
        one_line = "".join(c if c.isprintable() else ascii(c)[1:-1] for c in str(line))
        buf.write(f"# {one_line}\n")
    buf.write(",".join(trajectory_columns(q.shape[1])) + "\n")
    np.savetxt(buf, np.concatenate([t[:, None], q, qd, qdd], axis=1), delimiter=",", fmt="%.17g")
    return buf.getvalue()


def write_trajectory_csv(
    path: str | Path, t, q, qd, qdd, comments: Sequence[str] = (), overwrite: bool = False
) -> Path:
    """Write sampled states as ``time, q1..qn, qd1..qn, qdd1..qn`` (atomic)."""
    path = Path(path)
    _check_output(path, overwrite)
    return atomic_write(path, trajectory_csv_text(t, q, qd, qdd, comments))


def write_trajectory_json(
    path: str | Path, trajectory: FourierTrajectory, extra: Mapping | None = None, overwrite: bool = False
) -> Path:
    """Write the coefficients (and ``extra`` JSON-able fields, e.g. the design record) atomically."""
    path = Path(path)
    _check_output(path, overwrite)
    record = trajectory.to_dict()
    if extra:
        record.update(extra)
    return atomic_write(path, json.dumps(record, indent=1) + "\n")


def read_trajectory_json(path: str | Path) -> tuple[FourierTrajectory, dict]:
    """``(trajectory, the whole record)`` from a ``traj.json``.

    Raises:
        DatasetError: unreadable, not JSON, or not a trajectory record.
    """
    path = Path(path)
    try:
        record = read_json(path, "the trajectory file")
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot be read ({e})") from None
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except ValueError as e:  # nested too deep
        raise DatasetError(f"{path}: not a trajectory record (JSON {e})") from None
    return FourierTrajectory.from_dict(record, str(path)), record


@dataclass(frozen=True, eq=False)
class SampledTrajectory:
    """Joint states along a trajectory, one row per sample.

    Attributes:
        time: (F,) s, increasing.
        q, qd, qdd: (F, n_dof) rad, rad/s, rad/s^2 (m, m/s, m/s^2 for prismatic joints).
        source: where the samples came from (a file name).
        joint_names: the joints, if the source names them.
        fourier: the coefficients when the samples were evaluated from them.
    """

    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    source: str = ""
    joint_names: tuple[str, ...] = ()
    fourier: FourierTrajectory | None = None

    @property
    def n_frames(self) -> int:
        return int(self.time.shape[0])

    @property
    def n_dof(self) -> int:
        return int(self.q.shape[1])

    def digest(self) -> str:
        """SHA-256 (16 hex digits) of the sampled arrays: identifies the frames in a dataset's metadata."""
        h = hashlib.sha256()
        for x in (self.time, self.q, self.qd, self.qdd):
            h.update(np.ascontiguousarray(x, dtype=np.float64).tobytes())
        return h.hexdigest()[:16]

    def describe(self) -> dict:
        """JSON-able provenance (what a dataset records in its sampling settings)."""
        d = {
            "source": self.source,
            "n_frames": self.n_frames,
            "duration": float(self.time[-1] - self.time[0]),
            "sha256": self.digest(),
        }
        if self.fourier is not None:
            d["fourier"] = self.fourier.to_dict()
        return d


def read_trajectory_csv(path: str | Path) -> SampledTrajectory:
    """Read a ``time, q1..qn, qd1..qn, qdd1..qn`` CSV (header required, ``#`` lines skipped).

    Raises:
        DatasetError: a missing column, a cell that is not a finite number, time not
            strictly increasing, no rows.
    """
    path = Path(path)
    from ineid.data.recordings.csv_import import read_csv_rows

    numbered = read_csv_rows(path)
    if not numbered:
        raise DatasetError(f"{path}: the file is empty; expected a header row time,q1..qn,qd1..qn,qdd1..qn")
    header = [h.strip().lower() for h in numbered[0][1]]
    n = 0
    while f"q{n + 1}" in header:
        n += 1
    if n == 0:
        raise DatasetError(f"{path}: no joint columns (q1, qd1, qdd1, ...) in the header {','.join(header)}")
    required = trajectory_columns(n)
    missing = [c for c in required if c not in header]
    if missing:
        raise DatasetError(f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    cols = [header.index(c) for c in required]
    body = numbered[1:]
    if not body:
        raise DatasetError(f"{path}: the header has no data rows below it")
    data = np.empty((len(body), len(required)))
    for i, (line, row) in enumerate(body):
        if len(row) != len(header):
            raise DatasetError(f"{path}: line {line} has {len(row)} cells, the header has {len(header)}")
        for k, c in enumerate(cols):
            try:
                data[i, k] = float(row[c])
            except ValueError:
                raise DatasetError(
                    f"{path}: line {line}, column {required[k]!r}: {row[c].strip()!r} is not a number"
                ) from None
    bad = ~np.isfinite(data)
    if bad.any():
        r, k = np.argwhere(bad)[0]
        raise DatasetError(f"{path}: line {body[r][0]}, column {required[k]!r} is not finite; repair or drop the row")
    t = data[:, 0]
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        r = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise DatasetError(f"{path}: time does not increase at line {body[r][0]}; sort the rows or fix the time column")
    return SampledTrajectory(t, data[:, 1 : 1 + n], data[:, 1 + n : 1 + 2 * n], data[:, 1 + 2 * n :], source=path.name)


def load_trajectory(path: str | Path, rate: float | None = None, n_frames: int | None = None) -> SampledTrajectory:
    """Samples of a designed trajectory from its ``.csv`` (the rows) or its ``.json`` (exact).

    For a JSON file: ``n_frames`` equally spaced samples ``t_k = k * duration / n_frames``
    when given; else the samples at ``rate`` (default: the design rate the file records,
    else 100 Hz) over the duration, ends included, the same rows its CSV has.

    Raises:
        DatasetError: an unreadable file, or ``n_frames`` with a CSV file.
        InputFileError: ``path`` is not a regular file (a FIFO, a device: never opened).
    """
    path = regular_file(path, "the trajectory file")
    if path.suffix.lower() == ".json":
        traj, record = read_trajectory_json(path)
        if n_frames is not None:
            t = np.arange(n_frames) * (traj.duration / n_frames)
        else:
            use = rate if rate is not None else float(record.get("design", {}).get("rate", 100.0))
            try:
                t = traj.sample_times(use)
            except ValueError as e:
                raise DatasetError(f"{path}: {e}") from None
        q, qd, qdd = traj.evaluate(t)
        return SampledTrajectory(t, q, qd, qdd, source=path.name, joint_names=traj.joint_names, fourier=traj)
    if n_frames is not None:
        raise DatasetError(
            f"{path}: the rows of a trajectory CSV are the frames; drop the frame count (or use its .json)"
        )
    sampled = read_trajectory_csv(path)
    names = _csv_joint_names(path)
    if names and len(names) == sampled.n_dof:
        sampled = SampledTrajectory(sampled.time, sampled.q, sampled.qd, sampled.qdd, sampled.source, names)
    return sampled


def _csv_joint_names(path: Path) -> tuple[str, ...]:
    """Joint names from a ``# joints: ["a", "b"]`` comment line (a JSON list, as ineid writes it;
    ``# joints: a, b`` from older versions is read too); ``()`` when there is none or it is garbled."""
    try:
        with path.open(encoding="utf-8-sig") as fh:
            for line in fh:
                if not line.lstrip().startswith("#"):
                    break
                text = line.lstrip()[1:].strip()
                if text.startswith("joints:"):
                    rest = text[len("joints:") :].strip()
                    if not rest.startswith("["):
                        return tuple(n.strip() for n in rest.split(",") if n.strip())
                    names = parse_json(rest)
                    ok = isinstance(names, list) and all(isinstance(n, str) for n in names)
                    return tuple(names) if ok else ()
    except (OSError, UnicodeDecodeError, ValueError):
        return ()
    return ()


def check_trajectory_fits(trajectory: SampledTrajectory, model) -> None:
    """Check that ``trajectory`` is for ``model``: same joints (by count, and by name when it names them),
    positions within the joint limits.

    Raises:
        DatasetError: which check failed, and what to do.
    """
    src = trajectory.source or "the trajectory"
    if trajectory.n_dof != model.n_dof:
        raise DatasetError(
            f"{src} moves {trajectory.n_dof} joints, {model.name} has {model.n_dof}; "
            "design the trajectory for this robot (ineid excite)"
        )
    if trajectory.joint_names and tuple(trajectory.joint_names) != tuple(model.joint_names):
        raise DatasetError(
            f"{src} is for joints {', '.join(trajectory.joint_names)}, {model.name} has "
            f"{', '.join(model.joint_names)}; design the trajectory for this robot (ineid excite)"
        )
    lo, hi = np.asarray(model.q_lower, float), np.asarray(model.q_upper, float)
    tol = 1e-9 * (hi - lo)
    bad = np.flatnonzero(np.any((trajectory.q < lo - tol) | (trajectory.q > hi + tol), axis=0))
    if bad.size:
        j = int(bad[0])
        raise DatasetError(
            f"{src}: joint {model.joint_names[j]!r} leaves its limits [{lo[j]:g}, {hi[j]:g}]; "
            "design the trajectory within the limits (ineid excite)"
        )
