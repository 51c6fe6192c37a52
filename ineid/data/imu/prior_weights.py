"""How much to trust an estimate that the sensors check: the prior weights of the joint-state fusion.

An estimate ``p_k`` (the encoders' derivative, say) and the sensors' own estimate ``x_k`` of the same
quantity, frame by frame, differ by ``d_k = p_k - x_k ~ N(0, s^2 + v_k)``: ``s^2`` the variance of the
estimate's error, ``v_k`` the sensors' variance in frame ``k`` (known from their noise and maps, and
varying over the frames: huge where the sensors barely see a joint, as near an alignment of two axes
for IMUs on some links only). :func:`excess_variance` solves for ``s^2`` robustly;
:func:`prior_variance` does it for every joint of the fusion at once (expectation-maximisation); :func:`blend`
combines two
such estimates frame by frame.
"""

from __future__ import annotations

import numpy as np

MEDIAN_CHI2_1 = 0.454936
"""The median of a squared standard normal: ``median(d^2 / var) = 0.455`` for normal ``d`` (a few bad
frames, such as a filter's edges, do not move a median)."""
FLOOR = 1e-3
"""The prior std is at least this fraction of the sensors' own (median) std."""
SEEN = 0.01
"""A frame tells a joint when the sensors carry at least ``1 - SEEN`` of the first pass's information on it."""


def excess_variance(d2: np.ndarray, var1: np.ndarray, unseen: float) -> np.ndarray:
    """Per joint ``s^2`` solving ``median_k d_k^2 / (s^2 + v_k) =`` :data:`MEDIAN_CHI2_1` (module docstring).

    Only the frames where the sensors tell the joint count (``v_k < SEEN unseen``); a mean of ``v_k``, as
    ``median(d^2) / 0.455 - mean(v)``, lets a few near-singular frames swamp it and sends ``s^2`` to the floor:
    the prior then overrules the sensors everywhere. ``s^2`` is at least ``FLOOR^2 median(v)`` (the sensors'
    noise alone explains the differences: the prior is far better); a joint that no frame tells gets
    ``unseen`` (the prior alone gives it there, whatever its weight).

    Args:
        d2: (F, n) squared differences. var1: (F, n) the sensors' own variances. unseen: the variance of a
            joint the sensors do not see (the weak prior's).
    """
    n = d2.shape[1]
    s2 = np.empty(n)
    for j in range(n):
        seen = var1[:, j] < SEEN * unseen
        if not seen.any():
            s2[j] = unseen
            continue
        d, v = d2[seen, j], var1[seen, j]
        floor = FLOOR**2 * float(np.median(v))
        if np.median(d / (floor + v)) <= MEDIAN_CHI2_1:
            s2[j] = floor
            continue
        lo, hi = np.log(floor), np.log(max(float(np.median(d)) / MEDIAN_CHI2_1, floor * 1.0001))
        for _ in range(60):  # median(d / (s^2 + v)) falls as s^2 grows: bisect on log s^2
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.median(d / (np.exp(mid) + v)) > MEDIAN_CHI2_1 else (lo, mid)
        s2[j] = np.exp(0.5 * (lo + hi))
    return s2


