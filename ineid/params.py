"""The one parameter convention of ineid, converters, and physical-validity checks.

A link's inertial parameters, Pinocchio's order, expressed in the link frame and taken
about the link frame origin ``O``::

    theta = [m, m*cx, m*cy, m*cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]

with ``c`` the centre of mass in the link frame and ``I`` the rotational inertia about
``O`` (matrix entries, so ``Ixy = -integral(x*y dm)``). It relates to the inertia about
the centre of mass by the parallel-axis theorem ``I_O = I_C + m * S(c)^T S(c)``, where
``S(c)`` is the skew-symmetric matrix of ``c``. SI units: kg, kg*m, kg*m^2.

``theta`` is linear in the mass distribution, so parameters of rigidly joined bodies
add once they are expressed in the same frame about the same point.

References:
    Atkeson, An, Hollerbach (1986), Estimation of inertial parameters of manipulator
    loads and links. Wensing, Kim, Slotine (2017), Linear matrix inequalities for
    physically consistent inertial parameter identification.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ineid.errors import PhysicalConsistencyError

PARAM_NAMES: tuple[str, ...] = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
"""Names of the ten parameters of one link, in order."""

N_PARAMS_PER_LINK = 10

# Index pairs of the inertia matrix entries in theta[4:10], Pinocchio's order.
_INERTIA_INDEX = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


def full_theta(
    link_names: Sequence[str], unknown_links: Sequence[str], theta_unknown: np.ndarray, theta_known: np.ndarray
) -> np.ndarray:
    """Every link's parameters in chain order from the unknown links' and the known links'.

    Args:
        link_names: the moving links in chain order.
        unknown_links: the unknown ones, in chain order; the rest are known.
        theta_unknown: (..., 10 * n_unknown), the unknown links in chain order.
        theta_known: (10 * n_known,) or (..., 10 * n_known), broadcast against the batch.

    Returns:
        (..., 10 * n_links) with ``theta[..., 10 i : 10 i + 10]`` the parameters of link ``i``.
    """
    theta_unknown = np.asarray(theta_unknown, dtype=np.float64)
    theta_known = np.asarray(theta_known, dtype=np.float64)
    batch = np.broadcast_shapes(theta_unknown.shape[:-1], theta_known.shape[:-1])
    u = np.broadcast_to(theta_unknown, batch + theta_unknown.shape[-1:]).reshape(batch + (-1, N_PARAMS_PER_LINK))
    k = np.broadcast_to(theta_known, batch + theta_known.shape[-1:]).reshape(batch + (-1, N_PARAMS_PER_LINK))
    unknown, iu, ik, parts = set(unknown_links), 0, 0, []
    for link in link_names:
        if link in unknown:
            parts.append(u[..., iu, :])
            iu += 1
        else:
            parts.append(k[..., ik, :])
            ik += 1
    if iu != u.shape[-2] or ik != k.shape[-2]:
        raise ValueError(f"theta_unknown has {u.shape[-2]} links and theta_known {k.shape[-2]}, expected {iu} and {ik}")
    return np.concatenate(parts, axis=-1)


def param_names(link_names: Sequence[str]) -> list[str]:
    """Names ``"<link>.<param>"`` of a stacked parameter vector, link by link."""
    return [f"{link}.{p}" for link in link_names for p in PARAM_NAMES]


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``S(v)`` with ``S(v) @ w == cross(v, w)``; v: (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], axis=-1),
            np.stack([v[..., 2], z, -v[..., 0]], axis=-1),
            np.stack([-v[..., 1], v[..., 0], z], axis=-1),
        ],
        axis=-2,
    )


def inertia_matrix(theta: np.ndarray) -> np.ndarray:
    """The rotational inertia about the link origin, (..., 10) -> (..., 3, 3)."""
    theta = _as_theta(theta)
    ixx, ixy, iyy, ixz, iyz, izz = (theta[..., k] for k in range(4, 10))
    return np.stack(
        [
            np.stack([ixx, ixy, ixz], axis=-1),
            np.stack([ixy, iyy, iyz], axis=-1),
            np.stack([ixz, iyz, izz], axis=-1),
        ],
        axis=-2,
    )


def theta_from_inertial(mass, com, inertia_com) -> np.ndarray:
    """Parameters about the link origin from mass, centre of mass and inertia about it.

    ``theta = [m, m c, vech(I_C + m S(c)^T S(c))]`` in Pinocchio's order.

    Args:
        mass: (...,) kg.
        com: (..., 3) centre of mass in the link frame, m.
        inertia_com: (..., 3, 3) inertia about the centre of mass, link-frame axes, kg*m^2.

    Returns:
        theta: (..., 10).
    """
    m = np.asarray(mass, dtype=np.float64)
    c = np.asarray(com, dtype=np.float64)
    ic = np.asarray(inertia_com, dtype=np.float64)
    if c.shape[-1:] != (3,) or ic.shape[-2:] != (3, 3):
        raise ValueError(f"com must have shape (..., 3) and inertia_com (..., 3, 3), got {c.shape} and {ic.shape}")
    s = skew(c)
    i_o = ic + m[..., None, None] * np.swapaxes(s, -1, -2) @ s
    out = np.empty(np.broadcast_shapes(m.shape, c.shape[:-1], ic.shape[:-2]) + (10,))
    out[..., 0] = m
    out[..., 1:4] = m[..., None] * c
    for k, (a, b) in enumerate(_INERTIA_INDEX):
        out[..., 4 + k] = i_o[..., a, b]
    return out


def inertial_from_theta(theta) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass, centre of mass and inertia about it, the inverse of :func:`theta_from_inertial`.

    Args:
        theta: (..., 10) Pinocchio order, about the link origin. The mass must be non-zero.

    Returns:
        (mass (...,), com (..., 3), inertia_com (..., 3, 3)).
    """
    theta = _as_theta(theta)
    m = theta[..., 0]
    if np.any(m == 0):
        raise PhysicalConsistencyError("mass is zero: the centre of mass is undefined; give the link a positive mass")
    c = theta[..., 1:4] / m[..., None]
    s = skew(c)
    ic = inertia_matrix(theta) - m[..., None, None] * np.swapaxes(s, -1, -2) @ s
    return m, c, ic


