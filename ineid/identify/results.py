"""The results file of ``ineid solve`` (HDF5, documented in ``docs/identification.md``) and
its error summaries."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_write, check_output
from ineid._faults import require_disk
from ineid.errors import DatasetError
from ineid.identify.identifiability import BaseParameters
from ineid.identify.solve import SolveResults, SolveSettings

FORMAT = "ineid-results"
VERSION = 1


def save_results(res: SolveResults, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``res`` to ``path`` atomically (temporary file, then rename).

    Raises:
        OutputExistsError: ``path`` exists and ``overwrite`` is off.
        DatasetError: ``path`` is a folder or its folder does not exist.
        StorageError: the file will not fit on its disk (its size is known before the write).
        OSError: the file system refused the write (read-only, permissions); no file is left.
    """
    import h5py  # noqa: PLC0415

    from ineid import __version__  # noqa: PLC0415

    path = Path(path)
    if path.is_dir():
        raise DatasetError(f"{path} is a folder; give a file name such as results.h5")
    check_output(path, overwrite)
    if not path.parent.is_dir():
        raise DatasetError(f"folder {path.parent} does not exist; create it first")
    text = h5py.string_dtype()
    # Built in memory, then written by Python: HDF5 writing straight to a disk that fills up
    # fails inside the library's flushes and can crash the interpreter when the file is closed
    # (a segmentation fault); a Python write fails with a plain OSError (ENOSPC) instead.
    with h5py.File(f"{path}.in-memory", "w", driver="core", backing_store=False) as f:
        a = f.attrs
        a["format"], a["version"] = FORMAT, VERSION
        a["method"] = res.settings.method
        a["settings"] = json.dumps(res.settings.to_dict(), sort_keys=True)
        a["ineid_version"] = __version__
        a["param_names"] = np.array(res.param_names, dtype=text)
        a["base_names"] = np.array(res.base.names, dtype=text)
        a["n_frames_fit"], a["n_frames_validation"] = res.n_frames_fit, res.n_frames_validation
        for key in ("robot", "source", "urdf"):
            a[key] = res.meta[key]
        a["unknown_links"] = np.array(res.meta["unknown_links"], dtype=text)
        a["gravity"] = np.asarray(res.meta["gravity"], dtype=np.float64)
        a["locked_joints"] = json.dumps(res.meta.get("locked_joints") or {}, sort_keys=True)
        a["total_seconds"] = float(res.meta.get("total_seconds", np.nan))
        a["dataset_path"] = str(res.meta.get("dataset_path") or "")
        a["dataset_fingerprint"] = str(res.meta.get("dataset_fingerprint") or "")
        a["sensor"] = json.dumps(res.meta.get("sensor"), sort_keys=True)
        arrays = {
            "config_index": res.config_index,
            "theta_hat": res.theta_hat,
            "theta_std": res.theta_std,
            "base_hat": res.base_hat,
            "base_std": res.base_std,
            "base_matrix": res.base.B,
            "base_index": res.base.base_index,
            "null_basis": res.base.null_basis,
            "param_scales": res.base.scales,
            "theta_prior": res.theta_prior,
            "success": res.success.astype(np.uint8),
            "seconds": res.seconds,
            "fit_rms": res.fit_rms,
            "validation_rms": res.validation_rms,
            "validation_rel": res.validation_rel,
        }
        if res.bias_hat is not None:
            arrays["bias_hat"], arrays["bias_std"] = res.bias_hat, res.bias_std
        if res.theta_true is not None:
            arrays["theta_true"] = res.theta_true
            arrays["base_true"] = res.base_true
            arrays["theta_error"] = relative_error(res.theta_hat, res.theta_true)
            arrays["base_error"] = relative_error(res.base_hat, res.base_true)
        for name, arr in arrays.items():
            # uncompressed: estimates are noise-like floats (gzip saved ~20% of the size
            # and cost more time than the rest of the write)
            f.create_dataset(name, data=np.asarray(arr))
        f.create_dataset("status", data=np.array([str(s) for s in res.status], dtype=text))
        f.flush()
        image = f.id.get_file_image()
    require_disk(path, len(image), "the results file", "solve fewer configurations (--select)")
    atomic_write(path, image)
    return path


