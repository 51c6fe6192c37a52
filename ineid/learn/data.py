"""Training data: configuration splits, per-frame features, samples of K frames.

A *sample* is K frames of one configuration; its target is that configuration's unknown
parameters. Features of a frame: ``[q, qd, qdd, wrench]`` (3 n_dof + 6; 18 for the 4-DOF
arm; the values of every measurement channel, stacked, where the dataset has more than
the wrench), scaled by a scaler fitted on the training configurations. During training each
epoch regroups every configuration's frames at random into disjoint groups of K (seeded
by ``(seed, epoch)``, so a resumed run sees the same groups); evaluation uses the fixed
groups ``[0, K), [K, 2K), ...``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.errors import DatasetError


@dataclass(frozen=True)
class Split:
    """Configuration indices (into the dataset) of the train, validation and test sets."""

    train: np.ndarray
    val: np.ndarray
    test: np.ndarray

    def to_dict(self) -> dict:
        return {k: getattr(self, k).tolist() for k in ("train", "val", "test")}

    @classmethod
    def from_dict(cls, d: dict) -> Split:
        return cls(*(np.asarray(d[k], dtype=np.int64) for k in ("train", "val", "test")))


def split_configs(n_configs: int, n_train: int | None, n_val: int | None, n_test: int | None, seed: int) -> Split:
    """Disjoint random train / validation / test sets of configurations (seeded).

    Defaults: 70 % train, 15 % validation, the rest test; ``n_test`` limits the test set.
    """
    n_train = int(0.7 * n_configs) if n_train is None else int(n_train)
    n_val = max(1, int(0.15 * n_configs)) if n_val is None else int(n_val)
    rest = n_configs - n_train - n_val
    n_test = rest if n_test is None else int(n_test)
    if n_train < 1 or n_val < 1 or n_test < 1 or n_train + n_val + n_test > n_configs:
        raise DatasetError(
            f"cannot split {n_configs} configurations into {n_train} train, {n_val} validation and {max(n_test, 0)} "
            "test (each needs at least one, no configuration in two sets); use a bigger dataset or smaller splits"
        )
    perm = np.random.default_rng(np.random.SeedSequence([int(seed), 11])).permutation(n_configs)
    return Split(
        np.sort(perm[:n_train]),
        np.sort(perm[n_train : n_train + n_val]),
        np.sort(perm[n_train + n_val : n_train + n_val + n_test]),
    )


def frame_features(ds) -> np.ndarray:
    """(C, F, 3 n_dof + A) raw features ``[q, qd, qdd, values]`` of every frame (the channels' values stacked:
    the base wrench, ``A = 6``)."""
    return np.concatenate([ds.q, ds.qd, ds.qdd, ds.measured()], axis=-1)


def epoch_groups(n_configs: int, n_frames: int, k: int, seed: int, epoch: int) -> tuple[np.ndarray, np.ndarray]:
    """Random disjoint groups of ``k`` frames per configuration, shuffled across configurations.

    Returns:
        ``(config (S,), frames (S, k))`` with ``S = n_configs * (n_frames // k)``; positions
        into the arrays of the set (not dataset indices).
    """
    g = n_frames // k
    if g < 1:
        raise DatasetError(f"{k} frames per sample but the dataset has {n_frames} frames per configuration")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 12, int(epoch)]))
    frames = np.argsort(rng.random((n_configs, n_frames)), axis=1)[:, : g * k].reshape(n_configs * g, k)
    configs = np.repeat(np.arange(n_configs), g)
    order = rng.permutation(len(configs))
    return configs[order], frames[order]


def fixed_groups(n_configs: int, n_frames: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The evaluation groups ``[0, k), [k, 2k), ...`` of every configuration, in order."""
    g = n_frames // k
    if g < 1:
        raise DatasetError(f"{k} frames per sample but the dataset has {n_frames} frames per configuration")
    frames = np.tile(np.arange(g * k).reshape(g, k), (n_configs, 1))
    return np.repeat(np.arange(n_configs), g), frames
