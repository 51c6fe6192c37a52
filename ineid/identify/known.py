"""The known links' CAD uncertainty, propagated into the standard deviations of the estimates.

Identification subtracts the known links' share ``R_k theta_k`` from the measurements with
``theta_k`` the CAD values. When those are off, the estimate moves with them: per
configuration the weighted least squares ``beta_hat = (W_b^T D^2 W_b)^-1 W_b^T D^2 (y - R_k theta_k)``
has the sensitivity

    S = d beta_hat / d theta_k = -(W_b^T D^2 W_b)^-1 W_b^T D^2 R_k          (r, 10 n_k)

(``W_b`` the base columns of the unknown links' rows, ``R_k`` the known links' rows, both
centred per axis when sensor offsets are fitted, ``D`` the fit's row weights per axis).

**The model.** The known links' parameters are independent random variables about their
CAD values with standard deviation ``f_link * max(|theta_cad_j|, s_j)`` per parameter ``j``
of a link, ``f_link`` the fraction given for that link (``--known-uncertainty 0.05`` or
``LINK=0.05``) and ``s_j`` the link's own scale of that parameter
(:func:`ineid.identify.systems.parameter_scales`: ``m``, ``m l``, ``m l^2`` with ``l`` the
RMS distance of the mass from the link origin). Mass and diagonal inertias are then
``f`` relative; a first moment or a product of inertia that the CAD gives as zero (a centre
of mass on an axis, principal axes along the frame) still gets ``f`` of the body's own
moment or inertia, as a body that is ``f`` off in its mass distribution would be; with
``|theta_cad_j|`` alone they would count as exact. The covariance of the estimate becomes

    cov(beta_hat) = cov_noise + S Sigma_k S^T,     Sigma_k = diag(std_k^2)

exact (the fit is linear in ``theta_k``) for an error of the CAD that is fixed across the
frames. The part of the CAD error's effect that the unknown links cannot absorb stays in the
residuals and would be counted as noise a second time: the noise part ``cov_noise = s^2
V`` is taken with ``s^2 = max(rss - e, 0) / dof``, ``e`` the expected share of the CAD
errors in the weighted ``rss`` (:func:`known_covariance`). The row weights stay those of the
fit. The offsets' standard deviations (``--bias estimate``) follow through ``cov(beta_hat)`` only.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from ineid.channels import ChannelSet
from ineid.errors import IdentificationError
from ineid.identify.extras import unknown_rows
from ineid.identify.identifiability import BaseParameters
from ineid.identify.least_squares import BaseFit
from ineid.identify.systems import parameter_scales

ALL_KNOWN = "*"
"""The link name of a fraction that applies to every known link (``--known-uncertainty 0.05``)."""
CHUNK_ROWS = 200_000
"""Frames per batch of configurations when the known links' rows are formed."""


def known_std(model, uncertainty: Iterable[tuple[str, float]]) -> np.ndarray:
    """(10 n_k,) the standard deviation of each known parameter (module doc), in ``model.known_index`` order.

    Args:
        model: the :class:`ineid.RobotModel`.
        uncertainty: ``(link, fraction)`` pairs; link :data:`ALL_KNOWN` for every known link, a
            named link overrides it (a later pair for the same link overrides an earlier one).

    Raises:
        IdentificationError: a link that is not a known link of ``model`` (status ``unknown_link``).
    """
    known = list(model.known_links)
    frac = np.zeros(len(known))
    for link, f in sorted(uncertainty, key=lambda p: p[0] != ALL_KNOWN):  # a named link overrides "every link"
        if link == ALL_KNOWN:
            frac[:] = f
            continue
        if link not in known:
            what = "an unknown (identified) link" if link in model.unknown_links else "not a link of this robot"
            raise IdentificationError(
                f"--known-uncertainty {link}={f:g}: {link!r} is {what}; name one of the known links "
                f"({', '.join(known) or 'none'})",
                status="unknown_link",
            )
        frac[known.index(link)] = f
    cad = np.asarray(model.theta_cad[model.known_index], dtype=np.float64)
    if not len(cad):
        return cad
    size = np.maximum(np.abs(cad), parameter_scales(cad))
    return np.repeat(frac, 10) * size


