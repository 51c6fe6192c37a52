"""Which combinations of the unknown parameters the measurements determine.

The stacked regressor ``W`` (AF x 10n: the rows of the measurement channels,
:class:`ineid.channels.ChannelSet`, ``A`` axes a frame; the base wrench by default, six) of
generic frames has a structural rank ``r``
that no choice of frames can raise: some directions ``n`` of parameter space give
``W n = 0`` for every motion. With links 3 and 4 of the built-in arm unknown, ``r = 17``
of 20: mass on the elbow axis does not feel the elbow turn, so link 4's mass, its first
moment along the axis, and the equal pair of inertias perpendicular to the axis that such
a line of mass carries act on the base exactly as if welded to link 3.

What the data determine are ``r`` *base parameters* ``beta = B theta``. ineid picks them
by scanning the standard parameters in chain order (earlier links first) and keeping each
one whose regressor column is independent of those kept (Gautier 1990): the kept ones
``theta_b`` are the base columns, the rest ``theta_d`` depend on them through
``W_d = W_b K``, so ``W theta = W_b (theta_b + K theta_d)`` and

    beta = theta_b + K theta_d      (named like "upper_arm.m + forearm.m")

Each dependent parameter gives one null direction ``e_d - sum_b K_bd e_b``: a transfer of
that parameter of a later link onto the earlier link's parameters. A standard parameter is
individually identifiable when no null direction touches it.

Ranks are taken on the regressor scaled by :func:`ineid.identify.systems.parameter_scales`
(unit-consistent columns), with one tolerance relative to its largest singular value
(:func:`rank_tolerance`), used by the SVD and the column scan alike.

References:
    Gautier (1990), Numerical calculation of the base inertial parameters of robots.
    Khalil & Dombre (2002), Modeling, identification and control of robots, ch. 12.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ineid.channels import BASE_WRENCH, ChannelSet
from ineid.errors import IdentificationError
from ineid.identify.extras import extra_scales
from ineid.identify.frame_minimum import RANK_RTOL, FrameMinimum, frame_minimum_from_regressor, numerical_rank
from ineid.identify.systems import parameter_scales, stack_casadi
from ineid.params import param_names

STRUCTURAL_FRAMES = 200
"""Generic frames used to find the structural base parameters."""

_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _greedy_independent(w: np.ndarray, rtol: float = 1e-7, atol: float | None = None) -> list[int]:
    """Columns of ``w`` kept in order when each adds a new direction (Gram-Schmidt).

    A column is kept when its residual after the kept ones exceeds ``atol`` (an absolute
    tolerance: the rank decisions' own, see :func:`rank_tolerance`) or, without ``atol``,
    ``rtol`` of its own norm.
    """
    kept: list[int] = []
    basis = np.zeros((w.shape[0], 0))
    for j in range(w.shape[1]):
        col = w[:, j]
        norm = np.linalg.norm(col)
        if norm == 0 or (atol is not None and norm <= atol):
            continue
        resid = col - basis @ (basis.T @ col)
        resid = resid - basis @ (basis.T @ resid)  # re-orthogonalize once
        if np.linalg.norm(resid) > (rtol * norm if atol is None else atol):
            kept.append(j)
            basis = np.column_stack([basis, resid / np.linalg.norm(resid)])
    return kept


def rank_tolerance(singular_values: np.ndarray, rtol: float = RANK_RTOL) -> float:
    """The one absolute tolerance of the rank decisions on a scaled regressor: ``rtol`` times its
    largest singular value (the regressor's scale; its columns are already in units of the
    parameters' physical scales, :func:`ineid.identify.systems.parameter_scales`)."""
    s = np.asarray(singular_values)
    return float(rtol * s.max()) if s.size else 0.0


@dataclass(frozen=True)
class BaseParameters:
    """The identifiable combinations ``beta = B theta_unknown`` and the null space.

    Attributes:
        param_names: (10 n_u,) standard parameter names, ``"<link>.<param>"``.
        base_index: (r,) standard parameters kept as base columns.
        dependent_index: (10 n_u - r,) the others.
        K: (r, 10 n_u - r) ``beta = theta[base_index] + K @ theta[dependent_index]``.
        B: (r, 10 n_u) the same map on the whole vector.
        null_basis: (10 n_u, 10 n_u - r) one null direction per dependent parameter.
        identifiable: (10 n_u,) bool, standard parameters the data determine alone.
        names: (r,) readable names of the base parameters.
        scales: (10 n_u,) parameter scales used for ranks and priors.
        n_extra: the channels' extra kept columns ``x`` among the parameters (the last ``n_extra``:
            ``param_names`` is ``[theta_u names, x names]``, and every vector above runs over
            ``[theta_u, x]``); 0 without them.
    """

    param_names: tuple[str, ...]
    base_index: np.ndarray
    dependent_index: np.ndarray
    K: np.ndarray
    B: np.ndarray
    null_basis: np.ndarray
    identifiable: np.ndarray
    names: tuple[str, ...]
    scales: np.ndarray
    n_extra: int = 0

    @property
    def rank(self) -> int:
        return len(self.base_index)

    @property
    def n_link_params(self) -> int:
        """``10 n_u``: the unknown links' parameters, the first columns."""
        return len(self.param_names) - self.n_extra

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def null_directions(self) -> list[str]:
        """Each null direction as text: ``"+1 forearm.m, -1 upper_arm.m, -0.22 upper_arm.mz"``."""
        out = []
        for k in range(self.null_basis.shape[1]):
            v = self.null_basis[:, k]
            terms = [f"{_coef(v[i], signed=True)} {self.param_names[i]}" for i in np.flatnonzero(v)]
            out.append(", ".join(terms))
        return out


def _coef(c: float, signed: bool = False) -> str:
    if np.isclose(abs(c), 1.0, rtol=1e-9, atol=0):
        return ("+1" if c > 0 else "-1") if signed else ("" if c > 0 else "-")
    return f"{c:+.4g}" if signed else f"{c:.4g}"


NAME_RTOL = 1e-6
"""A base parameter's name leaves out a dependent parameter whose coefficient, in the parameters' scales
(:func:`ineid.identify.systems.parameter_scales`), is below this: it moves the combination by less than a
millionth of that parameter's scale against the base parameter's (round-off of the elimination, or a
CAD-rounded angle's 1e-10). :attr:`BaseParameters.B` and ``K`` keep it: the numbers are unchanged."""


def _base_name(name: str, deps: list[tuple[float, str]]) -> str:
    text = name
    for c, dep in deps:
        sign = "+" if c > 0 else "-"
        mag = abs(c)
        text += f" {sign} {dep}" if np.isclose(mag, 1.0, rtol=1e-9, atol=0) else f" {sign} {mag:.4g}*{dep}"
    return text


def base_parameters_from_regressor(w: np.ndarray, names, scales: np.ndarray, n_extra: int = 0) -> BaseParameters:
    """The base parameters of a stacked regressor ``w`` (rows x (10 n_u + n_extra)) of generic frames; its last
    ``n_extra`` columns are the channels' extra kept columns (:attr:`BaseParameters.n_extra`)."""
    w = np.asarray(w, dtype=np.float64)
    ws = w * scales
    _, sv, vt = np.linalg.svd(ws, full_matrices=False)
    rank = numerical_rank(sv)
    # The column scan runs on the rank-r part of ws (its truncated SVD, r x n: the same column
    # geometry without the directions below the SVD's tolerance) with the SVD's tolerance, so the
    # two agree by construction: it can keep no more than r columns, and a column that is zero up
    # to round-off (a CAD-rounded angle's 1e-12) is zero. Fewer than r only on ill-conditioned frames.
    tol = rank_tolerance(sv)
    core = sv[:rank, None] * vt[:rank]
    kept = _greedy_independent(core, atol=tol)
    if len(kept) != rank:
        raise IdentificationError(
            f"the frames are too ill-conditioned to find the base parameters (column scan finds {len(kept)} "
            f"independent columns, the SVD rank is {rank}); use more, and more varied, frames",
            status="ill_conditioned",
        )
    base = np.array(kept, dtype=np.int64)
    dep = np.array([j for j in range(w.shape[1]) if j not in set(kept)], dtype=np.int64)
    if dep.size:
        k_scaled = np.linalg.solve(core[:, base], core[:, dep])  # r x r, independent by the scan
        k = k_scaled * scales[base][:, None] / scales[dep][None, :]  # back to SI units
        k[np.abs(k_scaled) < 1e-9] = 0.0
    else:
        k = np.zeros((len(base), 0))
    n = w.shape[1]
    b = np.zeros((len(base), n))
    b[np.arange(len(base)), base] = 1.0
    b[:, dep] = k
    null = np.zeros((n, len(dep)))
    for col, d in enumerate(dep):
        null[d, col] = 1.0
        null[base, col] = -k[:, col]
    identifiable = ~np.any(np.abs(null) > 0, axis=1)
    named = np.abs(k_scaled) >= NAME_RTOL if dep.size else np.zeros_like(k, dtype=bool)
    base_names = tuple(
        _base_name(names[bi], [(k[row, c], names[d]) for c, d in enumerate(dep) if k[row, c] != 0 and named[row, c]])
        for row, bi in enumerate(base)
    )
    return BaseParameters(
        param_names=tuple(names),
        base_index=base,
        dependent_index=dep,
        K=k,
        B=b,
        null_basis=null,
        identifiable=identifiable,
        names=base_names,
        scales=np.asarray(scales, dtype=np.float64),
        n_extra=int(n_extra),
    )


def generic_frames(model, n_frames: int = STRUCTURAL_FRAMES, seed: int = 0):
    """Random frames within the model's bounds: (n_frames, n_dof) x 3."""
    from ineid.data.synthesis.sampling import model_uniform_states

    return model_uniform_states(model, n_frames, np.random.default_rng(seed))


def regressor_unknown(model, q, qd, qdd, channels: ChannelSet | None = None) -> np.ndarray:
    """Stacked ``Phi`` (AF, 10 n_u) of the unknown links through the generated CasADi functions:
    a one-off analysis needs no compilation (milliseconds for hundreds of frames).

    In the model's frame: each channel's ``T`` is invertible, so ranks, base parameters and
    null spaces are those of ``Phi`` (and the analysis of a base wrench in a sensor frame is
    that of the base frame, as it always was). With extra kept columns ``E`` (in the channels'
    own axes) the rows are ``[T Phi_u | E]`` (AF, 10 n_u + n_extra): ``T`` does not act on ``E``,
    so it cannot be taken out."""
    channels = BASE_WRENCH if channels is None else channels
    n_extra = channels.n_extra(model)
    if len(channels) == 1 and channels.transform(model) is None:  # one channel: the reference's own route
        theta_known = model.theta_cad[model.known_index]
        w, _ = stack_casadi(model, q, qd, qdd, np.zeros((len(q), channels.n_axes(model))), theta_known, channels)
        return w
    n_axes = channels.n_axes(model)
    f = len(q)
    args = [np.asarray(a, dtype=np.float64).T for a in (q, qd, qdd)]
    phi = np.array(channels.casadi_rows(model, transformed=n_extra > 0).map(f)(*args))
    w = phi.reshape(n_axes, f, -1).transpose(1, 0, 2)[..., model.unknown_index]
    if n_extra:
        e = np.array(channels.casadi_extra_rows(model).map(f)(*args)).reshape(n_axes, f, -1).transpose(1, 0, 2)
        w = np.concatenate([w, e], axis=-1)
    return w.reshape(n_axes * f, -1)


def _phi_key(model, channels: ChannelSet | None) -> tuple:
    """What the structural analysis depends on: each channel's ``Phi`` (not its ``T``, key or offsets), named by
    its entries function (the same object on every call: :meth:`ineid.channels.Channel.entries_function`);
    with extra kept columns, every channel's record too (its extra columns, its ``T``)."""
    channels = BASE_WRENCH if channels is None else channels
    phi = tuple(c.entries_function(model) for c in channels)
    if channels.n_extra(model):
        return phi + (channels.with_offsets(False).key_tuple(), channels.extra_names(model))
    return phi


def offset_mask(channels: ChannelSet | None, model, bias: bool) -> np.ndarray | None:
    """The axes centred for offsets: every axis with ``bias`` (the channels'
    :meth:`~ineid.channels.ChannelSet.offset_mask` once they are set up with offsets), none without."""
    return (BASE_WRENCH if channels is None else channels).with_offsets(True).offset_mask(model) if bias else None


def unknown_scales(model, w: np.ndarray, channels: ChannelSet | None = None) -> np.ndarray:
    """The scales of ``[theta_u, x]``: the links' :func:`ineid.identify.systems.parameter_scales`, then the
    extra parameters' :func:`ineid.identify.extras.extra_scales` from the stacked rows ``w`` of generic frames."""
    channels = BASE_WRENCH if channels is None else channels
    scales = parameter_scales(model.theta_cad[model.unknown_index])
    n_extra = channels.n_extra(model)
    if not n_extra:
        return scales
    n_u = len(scales)
    return np.concatenate([scales, extra_scales(w[:, :n_u], scales, w[:, n_u:], channels.n_axes(model))])


def base_parameters(model, bias: bool = False, channels: ChannelSet | None = None) -> BaseParameters:
    """The structural base parameters of ``model``'s unknown links (cached per model and channels).

    From :data:`STRUCTURAL_FRAMES` generic frames (:func:`generic_frames`), evaluated by the
    generated CasADi functions: milliseconds, no JAX compilation. ``bias=True``: with
    constant offsets identified too (six for the base wrench), a reading that is constant
    over every motion cannot be told from them, so the base parameters are those of the
    regressor centred per axis (:func:`centred_regressor`). ``channels``: the measurement
    channels whose rows are analysed (:class:`ineid.channels.ChannelSet`); None: the base
    wrench. Their ``T`` (a sensor frame) is invertible and changes no base parameter: the
    analysis is of ``Phi``. Channels with extra kept columns ``x``
    (:meth:`ineid.channels.ChannelSet.extra_names`): the analysis is over ``[theta_u, x]``
    (:mod:`ineid.identify.extras`: names, scales), ``BaseParameters.n_extra`` of them last.
    """
    phi = _phi_key(model, channels)
    key = (tuple(model.unknown_links), bool(bias)) + (() if phi == _phi_key(model, None) else (phi,))
    cache = _CACHE.setdefault(model, {})
    if key not in cache:
        q, qd, qdd = generic_frames(model)
        w = regressor_unknown(model, q, qd, qdd, channels)
        scales = unknown_scales(model, w, channels)
        chans = BASE_WRENCH if channels is None else channels
        n_axes = chans.n_axes(model)
        w = centred_regressor(w, n_axes, offset_mask(channels, model, bias)) if bias else w
        names = (*param_names(model.unknown_links), *chans.extra_names(model))
        cache[key] = base_parameters_from_regressor(w, names, scales, chans.n_extra(model))
    return cache[key]


def frame_minimum(model, bias: bool = False, channels: ChannelSet | None = None) -> FrameMinimum:
    """The fewest frames that determine the base parameters of ``model``'s unknown links from ``channels``
    (None: the base wrench), with their offsets when ``bias`` (:mod:`ineid.identify.frame_minimum`): the
    rank of the first ``F`` of the :func:`generic_frames`, ``F = 1, 2, ...``; cached like :func:`base_parameters`."""
    base = base_parameters(model, bias, channels)
    cache = _CACHE.setdefault(model, {})
    key = ("frame_minimum", tuple(model.unknown_links), bool(bias), _phi_key(model, channels))
    if key not in cache:
        chans = BASE_WRENCH if channels is None else channels
        w = regressor_unknown(model, *generic_frames(model), channels) * base.scales
        names, units = chans.axes(model), chans.units(model)
        groups = [(n.split(".")[0] if "." in n else "", u) for n, u in zip(names, units, strict=True)]
        mask = offset_mask(channels, model, bias)
        cache[key] = frame_minimum_from_regressor(w, len(names), base.rank, names, groups, mask)
    return cache[key]


def centred_regressor(w: np.ndarray, n_axes: int = 6, mask: np.ndarray | None = None) -> np.ndarray:
    """A stacked regressor (AF, p) minus its mean over the frames, per axis (``n_axes`` a frame; only
    ``mask``'s axes when given).

    A column that the centring cancels to round-off (``||W_c|| <= 1e-9 ||W||``: a
    parameter whose whole effect is a constant reading) is set to zero exactly, so that
    rank decisions do not see its round-off as a direction.
    """
    w = np.asarray(w, dtype=np.float64)
    f = w.shape[0] // n_axes
    w3 = w.reshape(f, n_axes, -1)
    mean = w3.mean(axis=0) if mask is None or np.all(mask) else w3.mean(axis=0) * np.asarray(mask)[:, None]
    wc = (w3 - mean).reshape(n_axes * f, -1)
    tiny = np.linalg.norm(wc, axis=0) <= 1e-9 * np.linalg.norm(w, axis=0)
    wc[:, tiny] = 0.0
    return wc


@dataclass(frozen=True)
class FrameAnalysis:
    """How well a set of frames determines the base parameters.

    Attributes:
        n_frames: frames analysed.
        rank: numerical rank of their stacked regressor.
        structural_rank: the most any frames can reach (the number of base parameters).
        singular_values: of the scaled regressor, descending.
        condition_number: ``s_1 / s_r`` over the identifiable part (inf when deficient).
        min_frames: fewest leading frames that reach ``structural_rank`` (None if never).
        undetermined: base parameters these frames leave undetermined.
        n_axes: measured axes a frame (six: the base wrench).
        minimum: the fewest frames any frames need (:func:`frame_minimum`).
    """

    n_frames: int
    rank: int
    structural_rank: int
    singular_values: np.ndarray
    condition_number: float
    min_frames: int | None
    undetermined: tuple[str, ...]
    n_axes: int = 6
    minimum: FrameMinimum | None = None

    @property
    def ok(self) -> bool:
        return self.rank == self.structural_rank

    def problem(self) -> str | None:
        """A one-line explanation of what is missing, or None when the frames suffice."""
        if self.ok:
            return None
        if self.minimum is not None and self.n_frames < self.minimum.frames:
            return self.minimum.message(self.n_frames)
        shown = ", ".join(self.undetermined[:4]) + (", ..." if len(self.undetermined) > 4 else "")
        return (
            f"the frames determine only {self.rank} of the {self.structural_rank} identifiable parameters "
            f"(undetermined: {shown}); add frames that move every joint with varied positions, velocities "
            "and accelerations (frames at rest show only gravity)"
        )


def analyze_frames(
    model, q, qd, qdd, base: BaseParameters | None = None, bias: bool = False, channels: ChannelSet | None = None
) -> FrameAnalysis:
    """Rank, singular values, conditioning and missing directions of one set of frames.

    Args:
        model: the :class:`ineid.RobotModel`.
        q, qd, qdd: (F, n_dof) frames.
        base: the structural base parameters (default: :func:`base_parameters` with ``bias``).
        bias: constant offsets are identified too (the regressor is centred per axis).
        channels: the measurement channels (None: the base wrench).
    """
    base = base or base_parameters(model, bias, channels)
    n_axes = (BASE_WRENCH if channels is None else channels).n_axes(model)
    q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (q, qd, qdd))
    w = regressor_unknown(model, q, qd, qdd, channels)
    ws = (centred_regressor(w, n_axes, offset_mask(channels, model, bias)) if bias else w) * base.scales
    sv = np.linalg.svd(ws, compute_uv=False)
    rank = numerical_rank(sv)
    r = base.rank
    cond = float(sv[0] / sv[r - 1]) if rank >= r and sv[r - 1] > 0 else float("inf")
    min_frames = None
    for k in range(-(-r // n_axes), len(q) + 1):
        if numerical_rank(np.linalg.svd(ws[: n_axes * k], compute_uv=False)) >= r:
            min_frames = k
            break
    undetermined: tuple[str, ...] = ()
    if rank < r:
        wb = ws[:, base.base_index]
        kept = set(_greedy_independent(wb, rtol=1e-6))
        undetermined = tuple(base.names[i] for i in range(r) if i not in kept)
    return FrameAnalysis(
        len(q), rank, r, sv, cond, min_frames, undetermined, n_axes, frame_minimum(model, bias, channels)
    )


@dataclass(frozen=True)
class BiasCost:
    """What identifying six constant sensor offsets costs, structurally and on given frames.

    A wrench that is constant over the whole recording is indistinguishable from the
    offsets: the weight of mass that never moves (mass at a point all joint axes before it
    pass through) is lost, and the rest of the mass is seen only through how the weight's
    moment changes with the configuration and through accelerations.

    Attributes:
        base: base parameters without offsets.
        base_bias: base parameters with offsets (``base_bias.rank <= base.rank``).
        lost: standard parameters individually identifiable without offsets, not with them.
        new_null_directions: the null directions the offsets add (as text).
        std_inflation: (base_bias.rank,) on the given frames, the standard deviation of each
            base parameter of ``base_bias`` with the offsets over its standard deviation
            without them (same noise); 1 means the offsets cost nothing there.
        condition: (without, with) condition numbers of the scaled, identifiable regressor.
    """

    base: BaseParameters
    base_bias: BaseParameters
    lost: tuple[str, ...]
    new_null_directions: tuple[str, ...]
    std_inflation: np.ndarray
    condition: tuple[float, float]


def bias_cost(model, q, qd, qdd, channels: ChannelSet | None = None) -> BiasCost:
    """Compare identification with and without constant offsets on frames ``q, qd, qdd`` (F, n_dof)
    of ``channels`` (None: the base wrench, six offsets).

    The standard deviations assume the same white noise on every row: ``cov(beta) ~
    (W_b^T W_b)^-1``. Each base parameter of the offset case is a combination
    ``beta_c = M beta`` of the base parameters without offsets (``M = B_c B^+``), so
    its variance without offsets is ``M cov(beta) M^T``.
    """
    base, base_c = base_parameters(model, channels=channels), base_parameters(model, bias=True, channels=channels)
    q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (q, qd, qdd))
    w = regressor_unknown(model, q, qd, qdd, channels)
    wc = centred_regressor(
        w, (BASE_WRENCH if channels is None else channels).n_axes(model), offset_mask(channels, model, True)
    )

    def cov(a: np.ndarray) -> np.ndarray:
        return np.linalg.pinv(a.T @ a)

    def cond(a: np.ndarray, scales: np.ndarray) -> float:
        sv = np.linalg.svd(a * scales, compute_uv=False)
        return float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")

    cov_nb = cov(w[:, base.base_index])
    m = base_c.B @ np.linalg.pinv(base.B)
    var_nb = np.einsum("ij,jk,ik->i", m, cov_nb, m)
    var_c = np.diag(cov(wc[:, base_c.base_index]))
    lost = tuple(
        p for p, a, b in zip(base.param_names, base.identifiable, base_c.identifiable, strict=True) if a and not b
    )
    # the offsets' null directions that are new: those of the column scan's (sparse, readable)
    # directions that each add a dimension to the null space without offsets (scaled coordinates)
    span = base.null_basis / base.scales[:, None]
    texts = base_c.null_directions()
    new_dirs = []
    for k in range(base_c.null_basis.shape[1]):
        trial = np.column_stack([span, base_c.null_basis[:, k] / base.scales])
        if numerical_rank(np.linalg.svd(trial, compute_uv=False), 1e-8) > span.shape[1]:
            span = trial
            new_dirs.append(texts[k])
    return BiasCost(
        base,
        base_c,
        lost,
        tuple(new_dirs),
        np.sqrt(var_c / np.maximum(var_nb, 1e-300)),
        (
            cond(w[:, base.base_index], base.scales[base.base_index]),
            cond(wc[:, base_c.base_index], base_c.scales[base_c.base_index]),
        ),
    )
