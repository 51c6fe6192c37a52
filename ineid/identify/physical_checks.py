"""Physical validity of a solve's estimates, whatever the method: a plausibility finding when they are not.

A rigid body's parameters (Wensing et al. 2017) have a positive semidefinite pseudo-inertia
``J = [[Sigma, h], [h^T, m]]`` (:func:`ineid.params.pseudo_inertia`) and a positive mass: equivalently a
positive mass, an inertia about the centre of mass positive semidefinite and its principal moments obeying
the triangle inequalities. A passive drive has viscous and Coulomb friction and an armature ``>= 0``. Per
solved configuration, :func:`check_physical_estimates` checks

* every unknown link's estimate (payloads included): ``m > 0`` and the smallest eigenvalue of ``J`` not
  below :data:`EIG_RTOL` times its largest (round-off of a body at the boundary of the physical set);
* the channels' extra parameters that are dissipative (``<joint>.fv``, ``.fc``, their per-direction forms,
  ``.Ia``: :func:`ineid.identify.extras.nonnegative`) where they are fitted: not below :data:`EIG_RTOL` times
  their scale below 0.

What is checked depends on what the method chose. ``consistent``, ``lsqlin``, ``lsqnonlin`` and a trained
``network`` report standard parameters of their own: those are checked. ``linear`` and ``nonlinear``
(:data:`COMPLETING_METHODS`) complete the base estimate by the null-space rule, nearest the prior
(:mod:`ineid.identify.linear`), and the data say nothing of the other completions: on noise-free data of
random links that completion is not a rigid body in most configurations although the truth is one. For them
the finding is about what the data determine, the base estimate: it warns where no completion of it is
physical, proven by the certificate that costs nothing, a base parameter that is a same-signed sum of masses,
diagonal moments about a link origin (``Ixx``, ``Iyy``, ``Izz``: each ``>= 0`` for any rigid body) and
dissipative extras, estimated with the other sign by more than :data:`CERTAIN_Z` std
(:func:`sign_certificates`). The exact test is a semidefinite feasibility problem, which this does not
solve: a base estimate that no certificate rules out may still have no physical completion. A completion
that is not a rigid body is said in one line of the summary (:func:`linear_completion_note`), not as a
warning. ``--method consistent`` finds the rigid bodies nearest the data either way.
"""

from __future__ import annotations

import numpy as np

from ineid.data.recordings.plausibility import Finding
from ineid.identify.extras import nonnegative
from ineid.identify.nlp import MAX_ITER
from ineid.params import pseudo_inertia

__all__ = [
    "check_iteration_cap",
    "check_physical_estimates",
    "linear_completion_note",
    "link_eigenvalues",
    "sign_certificates",
]

EIG_RTOL = 1e-9
"""A pseudo-inertia eigenvalue below ``-EIG_RTOL x`` the largest (an extra parameter below ``-EIG_RTOL x`` its
scale) is non-physical; above it, round-off of a body at the boundary of the physical set."""
COMPLETING_METHODS = ("linear", "nonlinear")
"""The methods whose standard parameters complete the base estimate by the null-space rule (``nonlinear``: the
same rule as constraints, the same estimate while its mass bound is inactive): checked on the base estimate."""
CERTAIN_Z = 3.0
"""A base parameter proves the base estimate non-physical (:func:`sign_certificates`) where it lies more than this
many standard deviations on the side no rigid body reaches: within them a physical body fits the data as well
(heavy noise on 30 frames put ``forearm.Iyy`` of the built-in arm 0.67 std below 0)."""
SHOWN = 6
"""At most this many links (extra parameters) are named in the finding; the rest are counted."""
_SIGNED_COLUMNS = (0, 4, 6, 9)
"""Within a link's 10 parameters: m, Ixx, Iyy, Izz, each >= 0 for a rigid body (about any point)."""


