"""Writing ineid dataset files (the schema is :mod:`ineid.data.dataset.schema`).

Files are written to a temporary name beside the target and renamed when complete, so
an interrupted write (an exception, Ctrl-C, a scheduler's SIGTERM) leaves no file. Chunks
are compressed (shuffle + gzip level 1, the filters every HDF5 reader has) by a thread
pool and stored with ``write_direct_chunk``, so compression runs on all cores and overlaps
the computation of the next chunk.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import suppress
from pathlib import Path

import numpy as np

from ineid._atomic import check_output
from ineid._faults import format_bytes, free_disk
from ineid._temporary import create_temporary
from ineid.data.dataset.meta import FORMAT, VERSION, DatasetMeta, expected_shapes
from ineid.errors import DatasetError, StorageError
from ineid.params import PARAM_NAMES

GZIP_LEVEL = 1
CHUNK_BYTES = 1 << 20
"""Target size of one stored chunk (all frames of a few configurations)."""


def _string_array(values: Sequence[str]) -> np.ndarray:
    import h5py

    return np.array(list(values), dtype=h5py.string_dtype())


def _meta_attrs(meta: DatasetMeta) -> dict:
    attrs = {
        "format": FORMAT,
        "version": np.int64(VERSION),  # a file is written in this ineid's format, whatever it was read from
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
        "channels": json.dumps(meta.channels.to_list(), sort_keys=True),
        "ineid_version": meta.ineid_version,
        "extra_truth": json.dumps(meta.extra_truth, sort_keys=True),
    }
    if meta.seed is not None:
        attrs["seed"] = np.int64(meta.seed)
    return attrs


def row_width(meta: DatasetMeta) -> int:
    """The widest per-frame array of a dataset: ``n_dof`` or a channel's axes (at least 6)."""
    return max(6, meta.n_dof, *(c.n_axes(meta) for c in meta.channels))


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
        import h5py

        self.path = Path(path)
        if self.path.is_dir():
            raise DatasetError(f"{self.path} is a folder; give a file name such as data.h5")
        check_output(self.path, overwrite)
        if not self.path.parent.is_dir():
            raise DatasetError(f"folder {self.path.parent} does not exist; create it first")
        self.meta = meta
        self.n_configs, self.n_frames = int(n_configs), int(n_frames)
        if self.n_configs < 1 or self.n_frames < 1:
            raise DatasetError(
                f"a dataset needs at least one configuration and one frame, got {n_configs} x {n_frames}"
            )
        self.shapes = expected_shapes(meta, self.n_configs, self.n_frames)
        unknown = [a for a in arrays if a not in self.shapes or a == "theta_known"]
        if unknown:
            raise ValueError(f"not per-configuration datasets: {unknown}")
        self.rows = rows or chunk_rows(self.n_frames, row_width(meta), self.n_configs)
        self._tmp = create_temporary(self.path)  # a file of this process: h5py's "w" writes into it
        try:
            self._file = h5py.File(self._tmp, "w")
        except BaseException:
            # HDF5 may have created the file before failing (a full disk): leave nothing
            with suppress(OSError):
                self._tmp.unlink(missing_ok=True)
            raise
        self._pool = ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1)
        self._pending: list[tuple[Future, object, tuple[int, ...]]] = []
        self._space = _SpaceWatch(self.path, arrays, self.n_configs)
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
        """A small dataset written whole (``theta_known``).

        Raises:
            DatasetError: a wrong shape, or NaN or infinite values (nothing is written).
        """
        array = np.asarray(array, dtype=np.float64)
        if array.shape != self.shapes[name]:
            raise DatasetError(f"{name} has shape {array.shape}, expected {self.shapes[name]}")
        self._check_finite(name, 0, array)
        self._file.create_dataset(name, data=array)

    def write(self, name: str, start: int, array: np.ndarray) -> None:
        """Store configurations ``start .. start + len(array)`` of ``name``.

        Raises:
            DatasetError: NaN or infinite values (a dataset never holds them: the write
                stops and the file is dropped), or a projected size above the free disk.
        """
        dset = self._dsets[name]
        shape = self.shapes[name]
        array = np.ascontiguousarray(array, dtype=dset.dtype)
        if array.shape[1:] != shape[1:] or start % self.rows or start + len(array) > shape[0]:
            raise ValueError(f"{name}: block of shape {array.shape} at {start} does not fit chunks of {self.rows}")
        if start + len(array) < shape[0] and len(array) % self.rows:
            raise ValueError(f"{name}: only the last block may end inside a chunk")
        self._check_finite(name, start, array)
        for c0 in range(0, len(array), self.rows):
            offset = (start + c0,) + (0,) * (array.ndim - 1)
            job = self._pool.submit(_compress_chunk, array[c0 : c0 + self.rows], self.rows)
            self._pending.append((job, dset, offset))
        self._drain(keep=2 * (os.cpu_count() or 1))

    def _check_finite(self, name: str, start: int, array: np.ndarray) -> None:
        if array.dtype.kind != "f" or np.isfinite(array).all():
            return
        bad = np.argwhere(~np.isfinite(array))[0].tolist()
        what = "NaN" if np.isnan(array[tuple(bad)]) else "an infinite value"
        if name == "theta_known":
            labels = ("entry",)
        else:
            bad[0] += start
            labels = ("configuration", "frame" if array.ndim == 3 or name == "time" else "column", "column")
        loc = ", ".join(f"{label} {i}" for label, i in zip(labels, bad, strict=False))
        raise DatasetError(
            f"{self.path}: {name} would hold {what} ({loc}); nothing was written. A dataset holds finite numbers "
            "only: lower the value that overflows (--noise, --gravity, a sampling setting)"
        )

    def _drain(self, keep: int = 0) -> None:
        # Chunks are stored in submission order by this thread, the only one using h5py.
        while len(self._pending) > keep:
            job, dset, offset = self._pending.pop(0)
            chunk = job.result()
            self._space.check(dset.name.lstrip("/"), len(chunk), min(self.rows, self.n_configs - offset[0]))
            dset.id.write_direct_chunk(offset, chunk)

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
        except Exception:  # the file is being discarded anyway
            pass
        with suppress(OSError):  # never hide the error that brought us here
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.abort()


