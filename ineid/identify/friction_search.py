"""The friction laws' nonlinear velocities, identified: a 1-D search with every other parameter linear.

The smooth Coulomb zone ``zone`` (``tanh(qd / zone)``) and the Stribeck velocity ``vs``
(``exp(-(qd / vs)^2)``, :mod:`ineid.channels.friction`) enter the joint torques nonlinearly; every other
parameter (the links', the friction coefficients, armature, offsets) linearly. ``SolveSettings(coulomb_zone=
"identify")`` (``ineid solve --coulomb-zone identify``; ``stribeck_velocity`` alike) finds them by
variable projection: at a given velocity ``v`` the weighted least-squares residual

    S(v) = min_beta || W (y - [A  E(v)] beta) ||^2

is the linear fit's (``A`` the links' rows and the offsets', fixed; ``E(v)`` the channels' actuation
columns), so ``v`` minimises the profile ``S`` over every configuration fitted: a grid of
:data:`GRID_POINTS` values log-spaced over :data:`GRID_RANGE` times the drives' 95th-percentile speed,
then a golden-section search between the best point's neighbours (in ``log v``). Both velocities: three
rounds of coordinate descent. ``W`` holds ``1 / sigma`` per axis: the noise given (``weights="noise"``), or
the residual RMS per axis at the first estimate, refined once at the minimum.

The std is the profile likelihood's: ``S`` is ``-2 log L`` up to a constant, so ``cov(v) = 2 H^-1`` with
``H`` the Hessian of ``S`` at the minimum (central differences, 1 % steps), for independent frames; it is
conditional on nothing else: the other parameters are profiled out. On a filtered recording
(:func:`ineid.identify.time_correlation.filtered_frames`) the frames are correlated in time, and each axis's
residual counts ``kappa_a`` times (its band density, as the linear fit's std takes it): the variance grows by
``sum_a kappa_a H_a / sum_a H_a`` (:func:`long_run_factors`), ``H_a`` the axis's share of the curvature; and the
low-pass and the differentiation move the velocity themselves (a filtered ``tanh`` looks like a wider zone), by
``delta`` estimated from the data (:func:`filter_shifts`), added as ``delta^2``. The
other parameters' std are those of the fit at the velocities found (conditional on them). On 20 simulated
torque sets each (``tests/test_actuation_friction.py``'s, 300 frames, 0.02 N*m noise) the RMS error/std is 1.19
for the zone and 1.10 for the Stribeck velocity (which comes out low by 0.7 std on average), 0.98 and 1.08 for
the friction coefficients.
A minimum at the grid's edge (a zone below its range is a sign; a Stribeck velocity above it, a Coulomb
level) is reported with an infinite std. The solve then runs at the velocities found, by the chosen method;
the channels' records carry the values and their std (``identified``).

With ``two_step``, the search runs in step 2: the links fixed at step 1's estimate, ``A`` the offsets and
the torque constants' columns alone. Above :data:`MAX_NUMBERS` numbers of ``A`` per configuration, every
``k``-th frame enters the search (``S`` scaled by ``k``).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ineid.channels import ChannelSet
from ineid.errors import IdentificationError
from ineid.identify.choose import (
    is_actuated,
    noise_levels,
    solve_channels,
    torque_noise_levels,
    two_step_channels,
    wrench_settings,
)
from ineid.identify.identifiability import frame_minimum
from ineid.identify.settings import FRICTION_VELOCITIES, SolveSettings
from ineid.identify.solve_results import SolveResults
from ineid.identify.time_correlation import (
    NYQUIST_SHARE,
    FilteredFrames,
    band_long_run,
    filter_gain,
    filtered_frames,
)
from ineid.identify.two_step import k_columns, second_step

GRID_POINTS = 25
GRID_RANGE = (1e-3, 2.0)
"""The search's grid: this range times the drives' 95th-percentile speed (rad/s), log-spaced."""
MAX_NUMBERS = 20_000_000
"""Numbers of ``A`` (frames x axes x columns) per configuration above which the search thins the frames."""
ROUNDS = 3
"""Rounds of coordinate descent when both velocities are identified."""
GOLDEN_STEPS = 30
"""Golden-section steps in ``log v`` (the bracket shrinks to 5e-7 of its width)."""
HESSIAN_STEP = 1e-2
"""The relative step of the central differences of ``S`` at the minimum."""


@dataclasses.dataclass
class Profile:
    """``S(v)`` over every configuration (module doc): the data, the fixed columns and their projection.

    Attributes:
        channels: the channels fitted (their velocities replaced at each evaluation).
        model: the :class:`ineid.RobotModel`.
        frames: per configuration, ``(q, qd, qdd)`` of the frames searched.
        fixed: per configuration, ``A`` (F, A, p) or None.
        targets: per configuration, the values less what is known (F, A).
        stride: every ``stride``-th frame is searched.
        rebuild: ``f(c, q, qd, qdd) -> (known (F, A), fixed)``: configuration ``c``'s known share of the values and
            its fixed columns at other states (:func:`filter_shifts`), or None.
    """

    channels: ChannelSet
    model: object
    frames: list
    fixed: list
    targets: list
    stride: int
    weights: np.ndarray | None = None
    bases: list = dataclasses.field(default_factory=list)
    rebuild: object = None

    def set_weights(self, weights: np.ndarray) -> None:
        """``1 / sigma`` per configuration and axis (C, A); the orthonormal bases of the weighted ``A``."""
        self.weights = weights
        self.bases = []
        for a, w in zip(self.fixed, weights, strict=True):
            if a is None or a.shape[-1] == 0:
                self.bases.append(None)
                continue
            u, s, _ = np.linalg.svd((a * w[:, None]).reshape(-1, a.shape[-1]), full_matrices=False)
            self.bases.append(u[:, s > s[0] * max(u.shape) * np.finfo(float).eps])

    def residuals(self, values: dict) -> list:
        """Per configuration, the residual (F, A) of the weighted linear fit at the velocities ``values``."""
        out = []
        for (_, qd, qdd), y, w, basis in zip(self.frames, self.targets, self.weights, self.bases, strict=True):
            e = self.columns(values, qd, qdd) * w[:, None]
            e, r = e.reshape(-1, e.shape[-1]), (y * w).reshape(-1)
            if basis is not None:
                r, e = r - basis @ (basis.T @ r), e - basis @ (basis.T @ e)
            gamma = np.linalg.lstsq(e, r, rcond=None)[0]
            out.append((r - e @ gamma).reshape(y.shape) / w)
        return out

    def columns(self, values: dict, qd, qdd) -> np.ndarray:
        """``E`` (F, A, n_e) of the channels at the velocities ``values``: each actuated channel's block."""
        n_axes = self.channels.n_axes(self.model)
        parts = []
        for b in self.channels.blocks(self.model):
            if is_actuated(b.channel):
                e = dataclasses.replace(b.channel, **values).numpy_extra_rows(self.model, qd, qdd)
                block = np.zeros(qd.shape[:-1] + (n_axes, e.shape[-1]))
                block[..., b.start : b.stop, :] = e
                parts.append(block)
        return np.concatenate(parts, axis=-1)

    def __call__(self, values: dict) -> float:
        """``S(values)``: the weighted residual sum of squares over every configuration, times the stride."""
        res = self.residuals(values)
        return self.stride * sum(float(np.sum((r * w) ** 2)) for r, w in zip(res, self.weights, strict=True))

    def estimate_weights(self, values: dict) -> None:
        """Weights ``1 / RMS`` of each axis's residual at ``values`` (first those of the values' RMS; a tiny floor
        against exact data)."""
        floor = 1e-12 * max(float(np.max(np.abs(np.concatenate([y.ravel() for y in self.targets])))), 1e-300)
        if self.weights is None:
            self.set_weights(1.0 / np.maximum(np.stack([np.sqrt(np.mean(y**2, axis=0)) for y in self.targets]), floor))
        rms = np.stack([np.sqrt(np.mean(r**2, axis=0)) for r in self.residuals(values)])
        self.set_weights(1.0 / np.maximum(rms, floor))

    def speed(self) -> float:
        """The drives' 95th-percentile speed over the frames searched (rad/s)."""
        speeds = []
        for ch in self.channels:
            if is_actuated(ch):
                m = ch.drive_matrix()
                for _, qd, _ in self.frames:
                    speeds.append(np.abs(qd if m is None else qd @ m.T).ravel())
        return float(np.percentile(np.concatenate(speeds), 95))


