"""The linear fit from per-axis triangular factors (:mod:`ineid.identify.qr_blocks`) against the QR of every row.

The factors of each axis's rows, accumulated over chunks of frames (and recordings), must give what
:func:`ineid.identify.least_squares.fit_base` gives on the stacked rows: the estimates, the residual sum of
squares, the covariance, the estimated weights, the rank decisions, for a base wrench stacked with joint
torques carrying friction and offset columns, with sensor offsets centred, over several recordings, and on
frames that leave the regressor ill-conditioned or rank-deficient.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from ineid.channels import ChannelSet, JointTorque
from ineid.identify import SolveSettings, fused, qr_blocks, solve_dataset, steps
from ineid.identify.identifiability import base_parameters
from ineid.identify.least_squares import fit_base
from ineid.identify.qr_blocks import factor_blocks, fit_base_factors
from ineid.identify.systems import remove_offsets, stack
from tests.conftest import random_states

CHANNELS = ChannelSet.of(JointTorque().with_actuation(friction=("viscous", "coulomb"), torque_offset=True))
SIGMA = np.array([0.05, 0.1, 0.02, 0.04])
"""Noise per joint torque: unequal, so the estimated weights matter."""
N_FRAMES = 60
"""Frames per configuration, the same in every test: one compiled shape (the kernels are the slow part)."""


def _frames(model, n_configs: int, n_frames: int, seed: int):
    q, qd, qdd = random_states(model, n_configs * n_frames, np.random.default_rng(seed))
    return tuple(a.reshape(n_configs, n_frames, -1) for a in (q, qd, qdd))


def _values(model, channels, base, q, qd, qdd, seed: int, offsets=None):
    """Measured values of the channels: the CAD links, friction parameters, offsets and noise (C, F, A)."""
    rng = np.random.default_rng(seed)
    n_axes = channels.n_axes(model)
    c, f = q.shape[:2]
    theta_known = model.theta_cad[model.known_index]
    w, y0 = stack(model, q, qd, qdd, np.zeros((c, f, n_axes)), theta_known, channels)
    truth = np.concatenate([model.theta_cad[model.unknown_index], rng.uniform(0.1, 1.0, base.n_extra)])
    values = (w @ truth - y0).reshape(c, f, n_axes) + SIGMA * rng.standard_normal((c, f, n_axes))
    return values if offsets is None else values + offsets


@functools.cache
def _base(model, channels):
    return base_parameters(model, channels=channels)


def _assert_same_fit(fit, ref, base, rtol: float = 1e-9):
    scales = base.scales[base.base_index]
    np.testing.assert_array_equal(fit.rank, ref.rank)
    ok = ref.full_rank
    assert np.array_equal(np.isnan(fit.beta), np.isnan(ref.beta))
    np.testing.assert_allclose(fit.beta[ok] / scales, ref.beta[ok] / scales, rtol=0, atol=rtol)
    np.testing.assert_allclose(fit.rss, ref.rss, rtol=rtol)
    np.testing.assert_allclose(fit.axis_weights, ref.axis_weights, rtol=rtol)
    np.testing.assert_allclose(fit.cond[ok], ref.cond[ok], rtol=1e-6)
    cov_scale = np.sqrt(np.einsum("cii->ci", ref.cov_beta[ok]))
    norm = cov_scale[:, :, None] * cov_scale[:, None, :]
    np.testing.assert_allclose(fit.cov_beta[ok] / norm, ref.cov_beta[ok] / norm, rtol=0, atol=rtol)
    assert np.all(np.isnan(fit.cov_beta[~ok])) and np.all(np.isnan(ref.cov_beta[~ok]))
    assert fit.dof == ref.dof


@pytest.mark.parametrize("weights", ["estimate", "none", "noise"])
def test_factor_fit_equals_the_qr_of_every_row(model, weights):
    """A base wrench and joint torques with friction and offset columns: every weight mode, the same fit."""
    base = _base(model, CHANNELS)
    q, qd, qdd = _frames(model, 3, N_FRAMES, seed=1)
    values = _values(model, CHANNELS, base, q, qd, qdd, seed=2)
    theta_known = model.theta_cad[model.known_index]
    w, y = stack(model, q, qd, qdd, values, theta_known, CHANNELS)
    sigma = SIGMA if weights == "noise" else None
    ref = fit_base(w, y, base, weights, sigma, CHANNELS.n_axes(model))
    factors = factor_blocks(model, base, q, qd, qdd, values, theta_known, CHANNELS)
    fit = fit_base_factors(factors, base, weights, sigma)
    assert ref.full_rank.all()
    _assert_same_fit(fit, ref, base)
    # the residual per axis from the factors: the frames' own, exact
    resid = (y - np.einsum("cnr,cr->cn", w[:, :, base.base_index], fit.beta)).reshape(3, N_FRAMES, -1)
    np.testing.assert_allclose(factors.axis_rss(fit.beta), np.sum(resid**2, axis=1), rtol=1e-10)


def test_factors_in_frame_chunks_equal_one_chunk(model, monkeypatch):
    """Long recordings are factored in chunks of frames (padded), and the chunks' factors factored again."""
    base = _base(model, CHANNELS)
    q, qd, qdd = _frames(model, 2, N_FRAMES, seed=3)
    values = _values(model, CHANNELS, base, q, qd, qdd, seed=4)
    theta_known = model.theta_cad[model.known_index]
    whole = fit_base_factors(factor_blocks(model, base, q, qd, qdd, values, theta_known, CHANNELS), base)
    monkeypatch.setattr(fused, "MAX_FRAME_CHUNK", 25)  # 60 frames: two full chunks and a padded one
    chunked = factor_blocks(model, base, q, qd, qdd, values, theta_known, CHANNELS)
    _assert_same_fit(fit_base_factors(chunked, base), whole, base, rtol=1e-11)