def load_results(path: str | Path) -> SolveResults:
    """Read a results file written by :func:`save_results`, checking its format."""
    import h5py  # noqa: PLC0415

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DatasetError(f"{path} is not a readable HDF5 file ({str(e).splitlines()[0]}); truncated or corrupt") from None
    with f:
        fmt = f.attrs.get("format", "")
        if fmt != FORMAT:
            hint = " (it is a dataset: run `ineid solve` on it)" if fmt == "ineid-dataset" else ""
            raise DatasetError(f"{path}: not an ineid results file (format {fmt or 'missing'!r}){hint}")
        if int(f.attrs["version"]) > VERSION:
            raise DatasetError(f"{path}: results format version {int(f.attrs['version'])} is newer; upgrade ineid")
        a = f.attrs
        names = tuple(str(s) for s in a["param_names"])
        settings = SolveSettings(**{k: (tuple(v) if k == "axis_sigma" and v is not None else v)
                                    for k, v in json.loads(a["settings"]).items()})
        base_matrix = f["base_matrix"][()]
        base_index = f["base_index"][()]
        null = f["null_basis"][()]
        dep = np.array([j for j in range(len(names)) if j not in set(base_index.tolist())], dtype=np.int64)
        base = BaseParameters(
            param_names=names,
            base_index=base_index,
            dependent_index=dep,
            K=base_matrix[:, dep],
            B=base_matrix,
            null_basis=null,
            identifiable=~np.any(np.abs(null) > 0, axis=1),
            names=tuple(str(s) for s in a["base_names"]),
            scales=f["param_scales"][()],
        )
        get = lambda k: f[k][()] if k in f else None  # noqa: E731
        meta = {
            "robot": str(a["robot"]),
            "source": str(a["source"]),
            "urdf": str(a["urdf"]),
            "unknown_links": [str(s) for s in a["unknown_links"]],
            "gravity": a["gravity"].tolist(),
            "locked_joints": json.loads(a["locked_joints"]),
            "total_seconds": float(a["total_seconds"]),
            "ineid_version": str(a["ineid_version"]),
            "dataset_path": str(a.get("dataset_path", "")) or None,
            "dataset_fingerprint": str(a.get("dataset_fingerprint", "")) or None,
            "sensor": json.loads(a["sensor"]) if "sensor" in a else None,
        }
        return SolveResults(
            settings=settings,
            base=base,
            param_names=names,
            config_index=get("config_index"),
            theta_hat=get("theta_hat"),
            theta_std=get("theta_std"),
            base_hat=get("base_hat"),
            base_std=get("base_std"),
            success=get("success").astype(bool),
            status=np.array([s.decode() if isinstance(s, bytes) else str(s) for s in f["status"][()]], dtype=object),
            seconds=get("seconds"),
            fit_rms=get("fit_rms"),
            validation_rms=get("validation_rms"),
            validation_rel=get("validation_rel"),
            n_frames_fit=int(a["n_frames_fit"]),
            n_frames_validation=int(a["n_frames_validation"]),
            theta_prior=get("theta_prior"),
            theta_true=get("theta_true"),
            bias_hat=get("bias_hat"),
            bias_std=get("bias_std"),
            meta=meta,
        )


def relative_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``|estimate - truth| / |truth|`` elementwise (the paper's measure; NaN where failed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(np.asarray(estimate) - truth) / np.abs(truth)


@dataclass(frozen=True)
class ErrorRow:
    """Relative-error statistics of one parameter over the successful configurations."""

    name: str
    median: float
    p95: float
    within_1: float
    within_5: float
    identifiable: bool | None = None


def error_summary(estimate: np.ndarray, truth: np.ndarray, names, success: np.ndarray, identifiable=None) -> list[ErrorRow]:
    """Median and 95th-percentile relative error, and the shares within 1 % and 5 %."""
    err = relative_error(estimate[success], truth[success])
    rows = []
    for k, name in enumerate(names):
        e = err[:, k]
        e = e[np.isfinite(e)]
        if e.size == 0:
            rows.append(ErrorRow(name, np.nan, np.nan, np.nan, np.nan, None if identifiable is None else bool(identifiable[k])))
            continue
        rows.append(ErrorRow(
            name,
            float(np.median(e)),
            float(np.percentile(e, 95)),
            float(np.mean(e <= 0.01)),
            float(np.mean(e <= 0.05)),
            None if identifiable is None else bool(identifiable[k]),
        ))  # fmt: skip
    return rows
