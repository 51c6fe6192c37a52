"""The ineid dataset: an HDF5 file of frames, wrenches and (for synthetic data) the truth.

The format is documented field by field in ``docs/dataset.md``. In short, a file holds
``n_configs`` configurations (robots with one parameter set each) of ``n_frames`` frames:

========================  ====================================  ================
dataset                   shape                                 unit
========================  ====================================  ================
``q, qd, qdd``            (n_configs, n_frames, n_dof)          rad, rad/s, ...
``wrench``                (n_configs, n_frames, 6)              N, N*m
``theta_unknown``         (n_configs, 10 * n_unknown)           kg, kg*m, kg*m^2
``theta_known``           (10 * n_known,)                       same
``*_clean``               as the noisy array                    same
``time``                  (n_configs, n_frames), optional       s
``link_set_index``        (n_configs, n_unknown), optional      -
========================  ====================================  ================

Files are written to a temporary name beside the target and renamed when complete, so
an interrupted write leaves no file. Chunks are compressed (shuffle + gzip level 1, the
filters every HDF5 reader has) by a thread pool and stored with ``write_direct_chunk``,
so compression runs on all cores and overlaps the computation of the next chunk.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_write, temporary_path
from ineid.errors import DatasetError
from ineid.params import N_PARAMS_PER_LINK, PARAM_NAMES, param_names

FORMAT = "ineid-dataset"
VERSION = 1
"""Format version this ineid writes and the newest it reads."""

STATE_KEYS = ("q", "qd", "qdd")
MEASURED_KEYS = (*STATE_KEYS, "wrench")
GZIP_LEVEL = 1
CHUNK_BYTES = 1 << 20
"""Target size of one stored chunk (all frames of a few configurations)."""


@dataclass
class DatasetMeta:
    """Everything in a dataset file besides the arrays (the HDF5 attributes).

    Attributes:
        robot: the robot's name (a built-in name, or the URDF's robot name).
        urdf: the full URDF text, so the file is self-contained.
        gravity: (3,) m/s^2, base frame.
        joint_names: moving joints in chain order (the columns of ``q``).
        link_names: moving links in chain order.
        unknown_links, known_links: the split of ``link_names``.
        locked_joints: ``{joint: position}`` locked when the URDF was loaded.
        source: ``"synthetic"`` (sampled truth) or ``"recording"`` (measured, truth unknown).
        seed: the sampling seed (``None`` for recordings).
        sampling: parameter, combination and frame settings (JSON-able).
        noise: noise settings, or ``None`` for clean data.
        origin: free-form provenance (e.g. the CSV file and its sign convention).
        ineid_version: the ineid that wrote the file.
        version: the format version.
    """

    robot: str
    urdf: str
    gravity: np.ndarray
    joint_names: tuple[str, ...]
    link_names: tuple[str, ...]
    unknown_links: tuple[str, ...]
    known_links: tuple[str, ...]
    locked_joints: dict[str, float] = field(default_factory=dict)
    source: str = "synthetic"
    seed: int | None = None
    sampling: dict | None = None
    noise: dict | None = None
    origin: dict | None = None
    ineid_version: str = ""
    version: int = VERSION

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def unknown_param_names(self) -> list[str]:
        return param_names(self.unknown_links)

    @classmethod
    def for_model(cls, model, **kwargs) -> DatasetMeta:
        """The metadata of a dataset of ``model`` (a :class:`ineid.RobotModel`)."""
        from ineid import __version__  # noqa: PLC0415

        return cls(
            robot=model.name,
            urdf=Path(model.urdf_path).read_text(),
            gravity=np.asarray(model.gravity, dtype=np.float64),
            joint_names=tuple(model.joint_names),
            link_names=tuple(model.link_names),
            unknown_links=tuple(model.unknown_links),
            known_links=tuple(model.known_links),
            locked_joints=dict(getattr(model, "locked_joints", None) or {}),
            ineid_version=__version__,
            **kwargs,
        )


@dataclass
class Dataset:
    """A dataset in memory. Arrays are float64 NumPy; shapes as in the module table.

    ``config_index`` holds each configuration's index in the file it came from, so
    results on a selection can be traced back.
    """

    meta: DatasetMeta
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    wrench: np.ndarray
    theta_known: np.ndarray
    theta_unknown: np.ndarray | None = None
    clean: dict[str, np.ndarray] = field(default_factory=dict)
    time: np.ndarray | None = None
    link_set_index: np.ndarray | None = None
    config_index: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.config_index is None:
            self.config_index = np.arange(self.q.shape[0], dtype=np.int64)
        _check_shapes(self.meta, {k: v.shape for k, v in self.arrays().items()}, "dataset")

    @property
    def n_configs(self) -> int:
        return int(self.q.shape[0])

    @property
    def n_frames(self) -> int:
        return int(self.q.shape[1])

    @property
    def n_dof(self) -> int:
        return int(self.q.shape[2])

    @property
    def has_truth(self) -> bool:
        return self.theta_unknown is not None

    def arrays(self) -> dict[str, np.ndarray]:
        """Every stored array by its dataset name."""
        out = {"q": self.q, "qd": self.qd, "qdd": self.qdd, "wrench": self.wrench, "theta_known": self.theta_known}
        if self.theta_unknown is not None:
            out["theta_unknown"] = self.theta_unknown
        for k, v in self.clean.items():
            out[f"{k}_clean"] = v
        if self.time is not None:
            out["time"] = self.time
        if self.link_set_index is not None:
            out["link_set_index"] = self.link_set_index
        return out

    def theta(self) -> np.ndarray:
        """(n_configs, 10 * n_links): every link's parameters in chain order (needs the truth)."""
        if self.theta_unknown is None:
            raise DatasetError("this dataset is a recording: its unknown links' parameters are not in it")
        return assemble_theta(self.meta, self.theta_unknown, self.theta_known)

    def select(self, configs=None, frames=None) -> Dataset:
        """A copy of some configurations and frames: slices, index arrays, integers or ``None`` (all)."""
        c = slice(None) if configs is None else ([configs] if np.ndim(configs) == 0 and not isinstance(configs, slice) else configs)
        f = slice(None) if frames is None else ([frames] if np.ndim(frames) == 0 and not isinstance(frames, slice) else frames)

        def pick(a, per_frame=True):
            # always a copy: editing a selection must not change the dataset it came from
            if a is None:
                return None
            a = a[c]
            return np.array(a[:, f] if per_frame else a)

        return Dataset(
            meta=self.meta,
            q=pick(self.q),
            qd=pick(self.qd),
            qdd=pick(self.qdd),
            wrench=pick(self.wrench),
            theta_known=self.theta_known,
            theta_unknown=pick(self.theta_unknown, False),
            clean={k: pick(v) for k, v in self.clean.items()},
            time=pick(self.time),
            link_set_index=pick(self.link_set_index, False),
            config_index=np.asarray(self.config_index)[c],
        )

    def model(self, codegen_dir: str | Path | None = None):
        """The :class:`ineid.RobotModel` this dataset was made with (gravity, unknown links)."""
        return model_from_meta(self.meta, codegen_dir)

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the dataset to ``path`` atomically; see :func:`save_dataset`."""
        return save_dataset(self, path, overwrite=overwrite)


def assemble_theta(meta: DatasetMeta, theta_unknown: np.ndarray, theta_known: np.ndarray) -> np.ndarray:
    """Stack unknown (..., 10 n_unknown) and known (10 n_known,) parameters in chain order."""
    theta_unknown = np.asarray(theta_unknown, dtype=np.float64)
    batch = theta_unknown.shape[:-1]
    u = theta_unknown.reshape(batch + (len(meta.unknown_links), N_PARAMS_PER_LINK))
    k = np.broadcast_to(
        np.asarray(theta_known, dtype=np.float64).reshape(len(meta.known_links), N_PARAMS_PER_LINK),
        batch + (len(meta.known_links), N_PARAMS_PER_LINK),
    )
    parts = []
    for link in meta.link_names:
        if link in meta.unknown_links:
            parts.append(u[..., meta.unknown_links.index(link), :])
        else:
            parts.append(k[..., meta.known_links.index(link), :])
    return np.concatenate(parts, axis=-1)


def model_from_meta(meta: DatasetMeta, codegen_dir: str | Path | None = None):
    """Rebuild the robot model of a dataset from the URDF text it carries.

    A built-in robot whose URDF is unchanged loads its checked-in code; any other URDF is
    written to the cache (keyed by its content) and loaded from there.
    """
    import hashlib  # noqa: PLC0415

    from ineid.cache import cache_dir  # noqa: PLC0415
    from ineid.codegen import load_robot  # noqa: PLC0415
    from ineid.robots import BUILTIN_ROBOTS  # noqa: PLC0415

    kwargs = {"unknown_links": list(meta.unknown_links), "gravity": tuple(float(g) for g in meta.gravity)}
    spec = BUILTIN_ROBOTS.get(meta.robot)
    if spec is not None and spec.urdf_path.read_text() == meta.urdf and not meta.locked_joints:
        model = load_robot(meta.robot, **kwargs)
    else:
        digest = hashlib.sha256(meta.urdf.encode()).hexdigest()[:16]
        path = cache_dir() / "urdf" / f"{digest}.urdf"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(path, meta.urdf)
        model = load_robot(path, locked_joints=meta.locked_joints or None, codegen_dir=codegen_dir, **kwargs)
    if tuple(model.joint_names) != tuple(meta.joint_names) or tuple(model.link_names) != tuple(meta.link_names):
        raise DatasetError(
            f"the URDF in the dataset gives joints {list(model.joint_names)}, but the file's columns are "
            f"{list(meta.joint_names)}; the file is inconsistent, regenerate it"
        )
    return model


# -- checks ----------------------------------------------------------------------------


def _expected_shapes(meta: DatasetMeta, n_configs: int, n_frames: int) -> dict[str, tuple[int, ...]]:
    n_dof, n_u, n_k = meta.n_dof, len(meta.unknown_links), len(meta.known_links)
    shapes = {k: (n_configs, n_frames, n_dof) for k in STATE_KEYS}
    shapes["wrench"] = (n_configs, n_frames, 6)
    shapes.update({f"{k}_clean": shapes[k] for k in MEASURED_KEYS})
    shapes["theta_unknown"] = (n_configs, N_PARAMS_PER_LINK * n_u)
    shapes["theta_known"] = (N_PARAMS_PER_LINK * n_k,)
    shapes["time"] = (n_configs, n_frames)
    shapes["link_set_index"] = (n_configs, n_u)
    return shapes


def _check_shapes(meta: DatasetMeta, shapes: Mapping[str, tuple[int, ...]], where: str) -> None:
    """Check array shapes (by dataset name) against the metadata's sizes."""
    if "q" not in shapes:
        raise DatasetError(f"{where}: no 'q' dataset; not an ineid dataset, or a damaged one")
    q = tuple(shapes["q"])
    if len(q) != 3:
        raise DatasetError(f"{where}: q must have shape (n_configs, n_frames, n_dof), got {q}")
    expected = _expected_shapes(meta, q[0], q[1])
    for name, shape in shapes.items():
        if name in expected and tuple(shape) != expected[name]:
            raise DatasetError(
                f"{where}: {name} has shape {tuple(shape)}, expected {expected[name]} for "
                f"{meta.n_dof} joints and unknown links {list(meta.unknown_links)}"
            )
    if set(meta.unknown_links) | set(meta.known_links) != set(meta.link_names) or set(meta.unknown_links) & set(
        meta.known_links
    ):
        raise DatasetError(f"{where}: unknown_links and known_links must split link_names {list(meta.link_names)}")


