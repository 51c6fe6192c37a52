"""Reading ineid dataset files: format and version checks, shapes, finite values.

The schema is :mod:`ineid.data.dataset.schema`; files from older format versions are read too.
"""

from __future__ import annotations

import logging
import os
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ineid._faults import fault_errno, require_memory
from ineid._inputs import JsonDepthError, parse_json, regular_file
from ineid.channels import ChannelSet, SensorPose
from ineid.data.dataset.hdf5_audit import audit_hdf5
from ineid.data.dataset.meta import check_extra_truth
from ineid.data.dataset.schema import (
    FORMAT,
    VERSION,
    Dataset,
    DatasetMeta,
    check_finite,
    check_shapes,
    expected_shapes,
)
from ineid.errors import DatasetError
from ineid.params import PARAM_NAMES

log = logging.getLogger(__name__)


def _open(path: Path):
    """The dataset file ``path`` open for reading, checked by :func:`~ineid.data.dataset.hdf5_audit.audit_hdf5`.

    Raises:
        DatasetError: missing, a folder, or not HDF5 (a recording says how to import it).
        InputFileError: not a regular file (a FIFO is never opened), or a file that reaches outside itself.
    """
    import h5py

    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    if path.is_dir():
        raise DatasetError(foreign_file(path) or f"{path} is a folder, not a dataset file")
    regular_file(path, "the dataset")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        if fault_errno(e) is not None:
            raise  # permission denied, an I/O error: the CLI names the file and the fix
        raise DatasetError(
            foreign_file(path)
            or f"{path} is not a readable HDF5 file ({_first_line(e)}); it may be truncated or corrupt: "
            "regenerate it or copy it again"
        ) from None
    try:
        audit_hdf5(f, path)
    except BaseException:
        f.close()
        raise
    return f


_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_ROSBAG_MAGIC = b"#ROSBAG V2.0"


