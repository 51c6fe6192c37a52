"""Stacked linear systems ``W theta_unknown = y`` of frames, and the parameter scales.

For one configuration with frames ``k = 1..F`` the measurement channels
(:class:`ineid.channels.ChannelSet`, ``A`` stacked axes a frame; the base wrench: six) read
``y_k = R_u(s_k) theta_u + R_k(s_k) theta_k`` with ``R = T Phi`` their stacked rows at the
unknown and known links' columns, so

    W = [R_u(s_1) E(s_1); ...; R_u(s_F) E(s_F)]      (AF, 10 n_unknown + n_extra)
    y = [y_1 - R_k(s_1) theta_k; ...]                 (AF,)

with rows in frame-major order (frame 1's axes, ``fx..mz`` for the base wrench, then frame
2's, ...) and the channels' extra kept columns ``E`` last (:mod:`ineid.identify.extras`; zero columns without). Rows
come from :meth:`ineid.channels.ChannelSet.rows_split` (the base wrench: the generated JAX
code through :meth:`ineid.RobotModel.regressor_split`, compiled once, chunked); the CasADi
path (:func:`stack_casadi`) evaluates the generated CasADi functions instead, as an
independent route that needs no compilation. The solvers themselves do not form these
stacks (:mod:`ineid.identify.fused`); they are the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.channels import BASE_WRENCH, ChannelSet
from ineid.errors import IdentificationError
from ineid.params import N_PARAMS_PER_LINK

MASSLESS_KG = 1e-6
"""kg: a CAD mass at or below this is none (:data:`ineid.robots.inertial.FRAME_MASS`)."""


def parameter_scales(theta_cad_unknown: np.ndarray) -> np.ndarray:
    """Typical magnitude of each unknown parameter, from the CAD values (same units).

    Per link: mass ``m``; first moments ``m l``; inertias ``m l^2``, with
    ``l^2 = tr(Sigma_O) / m = tr(I_O) / (2 m)`` the mean squared distance of the mass from
    the link origin. Used to make solvers unit-consistent: the null-space rule and the
    prior pull measure ``(theta - theta_prior) / scale``.

    Args:
        theta_cad_unknown: (10 * n_unknown,).

    Returns:
        (10 * n_unknown,) positive scales.
    """
    cad = np.asarray(theta_cad_unknown, dtype=np.float64).reshape(-1, N_PARAMS_PER_LINK)
    m = np.abs(cad[:, 0])
    trace = cad[:, 4] + cad[:, 6] + cad[:, 9]
    length = np.sqrt(np.maximum(trace, 1e-12) / (2.0 * np.maximum(m, 1e-12)))
    # A link whose CAD has no mass (a frame, a tool flange named as a payload) has no scale of its
    # own: it gets the mean mass and length of the unknown links with mass (1 kg, 0.1 m if none),
    # not 1e-12, which would make its columns vanish from every rank decision.
    massless = m <= MASSLESS_KG
    if np.any(massless):
        heavy = ~massless
        m = np.where(massless, float(np.mean(m[heavy])) if heavy.any() else 1.0, m)
        length = np.where(massless, float(np.mean(length[heavy])) if heavy.any() else 0.1, length)
    scales = np.empty_like(cad)
    scales[:, 0] = m
    scales[:, 1:4] = (m * length)[:, None]
    scales[:, 4:10] = (m * length**2)[:, None]
    return np.maximum(scales, 1e-12).ravel()


def stack(model, q, qd, qdd, wrench, theta_known, channels: ChannelSet | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(W, y)`` of each configuration: (C, AF, 10 n_unknown + n_extra) and (C, AF).

    Args:
        model: the :class:`ineid.RobotModel` (its unknown links define the columns).
        q, qd, qdd: (C, F, n_dof).
        wrench: (C, F, A) the channels' measured values, stacked (the base wrench: (C, F, 6),
            in the frame of its sensor).
        theta_known: (10 n_known,) the known links' parameters.
        channels: the :class:`ineid.channels.ChannelSet` measured; None: the base wrench in
            the base frame. A channel with a transform ``T`` has rows ``T Phi``.
    """
    channels = BASE_WRENCH if channels is None else channels
    n_axes = channels.n_axes(model)
    q, qd, qdd, wrench = (np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench))
    if q.ndim != 3 or wrench.shape != q.shape[:2] + (n_axes,):
        raise ValueError(f"expected q (C, F, n_dof) and values (C, F, {n_axes}), got {q.shape} and {wrench.shape}")
    c, f, _ = q.shape
    rows_u, rows_k = channels.rows_split(model, q, qd, qdd)
    known = rows_k @ np.asarray(theta_known, dtype=np.float64)
    if channels.n_extra(model):
        rows_u = np.concatenate([rows_u, channels.extra_rows(model, q, qd, qdd)], axis=-1)
    w = rows_u.reshape(c, n_axes * f, -1)
    y = (wrench - known).reshape(c, n_axes * f)
    return w, y


