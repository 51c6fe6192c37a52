"""Honest standard deviations: the default weighting (:mod:`ineid.identify.weighting`), the known links' CAD
uncertainty (:mod:`ineid.identify.known`), several recordings (:mod:`ineid.identify.joint`)."""

from __future__ import annotations

import numpy as np
import pytest

from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, base_parameters, fused, solve_dataset
from ineid.identify.linear import fit_base_blocks

AXIS_NOISE = NoiseModel.create(4, force=[0.2, 0.5, 1.5], moment=[0.02, 0.05, 0.1])
"""Noise that differs per wrench axis, as a real F/T sensor's does."""


@pytest.fixture(scope="module")
def axis_noisy(model):
    return generate_dataset(
        model, DatasetSpec(Combination("random", n_configs=200), n_frames=30, seed=7, noise=AXIS_NOISE)
    )


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

    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=200),
            n_frames=30,
            seed=11,
            noise=NoiseModel.create(4, force=0.05, moment=0.005),
        ),
    )
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


# -- several recordings, validation on a separate one --------------------------------------


@pytest.fixture(scope="module")
def sessions(model):
    """Three 'recordings' of the same configurations (the same links), 30 frames each, offsets of their own."""
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=3), n_frames=90, seed=5, noise=NoiseModel.create(4, force=0.3, moment=0.03)
        ),
    )
    parts = [ds.select(frames=slice(30 * k, 30 * (k + 1))) for k in range(3)]
    offsets = np.random.default_rng(2).normal(0.0, [2, 2, 2, 0.2, 0.2, 0.2], size=(3, 6))
    for p, b in zip(parts, offsets, strict=True):
        p.wrench = p.wrench + b
    return parts, offsets


def test_joint_fit_has_its_own_offsets_per_recording_and_validates_on_another(model, base, sessions):
    from ineid.identify import fit_base, stack_casadi
    from ineid.identify.joint import solve_recordings
    from ineid.identify.systems import remove_offsets

    (a, b, c), offsets = sessions
    res = solve_recordings([a, b], SolveSettings(bias="estimate", weights="none"), model=model, validate=c)
    assert res.n_frames_fit == 60 and res.n_frames_validation == 30 and res.success.all()

    def rows(d):  # through CasADi: an independent route, nothing to compile
        w, y = zip(
            *(stack_casadi(model, d.q[i], d.qd[i], d.qdd[i], d.wrench[i], d.theta_known) for i in range(d.n_configs)),
            strict=True,
        )
        return np.array(w), np.array(y)

    # the reference: each recording centred on its own, stacked, one QR
    parts = [remove_offsets(*rows(d), 6)[:2] for d in (a, b)]
    bias_base = base_parameters(model, bias=True)
    ref = fit_base(
        np.concatenate([w for w, _ in parts], 1),
        np.concatenate([y for _, y in parts], 1),
        bias_base,
        "none",
        axis_offsets=np.full(6, 2.0),
    )
    np.testing.assert_allclose(res.base_hat, ref.beta, rtol=1e-8, atol=1e-10)
    # each recording's offsets: up to what a constant wrench cannot be told from (the weight of mass at the
    # shoulder, the same in both), so their difference is the difference of the true offsets
    (b0, s0), (b1, s1) = ((np.asarray(r["bias_hat"]), np.asarray(r["bias_std"])) for r in res.meta["recordings"])
    assert np.all(np.abs((b0 - b1) - (offsets[0] - offsets[1])) < 5 * (s0 + s1))
    # validation: c's own offsets fitted alone with theta fixed, then the RMS of what is left
    w, y = rows(c)
    resid = (y - np.einsum("cnp,cp->cn", w, res.theta_hat)).reshape(c.n_configs, c.n_frames, 6)
    resid -= resid.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(res.validation_rms, np.sqrt(np.mean(resid**2, axis=1)), rtol=1e-9)
    assert np.all(res.validation_rms < 2 * np.array([0.3] * 3 + [0.03] * 3))  # the noise level: a good fit
    assert res.meta["validation"]["offsets"].startswith("fitted alone")


def test_solve_several_recordings_cli(run, tmp_path, sessions):
    import dataclasses

    from ineid.data import save_dataset
    from ineid.identify import load_results

    (a, b, c), _ = sessions
    paths = [save_dataset(d, tmp_path / f"{n}.h5") for n, d in zip("abc", (a, b, c), strict=True)]
    out = tmp_path / "r.h5"
    r = run(
        "solve",
        paths[0],
        paths[1],
        "--validate",
        paths[2],
        "--bias",
        "estimate",
        "--known-uncertainty",
        "0.03",
        "--known-uncertainty",
        "shoulder_roll_link=0.1",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    assert "validation on" in r.output and "relative error" in r.output
    res = load_results(out)
    assert [x["path"] for x in res.meta["recordings"]] == [str(p) for p in paths[:2]]
    assert res.meta["validation"]["path"] == str(paths[2]) and np.isfinite(res.meta["validation"]["rel"])
    assert res.settings.known_uncertainty == (("*", 0.03), ("shoulder_roll_link", 0.1))
    for bad in ("abc", "=0.1", "-0.1", "forearm=nan"):
        r = run("solve", paths[0], "--known-uncertainty", bad, "--out", tmp_path / "x.h5")
        assert r.exit_code == 2 and "--known-uncertainty" in r.output, (bad, r.output)
    r = run("solve", paths[0], paths[1], "--known-uncertainty", "forearm=0.1", "--out", tmp_path / "x.h5")
    assert r.exit_code == 1 and "is an unknown (identified) link" in r.output
    info = " ".join(run("results", "info", out).output.split())  # rich wraps at the path's length
    assert "recording 2:" in info and "validation:" in info and "fitted alone" in info
    # another robot's recording: one line naming both, no file
    other = dataclasses.replace(
        c,
        meta=dataclasses.replace(
            c.meta, robot="other-arm", urdf=c.meta.urdf.replace('name="sweaty-arm"', 'name="other-arm"')
        ),
    )
    bad = save_dataset(other, tmp_path / "other.h5")
    for args in ((paths[0], "--validate", bad), (paths[0], bad)):
        r = run("solve", *args, "--out", tmp_path / "x.h5")
        assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
        assert "'other-arm'" in r.output and "'sweaty-arm'" in r.output and "one robot" in r.output
        assert not (tmp_path / "x.h5").exists()
    # synthetic datasets of other true parameters: nothing joint to fit
    odd = save_dataset(dataclasses.replace(c, theta_unknown=c.theta_unknown * 1.1), tmp_path / "odd.h5")
    r = run("solve", paths[0], odd, "--out", tmp_path / "x.h5")
    assert r.exit_code == 1 and "different true parameters" in r.output and not (tmp_path / "x.h5").exists()
