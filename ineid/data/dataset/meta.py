"""A dataset's metadata (the HDF5 attributes), its format version, and the checks on its arrays' shapes.

The arrays themselves, in memory, are :class:`ineid.data.dataset.schema.Dataset`; the format is
documented field by field in ``docs/dataset.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import InitVar, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.channels import BaseWrench, ChannelSet, SensorPose
from ineid.errors import DatasetError
from ineid.params import N_PARAMS_PER_LINK, full_theta, param_names

if TYPE_CHECKING:
    from ineid.robots import RobotModel

FORMAT = "ineid-dataset"
VERSION = 4
"""Format version this ineid writes and the newest it reads.

Version 4 adds the simulated truth of the channels' extra parameters (``extra_truth``: joint
friction, armature, torque offsets by name) and the channels beyond the base wrench (joint torques,
motor currents, a wrench at a link), with each channel's noise under its key in ``noise``; it
reads as version 3 otherwise. Version 3 stores the measurement channels: the ``channels`` attribute holds one record per
channel (:meth:`ineid.channels.ChannelSet.to_list`), and each channel's values are the
dataset named by its key (the base wrench: ``wrench``). Version 2 added the ``sensor``
attribute (the F/T sensor's pose in the base frame). A version-1 or version-2 file reads as
one base-wrench channel under ``wrench``, in the base frame (version 1) or its ``sensor``'s.
"""

STATE_KEYS = ("q", "qd", "qdd")
MEASURED_KEYS = (*STATE_KEYS, "wrench")
"""The measured arrays of a file with the default channel (:meth:`DatasetMeta.measured_keys` in general)."""


class _Unset:
    def __repr__(self) -> str:
        return "<from the channels>"


_UNSET = _Unset()


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
        channels: the measurement channels (:class:`ineid.channels.ChannelSet`; a list of
            their records is accepted too); default: one base wrench under ``wrench``.
        sensor: init-only, the short way to say where the base wrench is measured: the
            F/T sensor's pose (:meth:`ineid.channels.SensorPose.to_dict`) given to the
            channel ``wrench`` (the wrench is then what the sensor reads, in its frame,
            moment about its origin; ``None``: the base frame, about the base origin).
            Reading ``meta.sensor`` gives that channel's pose record (None for the base frame).
            ``dataclasses.replace`` passes it on, so ``replace(meta, sensor=...)`` moves the base
            wrench; to change the channels use :meth:`with_channels`.
        ineid_version: the ineid that wrote the file.
        version: the format version.
        extra_truth: synthetic data: the simulated values of the channels' extra kept
            parameters ``{name: value}`` (``"<joint>.fv"``, ..., the names of
            :meth:`ineid.channels.Channel.extra_names`; SI units), so solvers can report
            their errors; None when nothing beyond the links was simulated (and for recordings).
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
    sensor: InitVar[dict | None] = _UNSET
    ineid_version: str = ""
    version: int = VERSION
    channels: ChannelSet | None = None
    extra_truth: dict[str, float] | None = None

    def __post_init__(self, sensor) -> None:
        if self.extra_truth is not None:
            self.extra_truth = check_extra_truth(self.extra_truth, "dataset extra_truth")
        channels = self.channels
        if channels is not None and not isinstance(channels, ChannelSet):
            channels = ChannelSet.from_list(channels, "dataset channels")
        if sensor is not _UNSET and sensor is not None and not isinstance(sensor, Mapping):
            raise DatasetError(f"dataset sensor: expected a pose record (SensorPose.to_dict()) or None, got {sensor!r}")
        pose = None if sensor is _UNSET or sensor is None else SensorPose.from_dict(sensor, "dataset sensor")
        if channels is None:
            channels = ChannelSet.of(BaseWrench(sensor=pose))
        elif sensor is not _UNSET:  # a pose given beside the channels: it is the base wrench's
            wrench = channels.get("wrench")
            if isinstance(wrench, BaseWrench):
                channels = channels.replace(wrench.with_sensor(pose))
            elif pose is not None:
                raise DatasetError("dataset sensor: a sensor pose but no base-wrench channel 'wrench' to give it to")
        self.channels = channels
        self._sensor = None if sensor is _UNSET else sensor

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    def with_channels(self, channels: ChannelSet) -> DatasetMeta:
        """A copy measuring ``channels`` (their own poses: a ``sensor`` given at construction is not carried over)."""
        import dataclasses

        return dataclasses.replace(self, channels=channels, sensor=_UNSET)

    def measured_keys(self) -> tuple[str, ...]:
        """The measured arrays: ``q, qd, qdd`` and every channel's values (their noise-free copies are ``*_clean``)."""
        return (*STATE_KEYS, *self.channels.keys)

    @property
    def unknown_param_names(self) -> list[str]:
        return param_names(self.unknown_links)

    def sensor_pose(self) -> SensorPose | None:
        """The :class:`ineid.channels.SensorPose` of the base wrench ``wrench``, or None for the base frame."""
        wrench = self.channels.get("wrench")
        return wrench.sensor if isinstance(wrench, BaseWrench) else None

    def sensor_transform(self) -> np.ndarray | None:
        """``X`` (6, 6) with ``wrench = X @ base wrench`` (:func:`ineid.channels.wrench_transform`), or None."""
        wrench = self.channels.get("wrench")
        return wrench.transform() if isinstance(wrench, BaseWrench) else None

    @classmethod
    def for_model(cls, model: RobotModel, **kwargs) -> DatasetMeta:
        """The metadata of a dataset of ``model`` (a :class:`ineid.RobotModel`)."""
        from ineid._version import __version__

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


def check_extra_truth(values, where: str) -> dict[str, float] | None:
    """``{name: value}`` of finite numbers (an empty one is None), else :class:`DatasetError` naming ``where``."""
    if values is None:
        return None
    if not isinstance(values, Mapping):
        raise DatasetError(
            f"{where}: expected a record {{name: value}} of the simulated extra parameters, got {values!r:.80}"
        )
    out = {}
    for name, value in values.items():
        ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
        if not isinstance(name, str) or not name or not ok or not np.isfinite(value):
            raise DatasetError(f"{where}: {name!r} = {value!r} is not a named finite number; the file is damaged")
        out[name] = float(value)
    return out or None


def _sensor_record(meta: DatasetMeta) -> dict | None:
    """``meta.sensor``: the pose record given at construction, else the base wrench channel's (None: base frame)."""
    pose = meta.sensor_pose()
    if pose is None:
        return None
    given = meta._sensor  # the caller's own record (keeps its numbers as written: fingerprints)
    return given if given is not None and SensorPose.from_dict(given) == pose else pose.to_dict()


# ``sensor`` is an init-only argument of the dataclass (so ``dataclasses.replace(meta, sensor=...)``
# moves the base wrench and ``replace(meta, channels=...)`` does not undo it) and a read-only
# property of the instances: set after the decorator made ``__init__``.
DatasetMeta.sensor = property(_sensor_record, doc=_sensor_record.__doc__)  # type: ignore[assignment]


def assemble_theta(meta: DatasetMeta, theta_unknown: np.ndarray, theta_known: np.ndarray) -> np.ndarray:
    """Stack unknown (..., 10 n_unknown) and known (10 n_known,) parameters in chain order
    (:func:`ineid.params.full_theta`)."""
    return full_theta(meta.link_names, meta.unknown_links, theta_unknown, theta_known)


def model_from_meta(meta: DatasetMeta, codegen_dir: str | Path | None = None) -> RobotModel:
    """Rebuild the robot model of a dataset from the URDF text it carries.

    A built-in robot whose URDF is unchanged loads its checked-in code. Any other URDF is
    parsed from the text; its generated code is looked up by kinematic fingerprint and
    derived into the cache only when missing (nothing else is written).
    """
    from ineid.robots import BUILTIN_ROBOTS, RobotModel
    from ineid.robots.codegen import generated_modules_for
    from ineid.robots.load import load_robot
    from ineid.robots.urdf import parse_chain

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
    for c in meta.channels:
        shapes[c.key] = (n_configs, n_frames, c.n_axes(meta))
    shapes.update({f"{k}_clean": shapes[k] for k in meta.measured_keys()})
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