def pseudo_inertia(theta) -> np.ndarray:
    """The 4x4 pseudo-inertia ``J = [[Sigma, h], [h^T, m]]``, ``Sigma = tr(I)/2 * 1 - I``.

    ``J`` is the second moment of the mass distribution, ``integral([p; 1][p; 1]^T dm)``,
    so a rigid body with positive mass has ``J`` positive definite (Wensing et al. 2017).
    """
    theta = _as_theta(theta)
    i_o = inertia_matrix(theta)
    tr = np.trace(i_o, axis1=-2, axis2=-1)
    sigma = 0.5 * tr[..., None, None] * np.eye(3) - i_o
    j = np.zeros(theta.shape[:-1] + (4, 4))
    j[..., :3, :3] = sigma
    j[..., :3, 3] = theta[..., 1:4]
    j[..., 3, :3] = theta[..., 1:4]
    j[..., 3, 3] = theta[..., 0]
    return j


def theta_from_pseudo_inertia(j) -> np.ndarray:
    """Inverse of :func:`pseudo_inertia`: (..., 4, 4) -> (..., 10)."""
    j = np.asarray(j, dtype=np.float64)
    sigma = j[..., :3, :3]
    tr = np.trace(sigma, axis1=-2, axis2=-1)
    i_o = tr[..., None, None] * np.eye(3) - sigma
    out = np.empty(j.shape[:-2] + (10,))
    out[..., 0] = j[..., 3, 3]
    out[..., 1:4] = j[..., :3, 3]
    for k, (a, b) in enumerate(_INERTIA_INDEX):
        out[..., 4 + k] = i_o[..., a, b]
    return out


