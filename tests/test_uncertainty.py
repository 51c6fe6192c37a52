"""Honest standard deviations: the default weighting, the known links' CAD uncertainty, several recordings."""

from __future__ import annotations

import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, fused, solve_dataset
from ineid.identify.linear import fit_base_blocks

AXIS_NOISE = NoiseModel.create(4, force=[0.2, 0.5, 1.5], moment=[0.02, 0.05, 0.1])
"""Noise that differs per wrench axis, as a real F/T sensor's does."""


@pytest.fixture(scope="module")
def axis_noisy(model):
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=200), n_frames=30, seed=7,
                                               noise=AXIS_NOISE))


def _z_spread(res, ds, base) -> np.ndarray:
    """(r,) the spread over configurations of each base parameter's error / reported std."""
    z = (res.base_hat - ds.theta_unknown @ base.B.T) / res.base_std
    return z[res.success].std(axis=0)


def test_default_weighting_gives_calibrated_std_when_noise_differs_per_axis(model, base, axis_noisy):
    ds = axis_noisy
    default = _z_spread(solve_dataset(ds, SolveSettings(frames=30), model=model), ds, base)
    assert np.all((default > 0.8) & (default < 1.25)), default.round(2)
    # the unweighted fit of the same blocks: some std far too large, some too small
    blocks = fused.information_blocks(model, base, ds.q, ds.qd, ds.qdd, ds.wrench, ds.theta_known)
    fit, _ = fit_base_blocks(blocks, base, "none")
    z = (fit.beta - ds.theta_unknown @ base.B.T) / np.sqrt(np.diagonal(fit.cov_beta, axis1=1, axis2=2))
    none = z.std(axis=0)
    assert none.min() < 0.5 and none.max() > 1.5, none.round(2)