def link_eigenvalues(theta_links: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mass, smallest, largest)``, each (C, n_links): the mass and the extreme pseudo-inertia eigenvalues
    of every link (SI: the eigenvalues mix kg, kg*m and kg*m^2 as ``J`` does); NaN where not finite."""
    theta = np.asarray(theta_links, dtype=np.float64)
    links = theta.reshape(theta.shape[0], -1, 10)
    finite = np.all(np.isfinite(links), axis=-1)
    eig = np.linalg.eigvalsh(pseudo_inertia(np.where(finite[..., None], links, 0.0)))
    nan = np.where(finite, 1.0, np.nan)
    return links[..., 0] * nan, eig[..., 0] * nan, eig[..., -1] * nan


def _link_names(res) -> list[str]:
    names = res.param_names[: res.theta_links.shape[1]]
    return [n.rsplit(".", 1)[0] for n in names[0::10]]


def _describe_link(mass: np.ndarray, low: np.ndarray, high: np.ndarray) -> str:
    """How far one link is from a rigid body, at its worst configuration (the columns of one link)."""
    if np.nanmin(mass) <= 0:
        return f"mass {np.nanmin(mass):.3g} kg"
    k = int(np.nanargmin(low / high))
    return f"smallest pseudo-inertia eigenvalue {low[k]:.3g} (largest {high[k]:.3g})"


def _listed(items: list[str]) -> str:
    shown = ", ".join(items[:SHOWN])
    return shown + (f" and {len(items) - SHOWN} more" if len(items) > SHOWN else "")


def _bad_links(res, ok: np.ndarray) -> tuple[list[str], np.ndarray]:
    """``(descriptions, bad configurations)``: the links non-physical in any solved configuration."""
    mass, low, high = link_eigenvalues(res.theta_links[ok])
    with np.errstate(invalid="ignore"):
        bad = (mass <= 0) | (low < -EIG_RTOL * np.abs(high))
    bad &= np.isfinite(mass)
    out = []
    for j, name in enumerate(_link_names(res)):
        if bad[:, j].any():
            b = bad[:, j]
            out.append(f"{name} ({_describe_link(mass[b, j], low[b, j], high[b, j])})")
    return out, bad.any(axis=1)


def _bad_extras(res, ok: np.ndarray) -> tuple[list[str], np.ndarray]:
    """``(descriptions, bad configurations)``: dissipative extra parameters below 0 in any solved configuration."""
    n_e, n_l = res.n_extra, res.theta_links.shape[1]
    if not n_e:
        return [], np.zeros(int(ok.sum()), dtype=bool)
    names = res.param_names[n_l:]
    signed = nonnegative(names)
    x = np.asarray(res.theta_hat, dtype=np.float64)[ok][:, n_l:]
    scale = np.asarray(res.base.scales, dtype=np.float64)[n_l:]
    with np.errstate(invalid="ignore"):
        bad = signed[None, :] & (x < -EIG_RTOL * scale[None, :])
    out = [f"{names[k]} {np.nanmin(x[:, k]):.3g}" for k in np.flatnonzero(bad.any(axis=0))]
    return out, bad.any(axis=1)


def sign_certificates(res) -> list[str]:
    """Base parameters that prove the base estimate has no physical completion (module docstring): more than
    :data:`CERTAIN_Z` std on the side no rigid body reaches, at their worst configuration each:
    ``"<name> = <value> (<z> std beyond 0)"``; empty when none does."""
    base = res.base
    b = np.asarray(base.B, dtype=np.float64)
    n_l = res.theta_links.shape[1]
    signed = np.zeros(b.shape[1], dtype=bool)
    for k in _SIGNED_COLUMNS:
        signed[k:n_l:10] = True
    signed[n_l:] = nonnegative(res.param_names[n_l:])
    ok = np.asarray(res.success, dtype=bool)
    beta = np.asarray(res.base_hat, dtype=np.float64)[ok]
    std = np.asarray(res.base_std, dtype=np.float64)[ok]
    out = []
    for k, row in enumerate(b):
        touched = np.abs(row) > 1e-12 * np.max(np.abs(row))
        if not touched.any() or not signed[touched].all():
            continue
        sign = np.sign(row[touched])
        if not (sign == sign[0]).all():
            continue
        size = float(np.abs(row) @ np.asarray(base.scales, dtype=np.float64))
        below = -sign[0] * beta[:, k] / np.maximum(np.nan_to_num(std[:, k]), EIG_RTOL * size)  # in std
        if not len(below) or not np.nanmax(below) > CERTAIN_Z:
            continue
        c = int(np.nanargmax(below))
        z = f"{below[c]:.3g} std" if np.isfinite(std[c, k]) and std[c, k] > 0 else "exact data"
        out.append(f"{base.names[k]} = {beta[c, k]:.3g} ({z} beyond 0)")
    return out


def check_physical_estimates(res) -> Finding | None:
    """A ``non_physical`` finding naming what is not physical in ``res`` (module docstring), or None.

    ``consistent``, ``lsqlin``, ``lsqnonlin``, ``network``: the links whose estimate is not a rigid body (their
    mass, or their smallest pseudo-inertia eigenvalue, at their worst configuration) and the dissipative extra
    parameters below 0. ``linear``, ``nonlinear`` (:data:`COMPLETING_METHODS`): the base parameters that prove
    no completion of the base estimate physical (:func:`sign_certificates`) and the dissipative extras below 0;
    their standard parameters are one completion among many, chosen by the prior rule:
    :func:`linear_completion_note` says when they are not physical.

    Args:
        res: a :class:`ineid.identify.SolveResults` of any method.
    """
    ok = np.asarray(res.success, dtype=bool)
    if not ok.any():
        return None
    method = res.settings.method
    extras, bad_extras = _bad_extras(res, ok)
    parts = []
    if method in COMPLETING_METHODS:
        proofs = sign_certificates(res)
        if proofs:
            parts.append(
                "not physical whatever the unidentifiable parameters: the base estimate has "
                + _listed(proofs)
                + " where any rigid body (and friction) gives the other sign"
            )
        n_bad = int(bad_extras.sum()) if not proofs else None
    else:
        links, bad_links = _bad_links(res, ok)
        if links:
            parts.append(f"not a rigid body for {_listed(links)}")
        n_bad = int(np.sum(bad_links | bad_extras))
    if extras:
        parts.append(f"friction or armature below 0 for {_listed(extras)}")
    if not parts:
        return None
    where = f" in {n_bad} of {int(ok.sum())} configurations" if n_bad and ok.sum() > 1 else ""
    fix = (
        "the fit is constrained to rigid bodies already: check the data and the model (the links' frames, the "
        "known links' CAD values)"
        if method == "consistent"
        else "identify with --method consistent (physically consistent by construction)"
    )
    return Finding("non_physical", f"the {method} estimate is {' and '.join(parts)}{where}: {fix}")


def linear_completion_note(res) -> str | None:
    """One line when the standard parameters of ``linear`` (or ``nonlinear``: :data:`COMPLETING_METHODS`), the
    completion of the base estimate nearest the prior, are not a rigid body for some link; None otherwise, or for
    another method."""
    ok = np.asarray(res.success, dtype=bool)
    if res.settings.method not in COMPLETING_METHODS or not ok.any():
        return None
    links, bad = _bad_links(res, ok)
    if not links:
        return None
    where = f" in {int(bad.sum())} of {int(ok.sum())} configurations" if ok.sum() > 1 else ""
    return (
        f"the {res.settings.method} method's standard parameters (the base estimate completed nearest the prior) "
        f"are not a rigid body for {_listed(links)}{where}; the data determine only the base parameters: "
        "--method consistent gives the rigid bodies nearest the data (export-urdf needs them)"
    )


def check_iteration_cap(res) -> Finding | None:
    """An ``iteration_cap`` finding where IPOPT stopped at its iteration cap (:data:`ineid.identify.nlp.MAX_ITER`)
    in some configuration: those have no estimate, and the summary's count of failures alone would not say why."""
    status = np.asarray(res.status).astype(str)
    capped = np.char.find(status, "Maximum_Iterations_Exceeded") >= 0
    if not capped.any():
        return None
    return Finding(
        "iteration_cap",
        f"the {res.settings.method} fit stopped at IPOPT's cap of {MAX_ITER} iterations in {int(capped.sum())} of "
        f"{len(status)} configurations, which have no estimate: their optimum lies at the edge of what the "
        "parameterization reaches (a body at the boundary of the physical set, where IPOPT creeps); "
        "--method linear gives their base parameters",
    )
