"""Writing ineid dataset files (the schema is :mod:`ineid.data.schema`).

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
from pathlib import Path

import numpy as np

from ineid._atomic import check_output, temporary_path
from ineid.data.schema import FORMAT, VERSION, Dataset, DatasetMeta, expected_shapes
from ineid.errors import DatasetError
from ineid.params import PARAM_NAMES

GZIP_LEVEL = 1
CHUNK_BYTES = 1 << 20
"""Target size of one stored chunk (all frames of a few configurations)."""


def _string_array(values: Sequence[str]) -> np.ndarray:
    import h5py  # noqa: PLC0415

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
        "sensor": json.dumps(meta.sensor, sort_keys=True),
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
        check_output(self.path, overwrite)
        if not self.path.parent.is_dir():
            raise DatasetError(f"folder {self.path.parent} does not exist; create it first")
        self.meta = meta
        self.n_configs, self.n_frames = int(n_configs), int(n_frames)
        if self.n_configs < 1 or self.n_frames < 1:
            raise DatasetError(f"a dataset needs at least one configuration and one frame, got {n_configs} x {n_frames}")
        self.shapes = expected_shapes(meta, self.n_configs, self.n_frames)
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
