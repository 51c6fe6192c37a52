"""The results file of ``ineid solve`` (HDF5, documented in ``docs/identification.md``) and
its error summaries."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_write, check_output_file
from ineid._faults import require_disk
from ineid._inputs import parse_json, regular_file
from ineid.channels import WRENCH_AXES
from ineid.data.dataset.hdf5_audit import audit_hdf5
from ineid.errors import DatasetError
from ineid.identify.identifiability import BaseParameters
from ineid.identify.settings import SolveSettings
from ineid.identify.solve_results import SolveResults

FORMAT = "ineid-results"
VERSION = 2
"""Results format this ineid writes and the newest it reads. Version 2 records the measurement channels
fitted (``channels``: their records; ``axes``, ``units``: the names and units of the per-axis arrays'
columns, which run over the channels' stacked axes). A version-1 file reads as the base wrench's six axes."""


def save_results(res: SolveResults, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``res`` to ``path`` atomically (temporary file, then rename).

    Raises:
        OutputExistsError: ``path`` exists and ``overwrite`` is off.
        DatasetError: ``path`` is a folder or its folder does not exist.
        StorageError: the file will not fit on its disk (its size is known before the write).
        OSError: the file system refused the write (read-only, permissions); no file is left.
    """
    import h5py

    path = check_output_file(path, overwrite, "results.h5")
    text = h5py.string_dtype()
    # Built in memory, then written by Python: HDF5 writing straight to a disk that fills up
    # fails inside the library's flushes and can crash the interpreter when the file is closed
    # (a segmentation fault); a Python write fails with a plain OSError (ENOSPC) instead.
    with h5py.File(f"{path}.in-memory", "w", driver="core", backing_store=False) as f:
        a = f.attrs
        _write_attributes(a, res, text)
        for name, arr in _arrays(res).items():
            # uncompressed: estimates are noise-like floats (gzip saved ~20% of the size
            # and cost more time than the rest of the write)
            f.create_dataset(name, data=np.asarray(arr))
        f.create_dataset("status", data=np.array([str(s) for s in res.status], dtype=text))
        if res.payload:  # datasets payload/<k>/<quantity>, k indexing the attribute payload_links (names are data)
            a["payload_links"] = np.array(list(res.payload), dtype=text)
            for k, quantities in enumerate(res.payload.values()):
                for key, value in quantities.items():
                    f.create_dataset(f"payload/{k}/{key}", data=np.asarray(value, dtype=np.float64))
        f.flush()
        image = f.id.get_file_image()
    require_disk(path, len(image), "the results file", "solve fewer configurations (--select)")
    atomic_write(path, image)
    return path


def _write_attributes(a, res: SolveResults, text) -> None:
    """The file's attributes (``a``): its format, the settings, the parameters' names, what it records of the
    dataset and the channels, the joint inputs and the validation, the plausibility findings."""
    from ineid._version import __version__

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
    a["channels"] = json.dumps(res.meta.get("channels"), sort_keys=True)
    a["axes"] = np.array(res.axes, dtype=text)
    a["units"] = np.array(res.units, dtype=text)
    for key in ("recordings", "validation", "std", "notes"):  # joint recordings, a validation, the std's source, notes
        if res.meta.get(key) is not None:
            a[key] = json.dumps(res.meta[key], sort_keys=True)
    if res.meta.get("warnings") is not None:  # plausibility findings ({code, message}) of ineid solve
        a["warnings"] = json.dumps(list(res.meta["warnings"]))


def _arrays(res: SolveResults) -> dict[str, np.ndarray]:
    """The file's datasets of numbers, by name (the offsets and the truth where ``res`` has them)."""
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
    return arrays


def load_results(path: str | Path) -> SolveResults:
    """Read a results file written by :func:`save_results`, checking its format.

    Raises:
        DatasetError: not a readable HDF5 file (truncated, corrupt), another format or a
            newer version, or a damaged one: an attribute or dataset missing, of the wrong
            type or shape (named, with the fix).
    """
    import h5py

    from ineid._faults import fault_errno

    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    regular_file(path, "the results file")  # a FIFO is never opened
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        if fault_errno(e) is not None:
            raise  # permission denied and the like: the CLI words it
        from ineid.data.dataset.read import foreign_file

        raise DatasetError(
            foreign_file(path, "an ineid results file", ", then solve it (ineid solve)")
            or f"{path} is not a readable HDF5 file ({str(e).splitlines()[0]}); truncated or corrupt"
        ) from None
    with f:
        audit_hdf5(f, path)
        fmt = _attr_text(f.attrs.get("format", ""))
        if fmt != FORMAT:
            hint = " (it is a dataset: run `ineid solve` on it)" if fmt == "ineid-dataset" else ""
            raise DatasetError(f"{path}: not an ineid results file (format {fmt or 'missing'!r}){hint}")
        r = _Reader(f, path)
        version = r.integer("version")
        if version > VERSION:
            raise DatasetError(f"{path}: results format version {version} is newer; upgrade ineid")
        return r.results()


def _attr_text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


class _Reader:
    """Reads one results file, every attribute and dataset checked; a problem is one :class:`DatasetError`."""

    def __init__(self, f, path: Path) -> None:
        self.f, self.path = f, path

    def damaged(self, what: str) -> DatasetError:
        return DatasetError(
            f"{self.path}: {what}; the results file is damaged: solve again (ineid solve ... --overwrite) or restore it"
        )

    def attr(self, key: str):
        if key not in self.f.attrs:
            raise self.damaged(f"attribute {key!r} is missing")
        try:
            return self.f.attrs[key]
        except (OSError, KeyError, ValueError, TypeError) as e:
            raise self.damaged(f"attribute {key!r} cannot be read ({e})") from None

    def text(self, key: str) -> str:
        value = self.attr(key)
        if not isinstance(value, (str, bytes)):
            raise self.damaged(f"attribute {key!r} is not text")
        return _attr_text(value)

    def texts(self, key: str) -> tuple[str, ...]:
        value = np.atleast_1d(self.attr(key))
        if value.ndim != 1 or value.dtype.kind not in "OSU":
            raise self.damaged(f"attribute {key!r} is not a list of names")
        return tuple(_attr_text(v) for v in value)

    def integer(self, key: str) -> int:
        value = self.attr(key)
        if np.ndim(value) or np.asarray(value).dtype.kind not in "iu":
            raise self.damaged(f"attribute {key!r} is not an integer")
        return int(value)

    def number(self, key: str) -> float:
        try:
            return float(self.attr(key))
        except (TypeError, ValueError):
            raise self.damaged(f"attribute {key!r} is not a number") from None

    def json(self, key: str):
        try:
            return parse_json(self.text(key))
        except json.JSONDecodeError as e:
            raise self.damaged(f"attribute {key!r} is not JSON ({e.msg})") from None
        except ValueError as e:  # nested too deep, too long
            raise self.damaged(f"attribute {key!r} is JSON {e}") from None

    def array(self, key: str, shape: tuple, kind: str = "f", required: bool = True):
        """Dataset ``key`` of ``shape`` (None: any length), numbers of ``kind`` ("f": float64 of any real)."""
        if key not in self.f:
            if required:
                raise self.damaged(f"dataset {key!r} is missing")
            return None
        dset = self.f[key]
        if not hasattr(dset, "dtype"):
            raise self.damaged(f"{key!r} is a group, not a dataset")
        if kind == "O":
            ok = dset.dtype.kind in "OSU"
        else:
            ok = dset.dtype.kind in ("iub" if kind == "i" else "iufb")
        got = tuple(dset.shape)
        if not ok or len(got) != len(shape) or any(e is not None and e != g for e, g in zip(shape, got, strict=True)):
            want = " x ".join("?" if e is None else str(e) for e in shape)
            have = "text" if dset.dtype.kind in "OSU" else str(dset.dtype)
            raise self.damaged(
                f"dataset {key!r} is {have} of shape {got}, expected "
                f"{'text' if kind == 'O' else 'numbers'} of shape ({want})"
            )
        try:
            value = dset[()]
        except (OSError, ValueError) as e:
            raise self.damaged(f"dataset {key!r} cannot be read ({str(e).splitlines()[0]})") from None
        return value if kind == "O" else np.asarray(value, dtype=np.int64 if kind == "i" else np.float64)

    def results(self) -> SolveResults:
        settings = self.settings()
        names = self.texts("param_names")
        base_names = self.texts("base_names")
        p, nb = len(names), len(base_names)
        if not 0 < nb <= p:
            raise self.damaged(f"{nb} base parameters for {p} parameters")
        config_index = self.array("config_index", (None,), "i")
        n = len(config_index)
        base = self.base_parameters(names, base_names)
        prior_shape = (n, p) if "theta_prior" in self.f and self.f["theta_prior"].ndim == 2 else (p,)
        meta = self.meta()
        n_axes = len(meta.get("axes") or WRENCH_AXES)
        status = self.array("status", (n,), "O")
        return SolveResults(
            settings=settings,
            base=base,
            param_names=names,
            config_index=config_index,
            theta_hat=self.array("theta_hat", (n, p)),
            theta_std=self.array("theta_std", (n, p)),
            base_hat=self.array("base_hat", (n, nb)),
            base_std=self.array("base_std", (n, nb)),
            success=self.array("success", (n,), "i").astype(bool),
            status=np.array([_attr_text(s) for s in status], dtype=object),
            seconds=self.array("seconds", (n,)),
            fit_rms=self.array("fit_rms", (n, n_axes)),
            validation_rms=self.array("validation_rms", (n, n_axes)),
            validation_rel=self.array("validation_rel", (n,)),
            n_frames_fit=self.integer("n_frames_fit"),
            n_frames_validation=self.integer("n_frames_validation"),
            theta_prior=self.array("theta_prior", prior_shape),
            theta_true=self.array("theta_true", (n, p), required=False),
            bias_hat=self.array("bias_hat", (n, n_axes), required=False),
            bias_std=self.array("bias_std", (n, n_axes), required=False),
            meta=meta,
            payload=self.payload(n),
        )

    def settings(self) -> SolveSettings:
        """The :class:`SolveSettings` the file was solved with."""
        try:
            return SolveSettings(
                **{
                    k: (tuple(v) if k in ("axis_sigma", "known_uncertainty") and v is not None else v)
                    for k, v in self.json("settings").items()
                }
            )
        except (TypeError, ValueError, AttributeError) as e:
            raise self.damaged(f"its settings do not parse ({e})") from None

    def base_parameters(self, names: tuple[str, ...], base_names: tuple[str, ...]) -> BaseParameters:
        """The :class:`BaseParameters` of the file's parameters ``names``, base parameters ``base_names``."""
        p, nb = len(names), len(base_names)
        base_matrix = self.array("base_matrix", (nb, p))
        base_index = self.array("base_index", (nb,), "i")
        if base_index.size and (base_index.min() < 0 or base_index.max() >= p):
            raise self.damaged("base_index points outside the parameters")
        null = self.array("null_basis", (p, p - nb))
        dep = np.array([j for j in range(p) if j not in set(base_index.tolist())], dtype=np.int64)
        n_links = len(self.texts("unknown_links"))
        if not 0 <= p - 10 * n_links:
            raise self.damaged(f"{p} parameters for {n_links} unknown links")
        return BaseParameters(
            param_names=names,
            base_index=base_index,
            dependent_index=dep,
            K=base_matrix[:, dep],
            B=base_matrix,
            null_basis=null,
            identifiable=~np.any(np.abs(null) > 0, axis=1),
            names=base_names,
            scales=self.array("param_scales", (p,)),
            n_extra=p - 10 * n_links,  # the channels' extra parameters after the links' (older files: none)
        )

    def meta(self) -> dict:
        """What the file records of the dataset, the channels fitted, the joint inputs and the validation."""
        gravity = np.asarray(self.attr("gravity"))
        if gravity.shape != (3,) or gravity.dtype.kind not in "iuf":
            raise self.damaged("attribute 'gravity' is not 3 numbers")
        meta = {
            "robot": self.text("robot"),
            "source": self.text("source"),
            "urdf": self.text("urdf"),
            "unknown_links": list(self.texts("unknown_links")),
            "gravity": gravity.astype(np.float64).tolist(),
            "locked_joints": self.json("locked_joints"),
            "total_seconds": self.number("total_seconds"),
            "ineid_version": self.text("ineid_version"),
            "dataset_path": _attr_text(self.f.attrs.get("dataset_path", "")) or None,
            "dataset_fingerprint": _attr_text(self.f.attrs.get("dataset_fingerprint", "")) or None,
            "sensor": self.json("sensor") if "sensor" in self.f.attrs else None,
            "warnings": _warnings(self.path, self.f.attrs),
            **{k: self.json(k) for k in ("recordings", "validation", "std", "notes") if k in self.f.attrs},
        }
        if "axes" in self.f.attrs:  # version 2: the channels fitted and the per-axis columns' names
            meta.update(channels=self.json("channels"), axes=list(self.texts("axes")), units=list(self.texts("units")))
            if len(meta["units"]) != len(meta["axes"]):
                raise self.damaged(f"{len(meta['axes'])} axes but {len(meta['units'])} units")
        return meta

    def payload(self, n: int) -> dict | None:
        """The ``payload`` section (:mod:`ineid.identify.payload`), or None when the file has none."""
        if "payload_links" not in self.f.attrs:
            return None
        shapes = {
            "mass": (n,),
            "mass_std": (n,),
            "com": (n, 3),
            "com_std": (n, 3),
            "inertia": (n, 6),
            "inertia_std": (n, 6),
        }
        return {
            link: {key: self.array(f"payload/{k}/{key}", shape) for key, shape in shapes.items()}
            for k, link in enumerate(self.texts("payload_links"))
        }


def _warnings(path: Path, attrs) -> list[dict] | None:
    """The plausibility findings a results file records (``warnings``, JSON), or None when it records none."""
    if "warnings" not in attrs:
        return None
    try:
        found = parse_json(attrs["warnings"])
        return [{"code": str(w["code"]), "message": str(w["message"])} for w in found]
    except (TypeError, ValueError, KeyError) as e:
        raise DatasetError(f"{path}: its 'warnings' attribute is damaged ({e}); solve again to rewrite it") from None


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


def error_summary(
    estimate: np.ndarray, truth: np.ndarray, names, success: np.ndarray, identifiable=None
) -> list[ErrorRow]:
    """Median and 95th-percentile relative error, and the shares within 1 % and 5 %."""
    err = relative_error(estimate[success], truth[success])
    rows = []
    for k, name in enumerate(names):
        e = err[:, k]
        e = e[np.isfinite(e)]
        if e.size == 0:
            rows.append(
                ErrorRow(name, np.nan, np.nan, np.nan, np.nan, None if identifiable is None else bool(identifiable[k]))
            )
            continue
        rows.append(
            ErrorRow(
                name,
                float(np.median(e)),
                float(np.percentile(e, 95)),
                float(np.mean(e <= 0.01)),
                float(np.mean(e <= 0.05)),
                None if identifiable is None else bool(identifiable[k]),
            )
        )
    return rows
