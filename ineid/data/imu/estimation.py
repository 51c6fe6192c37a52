"""Joint states from everything measured: encoders, gyroscopes, accelerometers, angular-acceleration sensors.

``q`` comes from the encoders. Every IMU reading is linear in the joint rates along the chain
(:mod:`ineid.data.imu.readings`, per frame ``k`` and IMU ``m``, sensor frame):

    gyro   y_w  = G_m(q_k) qd_k + b_m + e            G_m = R^T J_w           (b_m: a constant bias)
    alpha  y_al = G_m(q_k) qdd_k + R^T c_wd + e
    accel  y_a  = A_m(q_k) qdd_k + R^T (c_a + c_wd x r + w x (w x r)) + e     A_m = R^T (J_o - S(r) J_w)

**Velocities.** Stacking the gyros of frame ``k`` (rows whitened by the gyro noise ``s_g``:
``G_k``, ``y_k``, biases ``beta = b / s_g``) and the encoders' derivative as a prior with std ``s_e``
per joint (``P = diag(1 / s_e^2)``), the estimate minimises over all ``qd_k`` and ``beta``

    sum_k |y_k - G_k qd_k - beta|^2 + (qd_k - qd_enc,k)^T P (qd_k - qd_enc,k).

Its normal equations are block-arrow shaped; per frame ``A_k = G_k^T G_k + P`` (n_dof x n_dof),
``c_k = G_k^T y_k + P qd_enc,k``. Eliminating each frame's ``qd_k = A_k^-1 (c_k - G_k^T beta)``
leaves the small bias system (3 per gyro)

    S beta = sum_k (y_k - G_k A_k^-1 c_k),      S = sum_k (I - G_k A_k^-1 G_k^T),

solved once, then every ``qd_k`` by back-substitution: O(n_frames) work and memory, never the
whole recording's matrix. The biases' covariance is not ``s_g^2 S^-1`` (white noise alone) but a
sandwich over the frames' residuals with a Newey-West middle plus the encoders' angle errors
propagated through the maps, since the encoders' errors are correlated over many frames
(:mod:`ineid.data.imu.gyro_bias`). Without ``gyro_bias`` the biases are zero
and each frame is its own least squares.

**Accelerations.** Given ``q`` and the fused ``qd``, the angular-acceleration sensors and the
accelerometers are linear in ``qdd`` alone (no bias), whitened by their noise, with a prior on
``qdd`` (the encoders' second derivative, or with ``time`` and ``qdd_prior="gyros"`` the derivative
of the fused ``qd``) of std ``s_p``: per frame ``qdd_k = (H_k^T H_k + P_p)^-1 (H_k^T z_k + P_p qdd_prior,k)``.
Without such sensors ``qdd`` is the prior.

**Prior weights from the data** (``encoder_qd_std=None``): the sensors' residuals at the prior are
the prior's errors seen through the maps plus the sensors' noise; the prior's error variance per joint
(independent joints: one encoder each) is their maximum-likelihood estimate by expectation-maximisation
over the frames (:func:`ineid.data.imu.prior_weights.prior_variance`: winsorized, so a filter's edges do not
move it, and near-singular frames, where the posterior is the prior's own, neither swamp nor shrink it),
floored at ``1e-3`` of the sensors' own std (the encoders are then far better than the IMUs and win).
With gyro biases, biases and weights alternate (:data:`BIAS_ROUNDS`), starting from the readings' mean
misfit against the prior. The same for ``qdd``. With ``qdd_prior="gyros"``, the filter's ``cutoff``
and gyros that leave a direction unseen, the derivative of the fused ``qd`` is weighed against the
encoders' ``qdd`` frame by frame (:attr:`EstimationSettings.cutoff`).

**What the data cannot tell.** Each frame is estimated on its own (the biases aside): no smoothing
over time, so low-pass the IMU streams as the angles are and give the noise the filter leaves. A
gyro bias along the axis of a joint that no IMU further out sees (the last joint's axis, for an IMU
on the last link) is a constant error in that joint's rate: only the encoders fix it (the mean of
their derivative); the summary names such directions and gives no std for the axes along them. The
maps are evaluated at the encoders' angles, so their errors (quantization, filtering) reach the
biases too; the reported std includes them (``encoder_q_std``, or estimated).

**Checks.** Per IMU and kind the residual RMS (reading less its fitted value) is reported; one
whose RMS exceeds ``max_residual_ratio`` times its noise (and :data:`RESIDUAL_FLOOR` of its readings'
RMS), or whose readings differ from what the encoders predict by more than ``max_encoder_misfit`` of
the predicted RMS (gyro after its bias, and above the noise limit too), is a :class:`DatasetError`
naming the IMU and the fix: it does not sit where the mount says (a wrong link, pose or axis
order), or the noise setting is too low.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ineid.data.imu.gyro_bias import (
    angle_covariance,
    angle_error_variance,
    angle_sensitivity,
    bias_covariance,
    leaning_axes,
    unidentified_directions,
)
from ineid.data.imu.prior_weights import COVERAGE_MIN, blend, coverage, prior_variance
from ineid.data.imu.readings import (
    UNITS,
    ImuMount,
    check_imu_names,
    jacobians_from,
    link_jacobians,
    link_motion,
    moving_index,
)
from ineid.data.imu.settings import BIAS_ROUNDS, RESIDUAL_FLOOR, WEAK, EstimationSettings, EstimationSummary, ImuNoise
from ineid.errors import DatasetError


# -- the least squares -----------------------------------------------------------------------------
def _fuse(h: np.ndarray, z: np.ndarray, prior: np.ndarray, p: np.ndarray, bias: bool):
    """Per frame ``min |z_k - h_k x_k - beta|^2 + |x_k - prior_k|^2_P``, ``beta`` shared (if ``bias``).

    Args:
        h: (F, m, n) whitened maps. z: (F, m) whitened readings. prior: (F, n). p: (n,) prior weights.

    Returns:
        ``x`` (F, n), ``beta`` (m,), ``S^-1`` (m, m) (``cov(beta)`` for white errors; zeros without ``bias``),
        ``diag(A_k^-1)`` (F, n).
    """
    f, m, n = h.shape
    ht = np.swapaxes(h, 1, 2)
    a = ht @ h + np.diag(p)
    c = np.einsum("fnm,fm->fn", ht, z) + p * prior
    chol = np.linalg.cholesky(a)

    def solve(rhs):  # A_k^-1 rhs_k, rhs (F, n, k)
        y = np.linalg.solve(chol, rhs)
        return np.linalg.solve(np.swapaxes(chol, 1, 2), y)

    beta, cov = np.zeros(m), np.zeros((m, m))
    if bias and m:
        x0 = solve(c[..., None])[..., 0]
        s = f * np.eye(m) - np.einsum("fmn,fnk->mk", h, solve(ht))
        rhs = (z - np.einsum("fmn,fn->fm", h, x0)).sum(axis=0)
        cov = np.linalg.inv(0.5 * (s + s.T))
        beta = cov @ rhs
        c = c - np.einsum("fnm,m->fn", ht, beta)
    x = solve(c[..., None])[..., 0]
    inv = solve(np.broadcast_to(np.eye(n), (f, n, n)).copy())
    return x, beta, cov, np.diagonal(inv, axis1=1, axis2=2)


def _bias_cov(h, s_inv, white, qd, p, q, gyro_h, q_std):
    """The whitened biases' covariance: the sandwich over the residuals plus the angle errors' long-range
    part (:mod:`ineid.data.imu.gyro_bias`), and the angle errors' std used (``q_std``, or from the residuals)."""
    ht = np.swapaxes(h, 1, 2)
    a_inv_ht = np.linalg.solve(ht @ h + np.diag(p), ht)
    m_k = np.eye(h.shape[1]) - h @ a_inv_ht
    mk = m_k @ angle_sensitivity(gyro_h, q, qd)
    if q_std is None:
        s2 = np.full(len(p), angle_error_variance(white, m_k, mk, np.swapaxes(a_inv_ht, 1, 2) * p, 1.0 / p))
    else:
        s2 = _prior_std(q_std, None, None, None, False, len(p), "q") ** 2
    return bias_covariance(s_inv, white) + angle_covariance(s_inv, mk, s2), np.sqrt(s2)


