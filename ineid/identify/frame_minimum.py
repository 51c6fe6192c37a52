"""The fewest frames that can determine the base parameters, from the structure of the regressor.

Counting equations says ``A F >= r`` (``A`` axes a frame, ``r`` base parameters, plus one per
identified offset): for the built-in arm with links 3 and 4 unknown, ``6 F >= 17``, so 3 frames.
But 3 generic frames give rank 15, not 17: the force rows of the base wrench (``F = sum_i m_i
a_ci``) involve only the links' masses and first moments, and over every motion they span only
6 of the 17 identifiable directions, so however many force rows there are, they give at most 6;
the moment rows give at most ``3 F``, and ``6 + 3 F >= 17`` needs ``F = 4``. The paper needs "at
least four" frames too, but counting 20 unknowns against 6 equations a frame.

So the minimum is found, not counted: the rank of the stacked regressor of the first ``F`` of a
set of generic frames (:func:`ineid.identify.identifiability.frame_minimum`), ``F = 1, 2, ...``
until it reaches ``r``. Generic frames reach the structural rank of any ``F`` frames (a rank of a
matrix polynomial in the states is its generic rank almost everywhere), so that ``F`` is the
smallest any frames can do. The reason, when it differs from counting, is a group of axes (one
channel's axes of one unit: the forces, the moments) whose rows span fewer directions than their
count: the bound ``rank(F frames) <= sum_g min(|g| F, rank_g)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.errors import IdentificationError
from ineid.identify.settings import HOLDOUT_FRACTION

RANK_RTOL = 1e-9
"""Singular values below this fraction of the largest count as zero (scaled regressor)."""


def numerical_rank(singular_values: np.ndarray, rtol: float = RANK_RTOL) -> int:
    """The number of singular values above ``rtol`` times the largest."""
    s = np.asarray(singular_values)
    return int(np.sum(s > rtol * s.max())) if s.size and s.max() > 0 else 0


@dataclass(frozen=True)
class FrameMinimum:
    """The fewest frames that determine the base parameters, and why.

    Attributes:
        frames: the fewest frames whose stacked regressor can reach ``rank_needed`` (and, with offsets,
            ``A F >= rank + n_offsets``).
        by_counting: ``ceil((rank + n_offsets) / A)``, what counting equations says.
        rank: the structural rank (the number of base parameters).
        n_offsets: offsets identified with them (0 without).
        n_axes: ``A``, the measured axes a frame.
        ranks: the rank of ``F`` generic frames for ``F = 1 .. frames``.
        groups: ``(axes, rank)`` of each group of axes (one channel's axes of one unit) over every motion.
    """

    frames: int
    by_counting: int
    rank: int
    n_offsets: int
    n_axes: int
    ranks: tuple[int, ...]
    groups: tuple[tuple[tuple[str, ...], int], ...]

    @property
    def reason(self) -> str | None:
        """Why ``frames - 1`` generic frames are not enough when counting says they are; None otherwise."""
        if self.frames <= self.by_counting:
            return None
        f = self.frames - 1
        rows = f - (1 if self.n_offsets else 0)  # centring for the offsets takes one frame's rows of each axis
        short = [(axes, r) for axes, r in self.groups if r < len(axes) * rows]
        text = f"{f} generic frame{'s give' if f != 1 else ' gives'} rank {self.ranks[f - 1]} of {self.rank}"
        bound = sum(min(len(axes) * rows, r) for axes, r in self.groups)
        if short and bound < self.rank:
            spans = "; ".join(
                f"the {', '.join(axes)} rows span only {r} of the {self.rank} identifiable directions"
                for axes, r in short
            )
            text += f", since {spans}, whatever the motion"
            if self.n_offsets:
                text += " (and the offsets take one frame's rows of each axis)"
        return text

    def message(self, n_frames: int) -> str:
        """Why ``n_frames`` are too few, naming the minimum; the counting message when counting explains it."""
        s, verb = ("s", "give") if n_frames != 1 else ("", "gives")
        if self.reason is None or n_frames < self.by_counting:
            return (
                f"{n_frames} frame{s} {verb} {self.n_axes * n_frames} equations for {self.rank + self.n_offsets} "
                f"identifiable parameters{' and offsets' if self.n_offsets else ''}; use at least {self.frames} "
                "frames (more with noise)"
            )
        return f"use at least {self.frames} frames (more with noise): {self.reason}"

    def require(self, n_frames: int) -> None:
        """Refuse fewer than :attr:`frames` frames (``IdentificationError``, status ``too_few_frames``)."""
        if n_frames < self.frames:
            raise IdentificationError(self.message(n_frames), status="too_few_frames")

    def split(self, n_frames: int, frames: int | None = None) -> tuple[int, int]:
        """``(fitted, held out)`` frames of a configuration of ``n_frames``: the first ``frames``, the rest held
        out; None: :data:`ineid.identify.settings.HOLDOUT_FRACTION` held out, none when the rest would leave
        fewer than twice the unknowns' equations. Fewer fitted than :attr:`frames` is refused (:meth:`require`).
        """
        if frames is not None:
            if frames > n_frames:
                raise IdentificationError(
                    f"--fit-frames {frames} but the dataset has {n_frames} frames per configuration; use at most "
                    f"{n_frames}",
                    status="too_many_frames",
                )
            self.require(frames)
            return frames, n_frames - frames
        held = int(HOLDOUT_FRACTION * n_frames)
        fit = n_frames - held
        if self.n_axes * fit < 2 * (self.rank + self.n_offsets):  # too few to spare any: fit them all
            fit, held = n_frames, 0
        self.require(fit)
        return fit, held


def frame_minimum_from_regressor(
    ws: np.ndarray, n_axes: int, rank: int, axis_names, axis_groups, offset_mask: np.ndarray | None = None
) -> FrameMinimum:
    """The :class:`FrameMinimum` of generic frames' stacked regressor ``ws`` (AF, p): scaled, frame-major rows.

    Args:
        ws: the scaled regressor of ``F_max`` generic frames (:data:`ineid.identify.identifiability.STRUCTURAL_FRAMES`).
        n_axes: ``A``.
        rank: the structural rank to reach.
        axis_names: (A,) the axes' names.
        axis_groups: (A,) a label per axis; the axes of one label form a group.
        offset_mask: (A,) bool, the axes whose offsets are identified too: each prefix of frames is centred on
            them before its rank (:func:`ineid.identify.identifiability.centred_regressor`); None: no offsets.
    """
    centre = 0.0 if offset_mask is None else np.asarray(offset_mask, dtype=np.float64)[:, None]
    n_offsets = 0 if offset_mask is None else int(np.count_nonzero(offset_mask))
    f_max = ws.shape[0] // n_axes
    w3 = ws.reshape(f_max, n_axes, -1)
    by_counting = -(-(rank + n_offsets) // n_axes)
    ranks: list[int] = []
    frames = None
    for f in range(1, f_max + 1):
        block = w3[:f] - w3[:f].mean(axis=0) * centre
        ranks.append(numerical_rank(np.linalg.svd(block.reshape(f * n_axes, -1), compute_uv=False)))
        if ranks[-1] >= rank and f >= by_counting:
            frames = f
            break
    if frames is None:
        raise IdentificationError(
            f"{f_max} generic frames reach rank {max(ranks)} of {rank}: the structural "
            "analysis is inconsistent; report this",
            status="ill_conditioned",
        )
    labels = list(dict.fromkeys(axis_groups))
    groups = []
    for label in labels:
        idx = [a for a in range(n_axes) if axis_groups[a] == label]
        rows = (w3 - w3.mean(axis=0) * centre)[:, idx]
        groups.append(
            (
                tuple(axis_names[a] for a in idx),
                numerical_rank(np.linalg.svd(rows.reshape(-1, ws.shape[1]), compute_uv=False)),
            )
        )
    return FrameMinimum(frames, by_counting, rank, n_offsets, n_axes, tuple(ranks), tuple(groups))