def _golden(f, lo: float, hi: float) -> float:
    """The minimiser of ``f`` on ``[lo, hi]`` by golden-section search."""
    ratio = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - ratio * (b - a), a + ratio * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(GOLDEN_STEPS):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - ratio * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + ratio * (b - a)
            fd = f(d)
    return (a + b) / 2


def search_1d(profile: Profile, values: dict, name: str, grid: np.ndarray) -> tuple[float, bool]:
    """``(v, at_edge)``: the velocity ``name`` minimising ``S`` with the others at ``values`` (grid, then golden)."""
    s = np.array([profile({**values, name: float(v)}) for v in grid])
    k = int(np.argmin(s))
    lo, hi = math.log(grid[max(k - 1, 0)]), math.log(grid[min(k + 1, len(grid) - 1)])
    v = math.exp(_golden(lambda x: profile({**values, name: math.exp(x)}), lo, hi))
    return v, k in (0, len(grid) - 1)


def search(profile: Profile, names: tuple[str, ...], values: dict) -> tuple[dict, dict]:
    """``(values, std)``: the velocities ``names`` found (module doc), the others at ``values``."""
    speed = profile.speed()
    if not speed > 0:
        raise IdentificationError(
            f"the drives do not move in the frames fitted, so {' and '.join(names)} cannot be identified: "
            "give them (rad/s)",
            status="no_motion",
        )
    grid = speed * np.geomspace(*GRID_RANGE, GRID_POINTS)
    values = {**values, **{n: float(np.sqrt(grid[0] * grid[-1])) for n in names}}
    edges = {}
    estimated = profile.weights is None
    for _ in range(2 if estimated else 1):  # the residuals' RMS weights, then refined at the minimum
        if estimated:
            profile.estimate_weights(values)
        for _ in range(ROUNDS if len(names) > 1 else 1):
            for n in names:
                values[n], edges[n] = search_1d(profile, values, n, grid)
    return values, _profile_std(profile, names, values, edges)