def foreign_file(path: str | Path, expected: str = "an ineid dataset (HDF5)", then: str = "") -> str | None:
    """Why ``path`` is not an HDF5 file ineid can read, when it is a recording or text; else None.

    A recording that ``ineid data import`` reads (a CSV, a ROS 1 ``.bag``, a ``.mcap``, a ROS 2
    bag folder) gives the import command to run; any other text file is named as text, unless
    its name ends in ``.h5``. A file that starts like HDF5, or binary data of another kind, gives None (the
    caller's "truncated
    or corrupt" stands). Reads at most the first 4 KiB; never raises for an unreadable file.

    Args:
        path: the file (or folder) that failed to open as HDF5.
        expected: what the command wanted, for the message.
        then: appended to the import advice (``", then solve it"`` where a results file was wanted).
    """
    path = Path(path)
    out = path.with_suffix(".h5").name if path.suffix.lower() not in ("", ".h5") else f"{path.stem}-imported.h5"
    import_it = f"import it first: ineid data import {path} --robot ROBOT --out {out}{then}"
    if path.is_dir():
        if (path / "metadata.yaml").is_file() or any(path.glob("*.db3")) or any(path.glob("*.mcap")):
            return f"{path} is a ROS 2 bag folder, not {expected}; {import_it}"
        return None
    try:
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError:
        return None
    if head.startswith(_HDF5_SIGNATURE) or not head:
        return None
    if head.startswith(_ROSBAG_MAGIC):
        return f"{path} is a ROS 1 bag, not {expected}; {import_it}"
    if head.startswith(_MCAP_MAGIC):
        return f"{path} is an MCAP recording, not {expected}; {import_it}"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as e:
        if e.start < len(head) - 4:  # not a multi-byte character cut by the 4 KiB
            return None
        text = head[: e.start].decode("utf-8")
    text = text.removeprefix("\ufeff")  # a spreadsheet's byte-order mark
    if "\x00" in text or any(not (c.isprintable() or c in "\t\r\n") for c in text):
        return None
    first = text.splitlines()[0] if text.strip() else ""
    if path.suffix.lower() == ".csv" or first.count(",") >= 1:
        return f"{path} is a CSV recording, not {expected}; {import_it}"
    if path.suffix.lower() in (".h5", ".hdf5", ".hdf"):
        return None  # named as HDF5: a damaged file is the likelier story
    return f"{path} is a text file, not {expected}; a recording is imported with `ineid data import` (CSV, bags){then}"


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def _as_str(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _str_tuple(value) -> tuple[str, ...]:
    return tuple(_as_str(v) for v in np.atleast_1d(value))


def _json_attr(attrs, key: str, where: str):
    try:
        return parse_json(_as_str(attrs[key]))
    except JsonDepthError as e:
        raise DatasetError(f"{where}: attribute {key!r} is JSON {e}; the file is damaged") from None
    except (KeyError, ValueError):
        raise DatasetError(f"{where}: attribute {key!r} is missing or not JSON; the file is damaged") from None


def _number_attr(attrs, key: str, where: str, dtype) -> np.ndarray:
    value = np.asarray(attrs[key])
    if value.dtype.kind not in ("iu" if dtype is np.int64 else "iuf"):
        raise DatasetError(
            f"{where}: attribute {key!r} holds {value.dtype} {value.tolist()!r:.60}, not numbers; the file is damaged"
        )
    return value.astype(dtype)


def _describe_dtype(dtype) -> str:
    return {
        "O": "text (objects)",
        "S": "text (bytes)",
        "U": "text",
        "c": "complex numbers",
        "V": "records",
        "b": "booleans",
        "i": "integers",
        "u": "integers",
    }.get(dtype.kind, str(dtype))


def _array_shapes(f, where: str, meta: DatasetMeta) -> dict[str, tuple[int, ...]]:
    """The shapes of the file's datasets; the arrays ineid reads must be datasets of real numbers.

    A file ineid did not write may hold ``q`` as strings, objects, integers or complex
    numbers: refused here, naming the array, instead of a ``TypeError`` deep in a solver.
    """
    known = expected_shapes(meta, 1, 1)
    shapes = {}
    for name in f:
        obj = f[name]
        if not hasattr(obj, "dtype"):
            if name in known:
                raise DatasetError(
                    f"{where}: {name!r} is a group, not an array; the file is damaged or not an ineid dataset"
                )
            continue
        if name in known:
            want = "iu" if name == "link_set_index" else "f"
            if obj.dtype.kind not in want:
                raise DatasetError(
                    f"{where}: {name} holds {_describe_dtype(obj.dtype)}, expected "
                    f"{'integers' if want == 'iu' else 'floating-point numbers (float64)'}; the file was not written "
                    "by ineid or is damaged: convert the array or regenerate the file"
                )
        shapes[name] = tuple(obj.shape)
    return shapes


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
            gravity=_number_attr(attrs, "gravity", where, np.float64),
            joint_names=_str_tuple(attrs["joint_names"]),
            link_names=_str_tuple(attrs["link_names"]),
            unknown_links=_str_tuple(attrs["unknown_links"]),
            known_links=_str_tuple(attrs["known_links"]),
            locked_joints=_json_attr(attrs, "locked_joints", where) or {},
            source=_as_str(attrs["source"]),
            seed=int(_number_attr(attrs, "seed", where, np.int64)) if "seed" in attrs else None,
            sampling=_json_attr(attrs, "sampling", where),
            noise=_json_attr(attrs, "noise", where),
            origin=_json_attr(attrs, "origin", where),
            ineid_version=_as_str(attrs.get("ineid_version", "")),
            version=version,
            extra_truth=_extra_truth(attrs, version, where),
            **_channels(attrs, version, where),
        )
    except KeyError as e:
        raise DatasetError(f"{where}: attribute {e.args[0]!r} is missing; the file is damaged") from None
    if order != PARAM_NAMES:
        raise DatasetError(f"{where}: parameter order {list(order)} differs from ineid's {list(PARAM_NAMES)}")
    if meta.gravity.shape != (3,) or not np.all(np.isfinite(meta.gravity)):
        raise DatasetError(f"{where}: gravity must be 3 finite numbers, got {meta.gravity.tolist()}")
    return meta


