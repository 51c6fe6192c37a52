"""Stacked linear systems ``W theta_unknown = y`` of frames, and the parameter scales.

For one configuration with frames ``k = 1..F`` the base wrench is
``w_k = Psi_u(s_k) theta_u + Psi_k(s_k) theta_k`` (unknown and known links), so

    W = [Psi_u(s_1); ...; Psi_u(s_F)]            (6F, 10 n_unknown)
    y = [w_1 - Psi_k(s_1) theta_k; ...]          (6F,)

with rows in frame-major order (frame 1's ``fx..mz``, then frame 2's, ...). Regressors
come from :meth:`ineid.RobotModel.regressor_split` (the generated JAX code, compiled once,
chunked); the CasADi path (:func:`stack_casadi`) evaluates the generated CasADi function
instead, as an independent route that needs no compilation. The solvers themselves do
not form these stacks (:mod:`ineid.identify.fused`); they are the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ineid.errors import IdentificationError
from ineid.params import N_PARAMS_PER_LINK
from ineid.channels.pose import regressor_in_sensor, wrench_in_sensor


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
    scales = np.empty_like(cad)
    scales[:, 0] = m
    scales[:, 1:4] = (m * length)[:, None]
    scales[:, 4:10] = (m * length**2)[:, None]
    return np.maximum(scales, 1e-12).ravel()




def stack(model, q, qd, qdd, wrench, theta_known, sensor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(W, y)`` of each configuration: (C, 6F, 10 n_unknown) and (C, 6F).

    Args:
        model: the :class:`ineid.RobotModel` (its unknown links define the columns).
        q, qd, qdd: (C, F, n_dof).
        wrench: (C, F, 6) measured.
        theta_known: (10 n_known,) the known links' parameters.
        sensor: the 6x6 wrench transform ``X`` of a sensor frame
            (:func:`ineid.sensor.wrench_transform`): ``wrench`` is in that frame and every
            regressor row becomes ``X Psi``. None: the base frame.
    """
    q, qd, qdd, wrench = (np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench))
    if q.ndim != 3 or wrench.shape != q.shape[:2] + (6,):
        raise ValueError(f"expected q (C, F, n_dof) and wrench (C, F, 6), got {q.shape} and {wrench.shape}")
    c, f, _ = q.shape
    psi_u, psi_k = model.regressor_split(q, qd, qdd)
    psi_u = regressor_in_sensor(sensor, psi_u)
    known = wrench_in_sensor(sensor, psi_k @ np.asarray(theta_known, dtype=np.float64))
    w = psi_u.reshape(c, 6 * f, -1)
    y = (wrench - known).reshape(c, 6 * f)
    return w, y


def predict_wrench(model, q, qd, qdd, theta, sensor: np.ndarray | None = None) -> np.ndarray:
    """``X Psi(q, qd, qdd) @ theta`` per configuration: (C, F, n_dof) x3, theta (C, 10 n_links) -> (C, F, 6).

    ``sensor`` is the wrench transform ``X`` of :func:`stack` (None: the base frame).
    """
    theta = np.asarray(theta, dtype=np.float64)
    return wrench_in_sensor(sensor, model.base_wrench(q, qd, qdd, theta[:, None, :]))


def stack_casadi(model, q, qd, qdd, wrench, theta_known, sensor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(W, y)`` of one configuration through the generated CasADi function; (6F, 10 n_u), (6F,)."""
    q, qd, qdd, wrench = (np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench))
    f = q.shape[0]
    mapped = model.casadi_regressor.map(f)
    y_all = np.array(mapped(q.T, qd.T, qdd.T)).reshape(6, f, -1).transpose(1, 0, 2)  # (F, 6, 10 n)
    y_all = regressor_in_sensor(sensor, y_all)
    w = y_all[..., model.unknown_index].reshape(6 * f, -1)
    known = y_all[..., model.known_index] @ np.asarray(theta_known, dtype=np.float64)
    return w, (wrench - known).reshape(6 * f)


def check_frames(n_frames: int, rank_needed: int) -> None:
    """Refuse fewer frames than equations needed: ``6 F >= rank`` of the identifiable part."""
    needed = -(-rank_needed // 6)
    if n_frames < needed:
        raise IdentificationError(
            f"{n_frames} frame{'s' if n_frames != 1 else ''} give {6 * n_frames} equations for "
            f"{rank_needed} identifiable parameters; use at least {needed} frames (more with noise)",
            status="too_few_frames",
        )


@dataclass
class Offsets:
    """The per-axis means taken out of stacked systems for six constant sensor offsets (the bias).

    With a bias ``b`` (6,) the frames read ``y_k = W_k theta + b + e_k``. Minimizing over
    ``b`` first gives ``b = ybar - Wbar theta`` (means over the frames, per axis), and what
    is left is the least squares of the centred system ``y_k - ybar = (W_k - Wbar) theta``
    (Frisch-Waugh-Lovell): fitting the centred system *is* the joint fit of ``theta`` and
    ``b``, for every method, with 6 fewer degrees of freedom.

    Attributes:
        w_mean: (C, 6, 10 n_u) ``Wbar`` per configuration.
        y_mean: (C, 6) ``ybar``.
        n_frames: frames the means were taken over.
    """

    w_mean: np.ndarray
    y_mean: np.ndarray
    n_frames: int

    def bias(self, theta_u: np.ndarray) -> np.ndarray:
        """``b = ybar - Wbar theta`` (C, 6) for the unknown links' parameters ``theta_u`` (C, 10 n_u)."""
        return self.y_mean - np.einsum("cap,cp->ca", self.w_mean, np.nan_to_num(theta_u))

    @staticmethod
    def concat(parts: list[Offsets]) -> Offsets:
        return Offsets(np.concatenate([o.w_mean for o in parts]), np.concatenate([o.y_mean for o in parts]),
                       parts[0].n_frames)


def remove_offsets(w: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, Offsets]:
    """Centre stacked systems per wrench axis: ``(W - Wbar, y - ybar, Offsets)``; shapes as :func:`stack`'s."""
    c, rows, p = w.shape
    f = rows // 6
    w4, y3 = w.reshape(c, f, 6, p), y.reshape(c, f, 6)
    wm, ym = w4.mean(axis=1), y3.mean(axis=1)
    return (w4 - wm[:, None]).reshape(c, rows, p), (y3 - ym[:, None]).reshape(c, rows), Offsets(wm, ym, f)