def _profile_std(profile: Profile, names: tuple[str, ...], values: dict, edges: dict) -> dict:
    """The std of each velocity: ``sqrt(diag(2 H^-1))`` of ``S``'s Hessian ``H`` at ``values`` (module doc)."""
    steps = {n: HESSIAN_STEP * values[n] for n in names}

    def at(**shifts):
        return profile({**values, **{n: values[n] + k * steps[n] for n, k in shifts.items()}})

    s0 = at()
    h = np.empty((len(names), len(names)))
    for i, a in enumerate(names):
        h[i, i] = (at(**{a: 1}) - 2 * s0 + at(**{a: -1})) / steps[a] ** 2
        for j in range(i):
            b = names[j]
            cross = at(**{a: 1, b: 1}) - at(**{a: 1, b: -1}) - at(**{a: -1, b: 1}) + at(**{a: -1, b: -1})
            h[i, j] = h[j, i] = cross / (4 * steps[a] * steps[b])
    try:
        cov = 2 * np.linalg.inv(h)
        std = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.inf))
    except np.linalg.LinAlgError:
        std = np.full(len(names), np.inf)
    return {n: (math.inf if edges[n] else float(std[i])) for i, n in enumerate(names)}


def long_run_factors(profile: Profile, names: tuple[str, ...], values: dict, filtered: FilteredFrames) -> dict:
    """Per velocity, what its variance grows by on a filtered recording: ``sum_a kappa_a H_a / sum_a H_a``, with
    ``H_a`` axis ``a``'s share of the Gauss-Newton curvature of ``S`` (the residual's derivative by the velocity,
    weighted, squared) and ``kappa_a`` its residual band density at the minimum
    (:func:`ineid.identify.time_correlation.band_long_run`, the frames' rate divided by the stride; the fit's
    leverage in the axis taken out; the filter's gain where the band is too short), at least 1."""
    frames_at = FilteredFrames(filtered.cutoff, filtered.rate / profile.stride)
    gain = filter_gain(frames_at) if filtered.cutoff < NYQUIST_SHARE * frames_at.rate else 1.0
    resid = profile.residuals(values)
    num, den = dict.fromkeys(names, 0.0), dict.fromkeys(names, 0.0)
    for c, (r, w) in enumerate(zip(resid, profile.weights, strict=True)):
        kappa = np.ones(r.shape[1])
        if filtered.cutoff < NYQUIST_SHARE * frames_at.rate:
            band = band_long_run(r, frames_at, _axis_leverage(profile, values, c))
            kappa = np.where(np.isnan(band), gain, np.maximum(band, 1.0))
        for n in names:
            step = HESSIAN_STEP * values[n]
            up = profile.residuals({**values, n: values[n] + step})[c]
            down = profile.residuals({**values, n: values[n] - step})[c]
            h = np.sum(((up - down) * w) ** 2, axis=0)
            num[n], den[n] = num[n] + float(kappa @ h), den[n] + float(h.sum())
    return {n: max(num[n] / den[n], 1.0) if den[n] > 0 else 1.0 for n in names}


SHIFT_GRID = (1 / 3, 3.0, 15)
"""The grid of :func:`filter_shifts`' search: this range times the velocity found, log-spaced, this many points."""


