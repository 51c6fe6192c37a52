"""What to design and what comes back: :class:`ExcitationSettings` (the options of ``ineid excite``, checked
when made), :class:`ExcitationResult` and its starts (:class:`StartRecord`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ineid.channels import ChannelSet
from ineid.data.synthesis.imu_rehearsal import ImuRehearsal
from ineid.data.synthesis.trajectory import FourierTrajectory
from ineid.excite.criterion import DesignBase, DesignEvaluation
from ineid.excite.trajectory import Bounds

MAX_STARTS = 10_000
"""At most this many random starts (each an IPOPT solve of seconds; all are drawn up front)."""


MAX_SAMPLES = 1_000_000
"""At most this many samples (``duration * rate``): the design is evaluated on every one (the
regressor of each, about 1 KB), and the trajectory CSV has one row each."""


@dataclass(frozen=True)
class StartRecord:
    """One start: its criterion before and after, IPOPT's status, iterations, seconds, whether it converged
    (IPOPT's optimality test passed, to its tolerance or the acceptable one, and the design keeps every bound) and,
    stopped by the iteration cap, whether its criterion had settled (:data:`ineid.excite.search.SETTLED`)."""

    start_value: float
    final_value: float
    status: str
    iterations: int
    seconds: float
    converged: bool = False
    settled: bool = False


@dataclass
class ExcitationResult:
    """A designed excitation trajectory and how it compares with a random one.

    Attributes:
        trajectory: the design (coefficients; evaluate or sample it).
        criterion: ``"d-opt"`` or ``"cond"``, what was minimized.
        value: the criterion of the design on the design grid (one period).
        optimized, random: :class:`DesignEvaluation` of the design and of a random
            Fourier trajectory with the same period, harmonics and bounds (the start with
            the median criterion), both from the samples at ``rate`` over the duration.
        random_trajectory: that random trajectory.
        base: the base parameters designed for.
        sigma: (A,) noise std per measured axis of the expected standard deviations (the wrench: N, N*m).
        bounds: the bounds the design keeps at every instant.
        rate: Hz of the samples that the evaluations use (and a CSV has).
        starts: one record per IPOPT start.
        seconds: wall time of the design.
        compile_seconds: of that, the first evaluation of the criterion and its gradient (building the CasADi
            functions of the rows and their pull-back: milliseconds; nothing is compiled).
        settings: the arguments, JSON-able.
        safety: the floor, box and self-collision pairs kept (None: ``self_collision`` off and no
            floor or box): their settings, the grid and margins, the capsules and what had none,
            and the smallest clearance found on the samples at ``rate`` and on a grid ten times
            denser (:func:`ineid.excite.safety.verify`).
        states: with ``settings.sensors``: the sensors, the state errors each trajectory's rehearsal gives and
            the inflated noise (:func:`ineid.excite.states.states_record`); None: joint states exact.
        best_random, best_random_trajectory: the best of the ``n_candidates`` random feasible trajectories
            (the same criterion and bounds; :mod:`ineid.excite.search`), evaluated like the design.
        answer: ``"optimized"``, or ``"best random"`` when no start beat the best candidate (the trajectory
            is then that candidate).
        feasibility: the up-front check of the floor, box and self-collision on a sample of the joint space
            (:meth:`ineid.excite.feasibility.Feasibility.to_dict`); None when nothing bounds the poses.
    """

    trajectory: FourierTrajectory
    criterion: str
    value: float
    optimized: DesignEvaluation
    random: DesignEvaluation
    random_trajectory: FourierTrajectory
    base: DesignBase
    sigma: np.ndarray
    bounds: Bounds
    rate: float
    starts: list[StartRecord] = field(default_factory=list)
    seconds: float = 0.0
    compile_seconds: float = 0.0
    settings: dict = field(default_factory=dict)
    safety: dict | None = None
    states: dict | None = None
    best_random: DesignEvaluation | None = None
    best_random_trajectory: FourierTrajectory | None = None
    n_candidates: int = 0
    answer: str = "optimized"
    feasibility: dict | None = None

    @property
    def converged(self) -> int:
        """Starts that converged (:attr:`StartRecord.converged`)."""
        return sum(1 for r in self.starts if r.converged)

    def to_dict(self) -> dict:
        """The design record a ``traj.json`` carries beside the coefficients."""
        d = {
            "criterion": self.criterion,
            "value": self.value,
            "rate": self.rate,
            "base_parameters": list(self.base.names),
            "base_scales": self.base.scales.tolist(),
            "base_cad": self.base.cad.tolist(),
            "bias": self.base.bias,
            "wrench_noise_std": self.sigma.tolist(),
            "bounds": self.bounds.to_dict(),
            "optimized": self.optimized.to_dict(),
            "random_fourier": self.random.to_dict(),
            "best_random": None if self.best_random is None else self.best_random.to_dict(),
            "n_candidates": self.n_candidates,
            "answer": self.answer,
            "feasibility": self.feasibility,
            "starts": [vars(s) for s in self.starts],
            "seconds": self.seconds,
            "settings": self.settings,
            "workspace": self.safety,
        }
        if self.states is not None:
            d["joint_state_errors"] = self.states
        return d


@dataclass(frozen=True)
class ExcitationSettings:
    """What to design (the defaults of ``ineid excite``).

    Attributes:
        duration: s, a whole number of periods ``1 / base_frequency`` (required).
        harmonics: ``H >= 2`` per joint (two are the fewest that can start and stop at rest).
        base_frequency: ``f0`` Hz; None: ``1 / duration`` (one period).
        criterion: ``"d-opt"`` (``-log det M``) or ``"cond"`` (``log cond Phi``).
        candidates: random feasible trajectories drawn and compared (the best ``starts`` of them start
            IPOPT, and the best of them is the comparison a design must beat).
        starts: IPOPT starts from the best candidates; the best design is kept.
        rate: Hz of the samples (the CSV rows, and the reported evaluations).
        margin: fraction of each joint's range kept free at each end, in [0, 0.5).
        velocity_scale, acceleration_scale: fractions of the model's bounds, positive (above 1:
            beyond the URDF's bounds, see :func:`design_bounds`).
        bias: design for identification with six constant sensor offsets estimated
            jointly (``ineid solve --bias estimate``).
        channels: the measurement channels designed for (:class:`ineid.channels.ChannelSet`,
            their rows); None: the base wrench.
        seed: of the random starts.
        design_points: samples per period of the criterion (None: ``32 H`` rounded up to a
            multiple of :data:`DEFAULT_CHUNK`, the compiled block size).
        constraint_points: grid points per period of the bounds (None: ``32 H``).
        max_iter, tol: IPOPT's, per start.
        floor: m, every link frame origin and welded frame (the tool) at ``z >= floor`` of the
            base frame at every instant (:mod:`ineid.excite.safety`); None: no floor.
        workspace: ``(xmin, xmax, ymin, ymax, zmin, zmax)`` m, base frame: the same points kept
            in that box at every instant; None: no box.
        self_collision: keep the bounding capsules of non-adjacent bodies apart at every instant
            (:mod:`ineid.excite.collision`), where the URDF has collision geometry.
        sensors: the lab's encoders and link IMUs (:class:`ineid.data.synthesis.imu_rehearsal.ImuRehearsal`): the
            design accounts for the joint-state errors they cause (:mod:`ineid.excite.states`);
            None: joint states exact.
    """

    duration: float
    harmonics: int = 5
    base_frequency: float | None = None
    criterion: str = "d-opt"
    candidates: int = 32
    starts: int = 3
    rate: float = 100.0
    margin: float = 0.05
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    bias: bool = False
    seed: int = 0
    design_points: int | None = None
    constraint_points: int | None = None
    max_iter: int = 100
    tol: float = 1e-6
    channels: ChannelSet | None = None
    floor: float | None = None
    workspace: tuple[float, float, float, float, float, float] | None = None
    self_collision: bool = True
    sensors: ImuRehearsal | None = None

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if self.channels is None:
            del d["channels"]  # the base wrench: a record without channels
        else:
            d["channels"] = self.channels.to_list()
        if self.workspace is not None:
            d["workspace"] = list(self.workspace)
        if self.sensors is None:
            del d["sensors"]  # joint states exact: a record without sensors
        else:
            d["sensors"] = self.sensors.to_dict()
        return d