def known_covariance(
    model,
    base,
    q,
    qd,
    qdd,
    channels,
    axis_weights: np.ndarray,
    std_k: np.ndarray,
    offset_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(S Sigma_k S^T, e)`` of every configuration (module doc): (C, r, r) and (C,).

    ``e = E||(I - H) D R_k dtheta_k||^2 = ||(I - H) D R_k Sigma_k^(1/2)||_F^2`` is what the CAD
    errors add, on average, to the weighted residual sum of squares (``H`` the hat matrix of
    ``D W_b``): the part of their effect the unknown links cannot absorb.

    Args:
        model, base: the robot and its base parameters (``base.base_index`` into the unknown columns).
        q, qd, qdd: (C, F, n_dof) the fitted frames, or lists of them, one per recording fitted
            jointly (each centred on its own when offsets are fitted).
        channels: the :class:`ineid.channels.ChannelSet` fitted.
        axis_weights: (C, A) the fit's row weights ``d_a``.
        std_k: (10 n_k,) from :func:`known_std`.
        offset_mask: (A,) bool, the axes whose offsets were fitted (their rows centred); None: none.
    """
    segments = list(zip(q, qd, qdd, strict=True)) if isinstance(q, (list, tuple)) else [(q, qd, qdd)]
    c = segments[0][0].shape[0]
    f = sum(seg[0].shape[1] for seg in segments)
    r = len(base.base_index)
    out, extra = np.zeros((c, r, r)), np.zeros(c)
    if not np.any(std_k > 0):
        return out, extra
    scales = base.scales[base.base_index]
    centre = offset_mask is not None and np.any(offset_mask)
    per = max(1, CHUNK_ROWS // max(f, 1))
    for i in range(0, c, per):
        sl = slice(i, i + per)
        parts_u, parts_k = [], []
        for sq, sqd, sqdd in segments:  # each recording centred on its own (its own offsets)
            rows_u, rows_k = unknown_rows(model, sq[sl], sqd[sl], sqdd[sl], channels)  # (c, F, A, p [+ n_extra])
            w_b = rows_u[..., base.base_index] * scales  # scaled columns: the QR stays well conditioned
            rows_k = rows_k * std_k
            if centre:
                w_b = w_b - w_b.mean(axis=1, keepdims=True) * offset_mask[:, None]
                rows_k = rows_k - rows_k.mean(axis=1, keepdims=True) * offset_mask[:, None]
            parts_u.append(w_b)
            parts_k.append(rows_k)
        w_b, rows_k = np.concatenate(parts_u, axis=1), np.concatenate(parts_k, axis=1)
        d = axis_weights[sl][:, None, :, None]
        n = w_b.shape[0]
        qq, rr = np.linalg.qr((w_b * d).reshape(n, -1, r))
        dk = (rows_k * d).reshape(n, -1, rows_k.shape[-1])
        proj = np.swapaxes(qq, 1, 2) @ dk
        extra[sl] = np.einsum("cnp,cnp->c", dk, dk) - np.einsum("crp,crp->c", proj, proj)
        s = np.linalg.solve(rr, proj) * scales[:, None]  # back to the parameters' units
        out[sl] = s @ np.swapaxes(s, 1, 2)
    return out, np.maximum(extra, 0.0)


def with_known_uncertainty(
    fit: BaseFit,
    model,
    base: BaseParameters,
    ds,
    fit_sl: slice,
    channels: ChannelSet,
    uncertainty: Iterable[tuple[str, float]],
    with_offsets: bool = False,
) -> BaseFit:
    """``fit`` with ``S Sigma_k S^T`` added to the covariance of its full-rank configurations and the CAD errors'
    share taken out of its noise part (module doc).

    ``ds``: a dataset, or a list of datasets fitted jointly (``fit_sl`` of each one's frames);
    ``uncertainty`` the fractions (``SolveSettings.known_uncertainty``, :func:`known_std`); the rows centred on
    the offsets' axes ``with_offsets`` (``SolveSettings.bias == "estimate"``).
    """
    std_k = known_std(model, uncertainty)
    ok = np.flatnonzero(fit.full_rank)
    mask = channels.offset_mask(model) if with_offsets else None
    cov, sigma2 = fit.cov_beta.copy(), fit.sigma2.copy()  # sigma2 of the fit itself stays (IPOPT's noise level)
    parts = ds if isinstance(ds, list) else [ds]
    frames = [[getattr(d, k)[ok][:, fit_sl] for d in parts] for k in ("q", "qd", "qdd")]
    cad, extra = known_covariance(model, base, *frames, channels, fit.axis_weights[ok], std_k, mask)
    # the CAD errors' share of the residuals is not noise: s^2 without it (ineid.identify.known)
    sigma2[ok] = np.maximum(fit.rss[ok] - extra, 0.0) / max(fit.dof, 1)
    scale = np.divide(sigma2[ok], fit.sigma2[ok], out=np.zeros(len(ok)), where=fit.sigma2[ok] > 0)
    cov[ok] = cov[ok] * scale[:, None, None] + cad
    return dataclasses.replace(fit, cov_beta=cov)