def filter_shifts(profile: Profile, names: tuple[str, ...], values: dict, filtered: FilteredFrames) -> dict:
    """Per velocity, what the low-pass and the differentiation move it by, estimated from the data as the linear
    fit's filter error is (:func:`ineid.identify.time_correlation.filter_error`): the fitted model ``m(s_f)`` at the
    filtered states, low-passed again, searched against the model at the twice-filtered states ``LP s_f`` (the
    filter's start-up at each end left out); the velocity found there less the one at ``s_f``. 0 where the profile
    cannot rebuild its columns (``Profile.rebuild`` None) or the frames are too few."""
    from ineid.data.recordings.signals import LowPass, edge_seconds

    rate = filtered.rate / profile.stride
    zero = dict.fromkeys(names, 0.0)
    edge = int(math.ceil(edge_seconds(filtered.cutoff) * rate))
    if profile.rebuild is None or filtered.cutoff >= NYQUIST_SHARE * rate:
        return zero
    if any(len(f[0]) <= 4 * edge for f in profile.frames):
        return zero
    low = LowPass(filtered.cutoff, rate)
    frames, fixed, targets = [], [], []
    data = zip(profile.frames, profile.targets, profile.residuals(values), strict=True)
    for c, ((q, qd, qdd), y, r) in enumerate(data):
        known, _ = profile.rebuild(c, q, qd, qdd)
        keep = slice(edge, len(q) - edge)
        states = tuple(low.apply(a)[keep] for a in (q, qd, qdd))
        known_2, fixed_2 = profile.rebuild(c, *states)
        targets.append(low.apply(y - r + known)[keep] - known_2)
        frames.append(states)
        fixed.append(fixed_2)
    shifted = Profile(profile.channels, profile.model, frames, fixed, targets, profile.stride)
    shifted.set_weights(profile.weights)
    found = dict(values)
    for _ in range(ROUNDS if len(names) > 1 else 1):
        for n in names:
            grid = values[n] * np.geomspace(SHIFT_GRID[0], SHIFT_GRID[1], SHIFT_GRID[2])
            found[n], _ = search_1d(shifted, found, n, grid)
    return {n: found[n] - values[n] for n in names}


def _axis_leverage(profile: Profile, values: dict, c: int) -> np.ndarray:
    """(A,) configuration ``c``'s linear fit's leverage in each axis at ``values``: the fixed columns' and the
    actuation columns' (weighted, orthonormalised) squared norms summed over the axis's rows."""
    _, qd, qdd = profile.frames[c]
    w = profile.weights[c]
    e = profile.columns(values, qd, qdd) * w[:, None]
    parts = [e] if profile.fixed[c] is None else [profile.fixed[c] * w[:, None], e]
    a = np.concatenate(parts, axis=-1)
    u, s, _ = np.linalg.svd(a.reshape(-1, a.shape[-1]), full_matrices=False)
    u = u[:, s > s[0] * max(u.shape) * np.finfo(float).eps]
    return np.sum(u.reshape(*a.shape[:2], -1) ** 2, axis=(0, 2))


def solve_searched(ds, settings: SolveSettings, model, solve, progress=None, methods=None) -> SolveResults:
    """The solve of ``settings`` (``solve``: :func:`ineid.identify.solve.solve_dataset`) at the friction velocities
    found by :func:`search`, their std in the channels' records (module doc)."""
    t_start = time.perf_counter()
    names = settings.searched_velocities
    given = {n: float(getattr(settings, n)) for n in FRICTION_VELOCITIES if n not in names}
    start = dataclasses.replace(settings, **{n: 1.0 for n in names})
    first = None
    if settings.two_step:
        first = solve(ds, wrench_settings(ds, start, model), model, progress, methods)
        profile = _two_step_profile(ds, start, model, first)
    else:
        profile = _one_step_profile(ds, start, model)
    values, std = search(profile, names, given)
    filtered = filtered_frames(ds)
    if filtered is not None:  # frames correlated in time: each axis's residual counts kappa_a times
        factors = long_run_factors(profile, names, values, filtered)
        shifts = filter_shifts(profile, names, values, filtered)
        std = {n: math.sqrt(std[n] ** 2 * factors[n] + shifts[n] ** 2) for n in names}
    fixed = dataclasses.replace(settings, **{n: values[n] for n in names})
    if first is not None:
        res = second_step(first, ds, fixed, model, t_start)
    else:
        res = solve(ds, fixed, model, progress, methods)
    records = [{**r, "identified": {n: std[n] for n in names}} if "friction" in r else r for r in res.meta["channels"]]
    return dataclasses.replace(res, meta={**res.meta, "channels": records})


