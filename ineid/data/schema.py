"""The ineid dataset's schema: an HDF5 file of frames, wrenches and (for synthetic data) the truth.

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

This module holds what a dataset is: its metadata, its arrays' shapes and the checks on
them. Writing is :mod:`ineid.data.write`, reading :mod:`ineid.data.read`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.errors import DatasetError
from ineid.params import N_PARAMS_PER_LINK, full_theta, param_names

if TYPE_CHECKING:
    from ineid.robots import RobotModel

FORMAT = "ineid-dataset"
VERSION = 2
"""Format version this ineid writes and the newest it reads.

Version 2 added the ``sensor`` attribute (the F/T sensor's pose in the base frame); a
version-1 file reads as one whose wrench is in the base frame (``sensor = None``).
"""

STATE_KEYS = ("q", "qd", "qdd")
MEASURED_KEYS = (*STATE_KEYS, "wrench")


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
        sensor: the F/T sensor's pose (:meth:`ineid.sensor.SensorPose.to_dict`); the
            ``wrench`` array is then what the sensor reads, in its frame, moment about its
            origin. ``None``: the wrench is in the base frame, about the base origin.
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
    sensor: dict | None = None
    ineid_version: str = ""
    version: int = VERSION

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def unknown_param_names(self) -> list[str]:
        return param_names(self.unknown_links)

    def sensor_pose(self):
        """The :class:`ineid.sensor.SensorPose` of the wrench, or None for the base frame."""
        from ineid.sensor import SensorPose  # noqa: PLC0415

        return None if self.sensor is None else SensorPose.from_dict(self.sensor)

    def sensor_transform(self) -> np.ndarray | None:
        """``X`` (6, 6) with ``wrench = X @ base wrench`` (:func:`ineid.sensor.wrench_transform`), or None."""
        pose = self.sensor_pose()
        return None if pose is None or pose.is_identity else pose.transform()

    @classmethod
    def for_model(cls, model: RobotModel, **kwargs) -> DatasetMeta:
        """The metadata of a dataset of ``model`` (a :class:`ineid.RobotModel`)."""
        from ineid._version import __version__  # noqa: PLC0415

        return cls(
            robot=model.name,
            urdf=model.urdf_text,
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
    """A dataset in memory: NumPy arrays, shapes as in the module table.

    Every array is float64 except the integer indices ``link_set_index`` and
    ``config_index`` (int64). ``config_index`` holds each configuration's index in the file
    it came from, so results on a selection can be traced back.
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
    path: Path | None = None
    """The file the dataset was read from (None when made in memory)."""

    def __post_init__(self) -> None:
        if self.config_index is None:
            self.config_index = np.arange(self.q.shape[0], dtype=np.int64)
        check_shapes(self.meta, {k: v.shape for k, v in self.arrays().items()}, "dataset")

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

    def require_truth(self, purpose: str) -> np.ndarray:
        """``theta_unknown``, or :class:`DatasetError` saying that ``purpose`` needs it.

        A recording (``meta.source == "recording"``) has no truth: its unknown links'
        parameters are what identification is for.
        """
        if self.theta_unknown is None:
            raise DatasetError(
                f"{purpose} needs the true parameters, and this dataset is a recording (measured, truth unknown); "
                "use a synthetic dataset from `ineid data generate`"
            )
        return self.theta_unknown

    def theta(self) -> np.ndarray:
        """(n_configs, 10 * n_links): every link's parameters in chain order (needs the truth)."""
        return assemble_theta(self.meta, self.require_truth("the full parameter vector"), self.theta_known)

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
            path=self.path,
        )

    def fingerprint(self) -> str:
        """16 hex digits identifying the content: robot, URDF, sizes, seed, sampling, noise.

        A recording (no seed) adds a digest of its wrenches, its numbers being its identity.
        Results and training runs record it, so their dataset can be recognized later.
        """
        import hashlib  # noqa: PLC0415
        import json  # noqa: PLC0415

        m = self.meta
        key = json.dumps([m.robot, m.urdf, list(m.unknown_links), np.asarray(m.gravity).tolist(), self.n_configs,
                          self.n_frames, m.seed, m.sampling, m.noise, m.source], sort_keys=True, default=str)
        if m.seed is None:
            key += hashlib.sha256(np.ascontiguousarray(self.wrench).tobytes()).hexdigest()
        if m.sensor is not None:  # absent from version-1 keys, so their fingerprints stay
            key += json.dumps(m.sensor, sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def model(self, codegen_dir: str | Path | None = None) -> RobotModel:
        """The :class:`ineid.RobotModel` this dataset was made with (gravity, unknown links)."""
        return model_from_meta(self.meta, codegen_dir)

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the dataset to ``path`` atomically; see :func:`ineid.data.write.save_dataset`."""
        from ineid.data.write import save_dataset  # noqa: PLC0415

        return save_dataset(self, path, overwrite=overwrite)

def assemble_theta(meta: DatasetMeta, theta_unknown: np.ndarray, theta_known: np.ndarray) -> np.ndarray:
    """Stack unknown (..., 10 n_unknown) and known (10 n_known,) parameters in chain order (:func:`ineid.params.full_theta`)."""
    return full_theta(meta.link_names, meta.unknown_links, theta_unknown, theta_known)


def model_from_meta(meta: DatasetMeta, codegen_dir: str | Path | None = None) -> RobotModel:
    """Rebuild the robot model of a dataset from the URDF text it carries.

    A built-in robot whose URDF is unchanged loads its checked-in code. Any other URDF is
    parsed from the text; its generated code is looked up by kinematic fingerprint and
    derived into the cache only when missing (nothing else is written).
    """
    from ineid.codegen import generated_modules_for, load_robot  # noqa: PLC0415
    from ineid.robots import BUILTIN_ROBOTS, RobotModel  # noqa: PLC0415
    from ineid.robots.urdf import parse_chain  # noqa: PLC0415

    gravity = tuple(float(g) for g in meta.gravity)
    spec = BUILTIN_ROBOTS.get(meta.robot)
    if spec is not None and spec.urdf_path.read_text() == meta.urdf and not meta.locked_joints:
        model = load_robot(meta.robot, unknown_links=list(meta.unknown_links), gravity=gravity)
    else:
        locked = meta.locked_joints or None
        chain = parse_chain(meta.urdf, source=f"the URDF of dataset robot {meta.robot!r}", locked_joints=locked)
        jax_mod, ca_mod = generated_modules_for(chain, chain.name, codegen_dir)
        model = RobotModel(
            chain, None, chain.name, gravity, meta.unknown_links, jax_mod, ca_mod, locked, urdf_text=meta.urdf
        )
    if tuple(model.joint_names) != tuple(meta.joint_names) or tuple(model.link_names) != tuple(meta.link_names):
        raise DatasetError(
            f"the URDF in the dataset gives joints {list(model.joint_names)}, but the file's columns are "
            f"{list(meta.joint_names)}; the file is inconsistent, regenerate it"
        )
    return model


# -- checks ----------------------------------------------------------------------------


def expected_shapes(meta: DatasetMeta, n_configs: int, n_frames: int) -> dict[str, tuple[int, ...]]:
    n_dof, n_u, n_k = meta.n_dof, len(meta.unknown_links), len(meta.known_links)
    shapes = {k: (n_configs, n_frames, n_dof) for k in STATE_KEYS}
    shapes["wrench"] = (n_configs, n_frames, 6)
    shapes.update({f"{k}_clean": shapes[k] for k in MEASURED_KEYS})
    shapes["theta_unknown"] = (n_configs, N_PARAMS_PER_LINK * n_u)
    shapes["theta_known"] = (N_PARAMS_PER_LINK * n_k,)
    shapes["time"] = (n_configs, n_frames)
    shapes["link_set_index"] = (n_configs, n_u)
    return shapes


def check_shapes(meta: DatasetMeta, shapes: Mapping[str, tuple[int, ...]], where: str) -> None:
    """Check array shapes (by dataset name) against the metadata's sizes."""
    if "q" not in shapes:
        raise DatasetError(f"{where}: no 'q' dataset; not an ineid dataset, or a damaged one")
    q = tuple(shapes["q"])
    if len(q) != 3:
        raise DatasetError(f"{where}: q must have shape (n_configs, n_frames, n_dof), got {q}")
    expected = expected_shapes(meta, q[0], q[1])
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