def test_joined_recordings_with_their_own_offsets(model):
    """Several recordings, each centred on its own (sensor offsets), joined: the QR of their stacked rows."""
    channels = ChannelSet.of(JointTorque().with_actuation(friction=("viscous",))).with_offsets(True)
    base = base_parameters(model, bias=True, channels=channels)
    mask = channels.offset_mask(model)
    n_axes = channels.n_axes(model)
    theta_known = model.theta_cad[model.known_index]
    parts, factors = [], []
    for seed, n_frames in ((5, 40), (6, N_FRAMES)):
        q, qd, qdd = _frames(model, 2, n_frames, seed)
        values = _values(model, channels, base, q, qd, qdd, seed + 10, offsets=np.linspace(-2, 3, n_axes) * seed)
        w, y = stack(model, q, qd, qdd, values, theta_known, channels)
        parts.append(remove_offsets(w, y, n_axes, mask)[:2])
        f = factor_blocks(model, base, q, qd, qdd, values, theta_known, channels, offsets=True, n_frames_max=N_FRAMES)
        factors.append(f.centred(mask)[0])
    lost = mask.astype(np.float64) * 2
    w = np.concatenate([p[0] for p in parts], axis=1)
    y = np.concatenate([p[1] for p in parts], axis=1)
    ref = fit_base(w, y, base, "estimate", None, n_axes, lost)
    fit = fit_base_factors(factors[0].joined(factors[1]), base, "estimate", None, lost)
    _assert_same_fit(fit, ref, base)


def test_rank_deficient_and_ill_conditioned_frames_decided_alike(model):
    """Frames without motion (no friction columns: rank lost) and barely moving ones (ill-conditioned): the
    scale-aware rank test of the factors decides as the QR of every row."""
    base = _base(model, CHANNELS)
    q, qd, qdd = _frames(model, 3, N_FRAMES, seed=7)
    qd[1] *= 0.0  # no velocity: the viscous and Coulomb columns vanish
    qd[2] *= 1e-3
    qdd[2] *= 1e-3
    values = _values(model, CHANNELS, base, q, qd, qdd, seed=8)
    theta_known = model.theta_cad[model.known_index]
    w, y = stack(model, q, qd, qdd, values, theta_known, CHANNELS)
    for weights in ("estimate", "none"):
        ref = fit_base(w, y, base, weights, None, CHANNELS.n_axes(model))
        fit = fit_base_factors(factor_blocks(model, base, q, qd, qdd, values, theta_known, CHANNELS), base, weights)
        assert ref.full_rank.tolist() == [True, False, True]
        assert fit.cond[2] > 1e3  # the normal equations would refit it
        _assert_same_fit(fit, ref, base, rtol=1e-6)  # round-off amplified by cond, in both


def test_solve_of_a_long_recording_from_factors_equals_the_normal_equations(model, monkeypatch):
    """A few long recordings take the factors (:data:`ineid.identify.steps.FACTOR_MAX_CONFIGS`): estimates,
    residuals on the fitted and held-out frames and the offsets as the normal equations' route gives them."""
    from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset

    noise = NoiseModel(wrench=np.array([0.5, 0.5, 0.5, 0.05, 0.05, 0.05]))
    spec = DatasetSpec(Combination("random", n_configs=2), n_frames=150, seed=9, noise=noise)
    ds = generate_dataset(model, spec)
    ds.wrench += np.array([1.0, -2.0, 0.5, 0.1, 0.0, -0.2])  # an untared sensor
    settings = SolveSettings(bias="estimate")
    monkeypatch.setattr(steps, "FACTOR_MIN_FRAMES", 100)  # 2 x 120 fitted frames: the factors' route
    calls = []
    monkeypatch.setattr(steps, "factor_fit", _counted(steps.factor_fit, calls))
    new = solve_dataset(ds, settings, model=model)
    assert calls
    monkeypatch.setattr(steps, "FACTOR_MAX_CONFIGS", 0)
    old = solve_dataset(ds, settings, model=model)
    assert len(calls) == 1
    for name in ("theta_hat", "base_hat", "base_std", "fit_rms", "validation_rms", "validation_rel", "bias_hat"):
        a, b = getattr(new, name), getattr(old, name)
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-12 * np.nanmax(np.abs(b)), err_msg=name)
    assert qr_blocks.FACTOR_WORKERS == 1


def _counted(fn, calls: list):
    def counted(*args, **kwargs):
        calls.append(1)
        return fn(*args, **kwargs)

    return counted