def check_finite(name: str, arr: np.ndarray, where: str, config_index: np.ndarray | None = None) -> None:
    """Raise :class:`DatasetError` naming the first NaN or infinite entry of ``arr``.

    ``config_index`` maps rows of ``arr`` to configuration numbers in the file.
    """
    bad = ~np.isfinite(arr)
    if not bad.any():
        return
    idx = [int(i) for i in np.argwhere(bad)[0]]
    what = "NaN" if np.isnan(arr[tuple(idx)]) else "an infinite value"
    if arr.ndim == 1:
        loc = f"entry {idx[0]}"
    else:
        if config_index is not None:
            idx[0] = int(config_index[idx[0]])
        loc = ", ".join(f"{label} {i}" for label, i in zip(("config", "frame", "column"), idx, strict=False))
    raise DatasetError(
        f"{where}: {name} holds {what} ({int(bad.sum())} entries; first at {loc}); "
        "values must be finite: drop or repair those frames, or regenerate the file"
    )


# -- writing ---------------------------------------------------------------------------


def _string_array(values: Sequence[str]) -> np.ndarray:
    import h5py  # noqa: PLC0415

    return np.array(list(values), dtype=h5py.string_dtype())


def _meta_attrs(meta: DatasetMeta) -> dict:
    attrs = {
        "format": FORMAT,
        "version": np.int64(meta.version),
        "robot": meta.robot,
        "urdf": meta.urdf,
        "gravity": np.asarray(meta.gravity, dtype=np.float64),
        "joint_names": _string_array(meta.joint_names),
        "link_names": _string_array(meta.link_names),
        "unknown_links": _string_array(meta.unknown_links),
        "known_links": _string_array(meta.known_links),
        "param_order": _string_array(PARAM_NAMES),
        "unknown_param_names": _string_array(meta.unknown_param_names),
        "locked_joints": json.dumps(meta.locked_joints, sort_keys=True),
        "source": meta.source,
        "sampling": json.dumps(meta.sampling, sort_keys=True),
        "noise": json.dumps(meta.noise, sort_keys=True),
        "origin": json.dumps(meta.origin, sort_keys=True),
        "ineid_version": meta.ineid_version,
    }
    if meta.seed is not None:
        attrs["seed"] = np.int64(meta.seed)
    return attrs


