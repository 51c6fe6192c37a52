"""The ineid dataset's schema: an HDF5 file of frames, wrenches and (for synthetic data) the truth.

The format is documented field by field in ``docs/dataset.md``. In short, a file holds
``n_configs`` configurations (robots with one parameter set each) of ``n_frames`` frames:

========================  ====================================  ================
dataset                   shape                                 unit
========================  ====================================  ================
``q, qd, qdd``            (n_configs, n_frames, n_dof)          rad, rad/s, ...
``wrench``                (n_configs, n_frames, 6)              N, N*m
``<channel key>``         (n_configs, n_frames, n_axes)         the channel's
``theta_unknown``         (n_configs, 10 * n_unknown)           kg, kg*m, kg*m^2
``theta_known``           (10 * n_known,)                       same
``*_clean``               as the noisy array                    same
``time``                  (n_configs, n_frames), optional       s
``link_set_index``        (n_configs, n_unknown), optional      -
========================  ====================================  ================

``wrench`` is the values of the base-wrench channel; every measurement channel of the
file (``meta.channels``, :mod:`ineid.channels`) has its values under its key.

This module holds what a dataset is in memory (:class:`Dataset`); its metadata, format
version and the checks on its arrays' shapes are :mod:`ineid.data.dataset.meta` (re-exported
here). Writing is :mod:`ineid.data.dataset.write`, reading :mod:`ineid.data.dataset.read`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.channels import BaseWrench, ChannelSet
from ineid.data.dataset.meta import (  # noqa: F401  (re-exported: the schema's names)
    FORMAT,
    MEASURED_KEYS,
    STATE_KEYS,
    VERSION,
    DatasetMeta,
    assemble_theta,
    check_finite,
    check_shapes,
    expected_shapes,
    model_from_meta,
)
from ineid.errors import DatasetError

if TYPE_CHECKING:
    from ineid.robots import RobotModel


@dataclass
class Dataset:
    """A dataset in memory: NumPy arrays, shapes as in the module table.

    Every array is float64 except the integer indices ``link_set_index`` and
    ``config_index`` (int64). ``config_index`` holds each configuration's index in the file
    it came from, so results on a selection can be traced back.

    The measurement channels are ``meta.channels``: the values of the one keyed ``wrench``
    (the base wrench) are :attr:`wrench`, those of any other in :attr:`channel_values` by key
    (:attr:`measurements` has them all; :meth:`measured` stacks them).
    """

    meta: DatasetMeta
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    wrench: np.ndarray | None
    theta_known: np.ndarray
    theta_unknown: np.ndarray | None = None
    clean: dict[str, np.ndarray] = field(default_factory=dict)
    time: np.ndarray | None = None
    link_set_index: np.ndarray | None = None
    config_index: np.ndarray | None = None
    path: Path | None = None
    """The file the dataset was read from (None when made in memory)."""
    channel_values: dict[str, np.ndarray] = field(default_factory=dict)
    """Values (n_configs, n_frames, n_axes) of the channels other than ``wrench``, by key."""

    def __post_init__(self) -> None:
        if self.config_index is None:
            self.config_index = np.arange(self.q.shape[0], dtype=np.int64)
        keys = set(self.meta.channels.keys)
        have = set(self.channel_values) | ({"wrench"} if self.wrench is not None else set())
        if "wrench" in self.channel_values:
            raise DatasetError("dataset: the base wrench's values are Dataset.wrench, not channel_values['wrench']")
        if have != keys:
            missing, extra = sorted(keys - have), sorted(have - keys)
            raise DatasetError(
                f"dataset: the channels {', '.join(self.meta.channels.keys)} need values for each; "
                + (f"missing {', '.join(missing)}" if missing else f"no channel {', '.join(extra)}")
            )
        check_shapes(self.meta, {k: v.shape for k, v in self.arrays().items()}, "dataset")

    @property
    def measurements(self) -> dict[str, np.ndarray]:
        """Every channel's values by key, in the channels' order (the arrays themselves, not copies)."""
        return {k: self.wrench if k == "wrench" else self.channel_values[k] for k in self.meta.channels.keys}

    def measured(self, channels=None) -> np.ndarray:
        """The stacked values (n_configs, n_frames, n_axes) of ``channels`` (a :class:`ineid.channels.ChannelSet`
        of this dataset's; default all of them). One channel's are its own array, not a copy."""
        channels = self.meta.channels if channels is None else channels
        return channels.values(self.measurements, self.meta)

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
        out = {"q": self.q, "qd": self.qd, "qdd": self.qdd, **self.measurements, "theta_known": self.theta_known}
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
        c = (
            slice(None)
            if configs is None
            else ([configs] if np.ndim(configs) == 0 and not isinstance(configs, slice) else configs)
        )
        f = (
            slice(None)
            if frames is None
            else ([frames] if np.ndim(frames) == 0 and not isinstance(frames, slice) else frames)
        )

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
            channel_values={k: pick(v) for k, v in self.channel_values.items()},
        )

    def fingerprint(self) -> str:
        """16 hex digits identifying the content: robot, URDF, sizes, seed, sampling, noise.

        A recording (no seed) adds a digest of its wrenches, its numbers being its identity.
        Results and training runs record it, so their dataset can be recognized later. The
        channels count where they are not the single base wrench of versions 1 and 2 (so
        those files keep their fingerprints).
        """
        import hashlib
        import json

        m = self.meta
        key = json.dumps(
            [
                m.robot,
                m.urdf,
                list(m.unknown_links),
                np.asarray(m.gravity).tolist(),
                self.n_configs,
                self.n_frames,
                m.seed,
                m.sampling,
                m.noise,
                m.source,
            ],
            sort_keys=True,
            default=str,
        )
        base_wrench_only = m.channels == ChannelSet.of(BaseWrench(sensor=m.sensor_pose()))
        if m.seed is None:
            for k, v in self.measurements.items():
                key += ("" if base_wrench_only else k) + hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest()
        if m.sensor is not None:  # only with a sensor pose: a dataset in the base frame keeps its fingerprint
            key += json.dumps(m.sensor, sort_keys=True)
        if not base_wrench_only:
            key += json.dumps(m.channels.to_list(), sort_keys=True)
        if m.extra_truth:  # only with simulated actuation: a dataset without keeps its fingerprint
            key += json.dumps(m.extra_truth, sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def model(self, codegen_dir: str | Path | None = None) -> RobotModel:
        """The :class:`ineid.RobotModel` this dataset was made with (gravity, unknown links)."""
        return model_from_meta(self.meta, codegen_dir)

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the dataset to ``path`` atomically; see :func:`ineid.data.dataset.write.save_dataset`."""
        from ineid.data.dataset.write import save_dataset

        return save_dataset(self, path, overwrite=overwrite)
