"""How well the gyro biases are known: their covariance from the recording, and what the gyros cannot tell.

:func:`ineid.data.imu.estimation.estimate_joint_states` solves the bias system
``S beta = sum_k r_k`` (whitened biases ``beta``, module docstring there). Its error is
``S^-1 sum_k v_k``, each frame's contribution ``v_k`` being the gyro noise and the prior's error
(the encoders' derivative, and the maps evaluated at the encoders' angles) as that frame passes them
to the biases; at the estimate ``v_k`` is the frame's whitened gyro residual
``e_k = y_k - G_k qd_k - beta`` (up to ``M_k (beta_hat - beta)``, which sums to nothing).

**The covariance** is the sum of two parts.

- The sandwich ``S^-1 Omega S^-1`` (:func:`bias_covariance`), ``Omega`` the Newey-West estimate
  (Bartlett weights ``w(d) = 1 - |d| / (L + 1)``) of the variance of ``sum_k v_k`` from the residuals:
  white gyro noise alone gives back about ``S^-1``; errors correlated over a few frames (the prior's,
  the low-pass's) count as often as they recur. ``L`` is Andrews' (1991) plug-in for the Bartlett kernel
  from an AR(1) fit per component, ``L = 1.1447 (alpha F)^(1/3)``, at least :data:`MIN_LAG`, at most a
  quarter of the frames.
- The encoders' angle errors ``dq`` propagated through the maps (:func:`angle_covariance`): the gyros
  read ``G(q) qd`` at the true angles, the estimate uses ``G(q_enc)``, an error ``-K_k dq_k``
  (``K_k = d(G qd_k)/dq``, :func:`angle_sensitivity`) reaching the biases as ``-S^-1 sum_k M_k K_k dq_k``.
  A quantized, low-passed angle's error drifts slowly wherever its joint does, and its sum over the
  recording is what no residual shows (the biases absorb its constant part): it is taken as one offset
  per joint over the recording, of std ``s`` (``EstimationSettings.encoder_q_std``, or
  :func:`angle_error_variance`: the residuals' excess over the noise, plus two standard errors, so that an
  error below what the residuals resolve is not claimed absent).

Measured on the tests' recording (MuJoCo, fast motion, an IMU on every moving link; 30 draws of the gyro
noise with the quantization grid shifted at random; ``docs/recordings.md``): the z-scores' RMS over the
identifiable directions was 0.95, 2.3 and 3.1 (|z| up to 3.2, 6.4, 8.9) with 16-, 12- and 10-bit
encoders for ``s_g^2 S^-1``, and is 0.72, 1.11 and 0.87 (|z| up to 2.8, 2.8, 2.9) with both parts. The
sandwich alone gave 0.86, 1.6 and 2.0: the angle errors' sum is mostly a slow drift.

**What the gyros cannot tell** (:func:`unidentified_directions`): a bias ``u`` (stacked over the
gyros) that equals ``G_k w`` for one ``w`` in every frame is the same reading as a constant error
``w`` in the rates: only the prior fixes it (the mean of the encoders' derivative). That is a bias
along a joint's axis for the IMUs on the links after that joint when no gyro further out turns
against it (the last joint's axis, for IMUs on the last link). Such directions are found as the
near-null space of ``sum_k (I - P_k)``, ``P_k`` the projector onto the range of ``G_k``; their
variance is the prior's long-range error, which no estimate from one recording gives, so they are
reported as not identified (the per-axis std is NaN where an axis leans on one), never with a std.
"""

from __future__ import annotations

import numpy as np

UPPER = 2.0
"""Standard errors added to the angle-error variance the residuals give (:func:`angle_error_variance`)."""
MIN_LAG = 10
"""Frames: the smallest Newey-West lag (the plug-in is noisy when the residuals look white)."""
NULL_TOL = 1e-8
"""A direction whose gyro information is below this fraction of the frames is not identified by the gyros."""
LEAN = 0.1
"""A sensor axis whose unit vector has at least this component along an unidentified direction leans on it."""