def predict_wrench(
    model, q, qd, qdd, theta, channels: ChannelSet | None = None, extra: np.ndarray | None = None
) -> np.ndarray:
    """``T Phi(q, qd, qdd) @ theta + E(q, qd, qdd) @ x`` per configuration, the channels stacked: (C, F, n_dof) x3,
    theta (C, 10 n_links), extra ``x`` (C, n_extra) or None (zero) -> (C, F, A) (each channel's
    :meth:`ineid.channels.Channel.predict`, plus its extra kept columns; None: the base wrench)."""
    channels = BASE_WRENCH if channels is None else channels
    theta = np.asarray(theta, dtype=np.float64)
    out = channels.predict(model, q, qd, qdd, theta[:, None, :])
    if extra is not None and channels.n_extra(model):
        e = channels.extra_rows(model, q, qd, qdd)  # (C, F, A, n_e)
        out = out + np.einsum("cfae,ce->cfa", e, np.asarray(extra, dtype=np.float64))
    return out


def stack_casadi(
    model, q, qd, qdd, wrench, theta_known, channels: ChannelSet | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(W, y)`` of one configuration through the generated CasADi functions; (AF, 10 n_u + n_extra), (AF,)."""
    channels = BASE_WRENCH if channels is None else channels
    n_axes = channels.n_axes(model)
    q, qd, qdd, wrench = (np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench))
    f = q.shape[0]
    mapped = channels.casadi_rows(model).map(f)
    y_all = np.array(mapped(q.T, qd.T, qdd.T)).reshape(n_axes, f, -1).transpose(1, 0, 2)  # (F, A, 10 n)
    w = y_all[..., model.unknown_index]
    if channels.n_extra(model):
        extra = np.array(channels.casadi_extra_rows(model).map(f)(q.T, qd.T, qdd.T))
        w = np.concatenate([w, extra.reshape(n_axes, f, -1).transpose(1, 0, 2)], axis=-1)
    known = y_all[..., model.known_index] @ np.asarray(theta_known, dtype=np.float64)
    return w.reshape(n_axes * f, -1), (wrench - known).reshape(n_axes * f)


def check_frames(n_frames: int, rank_needed: int, n_axes: int = 6) -> None:
    """Refuse fewer frames than equations needed: ``A F >= rank`` of the identifiable part (``A`` axes a frame).

    A necessary count only: the fewest frames that can determine the base parameters are often more
    (:mod:`ineid.identify.frame_minimum`); the solvers refuse by that minimum where it applies (one
    recording's frames), and by this count only for several recordings with their own offsets."""
    needed = -(-rank_needed // n_axes)
    if n_frames < needed:
        raise IdentificationError(
            f"{n_frames} frame{'s' if n_frames != 1 else ''} give {n_axes * n_frames} equations for "
            f"{rank_needed} identifiable parameters; use at least {needed} frames (more with noise)",
            status="too_few_frames",
        )


@dataclass
class Offsets:
    """The per-axis means taken out of stacked systems for constant offsets (the bias; six for the base wrench).

    With a bias ``b`` (A,) the frames read ``y_k = W_k theta + b + e_k``. Minimizing over
    ``b`` first gives ``b = ybar - Wbar theta`` (means over the frames, per axis), and what
    is left is the least squares of the centred system ``y_k - ybar = (W_k - Wbar) theta``
    (Frisch-Waugh-Lovell): fitting the centred system *is* the joint fit of ``theta`` and
    ``b``, for every method, with one fewer degree of freedom per offset.

    Attributes:
        w_mean: (C, A, 10 n_u) ``Wbar`` per configuration.
        y_mean: (C, A) ``ybar``.
        n_frames: frames the means were taken over.
        mask: (A,) bool, the axes with offsets (the others are not centred: ``b_a = 0``);
            None: every axis (:meth:`ineid.channels.ChannelSet.offset_mask`).
    """

    w_mean: np.ndarray
    y_mean: np.ndarray
    n_frames: int
    mask: np.ndarray | None = None

    @property
    def n_offsets(self) -> int:
        return int(self.y_mean.shape[-1] if self.mask is None else np.count_nonzero(self.mask))

    def bias(self, theta_u: np.ndarray) -> np.ndarray:
        """``b = ybar - Wbar theta`` (C, A) for the unknown links' parameters ``theta_u`` (C, 10 n_u); 0 off the mask"""
        b = self.y_mean - np.einsum("cap,cp->ca", self.w_mean, np.nan_to_num(theta_u))
        return b if self.mask is None else b * self.mask

    @staticmethod
    def concat(parts: list[Offsets]) -> Offsets:
        return Offsets(
            np.concatenate([o.w_mean for o in parts]),
            np.concatenate([o.y_mean for o in parts]),
            parts[0].n_frames,
            parts[0].mask,
        )


def remove_offsets(
    w: np.ndarray, y: np.ndarray, n_axes: int = 6, mask: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, Offsets]:
    """Centre stacked systems per axis (``n_axes`` a frame; only ``mask``'s axes when given):
    ``(W - Wbar, y - ybar, Offsets)``; shapes as :func:`stack`'s."""
    c, rows, p = w.shape
    f = rows // n_axes
    w4, y3 = w.reshape(c, f, n_axes, p), y.reshape(c, f, n_axes)
    wm, ym = w4.mean(axis=1), y3.mean(axis=1)
    mask = None if mask is None or np.all(mask) else np.asarray(mask, dtype=bool)
    if mask is None:
        return (w4 - wm[:, None]).reshape(c, rows, p), (y3 - ym[:, None]).reshape(c, rows), Offsets(wm, ym, f)
    wc = (w4 - (wm * mask[:, None])[:, None]).reshape(c, rows, p)
    yc = (y3 - (ym * mask)[:, None]).reshape(c, rows)
    return wc, yc, Offsets(wm, ym, f, mask)