def _channels(attrs, version: int, where: str) -> dict:
    """The measurement channels' arguments of :class:`DatasetMeta`: version 3 stores their records
    (``channels``); versions 1 and 2 measured one base wrench under ``wrench`` (version 2 with its
    ``sensor`` pose), which is what :class:`DatasetMeta` makes of ``sensor``. Bad records raise
    :class:`DatasetError` naming the file and the record."""
    if version <= 2:
        sensor = _json_attr(attrs, "sensor", where) if version == 2 else None
        if sensor is not None and not isinstance(sensor, dict):
            raise DatasetError(f"{where}: the sensor attribute must be a pose record, got {sensor!r}")
        if sensor is not None:
            _checked(lambda: SensorPose.from_dict(sensor, "sensor"), where)
        return {"sensor": sensor}
    return {"channels": _checked(lambda: ChannelSet.from_list(_json_attr(attrs, "channels", where), "channels"), where)}


def _extra_truth(attrs, version: int, where: str) -> dict[str, float] | None:
    """Version 4: the simulated extra parameters ``{name: value}`` (JSON, ``null`` or absent: none)."""
    if version < 4 or "extra_truth" not in attrs:
        return None
    return _checked(lambda: check_extra_truth(_json_attr(attrs, "extra_truth", where), "extra_truth"), where)


def _checked(build, where: str):
    try:
        return build()
    except DatasetError as e:
        raise DatasetError(f"{where}: {e}") from None


def read_meta(path: str | Path) -> tuple[DatasetMeta, dict[str, tuple[int, ...]]]:
    """The attributes of a dataset file and the shapes of its arrays, without the data.

    Logged at DEBUG only: the INFO line ``read PATH: ...`` is :func:`load_dataset`'s, once per
    read of the data (a command that checks the header first does not log the file twice).
    """
    path = Path(path)
    with _open(path) as f:
        meta = _read_meta(f, str(path))
        shapes = _array_shapes(f, str(path), meta)
        check_shapes(meta, shapes, str(path))
        for name in ("q", "qd", "qdd", *meta.channels.keys, "theta_known"):
            if name not in shapes:
                raise DatasetError(f"{path}: dataset {name!r} is missing; the file is damaged")
        if meta.source == "synthetic" and "theta_unknown" not in shapes:
            raise DatasetError(f"{path}: a synthetic dataset without theta_unknown; the file is damaged")
    log.debug(
        "read the header of %s: %s dataset of %s, %d x %d frames", path, meta.source, meta.robot, *shapes["q"][:2]
    )
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


def load_dataset(path: str | Path, configs=None, frames=None, clean: bool = True) -> Dataset:
    """Read a dataset file, checking format, version, shapes and finite values.

    Args:
        path: the file.
        configs: which configurations (slice, index array, boolean mask; default all).
        frames: which frames of each (default all).
        clean: also read the noise-free copies of noisy arrays (``Dataset.clean``); False
            skips them (identification and training never read them).

    Raises:
        DatasetError: naming what is wrong (not HDF5, truncated, another format, a newer
            version, a missing or misshapen array, NaN or infinite values).
    """
    path = Path(path)
    meta, shapes = read_meta(path)
    n_configs, n_frames = shapes["q"][:2]
    cidx = _index(configs, n_configs, "configuration")
    fidx = _index(frames, n_frames, "frame")
    every_frame = np.array_equal(fidx, np.arange(n_frames))  # no copy of the arrays to take them all
    where = str(path)
    wanted = [k for k in shapes if k in expected_shapes(meta, 1, 1) and (clean or not k.endswith("_clean"))]
    per_config = sum(int(np.prod(shapes[k][1:])) for k in wanted if k != "theta_known")
    require_memory(
        per_config * len(cidx) * 8, f"reading {len(cidx):,} configurations of {path}", "select fewer (--select)"
    )
    out: dict[str, np.ndarray] = {}
    with _open(path) as f:
        for name in shapes:
            if name not in expected_shapes(meta, 1, 1) or (not clean and name.endswith("_clean")):
                continue
            dset = f[name]
            try:
                if name == "theta_known":
                    arr = dset[()]
                else:
                    arr = _read_rows(dset, cidx)
                    if (arr.ndim == 3 or name == "time") and not every_frame:
                        arr = arr[:, fidx]
            except (OSError, ValueError) as e:
                raise DatasetError(
                    f"{where}: dataset {name!r} cannot be read ({_first_line(e)}); the file is truncated or corrupt"
                ) from None
            if name != "link_set_index":
                check_finite(name, arr, where, None if name == "theta_known" else cidx)
            out[name] = np.asarray(arr, dtype=np.int64 if name == "link_set_index" else np.float64)
    clean_arrays = {k: out.pop(f"{k}_clean") for k in meta.measured_keys() if f"{k}_clean" in out}
    log.info(
        "read %s: %s dataset of %s, %d x %d frames%s",
        path,
        meta.source,
        meta.robot,
        n_configs,
        n_frames,
        "" if (len(cidx), len(fidx)) == (n_configs, n_frames) else f" ({len(cidx)} x {len(fidx)} selected)",
    )
    return Dataset(
        meta=meta,
        q=out["q"],
        qd=out["qd"],
        qdd=out["qdd"],
        wrench=out.get("wrench") if "wrench" in meta.channels.keys else None,
        channel_values={k: out[k] for k in meta.channels.keys if k != "wrench"},
        theta_known=out["theta_known"],
        theta_unknown=out.get("theta_unknown"),
        clean=clean_arrays,
        time=out.get("time"),
        link_set_index=out.get("link_set_index"),
        config_index=cidx.astype(np.int64),
        path=path,
    )