def chunk_rows(n_frames: int, width: int, n_configs: int) -> int:
    """Configurations per stored chunk: about :data:`CHUNK_BYTES` of float64."""
    return int(max(1, min(n_configs, CHUNK_BYTES // max(1, n_frames * width * 8))))


class DatasetWriter:
    """Write a dataset file chunk by chunk; the file appears only on :meth:`commit`.

    Per-configuration arrays are declared up front and filled by :meth:`write` in whole
    chunks of ``rows`` configurations, starting at multiples of ``rows`` (the last chunk may
    be short). Use as a context manager: leaving it by an exception (Ctrl-C included)
    deletes the temporary file; leaving it normally commits.

    Args:
        path: the target file.
        meta: the attributes.
        n_configs, n_frames: sizes.
        arrays: names of the per-configuration datasets to create (``q``, ``wrench``, ...).
        rows: configurations per chunk (default: about 1 MiB chunks of the widest array).
        overwrite: replace an existing ``path``.
        workers: compression threads (default: the CPU count).
    """

    def __init__(
        self,
        path: str | Path,
        meta: DatasetMeta,
        n_configs: int,
        n_frames: int,
        arrays: Sequence[str],
        rows: int | None = None,
        overwrite: bool = False,
        workers: int | None = None,
    ) -> None:
        import h5py  # noqa: PLC0415

        self.path = Path(path)
        if self.path.is_dir():
            raise DatasetError(f"{self.path} is a folder; give a file name such as data.h5")
        if self.path.exists() and not overwrite:
            raise DatasetError(f"{self.path} exists; pass --overwrite (overwrite=True) to replace it")
        if not self.path.parent.is_dir():
            raise DatasetError(f"folder {self.path.parent} does not exist; create it first")
        self.meta = meta
        self.n_configs, self.n_frames = int(n_configs), int(n_frames)
        if self.n_configs < 1 or self.n_frames < 1:
            raise DatasetError(f"a dataset needs at least one configuration and one frame, got {n_configs} x {n_frames}")
        self.shapes = _expected_shapes(meta, self.n_configs, self.n_frames)
        unknown = [a for a in arrays if a not in self.shapes or a == "theta_known"]
        if unknown:
            raise ValueError(f"not per-configuration datasets: {unknown}")
        self.rows = rows or chunk_rows(self.n_frames, max(6, meta.n_dof), self.n_configs)
        self._tmp = temporary_path(self.path)
        self._file = h5py.File(self._tmp, "w")
        self._pool = ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1)
        self._pending: list[tuple[Future, object, tuple[int, ...]]] = []
        try:
            for key, value in _meta_attrs(meta).items():
                self._file.attrs[key] = value
            self._dsets = {}
            for name in arrays:
                shape = self.shapes[name]
                dtype = np.int64 if name == "link_set_index" else np.float64
                self._dsets[name] = self._file.create_dataset(
                    name,
                    shape=shape,
                    dtype=dtype,
                    chunks=(self.rows, *shape[1:]),
                    compression="gzip",
                    compression_opts=GZIP_LEVEL,
                    shuffle=True,
                )
        except BaseException:
            self.abort()
            raise

    def write_constant(self, name: str, array: np.ndarray) -> None:
        """A small dataset written whole (``theta_known``)."""
        array = np.asarray(array, dtype=np.float64)
        if array.shape != self.shapes[name]:
            raise DatasetError(f"{name} has shape {array.shape}, expected {self.shapes[name]}")
        self._file.create_dataset(name, data=array)

    def write(self, name: str, start: int, array: np.ndarray) -> None:
        """Store configurations ``start .. start + len(array)`` of ``name``."""
        dset = self._dsets[name]
        shape = self.shapes[name]
        array = np.ascontiguousarray(array, dtype=dset.dtype)
        if array.shape[1:] != shape[1:] or start % self.rows or start + len(array) > shape[0]:
            raise ValueError(f"{name}: block of shape {array.shape} at {start} does not fit chunks of {self.rows}")
        if start + len(array) < shape[0] and len(array) % self.rows:
            raise ValueError(f"{name}: only the last block may end inside a chunk")
        for c0 in range(0, len(array), self.rows):
            offset = (start + c0,) + (0,) * (array.ndim - 1)
            job = self._pool.submit(_compress_chunk, array[c0 : c0 + self.rows], self.rows)
            self._pending.append((job, dset, offset))
        self._drain(keep=2 * (os.cpu_count() or 1))

    def _drain(self, keep: int = 0) -> None:
        # Chunks are stored in submission order by this thread, the only one using h5py.
        while len(self._pending) > keep:
            job, dset, offset = self._pending.pop(0)
            dset.id.write_direct_chunk(offset, job.result())

    def commit(self) -> Path:
        """Finish writing and move the file into place."""
        try:
            self._drain()
            self._file.close()
            self._pool.shutdown()
            os.replace(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Drop the temporary file; the target is left as it was."""
        for job, _, _ in self._pending:
            job.cancel()
        self._pending.clear()
        self._pool.shutdown(wait=True, cancel_futures=True)
        try:
            self._file.close()
        except Exception:  # noqa: BLE001 - the file is being discarded anyway
            pass
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.abort()


def _compress_chunk(block: np.ndarray, rows: int) -> bytes:
    """HDF5's shuffle + deflate of one chunk, padded to full size (as HDF5 stores edges)."""
    if len(block) < rows:
        block = np.concatenate([block, np.zeros((rows - len(block),) + block.shape[1:], block.dtype)])
    raw = np.ascontiguousarray(block).view(np.uint8).reshape(-1, block.itemsize)
    return zlib.compress(np.ascontiguousarray(raw.T).tobytes(), GZIP_LEVEL)


def save_dataset(ds: Dataset, path: str | Path, overwrite: bool = False) -> Path:
    """Write an in-memory :class:`Dataset` to ``path`` (atomic; see :class:`DatasetWriter`)."""
    per_config = [k for k in ds.arrays() if k != "theta_known"]
    with DatasetWriter(path, ds.meta, ds.n_configs, ds.n_frames, per_config, overwrite=overwrite) as w:
        w.write_constant("theta_known", ds.theta_known)
        for name, arr in ds.arrays().items():
            if name != "theta_known":
                w.write(name, 0, arr)
    return Path(path)


# -- reading ---------------------------------------------------------------------------


def _open(path: Path):
    import h5py  # noqa: PLC0415

    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    if path.is_dir():
        raise DatasetError(f"{path} is a folder, not a dataset file")
    try:
        return h5py.File(path, "r")
    except OSError as e:
        raise DatasetError(
            f"{path} is not a readable HDF5 file ({_first_line(e)}); it may be truncated or corrupt: "
            "regenerate it or copy it again"
        ) from None


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def _as_str(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _str_tuple(value) -> tuple[str, ...]:
    return tuple(_as_str(v) for v in np.atleast_1d(value))


def _json_attr(attrs, key: str, where: str):
    try:
        return json.loads(_as_str(attrs[key]))
    except (KeyError, json.JSONDecodeError):
        raise DatasetError(f"{where}: attribute {key!r} is missing or not JSON; the file is damaged") from None


def _read_meta(f, where: str) -> DatasetMeta:
    attrs = f.attrs
    fmt = _as_str(attrs.get("format", ""))
    if fmt != FORMAT:
        raise DatasetError(
            f"{where}: not an ineid dataset (format attribute {fmt or 'missing'!r}, expected {FORMAT!r}); "
            "make one with `ineid data generate` or `ineid data import`"
        )
    try:
        version = int(attrs["version"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{where}: the format version attribute is missing; the file is damaged") from None
    if version > VERSION or version < 1:
        raise DatasetError(
            f"{where}: format version {version} is not supported (this ineid reads versions 1..{VERSION}); "
            "upgrade ineid or regenerate the file"
        )
    try:
        order = _str_tuple(attrs["param_order"])
        meta = DatasetMeta(
            robot=_as_str(attrs["robot"]),
            urdf=_as_str(attrs["urdf"]),
            gravity=np.asarray(attrs["gravity"], dtype=np.float64),
            joint_names=_str_tuple(attrs["joint_names"]),
            link_names=_str_tuple(attrs["link_names"]),
            unknown_links=_str_tuple(attrs["unknown_links"]),
            known_links=_str_tuple(attrs["known_links"]),
            locked_joints=_json_attr(attrs, "locked_joints", where) or {},
            source=_as_str(attrs["source"]),
            seed=int(attrs["seed"]) if "seed" in attrs else None,
            sampling=_json_attr(attrs, "sampling", where),
            noise=_json_attr(attrs, "noise", where),
            origin=_json_attr(attrs, "origin", where),
            ineid_version=_as_str(attrs.get("ineid_version", "")),
            version=version,
        )
    except KeyError as e:
        raise DatasetError(f"{where}: attribute {e.args[0]!r} is missing; the file is damaged") from None
    if order != PARAM_NAMES:
        raise DatasetError(f"{where}: parameter order {list(order)} differs from ineid's {list(PARAM_NAMES)}")
    if meta.gravity.shape != (3,) or not np.all(np.isfinite(meta.gravity)):
        raise DatasetError(f"{where}: gravity must be 3 finite numbers, got {meta.gravity.tolist()}")
    return meta


def read_meta(path: str | Path) -> tuple[DatasetMeta, dict[str, tuple[int, ...]]]:
    """The attributes of a dataset file and the shapes of its arrays, without the data."""
    path = Path(path)
    with _open(path) as f:
        meta = _read_meta(f, str(path))
        shapes = {name: tuple(f[name].shape) for name in f}
        _check_shapes(meta, shapes, str(path))
        for name in ("q", "qd", "qdd", "wrench", "theta_known"):
            if name not in shapes:
                raise DatasetError(f"{path}: dataset {name!r} is missing; the file is damaged")
        if meta.source == "synthetic" and "theta_unknown" not in shapes:
            raise DatasetError(f"{path}: a synthetic dataset without theta_unknown; the file is damaged")
    return meta, shapes


def _index(sel, n: int, what: str) -> np.ndarray:
    if sel is None:
        return np.arange(n)
    if isinstance(sel, slice):
        return np.arange(n)[sel]
    idx = np.asarray(sel)
    if idx.dtype == bool:
        if idx.shape != (n,):
            raise DatasetError(f"{what} mask must have {n} entries, got {idx.shape}")
        return np.flatnonzero(idx)
    idx = idx.astype(np.int64).ravel()
    if idx.size and (idx.min() < -n or idx.max() >= n):
        raise DatasetError(f"{what} index out of range: the file has {n} {what}s (0..{n - 1})")
    return np.where(idx < 0, idx + n, idx)


def load_dataset(path: str | Path, configs=None, frames=None) -> Dataset:
    """Read a dataset file, checking format, version, shapes and finite values.

    Args:
        path: the file.
        configs: which configurations (slice, index array, boolean mask; default all).
        frames: which frames of each (default all).

    Raises:
        DatasetError: naming what is wrong (not HDF5, truncated, another format, a newer
            version, a missing or misshapen array, NaN or infinite values).
    """
    path = Path(path)
    meta, shapes = read_meta(path)
    n_configs, n_frames = shapes["q"][:2]
    cidx = _index(configs, n_configs, "configuration")
    fidx = _index(frames, n_frames, "frame")
    where = str(path)
    out: dict[str, np.ndarray] = {}
    with _open(path) as f:
        for name in shapes:
            if name not in _expected_shapes(meta, 1, 1):
                continue
            dset = f[name]
            try:
                if name == "theta_known":
                    arr = dset[()]
                else:
                    arr = _read_rows(dset, cidx)
                    if arr.ndim == 3 or name == "time":
                        arr = arr[:, fidx]
            except (OSError, ValueError) as e:
                raise DatasetError(
                    f"{where}: dataset {name!r} cannot be read ({_first_line(e)}); the file is truncated or corrupt"
                ) from None
            if name != "link_set_index":
                check_finite(name, arr, where, None if name == "theta_known" else cidx)
            out[name] = np.asarray(arr, dtype=np.int64 if name == "link_set_index" else np.float64)
    clean = {k: out.pop(f"{k}_clean") for k in MEASURED_KEYS if f"{k}_clean" in out}
    return Dataset(
        meta=meta,
        q=out["q"],
        qd=out["qd"],
        qdd=out["qdd"],
        wrench=out["wrench"],
        theta_known=out["theta_known"],
        theta_unknown=out.get("theta_unknown"),
        clean=clean,
        time=out.get("time"),
        link_set_index=out.get("link_set_index"),
        config_index=cidx.astype(np.int64),
    )


def _read_rows(dset, idx: np.ndarray) -> np.ndarray:
    if idx.size == 0:
        return np.empty((0,) + dset.shape[1:], dset.dtype)
    if np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return dset[int(idx[0]) : int(idx[0]) + idx.size]
    # h5py fancy indexing needs increasing indices; read sorted, then restore the order.
    uniq, inverse = np.unique(idx, return_inverse=True)
    return dset[uniq][inverse]


def iter_dataset(path: str | Path, name: str, rows: int = 4096):
    """Yield ``(start, block)`` of one per-configuration array, ``rows`` configurations at a time."""
    path = Path(path)
    with _open(path) as f:
        dset = f[name]
        for start in range(0, dset.shape[0], rows):
            try:
                yield start, dset[start : start + rows]
            except OSError as e:
                raise DatasetError(f"{path}: dataset {name!r} cannot be read ({_first_line(e)}); truncated or corrupt") from None


def meta_to_dict(meta: DatasetMeta) -> dict:
    """JSON-able form of the metadata (for reports)."""
    d = dataclasses.asdict(meta)
    d["gravity"] = np.asarray(meta.gravity).tolist()
    d.pop("urdf")
    return d
