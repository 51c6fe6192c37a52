"""The ``payload`` section of results: a payload's mass, centre of mass and inertia about it, with std.

For each unknown payload link (:mod:`ineid.robots.payload`) and configuration, from its
identified parameters ``theta_P`` (10, about the link origin, link axes) and their covariance
``T cov(beta) T^T`` (the same that gives ``theta_std``, :func:`ineid.identify.linear.standard_std`):

* ``mass`` (kg), ``com`` (3, m, link frame), ``inertia`` (6, kg*m^2, about the centre of mass in
  link axes, ordered ``Ixx, Ixy, Iyy, Ixz, Iyz, Izz`` like the parameters);
* their standard deviations by the delta method: ``sqrt(diag(J cov J^T))`` with ``J`` the
  Jacobian of the map at the estimate (analytic). NaN where a parameter the quantity depends
  on is not identifiable, or where the configuration failed.
"""

from __future__ import annotations

import numpy as np

from ineid.identify.linear import prior_map

INERTIA_NAMES = ("Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
_INERTIA_INDEX = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


def physical_quantities(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(q, J)``: ``q`` (10,) = ``[m, c (3), I_C (6)]`` of one link's ``theta`` (10,) and ``J`` (10, 10) = dq/dtheta.

    ``c = h / m`` and ``I_C = I_O - (|h|^2 E - h h^T) / m`` (parallel axis theorem), ``h`` the
    first moments, ``I_O`` the inertia about the link origin.
    """
    theta = np.asarray(theta, dtype=np.float64)
    m, h = theta[0], theta[1:4]
    q = np.empty(10)
    jac = np.zeros((10, 10))
    q[0], jac[0, 0] = m, 1.0
    q[1:4] = h / m
    jac[1:4, 0] = -h / m**2
    jac[1:4, 1:4] = np.eye(3) / m
    hh = float(h @ h)
    for k, (a, b) in enumerate(_INERTIA_INDEX):
        shift = ((hh if a == b else 0.0) - h[a] * h[b]) / m  # |h|^2 delta_ab - h_a h_b, over m
        q[4 + k] = theta[4 + k] - shift
        jac[4 + k, 4 + k] = 1.0
        jac[4 + k, 0] = shift / m
        d_shift = np.zeros(3)  # d(shift)/dh
        d_shift += (2.0 * h if a == b else 0.0) / m
        d_shift[a] -= h[b] / m
        d_shift[b] -= h[a] / m
        jac[4 + k, 1:4] = -d_shift
    return q, jac


def payload_section(model, base, theta: np.ndarray, cov_beta: np.ndarray, success: np.ndarray) -> dict | None:
    """``{link: {"mass", "mass_std", "com", "com_std", "inertia", "inertia_std"}}`` per payload (arrays,
    leading axis the configurations); None when the model has no payload.

    Args:
        model: the :class:`ineid.RobotModel` (its ``payloads`` and ``unknown_links``).
        base: the base parameters of the fit.
        theta: (C, 10 n_u) the estimates; cov_beta: (C, r, r) the base parameters' covariance;
        success: (C,) bool.
    """
    if not getattr(model, "payloads", ()):
        return None
    t = prior_map(base)
    cov = np.einsum("pr,crs,qs->cpq", t, np.nan_to_num(cov_beta), t)  # T cov(beta) T^T
    out = {}
    for payload in model.payloads:
        i = list(model.unknown_links).index(payload.link)
        cols = slice(10 * i, 10 * i + 10)
        unidentified = ~np.asarray(base.identifiable[cols], dtype=bool)
        values, stds = np.full((len(theta), 10), np.nan), np.full((len(theta), 10), np.nan)
        for c in range(len(theta)):
            if not success[c] or not np.all(np.isfinite(theta[c, cols])) or theta[c, cols][0] == 0:
                continue
            q, jac = physical_quantities(theta[c, cols])
            var = np.einsum("kp,pq,kq->k", jac, cov[c, cols, cols], jac)
            std = np.sqrt(np.maximum(var, 0.0))
            std[np.any(jac[:, unidentified] != 0, axis=1)] = np.nan
            values[c], stds[c] = q, std
        out[payload.link] = {
            "mass": values[:, 0],
            "mass_std": stds[:, 0],
            "com": values[:, 1:4],
            "com_std": stds[:, 1:4],
            "inertia": values[:, 4:],
            "inertia_std": stds[:, 4:],
        }
    return out