def newey_west_lag(e: np.ndarray) -> int:
    """Andrews' plug-in lag for the Bartlett kernel from AR(1) fits to the columns of ``e`` (F, m)."""
    f = len(e)
    x = e - e.mean(axis=0)
    num = np.einsum("fm,fm->m", x[1:], x[:-1])
    den = np.einsum("fm,fm->m", x[:-1], x[:-1])
    ok = den > 0
    if not np.any(ok):
        return MIN_LAG
    rho = np.clip(num[ok] / den[ok], -0.97, 0.97)
    var = np.einsum("fm,fm->m", x, x)[ok] / f * (1 - rho**2)  # the innovations' variance
    top = np.sum(4 * rho**2 * var**2 / ((1 - rho) ** 6 * (1 + rho) ** 2))
    bottom = np.sum(var**2 / (1 - rho) ** 4)
    alpha = top / bottom if bottom > 0 else 0.0
    return int(np.clip(np.ceil(1.1447 * (alpha * f) ** (1 / 3)), MIN_LAG, max(MIN_LAG, f // 4)))


def bias_covariance(s_inv: np.ndarray, e: np.ndarray, lag: int | None = None) -> np.ndarray:
    """The whitened biases' covariance: ``S^-1 Omega S^-1``, ``Omega`` the Newey-West long-run variance of
    the summed residuals ``e`` (F, m) with Bartlett weights up to ``lag`` (None: :func:`newey_west_lag`)."""
    f = len(e)
    lag = newey_west_lag(e) if lag is None else int(lag)
    x = e - e.mean(axis=0)  # zero at the exact solution; the mean removes round-off
    omega = x.T @ x
    for d in range(1, min(lag, f - 1) + 1):
        g = x[d:].T @ x[:-d]
        omega += (1 - d / (lag + 1)) * (g + g.T)
    cov = s_inv @ omega @ s_inv
    return 0.5 * (cov + cov.T)


def unidentified_directions(h: np.ndarray) -> np.ndarray:
    """Orthonormal bias directions (k, m) the gyros cannot tell from a constant rate error.

    Args:
        h: (F, m, n) the whitened gyro maps.
    """
    f, m, _ = h.shape
    u, sv, _ = np.linalg.svd(h, full_matrices=False)  # (F, m, r)
    rank = sv > sv.max(axis=1, keepdims=True) * 1e-10 + 1e-300
    u = u * rank[:, None, :]
    free = f * np.eye(m) - np.einsum("fmr,fkr->mk", u, u)  # sum_k (I - P_k)
    w, v = np.linalg.eigh(0.5 * (free + free.T))
    return v[:, w < NULL_TOL * f].T


def leaning_axes(null: np.ndarray) -> np.ndarray:
    """(m,) bool: the axes with a component of at least :data:`LEAN` along an unidentified direction, each
    direction normalised over the axes of one IMU (3 per gyro) so that an IMU's share counts on its own."""
    m = null.shape[1]
    out = np.zeros(m, dtype=bool)
    for d in null:
        for i in range(0, m, 3):
            block = d[i : i + 3]
            norm = np.linalg.norm(block)
            if norm > 1e-6:
                out[i : i + 3] |= np.abs(block / norm) >= LEAN
    return out


def angle_sensitivity(gyro_maps, q: np.ndarray, qd: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """``K_k = d(G(q) qd_k)/dq`` at the encoders' angles (F, m, n), central differences.

    Args:
        gyro_maps: ``q`` (F, n) -> the whitened gyro maps (F, m, n). q, qd: (F, n).
    """
    cols = []
    for j in range(q.shape[1]):
        step = np.zeros(q.shape[1])
        step[j] = eps
        diff = gyro_maps(q + step) - gyro_maps(q - step)
        cols.append(np.einsum("fmn,fn->fm", diff, qd) / (2 * eps))
    return np.stack(cols, axis=2)


def angle_error_variance(
    e: np.ndarray, m_k: np.ndarray, mk: np.ndarray, bk: np.ndarray, prior_var: np.ndarray
) -> float:
    """The encoders' angle-error variance (rad^2, one for all joints) that the residuals do not rule out.

    Per frame ``E|e_k|^2 = tr(M_k M_k) + tr(B_k V B_k^T) + s^2 sum_j |M_k K_kj|^2`` (white unit noise, the
    prior's errors of variance ``V``, angle errors of std ``s``): the least-squares ``s^2`` over the frames
    plus :data:`UPPER` of its standard error (robust to unequal variances), at least zero. The residuals see
    an angle error only where it rises above the gyro noise (on the tests' arm about 3e-4 rad); below, the
    standard error keeps the std from claiming it absent.

    Args:
        e: (F, m) whitened gyro residuals. m_k: (F, m, m) ``I - G_k A_k^-1 G_k^T``. mk: (F, m, n) ``M_k K_k``.
        bk: (F, m, n) ``G_k A_k^-1 P`` (how the prior's errors reach the residuals). prior_var: (n,) ``V``.
    """
    excess = (
        np.einsum("fm,fm->f", e, e) - np.einsum("fmk,fkm->f", m_k, m_k) - np.einsum("fmn,n,fmn->f", bk, prior_var, bk)
    )
    d = np.einsum("fmn,fmn->f", mk, mk)
    dd = float(d @ d) + 1e-300
    est = float(d @ excess) / dd
    se = float(np.sqrt(np.sum((d * (excess - d * est)) ** 2))) / dd
    return max(est + UPPER * se, 0.0)


def angle_covariance(s_inv: np.ndarray, mk: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """The whitened biases' covariance from angle errors of variance ``s2`` (n,) taken as one offset per joint
    over the whole recording (the long-range part no residual shows; a quantized, low-passed angle's error
    drifts slowly where the joint does): ``S^-1 (sum_k M_k K_k) diag(s2) (...)^T S^-1``."""
    t = s_inv @ mk.sum(axis=0)
    return (t * s2) @ t.T