def transform_matrix(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    """``X`` (10, 10) with ``theta_parent = X @ theta_child``: a body's parameters in another frame.

    The child frame sits in the parent frame at ``parent_R_child`` (``rotation``, (3, 3)) and
    ``parent_p_child`` (``position``, (3,), m); ``theta_child`` is about the child origin in
    child axes, ``theta_parent`` about the parent origin in parent axes. The pseudo-inertia
    transforms as ``J_parent = T J_child T^T`` with ``T = [[R, p], [0, 1]]``, which is linear
    in ``theta``: ``X`` is that map, exact for any parameters (massless and non-physical ones
    included), so ``X(T_a) @ X(T_b) == X(T_a T_b)``.
    """
    t = np.eye(4)
    t[:3, :3] = np.asarray(rotation, dtype=np.float64)
    t[:3, 3] = np.asarray(position, dtype=np.float64)
    images = theta_from_pseudo_inertia(t @ pseudo_inertia(np.eye(10)) @ t.T)  # row k: the image of e_k
    return images.T


def physical_violations(theta, rtol: float = 1e-12) -> list[str]:
    """What makes one link's parameters non-physical; an empty list when they are valid.

    Valid means positive mass, inertia about the centre of mass positive definite and
    obeying the triangle inequalities of its principal moments (strictly, up to ``rtol``
    of the largest moment): equivalently, a positive definite pseudo-inertia.

    Args:
        theta: (10,) one link.
        rtol: relative tolerance on the inequalities, for values rounded in a file.
    """
    theta = _as_theta(theta)
    if theta.shape != (10,):
        raise ValueError(f"theta must have shape (10,) for one link, got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        return ["parameters are not finite"]
    m = theta[0]
    if m <= 0:
        return [f"mass {m:.6g} kg is not positive"]
    _, _, ic = inertial_from_theta(theta)
    moments = np.linalg.eigvalsh(0.5 * (ic + ic.T))
    scale = max(float(np.max(np.abs(moments))), np.finfo(float).tiny)
    tol = rtol * scale
    out = []
    if moments[0] <= tol:
        out.append(f"inertia about the centre of mass is not positive definite (principal moments {_fmt(moments)})")
    a, b, c = moments
    if a + b < c - tol:
        out.append(f"principal moments {_fmt(moments)} violate the triangle inequality ({a:.6g} + {b:.6g} < {c:.6g})")
    return out


def is_physical(theta, rtol: float = 1e-12) -> np.ndarray:
    """Whether each link's parameters are physically valid: (..., 10) -> (...,) bool.

    The same test as :func:`physical_violations`, vectorized over links.
    """
    theta = _as_theta(theta)
    flat = theta.reshape(-1, 10)
    ok = np.all(np.isfinite(flat), axis=-1) & (flat[:, 0] > 0)
    safe = np.where(ok[:, None], flat, _UNIT_BODY)
    _, _, ic = inertial_from_theta(safe)
    moments = np.linalg.eigvalsh(0.5 * (ic + np.swapaxes(ic, -1, -2)))
    tol = rtol * np.maximum(np.max(np.abs(moments), axis=-1), np.finfo(float).tiny)
    ok &= moments[:, 0] > tol
    ok &= moments[:, 0] + moments[:, 1] >= moments[:, 2] - tol
    return ok.reshape(theta.shape[:-1])


def all_links_physical(theta, rtol: float = 1e-12) -> np.ndarray:
    """Whether every link of each stacked vector is physically valid: (..., 10 n_links) -> (...,) bool."""
    theta = _as_theta(theta)
    return is_physical(theta.reshape(theta.shape[:-1] + (-1, 10)), rtol).all(axis=-1)


# A valid placeholder body for entries already known to be invalid (keeps the batch finite).
_UNIT_BODY = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0])


def check_physical(theta, link_names: Sequence[str] | None = None, rtol: float = 1e-12) -> None:
    """Raise :class:`PhysicalConsistencyError` unless every link in ``theta`` is physical.

    Args:
        theta: (10 * n_links,) stacked parameters, or (n_links, 10).
        link_names: names used in the message; default ``link0, link1, ...``.
    """
    flat = _as_theta(theta).reshape(-1, 10)
    names = list(link_names) if link_names is not None else [f"link{i}" for i in range(len(flat))]
    for name, t in zip(names, flat, strict=True):
        problems = physical_violations(t, rtol)
        if problems:
            raise PhysicalConsistencyError(f"link {name!r}: {'; '.join(problems)}")


def _as_theta(theta) -> np.ndarray:
    theta = np.asarray(theta, dtype=np.float64)
    if theta.ndim == 0 or theta.shape[-1] % 10 != 0:
        raise ValueError(f"theta must have shape (..., 10 * n_links), got {theta.shape}")
    return theta


def _fmt(x: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.6g}" for v in x) + "]"