class _SpaceWatch:
    """Refuse a dataset that will not fit on its disk, projected from the chunks compressed so far.

    The compressed size depends on the data (noise compresses less than clean frames),
    so it is measured, not guessed: once every array has a stored chunk, and again every
    :attr:`EVERY` chunks, the size of the whole file is extrapolated per array (bytes per
    configuration so far, times the configurations) and compared with the free space left.
    A file that cannot fit stops within its first chunks, not when the disk is full.
    """

    EVERY = 64
    SLACK = 1.02
    """The projection may be off by a little (the last chunks, metadata): refuse only above this."""

    def __init__(self, path: Path, names, n_configs: int) -> None:
        self.path, self.n_configs = path, n_configs
        self.stored = dict.fromkeys(names, 0)
        self.rows = dict.fromkeys(names, 0)
        self.chunks = 0
        self.checked = False

    def check(self, name: str, nbytes: int, rows: int) -> None:
        """Count a compressed chunk of ``rows`` configurations of ``name`` about to be stored."""
        self.stored[name] += nbytes
        self.rows[name] += rows
        self.chunks += 1
        if not all(self.rows.values()) or (self.checked and self.chunks % self.EVERY):
            return  # a projection needs every array; then one check every EVERY chunks
        self.checked = True
        written = sum(self.stored.values())
        total = sum(self.stored[k] / self.rows[k] * self.n_configs for k in self.stored if self.rows[k])
        free = free_disk(self.path)
        if free is not None and total - written > self.SLACK * free:
            raise StorageError(
                f"{self.path} would be about {format_bytes(total)} (measured on its first "
                f"{min(self.rows.values()):,} configurations), and its disk has {format_bytes(free)} free; "
                "free some space, choose another --out, or make fewer configurations or frames"
            )


def _compress_chunk(block: np.ndarray, rows: int) -> bytes:
    """HDF5's shuffle + deflate of one chunk, padded to full size (as HDF5 stores edges)."""
    if len(block) < rows:
        block = np.concatenate([block, np.zeros((rows - len(block),) + block.shape[1:], block.dtype)])
    raw = np.ascontiguousarray(block).view(np.uint8).reshape(-1, block.itemsize)
    return zlib.compress(np.ascontiguousarray(raw.T).tobytes(), GZIP_LEVEL)


def save_dataset(ds, path: str | Path, overwrite: bool = False) -> Path:
    """Write an in-memory :class:`ineid.data.dataset.schema.Dataset` to ``path`` (atomic; see
    :class:`DatasetWriter`)."""
    per_config = [k for k in ds.arrays() if k != "theta_known"]
    with DatasetWriter(path, ds.meta, ds.n_configs, ds.n_frames, per_config, overwrite=overwrite) as w:
        w.write_constant("theta_known", ds.theta_known)
        for name, arr in ds.arrays().items():
            if name != "theta_known":
                w.write(name, 0, arr)
    return Path(path)