def _read_rows(dset, idx: np.ndarray) -> np.ndarray:
    if idx.size == 0:
        return np.empty((0,) + dset.shape[1:], dset.dtype)
    if np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        start, stop = int(idx[0]), int(idx[0]) + idx.size
        if _own_chunks(dset):
            return _read_chunks_parallel(dset, start, stop)
        return dset[start:stop]
    # h5py fancy indexing needs increasing indices; read sorted, then restore the order.
    uniq, inverse = np.unique(idx, return_inverse=True)
    return dset[uniq][inverse]


def _own_chunks(dset) -> bool:
    """Chunked by configurations with shuffle + deflate only (how :mod:`ineid.data.dataset.write` stores arrays)."""
    import h5py

    if dset.chunks is None or tuple(dset.chunks[1:]) != tuple(dset.shape[1:]) or dset.dtype.byteorder == ">":
        return False
    plist = dset.id.get_create_plist()
    pipeline = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    return pipeline == [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE]


def _read_chunks_parallel(dset, start: int, stop: int) -> np.ndarray:
    """``dset[start:stop]``, its chunks read raw and decoded (inflate, unshuffle) on all cores.

    The mirror of :class:`ineid.data.dataset.write.DatasetWriter`: h5py reads the stored bytes (in
    this thread, the only one using it) and a thread pool inflates them (zlib releases the
    GIL), about twice as fast as h5py's one-thread filter pipeline on two cores.
    """
    rows, dtype = dset.chunks[0], dset.dtype
    out = np.empty((stop - start,) + dset.shape[1:], dtype)

    def decode(c0: int, mask: int, raw: bytes) -> None:
        try:
            data = raw if mask & 2 else zlib.decompress(raw)  # bit k set: filter k was skipped
        except zlib.error as e:
            raise ValueError(f"chunk at configuration {c0} does not inflate: {e}") from None
        flat = np.frombuffer(data, np.uint8)
        if not mask & 1:
            flat = flat.reshape(dtype.itemsize, -1).T
        chunk = np.ascontiguousarray(flat).view(dtype).reshape((rows,) + dset.shape[1:])
        lo, hi = max(c0, start), min(c0 + rows, stop)
        out[lo - start : hi - start] = chunk[lo - c0 : hi - c0]

    first = start - start % rows
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        jobs = []
        for c0 in range(first, stop, rows):
            try:
                mask, raw = dset.id.read_direct_chunk((c0,) + (0,) * (dset.ndim - 1))
            except (KeyError, OSError, ValueError):  # a chunk never written (fill value): h5py decides
                lo, hi = max(c0, start), min(c0 + rows, stop)
                out[lo - start : hi - start] = dset[lo:hi]
                continue
            jobs.append(pool.submit(decode, c0, mask, raw))
        for job in jobs:
            job.result()
    return out


def iter_dataset(path: str | Path, name: str, rows: int = 4096):
    """Yield ``(start, block)`` of one per-configuration array, ``rows`` configurations at a time."""
    path = Path(path)
    with _open(path) as f:
        dset = f[name]
        for start in range(0, dset.shape[0], rows):
            try:
                yield start, dset[start : start + rows]
            except OSError as e:
                raise DatasetError(
                    f"{path}: dataset {name!r} cannot be read ({_first_line(e)}); truncated or corrupt"
                ) from None
