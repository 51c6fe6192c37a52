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


# -- the known links' CAD uncertainty ------------------------------------------------------


def test_known_uncertainty_covers_cad_errors_of_the_known_links(model, base):
    """Monte Carlo over CAD errors drawn as the model states: z-scores near 1 with the option, far above without."""
    from ineid.identify.known import known_std

    ds = generate_dataset(model, DatasetSpec(Combination("random", n_configs=200), n_frames=30, seed=11,
                                             noise=NoiseModel.create(4, force=0.05, moment=0.005)))
    frac = 0.05
    std_k = known_std(model, [("*", frac)])
    err_k = np.random.default_rng(3).standard_normal((ds.n_configs, len(std_k))) * std_k  # each its own CAD error
    _, rows_k = model.regressor_split(ds.q, ds.qd, ds.qdd)
    ds.wrench = ds.wrench + np.einsum("cfap,cp->cfa", rows_k, err_k)  # the real known links: CAD + error
    truth = ds.theta_unknown @ base.B.T
    with_it = solve_dataset(ds, SolveSettings(frames=30, known_uncertainty=(("*", frac),)), model=model)
    z = ((with_it.base_hat - truth) / with_it.base_std)[with_it.success].std(axis=0)
    assert np.all((z > 0.75) & (z < 1.3)), z.round(2)
    assert with_it.settings.known_uncertainty == (("*", frac),)
    without = solve_dataset(ds, SolveSettings(frames=30), model=model)
    z0 = ((without.base_hat - truth) / without.base_std)[without.success].std(axis=0)
    assert z0.max() > 3, z0.round(2)  # the CAD taken as exact: far too confident
    np.testing.assert_allclose(with_it.base_hat, without.base_hat, rtol=1e-12)  # the estimate itself is unchanged


def test_known_uncertainty_per_link_and_bad_links(model):
    from ineid import IdentificationError
    from ineid.identify.known import known_std

    both = known_std(model, [("*", 0.05)])
    one = known_std(model, [("shoulder_roll_link", 0.1), ("*", 0.05)])  # a named link overrides every link
    np.testing.assert_array_equal(one[:10], both[:10])
    np.testing.assert_allclose(one[10:], 2 * both[10:])
    cad = model.theta_cad[model.known_index]
    assert np.all(both >= 0.05 * np.abs(cad) - 1e-15) and np.all(both > 0)  # zero CAD products still uncertain
    for link, what in (("forearm", "an unknown"), ("nope", "not a link")):
        with pytest.raises(IdentificationError, match=what):
            known_std(model, [(link, 0.05)])