def _prior_std(given, h, z, prior, bias: bool, n: int, label: str) -> np.ndarray:
    """The prior's std per joint: ``given`` (a number or one per joint), or from the data (module docstring)."""
    if given is not None:
        s = np.broadcast_to(np.asarray(given, dtype=np.float64), (n,)).copy()
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise DatasetError(f"encoder_{label}_std must be positive numbers (one, or one per joint), got {given!r}")
        return s
    info = np.mean(np.einsum("fmn,fmn->fn", h, h), axis=0)  # the sensors' mean information per joint
    weak = WEAK * (np.max(info) + 1e-300)
    # the biases first from the readings' mean misfit against the prior (its errors average out), then
    # alternately the weights and the biases at those weights
    beta = np.mean(z - np.einsum("fmn,fn->fm", h, prior), axis=0) if bias else np.zeros(h.shape[1])
    s2 = np.zeros(n)
    for i in range(1 + (BIAS_ROUNDS if bias else 0)):
        if i:
            beta = _fuse(h, z, prior, 1.0 / s2, True)[1]
        s2 = prior_variance(h, z - beta - np.einsum("fmn,fn->fm", h, prior), weak)
    return np.sqrt(s2)


def _check_inputs(model, q, qd_enc, qdd_enc, mounts, readings):
    arrays = []
    for label, x in (("q", q), ("qd_enc", qd_enc), ("qdd_enc", qdd_enc)):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != model.n_dof or (arrays and x.shape != arrays[0].shape):
            raise ValueError(f"{label} must have shape (n_frames, {model.n_dof}), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise DatasetError(f"{label}: NaN or infinite values; drop or fill those frames first")
        arrays.append(x)
    check_imu_names(mounts)
    for m in mounts:
        moving_index(model, m)
        got = readings.get(m.name)
        for kind in m.kinds:
            y = None if got is None else got.get(kind)
            if y is None:
                raise DatasetError(
                    f"IMU {m.name!r}: no {kind} readings; give its columns "
                    f"{', '.join(m.columns(kind))} or leave {kind} out of its kinds"
                )
            y = np.asarray(y, dtype=np.float64)
            if y.shape != (len(arrays[0]), 3):
                raise DatasetError(
                    f"IMU {m.name!r}: {kind} readings must have shape ({len(arrays[0])}, 3) on the "
                    f"joints' frames, got {y.shape}"
                )
            if not np.all(np.isfinite(y)):
                raise DatasetError(f"IMU {m.name!r}: NaN or infinite {kind} readings; drop or fill those frames first")
    return arrays


def _misfit_error(name: str, kind: str, detail: str) -> DatasetError:
    return DatasetError(
        f"IMU {name!r}: its {kind} readings do not fit the model ({detail}); check its link and "
        "pose (--imu LINK:x,y,z,roll,pitch,yaw, the sensor frame in the link's) and its axes"
    )


def estimate_joint_states(
    model,
    q,
    qd_enc,
    qdd_enc,
    mounts: Sequence[ImuMount],
    readings: Mapping[str, Mapping[str, np.ndarray]],
    settings: EstimationSettings = EstimationSettings(),
    *,
    time=None,
) -> tuple[np.ndarray, np.ndarray, EstimationSummary]:
    """``qd``, ``qdd`` from the encoders and the IMUs together (equations in the module docstring).

    Args:
        model: the :class:`ineid.RobotModel` (its gravity enters the accelerometers).
        q: (F, n_dof) the encoders' angles (filtered as for identification).
        qd_enc, qdd_enc: (F, n_dof) their derivatives: the priors.
        mounts: the IMUs.
        readings: ``readings[mount.name][kind]`` (F, 3), sensor frame, on ``q``'s frames.
        settings: noise, priors, bias, checks.
        time: (F,) s, only for ``settings.qdd_prior == "gyros"``.

    Returns:
        ``(qd, qdd, summary)``: (F, n_dof) each, and an :class:`EstimationSummary`. Noise-free
        readings (``imu_readings``) give back the true rates to round-off when they determine them.

    Raises:
        DatasetError: missing or malformed readings, or an IMU that does not fit (one line naming it).
    """
    mounts = list(mounts)
    q, qd_enc, qdd_enc = _check_inputs(model, q, qd_enc, qdd_enc, mounts, readings)
    jac = link_jacobians(model, q) if mounts else None
    gyros = [m for m in mounts if "gyro" in m.kinds]
    rates = _fuse_gyros(model, q, jac, qd_enc, mounts, gyros, readings, settings) if gyros else _GyroFit(qd_enc.copy())
    prior = _qdd_prior(settings, rates, qdd_enc, time, bool(gyros))
    qdd, qdd_std, acc_maps, acc_residual = _fuse_accelerations(
        model, q, jac, rates.qd, prior, mounts, readings, settings
    )
    residual = {m.name: {} for m in mounts}
    for name, rms in rates.residual.items():
        residual[name]["gyro"] = rms
    for name, by_kind in acc_residual.items():
        residual[name].update(by_kind)
    summary = EstimationSummary(
        tuple(mounts),
        rates.bias,
        rates.bias_std,
        residual,
        settings.noise,
        rates.std,
        qdd_std,
        settings.qdd_prior,
        len(q),
        rates.bias_cov,
        rates.free,
        rates.q_err,
    )
    _check_fit(mounts, readings, settings, summary, qd_enc, prior, rates.maps, acc_maps)
    return rates.qd, qdd, summary


def _mount_maps(model, q: np.ndarray, jac: np.ndarray, mounts: Sequence[ImuMount], qd: np.ndarray) -> dict:
    """Each IMU's maps from the joint rates to its readings (:func:`ineid.data.imu.readings.jacobians_from`) at
    the angles ``q`` and rates ``qd`` (F, n_dof); ``jac`` the links' Jacobians at ``q``."""
    motion0 = link_motion(model, q, qd, np.zeros_like(qd))
    return {
        m.name: jacobians_from(m, jac[:, moving_index(model, m)], motion0[:, moving_index(model, m)]) for m in mounts
    }


def _shown(std: np.ndarray | None, maps: np.ndarray) -> np.ndarray | None:
    """``std`` (n_dof,) with NaN for a joint no sensor sees in ``maps`` (F, m, n_dof) (its std is the placeholder
    ``1 / weak``)."""
    return None if std is None else np.where(np.abs(maps).sum(axis=(0, 1)) > 0, std, np.nan)


@dataclass
class _GyroFit:
    """The joint rates fused from the gyros and the encoders' derivative (the prior), and the gyros' biases.

    Attributes:
        qd: (F, n_dof) rad/s, the rates (the encoders' derivative without gyros).
        std: (n_dof,) the prior's std per joint, NaN for a joint no gyro sees (None without gyros).
        var: (F, n_dof) ``diag(A_k^-1)``, the whitened rates' variances per frame (None without gyros).
        q_err: (n_dof,) the angle errors' std the biases' covariance takes (None without biases).
        maps: each IMU's maps at ``qd = 0`` (None without gyros).
        h: (F, 3 n_gyros, n_dof) the gyros' maps whitened by their noise (None without gyros).
        bias, bias_std, bias_cov: per gyro: its bias (3,) rad/s, the std (3,) and covariance (3, 3) of it.
        free: per gyro: its share of the bias directions the data leave unidentified, orthonormal rows.
        residual: per gyro: the RMS of its readings less their fitted values, rad/s.
    """

    qd: np.ndarray
    std: np.ndarray | None = None
    var: np.ndarray | None = None
    q_err: np.ndarray | None = None
    maps: dict | None = None
    h: np.ndarray | None = None
    bias: dict = field(default_factory=dict)
    bias_std: dict = field(default_factory=dict)
    bias_cov: dict = field(default_factory=dict)
    free: dict = field(default_factory=dict)
    residual: dict = field(default_factory=dict)


def _fuse_gyros(model, q, jac, qd_enc, mounts, gyros, readings, settings: EstimationSettings) -> _GyroFit:
    """``qd`` from the gyros ``gyros`` (of ``mounts``) with the encoders' ``qd_enc`` as the prior, and the gyros'
    biases when ``settings.gyro_bias`` (the velocities of the module docstring)."""
    noise, n = settings.noise, q.shape[1]
    maps = _mount_maps(model, q, jac, mounts, np.zeros_like(q))
    h = np.concatenate([maps[m.name].gyro_qd for m in gyros], axis=1) / noise.gyro

    def gyro_h(qq):  # the whitened gyro maps at other angles
        jq = link_jacobians(model, qq)
        return (
            np.concatenate([(m.link_R_sensor.T @ jq[:, moving_index(model, m), 0]) for m in gyros], axis=1) / noise.gyro
        )

    z = np.concatenate([np.asarray(readings[m.name]["gyro"], dtype=np.float64) for m in gyros], axis=1) / noise.gyro
    qd_std = _prior_std(settings.encoder_qd_std, h, z, qd_enc, settings.gyro_bias, n, "qd")
    qd, beta, s_inv, qd_var = _fuse(h, z, qd_enc, 1.0 / qd_std**2, settings.gyro_bias)
    white = z - np.einsum("fmn,fn->fm", h, qd) - beta
    res = white * noise.gyro
    cov, null, q_err = np.zeros_like(s_inv), np.zeros((0, len(beta))), None
    if settings.gyro_bias:
        cov, q_err = _bias_cov(h, s_inv, white, qd, 1.0 / qd_std**2, q, gyro_h, settings.encoder_q_std)
        cov = cov * noise.gyro**2
        null = unidentified_directions(h)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    std[leaning_axes(null)] = np.nan
    fit = _GyroFit(qd, _shown(qd_std, h), qd_var, q_err, maps, h)
    for i, m in enumerate(gyros):
        sl = slice(3 * i, 3 * i + 3)
        fit.bias[m.name], fit.bias_std[m.name], fit.bias_cov[m.name] = beta[sl] * noise.gyro, std[sl], cov[sl, sl]
        if len(null):  # this IMU's share of the unidentified directions, orthonormal
            _, sv, vt = np.linalg.svd(null[:, sl])
            if sv[0] > 1e-6:
                fit.free[m.name] = vt[: int(np.sum(sv > 1e-6 * sv[0]))]
        fit.residual[m.name] = float(np.sqrt(np.mean(res[:, sl] ** 2)))
    return fit


def _qdd_prior(settings: EstimationSettings, rates: _GyroFit, qdd_enc: np.ndarray, time, has_gyros: bool) -> np.ndarray:
    """(F, n_dof) the prior on ``qdd``: the encoders' ``qdd_enc``, or with ``settings.qdd_prior == "gyros"`` the
    derivative of the fused ``qd`` over ``time`` (blended with the encoders' where the gyros leave a direction
    unseen and the filter's cut-off is known).

    Raises:
        DatasetError: ``qdd_prior="gyros"`` without ``time`` or without a gyro.
    """
    if settings.qdd_prior != "gyros":
        return qdd_enc
    if time is None or not has_gyros:
        raise DatasetError("qdd_prior='gyros' needs the frames' time and at least one gyro; or use 'encoders'")
    prior = np.gradient(rates.qd, np.asarray(time, dtype=np.float64), axis=0)
    if settings.cutoff is not None and coverage(rates.h * settings.noise.gyro) < COVERAGE_MIN:
        # the gyros leave a direction unseen: there weighed against the encoders' (only then: elsewhere the
        # encoders' qdd, filtered at another cut-off than the wrench, costs the identification more than it
        # saves: 12-bit encoders with a gyro on every link, base error 0.013 against 0.0055 without)
        prior, _ = blend(prior, rates.var * (2 * np.pi * settings.cutoff) ** 2 / 3, qdd_enc)
    return prior


def _fuse_accelerations(model, q, jac, qd, prior, mounts, readings, settings: EstimationSettings):
    """``qdd`` from the angular-acceleration sensors and the accelerometers, given ``q`` and the fused ``qd``,
    with ``prior`` (F, n_dof) as the prior (the accelerations of the module docstring).

    Returns:
        ``(qdd, qdd_std, maps, residual)``: (F, n_dof) (the prior without such sensors); the prior's std per joint,
        NaN for a joint no sensor sees (None without such sensors); each IMU's maps at ``qd`` (None without);
        ``{imu: {kind: RMS of its readings less their fitted values}}``.
    """
    acc = [(m, k) for m in mounts for k in ("alpha", "accel") if k in m.kinds]
    if not acc:
        return prior.copy(), None, None, {}
    noise, n = settings.noise, q.shape[1]
    maps = _mount_maps(model, q, jac, mounts, qd)
    hs, zs = [], []
    for m, k in acc:
        mp, sig = maps[m.name], getattr(noise, k)
        y = np.asarray(readings[m.name][k], dtype=np.float64)
        hs.append((mp.gyro_qd if k == "alpha" else mp.accel_qdd) / sig)
        zs.append((y - (mp.alpha_0 if k == "alpha" else mp.accel_0)) / sig)
    h, z = np.concatenate(hs, axis=1), np.concatenate(zs, axis=1)
    qdd_std = _prior_std(settings.encoder_qdd_std, h, z, prior, False, n, "qdd")
    qdd, _, _, _ = _fuse(h, z, prior, 1.0 / qdd_std**2, False)
    res = z - np.einsum("fmn,fn->fm", h, qdd)
    residual: dict[str, dict[str, float]] = {}
    for i, (m, k) in enumerate(acc):
        residual.setdefault(m.name, {})[k] = float(np.sqrt(np.mean(res[:, 3 * i : 3 * i + 3] ** 2)) * getattr(noise, k))
    return qdd, _shown(qdd_std, h), maps, residual


def _check_fit(mounts, readings, settings, summary, qd_enc, qdd_prior, gyro_maps, acc_maps) -> None:
    """Raise for the worst IMU that does not fit: residual far above its noise, or readings against the encoders."""
    worst = None
    for m in mounts:
        for k, rms in summary.residual_rms[m.name].items():
            ratio = rms / getattr(settings.noise, k)
            y = np.asarray(readings[m.name][k], dtype=np.float64)
            signal = float(np.sqrt(np.mean((y - y.mean(axis=0)) ** 2)))
            if rms <= RESIDUAL_FLOOR * signal:  # the model's own error (filtered readings, the angles' errors)
                continue
            if ratio > settings.max_residual_ratio and (worst is None or ratio > worst[0]):
                sig = getattr(settings.noise, k)
                detail = (
                    f"residual RMS {rms:.3g} {UNITS[k]}, {ratio:.3g} times its noise {sig:g} {UNITS[k]}; "
                    "or raise the noise setting if it is noisier"
                )
                worst = (ratio, m.name, k, detail)
    for m in mounts:
        for k in m.kinds:
            y = np.asarray(readings[m.name][k], dtype=np.float64)
            if k == "gyro":
                pred = np.einsum("fmn,fn->fm", gyro_maps[m.name].gyro_qd, qd_enc)
            else:
                mp = acc_maps[m.name]
                pred = (
                    np.einsum("fmn,fn->fm", mp.gyro_qd, qdd_prior) + mp.alpha_0
                    if k == "alpha"
                    else np.einsum("fmn,fn->fm", mp.accel_qdd, qdd_prior) + mp.accel_0
                )
            d = y - pred
            if k == "gyro" and settings.gyro_bias:
                d = d - d.mean(axis=0)
            rms_d, rms_p = float(np.sqrt(np.mean(d**2))), float(np.sqrt(np.mean(pred**2)))
            limit = max(settings.max_encoder_misfit * rms_p, settings.max_residual_ratio * getattr(settings.noise, k))
            if rms_d > limit:
                ratio = settings.max_residual_ratio * rms_d / limit
                if worst is None or ratio > worst[0]:
                    detail = (
                        f"they differ from what the encoders predict by {rms_d:.3g} {UNITS[k]} RMS, "
                        f"{100 * rms_d / max(rms_p, 1e-300):.0f} % of it"
                    )
                    worst = (ratio, m.name, k, detail)
    if worst is not None:
        raise _misfit_error(worst[1], worst[2], worst[3])


__all__ = [
    "BIAS_ROUNDS",
    "RESIDUAL_FLOOR",
    "WEAK",
    "EstimationSettings",
    "EstimationSummary",
    "ImuNoise",
    "estimate_joint_states",
]
