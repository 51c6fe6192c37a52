"""Ground-truth sampling: physically valid link parameters and kinematic frames.

Parameters (section 3.1 of the paper): for each unknown link, sets drawn around the
model's CAD values, then combined into robot configurations, full factorial (the paper's
100 x 100 = 10,000) or paired at random. Every set is a rigid body by construction:

* mass ``m = m_cad * U(1 - mass_rel, 1 + mass_rel)``;
* centre of mass ``c = c_cad + U(-com_box, com_box)`` per axis (link frame, m);
* inertia about the centre of mass from its *second moments* ``s_i`` (the principal
  values of ``Sigma_C = integral(r r^T dm)``): the CAD ones, scaled with the mass and by
  ``U(1 - inertia_rel, 1 + inertia_rel)`` each, so every ``s_i > 0``; the principal moments
  are ``J_i = s_j + s_k``, which makes ``I_C`` positive definite and the triangle
  inequality strict (a positive definite pseudo-inertia, Wensing et al. 2017);
* principal axes: the CAD ones turned by a random rotation about a uniformly random axis,
  by an angle uniform in ``[0, orientation_deg]`` (``>= 180`` draws uniformly on SO(3)).

Frames: ``q`` uniform within the joint limits and ``qd, qdd`` uniform within the model's
bounds (the paper's way), or samples of smooth periodic excitation trajectories, a finite
Fourier series per joint (Swevers et al. 1997) with ``q, qd, qdd`` analytic::

    q(t)   = q0 + sum_l  a_l/(w l) sin(w l t) - b_l/(w l) cos(w l t)
    qd(t)  =      sum_l  a_l cos(w l t) + b_l sin(w l t)
    qdd(t) =      sum_l -a_l w l sin(w l t) + b_l w l cos(w l t),   w = 2 pi f0

scaled so that ``|qd| <= qd_max``, ``|qdd| <= qdd_max`` and ``q`` stays within its limits
for all ``t`` (the bound is the sum of harmonic amplitudes, so it holds exactly). Or the
samples of one given trajectory (``ineid excite``'s design), the same for every configuration.

Random streams are keyed by ``(seed, purpose, block)`` so that a configuration's draws do
not depend on how generation is chunked, and the clean data do not depend on the noise.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ineid.data.synthesis.trajectory import SampledTrajectory
from ineid.params import N_PARAMS_PER_LINK, inertial_from_theta, theta_from_inertial

# Purposes of the random streams; never renumber (files record only the seed).
STREAM_PARAMETERS = 1
STREAM_PAIRING = 2
STREAM_FRAMES = 3
STREAM_NOISE = 4

MAX_HARMONICS = 1000
"""Fourier frames: at most this many harmonics per joint (their coefficients and sines are held
for a chunk of configurations and frames; 1000 of 0.1 Hz already reach 100 Hz)."""
MAX_BASE_FREQUENCY = 1000.0
"""Fourier frames: the largest base frequency, Hz (a robot's joints do not follow kHz motion)."""
RNG_BLOCK_CONFIGS = 64
"""Configurations per random-number block: the unit of chunked, order-independent draws."""


def block_rng(seed: int, stream: int, block: int) -> np.random.Generator:
    """The generator of one ``(seed, stream, block)``, independent of every other."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(stream), int(block)]))


@dataclass(frozen=True)
class ParameterSampling:
    """Bands of the per-link parameter sampling around the CAD values (see module doc).

    Attributes:
        mass_rel: relative half-width of the mass band, in [0, 1).
        com_box: half-width of the centre-of-mass box per axis, link frame, m.
        inertia_rel: relative half-width of each second moment's band, in [0, 1).
        orientation_deg: largest turn of the principal axes from the CAD ones, degrees.
        min_second_moment_rel: floor of a CAD second moment relative to the largest, so
            that a rod-like CAD link still yields a full-rank sample.
    """

    mass_rel: float = 0.2
    com_box: float = 0.02
    inertia_rel: float = 0.3
    orientation_deg: float = 30.0
    min_second_moment_rel: float = 0.01

    def __post_init__(self) -> None:
        if not 0 <= self.mass_rel < 1:
            raise ValueError(f"mass_rel must be in [0, 1), got {self.mass_rel}")
        if not 0 <= self.com_box < math.inf:
            raise ValueError(f"com_box must be a finite number >= 0 m, got {self.com_box}")
        if not 0 <= self.inertia_rel < 1:
            raise ValueError(f"inertia_rel must be in [0, 1), got {self.inertia_rel}")
        if not 0 <= self.orientation_deg < math.inf:
            raise ValueError(f"orientation_deg must be a finite number >= 0, got {self.orientation_deg}")
        if not 0 < self.min_second_moment_rel <= 1:
            raise ValueError(f"min_second_moment_rel must be in (0, 1], got {self.min_second_moment_rel}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def second_moments(inertia_com: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal second moments ``s`` and axes ``R`` of an inertia about the centre of mass.

    ``I_C = R diag(J) R^T`` with ``J_i = s_j + s_k``, i.e. ``s = tr(I_C)/2 - J``.

    Args:
        inertia_com: (3, 3) kg*m^2.

    Returns:
        (s (3,) kg*m^2, R (3, 3) with columns the principal axes, det R = +1).
    """
    moments, axes = np.linalg.eigh(0.5 * (inertia_com + inertia_com.T))
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    return 0.5 * moments.sum() - moments, axes


def random_rotations(rng: np.random.Generator, n: int, max_angle_deg: float) -> np.ndarray:
    """``n`` rotation matrices, see :func:`rotations_from_uniform`."""
    return rotations_from_uniform(rng.random((n, 3)), max_angle_deg)


def rotations_from_uniform(u: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Rotation matrices from uniforms ``u`` (n, 3) in [0, 1).

    Axis uniform on the sphere, angle uniform in ``[0, max_angle_deg]``; with
    ``max_angle_deg >= 180`` uniform on SO(3) instead (Haar measure, Shoemake's
    quaternion method), so the rotations are unbiased.
    """
    u = np.asarray(u, dtype=np.float64)
    if max_angle_deg >= 180.0:
        r1, r2 = np.sqrt(1.0 - u[:, 0]), np.sqrt(u[:, 0])
        a, b = 2.0 * np.pi * u[:, 1], 2.0 * np.pi * u[:, 2]
        x, y, z, w = r1 * np.sin(a), r1 * np.cos(a), r2 * np.sin(b), r2 * np.cos(b)
        return np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
            ],
            axis=-2,
        )
    cz = 2.0 * u[:, 0] - 1.0
    phi = 2.0 * np.pi * u[:, 1]
    sz = np.sqrt(np.maximum(0.0, 1.0 - cz * cz))
    axis = np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], axis=-1)
    angle = np.deg2rad(max_angle_deg) * u[:, 2]
    n = len(u)
    k = np.zeros((n, 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)  # Rodrigues


def sample_link_parameters(
    theta_cad: np.ndarray, n_sets: int, rng: np.random.Generator, bands: ParameterSampling = ParameterSampling()
) -> np.ndarray:
    """``n_sets`` physically valid parameter sets of one link around its CAD values.

    Args:
        theta_cad: (10,) the link's CAD parameters (Pinocchio order, about the link origin).
        n_sets: how many sets.
        rng: the random stream (one per link).
        bands: sampling bands.

    Returns:
        (n_sets, 10) parameters; the draws for set ``k`` do not depend on ``n_sets``.
    """
    m_cad, c_cad, ic_cad = inertial_from_theta(np.asarray(theta_cad, dtype=np.float64))
    s_cad, axes_cad = second_moments(ic_cad)
    s_cad = np.maximum(s_cad, bands.min_second_moment_rel * s_cad.max())
    # One draw of 10 uniforms per set: set k's values do not depend on n_sets.
    u = rng.random((n_sets, 10))
    mass = m_cad * (1.0 + bands.mass_rel * (2.0 * u[:, 0] - 1.0))
    com = c_cad + bands.com_box * (2.0 * u[:, 1:4] - 1.0)
    s = (mass / m_cad)[:, None] * s_cad * (1.0 + bands.inertia_rel * (2.0 * u[:, 4:7] - 1.0))
    principal = s.sum(axis=-1, keepdims=True) - s  # J_i = s_j + s_k
    rot = axes_cad @ rotations_from_uniform(u[:, 7:10], bands.orientation_deg)
    inertia_com = rot @ (principal[:, :, None] * np.swapaxes(rot, -1, -2))
    inertia_com = 0.5 * (inertia_com + np.swapaxes(inertia_com, -1, -2))
    return theta_from_inertial(mass, com, inertia_com)


@dataclass(frozen=True)
class Combination:
    """How per-link sets combine into configurations.

    ``mode="factorial"``: ``per_link`` sets per unknown link (default 100), every combination
    (``per_link ** n_unknown`` configurations, the last link varying fastest).
    ``mode="random"``: ``n_configs`` configurations; each link's set drawn from a pool of
    ``per_link`` sets (default: a fresh set for every configuration).
    """

    mode: str = "factorial"
    per_link: int | None = None
    n_configs: int | None = None

    def __post_init__(self) -> None:
        if self.mode == "factorial" and self.per_link is None:
            object.__setattr__(self, "per_link", 100)  # the paper's 100 sets per link
        if self.mode not in ("factorial", "random"):
            raise ValueError(f"combination mode must be 'factorial' or 'random', got {self.mode!r}")
        if self.mode == "factorial" and (self.per_link is None or self.per_link < 1):
            raise ValueError("a factorial combination needs per_link >= 1 sets per link")
        if self.mode == "random" and (self.n_configs is None or self.n_configs < 1):
            raise ValueError("a random combination needs n_configs >= 1")
        if self.per_link is not None and self.per_link < 1:
            raise ValueError(f"per_link must be >= 1, got {self.per_link}")

    def count(self, n_unknown: int) -> int:
        if self.mode == "factorial":
            return int(self.per_link) ** n_unknown
        return int(self.n_configs)

    def pool_size(self) -> int:
        return int(self.per_link if self.per_link is not None else self.n_configs)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def sample_configurations(
    theta_cad_unknown: np.ndarray,
    combination: Combination,
    seed: int,
    bands: ParameterSampling = ParameterSampling(),
) -> tuple[np.ndarray, np.ndarray]:
    """The unknown links' parameters of every configuration.

    Args:
        theta_cad_unknown: (10 * n_unknown,) CAD parameters of the unknown links.
        combination: factorial or random pairing.
        seed: the dataset seed.
        bands: sampling bands.

    Returns:
        ``(theta_unknown (n_configs, 10 * n_unknown), link_set_index (n_configs, n_unknown))``;
        ``link_set_index[i, k]`` is the set of unknown link ``k`` used by configuration ``i``.
    """
    cad = np.asarray(theta_cad_unknown, dtype=np.float64).reshape(-1, N_PARAMS_PER_LINK)
    n_unknown = len(cad)
    pool = combination.pool_size()
    n_configs = combination.count(n_unknown)
    sets = [
        sample_link_parameters(cad[k], pool, block_rng(seed, STREAM_PARAMETERS, k), bands) for k in range(n_unknown)
    ]
    if combination.mode == "factorial":
        index = np.indices((pool,) * n_unknown).reshape(n_unknown, -1).T
    elif combination.per_link is None:
        index = np.repeat(np.arange(n_configs)[:, None], n_unknown, axis=1)
    else:
        index = block_rng(seed, STREAM_PAIRING, 0).integers(0, pool, size=(n_configs, n_unknown))
    theta = np.concatenate([sets[k][index[:, k]] for k in range(n_unknown)], axis=-1)
    return theta, index.astype(np.int64)


FRAME_MODES = ("uniform", "fourier", "trajectory")
"""How frames are sampled: independent uniform states, samples of random Fourier trajectories,
or the samples of one given (designed) trajectory, the same for every configuration."""


@dataclass(frozen=True)
class FrameSampling:
    """How the kinematic frames of a configuration are drawn (see module doc).

    Attributes:
        mode: ``"uniform"`` (independent frames, the paper's way) or ``"fourier"``
            (samples along a smooth periodic excitation trajectory).
        harmonics: Fourier harmonics per joint.
        base_frequency: ``f0``, Hz; one period ``1/f0`` is sampled.
        duration: seconds of trajectory sampled (default: one period), frames equally
            spaced at ``t_k = k * duration / n_frames``.
        velocity_scale, acceleration_scale: fractions of the model's bounds used.
        trajectory: for ``mode="trajectory"``, the samples every configuration moves
            through (:class:`ineid.data.synthesis.trajectory.SampledTrajectory`, e.g. from
            ``ineid excite``); the other settings do not apply to it.
    """

    mode: str = "uniform"
    harmonics: int = 5
    base_frequency: float = 0.1
    duration: float | None = None
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    trajectory: SampledTrajectory | None = None

    def __post_init__(self) -> None:
        if self.mode not in FRAME_MODES:
            raise ValueError(f"frame mode must be one of {', '.join(FRAME_MODES)}, got {self.mode!r}")
        if (self.mode == "trajectory") != (self.trajectory is not None):
            raise ValueError("frame mode 'trajectory' needs a trajectory (--trajectory FILE), and only it takes one")
        if not 1 <= self.harmonics <= MAX_HARMONICS:
            raise ValueError(f"harmonics must be in 1..{MAX_HARMONICS}, got {self.harmonics}")
        if not 0 < self.base_frequency <= MAX_BASE_FREQUENCY:
            raise ValueError(f"base_frequency must be in (0, {MAX_BASE_FREQUENCY:g}] Hz, got {self.base_frequency}")
        if self.duration is not None and not 0 < self.duration < math.inf:
            raise ValueError(f"duration must be > 0 s, got {self.duration}")
        for name in ("velocity_scale", "acceleration_scale"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")

    def to_dict(self) -> dict:
        if self.trajectory is None:
            return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "trajectory"}
        return {"mode": self.mode, "trajectory": self.trajectory.describe()}


def uniform_states(
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    qd_max: np.ndarray,
    qdd_max: np.ndarray,
    rng: np.random.Generator,
    shape: tuple[int, ...],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independent uniform states within the bounds: ``q`` in the limits, ``|qd|``, ``|qdd|`` below theirs.

    Each (shape..., n_dof). The draws of a leading index (a configuration) are one
    contiguous block of ``rng``: its q of every frame, then its qd, then its qdd; so a
    configuration's frames do not depend on how many configurations are drawn with it.
    """
    lo, hi = np.asarray(q_lower, float), np.asarray(q_upper, float)
    u = rng.random((*shape[:-1], 3, shape[-1], lo.shape[0]))
    q = lo + (hi - lo) * u[..., 0, :, :]
    qd = np.asarray(qd_max, float) * (2.0 * u[..., 1, :, :] - 1.0)
    qdd = np.asarray(qdd_max, float) * (2.0 * u[..., 2, :, :] - 1.0)
    return q, qd, qdd


def model_uniform_states(model, n_frames: int, rng: np.random.Generator):
    """:func:`uniform_states` within a :class:`ineid.RobotModel`'s bounds: (n_frames, n_dof) x 3."""
    return uniform_states(model.q_lower, model.q_upper, model.qd_max, model.qdd_max, rng, (n_frames,))


def sample_frames(
    n_configs: int,
    n_frames: int,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    qd_max: np.ndarray,
    qdd_max: np.ndarray,
    rng: np.random.Generator,
    spec: FrameSampling = FrameSampling(),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Frames of ``n_configs`` configurations from one random stream.

    Args:
        n_configs, n_frames: sizes.
        q_lower, q_upper: (n_dof,) joint limits (rad or m).
        qd_max, qdd_max: (n_dof,) velocity and acceleration bounds.
        rng: the block's stream; configuration ``i``'s draws do not depend on ``n_configs``.
        spec: the sampling mode.

    Returns:
        ``(q, qd, qdd, time)``, each state (n_configs, n_frames, n_dof); ``time``
        (n_configs, n_frames) seconds for trajectories, ``None`` for independent frames.
    """
    lo, hi = np.asarray(q_lower, float), np.asarray(q_upper, float)
    vmax = np.asarray(qd_max, float) * spec.velocity_scale
    amax = np.asarray(qdd_max, float) * spec.acceleration_scale
    n_dof = lo.shape[0]
    if spec.mode == "trajectory":
        tr = spec.trajectory
        if tr.n_dof != n_dof or tr.n_frames != n_frames:
            raise ValueError(
                f"the trajectory has {tr.n_frames} frames of {tr.n_dof} joints; asked for {n_frames} frames of {n_dof}"
            )
        return tuple(np.broadcast_to(a, (n_configs, *a.shape)).copy() for a in (tr.q, tr.qd, tr.qdd, tr.time))
    if spec.mode == "uniform":
        return (*uniform_states(lo, hi, vmax, amax, rng, (n_configs, n_frames)), None)
    n_h = spec.harmonics
    omega = 2.0 * np.pi * spec.base_frequency
    duration = spec.duration if spec.duration is not None else 1.0 / spec.base_frequency
    t = np.arange(n_frames) * (duration / n_frames)
    u = rng.random((n_configs, n_dof, 2 * n_h + 1))
    a, b = 2.0 * u[..., :n_h] - 1.0, 2.0 * u[..., n_h : 2 * n_h] - 1.0
    ell = np.arange(1, n_h + 1)
    amp = np.hypot(a, b)  # (C, n_dof, n_h)
    bound_q = (amp / (omega * ell)).sum(-1)
    bound_qd = amp.sum(-1)
    bound_qdd = (amp * omega * ell).sum(-1)
    half_range = 0.5 * (hi - lo)
    scale = np.minimum.reduce([vmax / bound_qd, amax / bound_qdd, half_range / bound_q])
    a, b = a * scale[..., None], b * scale[..., None]
    reach = bound_q * scale  # <= half_range
    q0 = lo + reach + (hi - lo - 2.0 * reach) * u[..., 2 * n_h]
    wt = omega * ell[:, None] * t[None, :]  # (n_h, F)
    sin, cos = np.sin(wt), np.cos(wt)
    wl = (omega * ell)[:, None]
    q = q0[..., None] + np.einsum("cjh,hf->cjf", a, sin / wl) - np.einsum("cjh,hf->cjf", b, cos / wl)
    qd = np.einsum("cjh,hf->cjf", a, cos) + np.einsum("cjh,hf->cjf", b, sin)
    qdd = np.einsum("cjh,hf->cjf", a, -wl * sin) + np.einsum("cjh,hf->cjf", b, wl * cos)
    # Rounding can put q a few ulps past a limit the bound touches exactly.
    q = np.clip(np.swapaxes(q, 1, 2), lo, hi)
    qd, qdd = np.swapaxes(qd, 1, 2), np.swapaxes(qdd, 1, 2)
    return q, qd, qdd, np.broadcast_to(t, (n_configs, n_frames)).copy()
