"""The excitation design's criterion: the scaled information of a trajectory's samples and its gradient.

The base parameters a design is for (:class:`DesignBase`), the scaled regressor
``Phi_k = D^-1 Psi_k[:, base columns] S`` and its exact derivatives along the states
(forward-mode AD of the measurement channels' jit-safe rows, :meth:`ineid.channels.ChannelSet.jax_rows_function`:
the generated JAX regressor of the base wrench by default), the criteria ``-log det M``
(D-optimality) and ``log cond Phi`` with their gradients ``df/dPhi``, and the evaluation of
a finished trajectory (:class:`DesignEvaluation`). The maths is in :mod:`ineid.excite.design`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ineid.channels import BASE_WRENCH, ChannelSet
from ineid.channels.wrench import WrenchSensor
from ineid.data.synthesis.noise import NoiseModel
from ineid.errors import ExcitationError
from ineid.identify.identifiability import BaseParameters, base_parameters, numerical_rank

CRITERIA = ("d-opt", "cond")
DEFAULT_CHUNK = 160
"""Samples per call of the compiled regressor and its derivatives (the design grid of 5 harmonics)."""
DESIGN_NOISE = {"force": 0.5, "moment": 0.05, "tau": 0.05}
"""Default noise of the design: the wrench's (N, N*m), the reference level of ``ineid study noise``, and joint
torques' (N*m, BIRDy's TX40 default)."""


@dataclass(frozen=True)
class DesignBase:
    """The base parameters a design is for: the unknown links', with or without sensor offsets.

    Attributes:
        names: (r,) base parameter names.
        columns: (r,) each one's column in ``[I_A | Psi]`` (``A +`` its column in the
            ``10 n_links`` regressor columns; ``A`` the channels' axes, six for the base wrench).
        scales: (r,) characteristic scales ``S`` (SI units of each parameter).
        cad: (r,) the CAD values ``B theta_cad``.
        base: the underlying :class:`BaseParameters`.
        bias: constant offsets are identified too (the regressor is centred per axis).
        channels: the measurement channels designed for (their rows ``T Phi``).
        n_axes: ``A``.
    """

    names: tuple[str, ...]
    columns: np.ndarray
    scales: np.ndarray
    cad: np.ndarray
    base: BaseParameters
    bias: bool
    channels: ChannelSet = BASE_WRENCH
    n_axes: int = 6

    @property
    def rank(self) -> int:
        return len(self.names)


def design_base(model, bias: bool = False, channels: ChannelSet | None = None) -> DesignBase:
    """The structural base parameters of ``model``'s unknown links, as ``ineid solve`` identifies
    them from ``channels`` (default: the base wrench) (:func:`ineid.identify.base_parameters`, with
    ``bias`` for ``--bias estimate``)."""
    channels = BASE_WRENCH if channels is None else channels
    base = base_parameters(model, bias=bias, channels=None if channels == BASE_WRENCH else channels)
    n_axes = channels.n_axes(model)
    idx = base.base_index
    n_u = base.n_link_params
    # the rows are [I_A | T Phi | E]: a link parameter's column in T Phi, an extra's after the 10 n_links
    columns = np.where(idx < n_u, model.unknown_index[np.minimum(idx, n_u - 1)], 10 * model.n_links + idx - n_u)
    prior = np.concatenate([model.theta_cad[model.unknown_index], np.zeros(base.n_extra)])  # extras: prior 0
    return DesignBase(
        names=base.names,
        columns=n_axes + columns,
        scales=base.scales[idx],
        cad=base.B @ prior,
        base=base,
        bias=bool(bias),
        channels=channels,
        n_axes=n_axes,
    )


def centred(phi: np.ndarray) -> np.ndarray:
    """``Phi_k - mean_j Phi_j`` (N, A, r): the offsets of every axis profiled out."""
    return phi - phi.mean(axis=0, keepdims=True)


def design_noise(noise: NoiseModel | None = None, channels: ChannelSet | None = None, model=None) -> np.ndarray:
    """(A,) noise std per axis of the design, the channels' axes stacked (default: the base wrench's six).

    A wrench channel (under the base or on a link: six axes ``fx..mz``) takes ``noise.wrench``
    (its sensor's axes), default :data:`DESIGN_NOISE` force and moment; any other channel (joint
    torques, motor currents) the noise recorded under its key (``noise.channels``, ``--noise
    tau=0.05``), default :data:`DESIGN_NOISE` ``tau`` (N*m, mapped through a motor-current
    channel's ``T`` into amperes).

    Raises:
        ExcitationError: a zero noise on an axis, or a noise of the wrong length for its channel.
    """
    if noise is None:
        wrench = np.array([DESIGN_NOISE["force"]] * 3 + [DESIGN_NOISE["moment"]] * 3)
    else:
        wrench = np.asarray(noise.wrench, dtype=np.float64)
    channels = BASE_WRENCH if channels is None else channels
    parts = []
    for c in channels:
        if isinstance(c, WrenchSensor):  # under the base or on a link: six axes fx..mz
            sigma, what = wrench, "the wrench noise (force= and moment=)"
        else:
            given = None if noise is None else dict(noise.channels).get(c.key)
            n_a = c.n_axes(model)
            if given is None:
                t = c.transform()
                sigma = np.full(n_a, DESIGN_NOISE["tau"]) if t is None else DESIGN_NOISE["tau"] * np.abs(np.diag(t))
            else:
                sigma = np.broadcast_to(np.asarray(given, dtype=np.float64), (n_a,))
            what = f"the noise of channel {c.key!r} ({c.key}=STD)"
        if sigma.shape != (c.n_axes(model),) or not np.all(sigma > 0):
            raise ExcitationError(
                f"the design needs a positive noise on every axis of channel {c.key!r}, got "
                f"{np.asarray(sigma).tolist()}; give {what}",
                reason="noise",
            )
        parts.append(sigma)
    return np.concatenate(parts)


def scaled_regressor(y_full: np.ndarray, base: DesignBase, sigma: np.ndarray) -> np.ndarray:
    """``Phi_k = D^-1 [I_A | Psi_k][:, columns] S``: (N, A, 10 n_links) -> (N, A, r)."""
    n, a = y_full.shape[:2]
    ext = np.concatenate([np.broadcast_to(np.eye(a), (n, a, a)), y_full], axis=-1)
    return ext[..., base.columns] * base.scales / sigma[:, None]


def criterion_and_gradient(phi: np.ndarray, criterion: str, gradient: bool = True):
    """``(f, df/dPhi)`` of the per-sample information ``M = Phi^T Phi / N`` (see module doc).

    Args:
        phi: (N, A, r) scaled regressor.
        criterion: ``"d-opt"`` (``-log det M``) or ``"cond"`` (``log cond Phi``).

    Returns:
        ``f`` (inf where ``M`` is singular) and (N, A, r) ``df/dPhi`` (None without
        ``gradient`` or where ``f`` is inf). With ``dM = df/dM`` symmetric,
        ``df/dPhi_k = (2/N) Phi_k dM``.
    """
    n, _, r = phi.shape
    a = phi.reshape(-1, r)
    m = a.T @ a / n
    if criterion == "d-opt":
        try:
            chol = np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            return math.inf, None
        f = -2.0 * float(np.sum(np.log(np.diag(chol))))
        if not gradient:
            return f, None
        inv_l = np.linalg.solve(chol, np.eye(r))
        dm = -(inv_l.T @ inv_l)
    elif criterion == "cond":
        lam, vec = np.linalg.eigh(m)
        if not lam[0] > 0:
            return math.inf, None
        f = 0.5 * float(np.log(lam[-1] / lam[0]))
        if not gradient:
            return f, None
        dm = 0.5 * (np.outer(vec[:, -1], vec[:, -1]) / lam[-1] - np.outer(vec[:, 0], vec[:, 0]) / lam[0])
    else:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    return f, (2.0 / n) * phi @ dm


@dataclass(frozen=True)
class DesignEvaluation:
    """How well the samples of one trajectory identify the base parameters.

    Attributes:
        n_samples: samples (frames) used.
        d_opt: ``-log det M`` of the per-sample scaled information.
        condition_number: ``cond(Phi)`` of the scaled regressor (inf when rank deficient).
        rank: numerical rank of ``Phi`` (relative tolerance ``RANK_RTOL``).
        std: (r,) expected standard deviations of the base parameters (their units)
            under the design's wrench noise, from all the samples.
        rel_std: (r,) ``std / scales``.
    """

    n_samples: int
    d_opt: float
    condition_number: float
    rank: int
    std: np.ndarray
    rel_std: np.ndarray

    def criterion(self, name: str) -> float:
        return self.d_opt if name == "d-opt" else math.log(self.condition_number)

    def to_dict(self) -> dict:
        return {
            "n_samples": self.n_samples,
            "d_opt": self.d_opt,
            "condition_number": self.condition_number,
            "rank": self.rank,
            "std": self.std.tolist(),
            "rel_std": self.rel_std.tolist(),
        }


def evaluate_design(model, q, qd, qdd, base: DesignBase, sigma: np.ndarray) -> DesignEvaluation:
    """Criteria, rank and expected base-parameter std of frames ``q, qd, qdd`` (F, n_dof)."""
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    f = len(q)
    psi, _ = regressor_and_derivatives(model, q, qd, qdd, derivatives=False, channels=base.channels)
    phi = scaled_regressor(psi, base, sigma)
    phi = centred(phi) if base.bias else phi
    a = phi.reshape(-1, base.rank)
    sv = np.linalg.svd(a, compute_uv=False)
    rank = numerical_rank(sv)
    r = base.rank
    ok = rank >= r and sv[r - 1] > 0
    d_opt = criterion_and_gradient(phi, "d-opt", gradient=False)[0] if ok else math.inf
    cond = float(sv[0] / sv[r - 1]) if ok else math.inf
    if ok:
        inv = np.linalg.inv(a.T @ a)
        rel = np.sqrt(np.maximum(np.diag(inv), 0.0))
    else:
        rel = np.full(r, np.inf)
    return DesignEvaluation(f, d_opt, cond, rank, rel * base.scales, rel)


@functools.cache
def _regressor_jet(jax_regressor):
    """Jitted ``(q, qd, qdd, g) -> (Psi, dPsi)``: the regressor (any jit-safe rows function) and its exact derivatives.

    ``Psi`` (N, A, 10 n_links); ``dPsi[d]`` (3 n_dof, N, A, 10 n_links) its derivative along
    state coordinate ``d`` of every sample (``q_1..q_n, qd_1..qd_n, qdd_1..qdd_n``), by
    forward-mode AD (``jax.jvp``, vmapped over the ``3 n`` directions). Cached per
    rows function (the base wrench's: the generated module's): every design of a robot
    shares the one compilation. Measured on the
    7-joint Z1 (2-core machine, CPU time): forward mode compiles in 46 s and runs in 20 ms
    for 160 samples; the reverse-mode pull-back (``jax.vjp``) compiled in 47 s and ran in
    54 ms (both under the same load).
    """
    import jax
    import jax.numpy as jnp

    def jet(q, qd, qdd, gravity):
        n = q.shape[-1]

        def along(direction):
            tangents = tuple(jnp.broadcast_to(direction[k * n : (k + 1) * n], q.shape) for k in range(3))
            return jax.jvp(lambda a, b, c: jax_regressor(a, b, c, gravity), (q, qd, qdd), tangents)

        psi, _ = along(jnp.zeros(3 * n))
        return psi, jax.vmap(lambda d: along(d)[1])(jnp.eye(3 * n))

    return jax.jit(jet)


@functools.cache
def _design_rows(rows, extra):
    """``[T Phi | E]``: the channels' rows and their extra kept columns (friction, armature), jit-safe."""
    if extra is None:
        return rows

    def both(q, qd, qdd, gravity):
        import jax.numpy as jnp

        return jnp.concatenate([rows(q, qd, qdd, gravity), extra(q, qd, qdd)], axis=-1)

    return both


def regressor_and_derivatives(
    model, q, qd, qdd, chunk: int = DEFAULT_CHUNK, derivatives: bool = True, channels: ChannelSet | None = None
):
    """The channels' rows ``Psi = [T Phi | E](q_k, qd_k, qdd_k)`` (F, A, 10 n_links + n_extra) and, with
    ``derivatives``, ``dPsi`` (3 n_dof, F, A, 10 n_links + n_extra); ``channels`` default the base wrench
    (``A = 6``, no extra columns). ``E`` (friction, armature, offsets) in the channels' own axes.

    Evaluated in padded chunks of ``chunk`` samples, so one compilation serves every size.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (q, qd, qdd))
    channels = BASE_WRENCH if channels is None else channels
    fn = _regressor_jet(_design_rows(channels.jax_rows_function(model), channels.jax_extra_rows_function(model)))
    gravity = np.asarray(model.gravity, dtype=np.float64)
    f = len(q)
    psis, jets = [], []
    for start in range(0, f, chunk):
        part = [a[start : start + chunk] for a in (q, qd, qdd)]
        m = len(part[0])
        if m < chunk:
            part = [np.concatenate([a, np.zeros((chunk - m, a.shape[1]))]) for a in part]
        psi, jet = fn(*part, gravity)
        psis.append(np.asarray(psi)[:m])
        if derivatives:
            jets.append(np.asarray(jet)[:, :m])
    psi = np.concatenate(psis)
    return (psi, np.concatenate(jets, axis=1)) if derivatives else (psi, None)
