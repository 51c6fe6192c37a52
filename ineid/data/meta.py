"""A dataset's metadata (the HDF5 attributes), its format version, and the checks on its arrays' shapes.

The arrays themselves, in memory, are :class:`ineid.data.schema.Dataset`; the format is
documented field by field in ``docs/dataset.md``.
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