def blend(a: np.ndarray, var_a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two estimates of one signal per frame and joint, ``a`` with known variance ``var_a`` (F, n) and ``b``
    with one unknown variance per joint: ``(x, s_b)``, ``x = (a / var_a + b / s_b^2) / (1 / var_a + 1 / s_b^2)``,
    ``s_b^2`` from their differences (:func:`excess_variance`, every frame counted).

    Where ``a`` is good (``var_a << s_b^2``) ``x`` is ``a``; in the frames where it is poor, ``b``.
    """
    a, var_a, b = (np.asarray(x, dtype=np.float64) for x in (a, var_a, b))
    var_a = np.maximum(var_a, 1e-300)
    s2 = excess_variance((a - b) ** 2, var_a, np.inf)
    w = s2 / (s2 + var_a)  # a's weight
    return w * a + (1 - w) * b, np.sqrt(s2)


MAX_FRAMES = 5000
""":func:`prior_variance` reads at most this many frames, evenly spaced (a long recording's estimate is no better
for more, and its cost grows with them)."""
EM_ROUNDS = 40
"""Expectation-maximisation rounds of :func:`prior_variance` (each one batched solve over the frames)."""
WINSOR = 25.0
"""A frame's squared prior error counts at most this many times its joint's median one (a filter's edges)."""


def prior_variance(h: np.ndarray, r: np.ndarray, weak: float) -> np.ndarray:
    """The prior's error variance per joint ``s^2`` from the sensors' residuals at the prior.

    With whitened maps ``h_k`` (F, m, n) and residuals ``r_k = z_k - h_k prior_k`` (biases off), ``r_k = h_k e_k +
    noise``, ``e_k ~ N(0, diag(s^2))`` the prior's errors (independent joints: one encoder each). Expectation-
    maximisation of the marginal likelihood: given ``s^2``, ``e_k``'s posterior has mean ``mu_k = A_k^-1 h_k^T r_k``
    and covariance ``A_k^-1``, ``A_k = h_k^T h_k + diag(1 / s^2)``; then ``s_j^2 = mean_k (mu_kj^2 + (A_k^-1)_jj)``
    (``mu^2`` winsorized at :data:`WINSOR` times its median). Where the sensors see a joint ``mu`` is its error;
    where they cannot tell it from another (an IMU whose gyro sees four joints through three axes, two joint axes
    lining up) the posterior is the prior's own and leaves ``s^2`` as it is, so near-singular frames neither
    swamp nor shrink it. It starts from each joint's residual alone (the others' errors counted in: too large),
    at least :data:`FLOOR` times the sensors' median std; a joint that no sensor sees keeps ``1 / weak``.

    Args:
        h: (F, m, n) whitened maps. r: (F, m) whitened residuals at the prior. weak: a tiny weight (1 / the
            variance of a joint nobody sees).
    """
    step = max(1, len(h) // MAX_FRAMES)  # one variance per joint: a few thousand frames tell it
    h, r = h[::step], r[::step]
    n = h.shape[2]
    hh = np.einsum("fmi,fmj->fij", h, h)
    g = np.einsum("fmj,fm->fj", h, r)
    col = np.diagonal(hh, axis1=1, axis2=2) + weak
    s2 = excess_variance((g / col) ** 2, 1.0 / col, 1.0 / weak)
    seen = (1.0 / col < SEEN / weak).any(axis=0)
    floor = np.array([FLOOR**2 * float(np.median(1.0 / col[:, j])) for j in range(n)])
    s2 = np.where(seen, np.maximum(s2, floor), 1.0 / weak)
    eye = np.eye(n)
    for _ in range(EM_ROUNDS if seen.any() else 0):
        inv = np.linalg.inv(hh + eye / s2)
        mu2 = np.einsum("fij,fj->fi", inv, g) ** 2
        mu2 = np.minimum(mu2, WINSOR * np.median(mu2, axis=0) + 1e-300)
        s2 = np.where(seen, np.maximum(np.mean(mu2 + np.diagonal(inv, axis1=1, axis2=2), axis=0), floor), 1.0 / weak)
    return s2


COVERAGE_MIN = 0.1
"""The gyros see every joint's rate when :func:`coverage` is at least this: a gyro on every moving link of the
built-in arm gives 0.83; on its upper arm and forearm only, 0.006 (the shoulder's axes line up); fewer gyro
axes than joints, 0."""


def coverage(g: np.ndarray) -> float:
    """How well gyros see every joint's rate: the 1st percentile over the frames of the least singular value of
    their stacked maps ``g`` (F, m, n), ``d w / d qd`` in rad/s per rad/s (0 with fewer rows than joints)."""
    g = np.asarray(g, dtype=np.float64)
    if g.shape[1] < g.shape[2] or not len(g):
        return 0.0
    return float(np.percentile(np.linalg.svd(g[:: max(1, len(g) // 2000)], compute_uv=False)[:, -1], 1))