def _rows(channels: ChannelSet, model, q, qd, qdd) -> np.ndarray:
    """``T Phi`` (F, A, 10 n) through the generated CasADi functions (no compilation for a one-off evaluation)."""
    args = [np.asarray(a, dtype=np.float64).T for a in (q, qd, qdd)]
    phi = np.array(channels.casadi_rows(model).map(len(q))(*args))
    return phi.reshape(channels.n_axes(model), len(q), -1).transpose(1, 0, 2)


def _stride(n_frames: int, n_axes: int, n_cols: int) -> int:
    return max(1, math.ceil(n_frames * n_axes * max(n_cols, 1) / MAX_NUMBERS))


def _offset_columns(mask: np.ndarray | None, n_frames: int, n_axes: int) -> np.ndarray:
    """One constant column per axis of ``mask`` (F, A, n_masked; none without): the offsets centring removes."""
    eye = np.eye(n_axes)[:, mask] if mask is not None else np.zeros((n_axes, 0))
    return np.broadcast_to(eye, (n_frames, *eye.shape))


def _one_step_profile(ds, settings: SolveSettings, model) -> Profile:
    """The profile of a one-step fit: ``A`` the unknown links' rows and the offsets'."""
    channels = solve_channels(ds, settings, model)
    with_bias = settings.estimates_offsets
    n_fit, _ = frame_minimum(model, with_bias, channels).split(ds.n_frames, settings.frames)
    n_axes = channels.n_axes(model)
    mask = channels.offset_mask(model) if with_bias else None
    stride = _stride(n_fit, n_axes, len(model.unknown_index))
    values = ds.measured(channels)
    frames, fixed, targets = [], [], []
    for c in range(ds.n_configs):
        q, qd, qdd = (a[c, :n_fit:stride] for a in (ds.q, ds.qd, ds.qdd))
        rows = _rows(channels, model, q, qd, qdd)
        targets.append(values[c, :n_fit:stride] - rows[..., model.known_index] @ ds.theta_known)
        fixed.append(np.concatenate([rows[..., model.unknown_index], _offset_columns(mask, len(q), n_axes)], axis=-1))
        frames.append((q, qd, qdd))

    def rebuild(c, q, qd, qdd):
        rows = _rows(channels, model, q, qd, qdd)
        unknown = np.concatenate([rows[..., model.unknown_index], _offset_columns(mask, len(q), n_axes)], axis=-1)
        return rows[..., model.known_index] @ ds.theta_known, unknown

    profile = Profile(channels, model, frames, fixed, targets, stride, rebuild=rebuild)
    sigma = noise_levels(ds, settings, channels, model)
    if sigma is not None:
        profile.set_weights(np.broadcast_to(1.0 / np.asarray(sigma), (ds.n_configs, n_axes)))
    return profile


def _two_step_profile(ds, settings: SolveSettings, model, first: SolveResults) -> Profile:
    """The profile of step 2: the links fixed at step 1's estimate, ``A`` the offsets and the torque constants'."""
    channels = solve_channels(ds, settings, model)
    _, torque = two_step_channels(channels)
    n_fit, n_axes = first.n_frames_fit, torque.n_axes(model)
    mask = torque.offset_mask(model) if settings.estimates_offsets else None
    blocks = [
        (b, np.asarray(b.channel.torque_constant))
        for b in torque.blocks(model)
        if getattr(b.channel, "identify_k", False)
    ]
    stride = _stride(n_fit, n_axes, n_axes)
    theta = model.full_theta(np.nan_to_num(first.theta_hat), ds.theta_known)
    values = ds.measured(torque)
    frames, fixed, targets = [], [], []
    for c in range(ds.n_configs):
        q, qd, qdd = (a[c, :n_fit:stride] for a in (ds.q, ds.qd, ds.qdd))
        y = values[c, :n_fit:stride]
        targets.append(y - _rows(torque, model, q, qd, qdd) @ theta[c])
        parts = [_offset_columns(mask, len(q), n_axes)]
        if blocks:
            parts.append(k_columns(y, blocks, n_axes))
        fixed.append(np.concatenate(parts, axis=-1))
        frames.append((q, qd, qdd))

    def rebuild(c, q, qd, qdd):
        return _rows(torque, model, q, qd, qdd) @ theta[c], _offset_columns(mask, len(q), n_axes)

    profile = Profile(torque, model, frames, fixed, targets, stride, rebuild=None if blocks else rebuild)
    sigma = torque_noise_levels(ds, settings, channels, torque, model)
    if sigma is not None:
        profile.set_weights(np.broadcast_to(1.0 / np.asarray(sigma), (ds.n_configs, n_axes)))
    return profile
