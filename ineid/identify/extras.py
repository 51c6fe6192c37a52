"""The channels' extra kept columns in identification: ``[theta_u, x]`` as one vector of unknowns.

A channel's model (:mod:`ineid.channels.base`) is ``y = T Phi theta + E x + b + e``: the
extra parameters ``x`` (joint friction ``<joint>.fv``, ``<joint>.fc``, an offset column
``<joint>.offset``, armature ``<joint>.Ia``, ...) are as linear as the links' parameters, so
identification treats them as more columns of the same regressor:

    W = [T Phi_u | E]          (A F, 10 n_u + n_e),     unknowns [theta_u; x]

Everything downstream (base parameters, the fits, the covariance, the null-space rule,
IPOPT) runs over ``[theta_u, x]``: an extra column collinear with a link direction shows up
as a combined base parameter, like any other dependency (``<link>.Izz + <joint>.Ia`` for the
first joint's armature when its link spins about its own ``z`` axis). The links' parameters come
first, in chain order, then the extras in the channels' order
(:meth:`ineid.channels.ChannelSet.extra_names`). An extra's prior is 0.

**Scales.** The rank decisions and the null-space rule measure parameters in units of their
characteristic size (:func:`ineid.identify.systems.parameter_scales` for the links). An extra
parameter gets the size at which its column produces the *typical reading* of the axes it
acts on:

    y_a = sqrt(mean_k sum_p (W_u[k, a, p] s_p)^2)       (the links' typical share of axis a)
    s_j = rms_(a in axes of j) y_a / rms_(k, a in axes of j) E[k, a, j]

over the generic frames of the base-parameter analysis: a viscous coefficient's scale is a
typical torque over a typical joint speed, an armature's a typical torque over a typical
acceleration, an offset's a typical torque. This makes every scaled column about as large as
the links' scaled rows, so the rank tolerance means the same for both, and it does not depend
on the units of ``x``. Where no unknown link acts on those axes, ``y`` is the mean over every
axis (1 if none); a column that is zero on every frame gets scale 1.

**Bounds.** Dissipative friction and armature cannot be negative: in the ``consistent`` method
the parameters named ``*.fv``, ``*.fv+``, ``*.fv-``, ``*.fc``, ``*.fc+``, ``*.fc-`` and ``*.Ia``
are bounded below by 0 (the columns of ``fv-`` and ``fc-`` are ``min(qd, 0)`` and
``-[qd < 0]``, so these too are >= 0 for a dissipative joint: the joint-torque channel's
columns, ``ineid.channels.torque``); offsets and the others are free.
"""

from __future__ import annotations

import numpy as np

NONNEGATIVE_SUFFIXES = ("fv", "fv+", "fv-", "fc", "fc+", "fc-", "Ia")
"""Extra parameters ``<joint>.<suffix>`` that are >= 0 in the ``consistent`` method."""


def extra_scales(w_u: np.ndarray, scales_u: np.ndarray, e: np.ndarray, n_axes: int) -> np.ndarray:
    """Characteristic sizes of the extra parameters (module doc), (n_e,).

    Args:
        w_u: (A F, 10 n_u) the unknown links' stacked rows of generic frames (frame-major).
        scales_u: (10 n_u,) their parameter scales.
        e: (A F, n_e) the extra columns of the same frames.
        n_axes: ``A``.
    """
    e = np.asarray(e, dtype=np.float64)
    n_e = e.shape[1]
    if n_e == 0:
        return np.zeros(0)
    f = e.shape[0] // n_axes
    if w_u.shape[1]:
        typical = np.sqrt(np.mean(((w_u * scales_u).reshape(f, n_axes, -1) ** 2).sum(axis=-1), axis=0))  # (A,)
    else:
        typical = np.zeros(n_axes)
    overall = float(np.mean(typical[typical > 0])) if np.any(typical > 0) else 1.0
    e3 = e.reshape(f, n_axes, n_e)
    out = np.ones(n_e)
    for j in range(n_e):
        axes = np.flatnonzero(np.any(e3[:, :, j] != 0.0, axis=0))
        if axes.size == 0:
            continue
        size = float(np.sqrt(np.mean(typical[axes] ** 2)))
        size = size if size > 0 else overall
        out[j] = size / float(np.sqrt(np.mean(e3[:, axes, j] ** 2)))
    return out


def nonnegative(names) -> np.ndarray:
    """(len(names),) bool: the extra parameters bounded below by 0 in ``consistent`` (module doc)."""
    return np.array([n.rsplit(".", 1)[-1] in NONNEGATIVE_SUFFIXES for n in names], dtype=bool)


def unknown_rows(model, q, qd, qdd, channels) -> tuple[np.ndarray, np.ndarray]:
    """``([T Phi_u | E], T Phi_k)``: (..., A, 10 n_u + n_e) and (..., A, 10 n_k), float64 NumPy.

    :meth:`ineid.channels.ChannelSet.rows_split` with the extra columns appended (the same
    arrays when there are none).
    """
    rows_u, rows_k = channels.rows_split(model, q, qd, qdd)
    if channels.n_extra(model):
        rows_u = np.concatenate([rows_u, channels.extra_rows(model, q, qd, qdd)], axis=-1)
    return rows_u, rows_k


def prior_with_extras(model, channels) -> np.ndarray:
    """``[theta_cad_u, 0]``: the CAD values of the unknown links, then 0 for every extra parameter."""
    prior = np.asarray(model.theta_cad[model.unknown_index], dtype=np.float64)
    n_e = channels.n_extra(model)
    return np.concatenate([prior, np.zeros(n_e)]) if n_e else prior


def split(theta: np.ndarray, n_extra: int) -> tuple[np.ndarray, np.ndarray]:
    """``(theta_u, x)``: the links' and the extras' parts of ``[theta_u, x]`` (last axis)."""
    theta = np.asarray(theta)
    n = theta.shape[-1] - n_extra
    return theta[..., :n], theta[..., n:]
