"""Physical validity of every result: a non-physical estimate is a plausibility warning naming its links.

A heavy-noise dataset of few frames makes the ``nonlinear`` estimate (the linear one's, its mass bound
inactive) a non-rigid body on both links: the warning is on stderr, in the results file and in ``results
info``, naming the links and ``--method consistent``; ``consistent`` on the same data is silent. The
``linear`` method warns where its base estimate proves no completion physical (a negative ``forearm.Iyy``),
and says in the summary when only its completion is not; ``--use torque`` with torques of the wrong sign
blames the torques, not a wrench that was not fitted.
"""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from ineid.cli import main
from ineid.data import Combination, DatasetSpec, NoiseModel, generate_dataset
from ineid.identify import SolveSettings, load_results, solve_dataset
from ineid.identify.physical_checks import check_physical_estimates, linear_completion_note, sign_certificates
from ineid.identify.plausibility import check_total_mass
from ineid.params import all_links_physical

HEAVY = NoiseModel.create(4, force=2.0, moment=0.2, qd=0.04, qdd=0.4)


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def warnings_of(result) -> list[str]:
    return [line.removeprefix("ineid: warning: ") for line in result.stderr.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def heavy(model):
    """Three configurations of 12 frames under heavy noise (test_identify's consistent test, smaller)."""
    return generate_dataset(model, DatasetSpec(Combination("random", n_configs=3), n_frames=12, seed=5, noise=HEAVY))


@pytest.fixture(scope="module")
def heavy_file(heavy, tmp_path_factory):
    path = tmp_path_factory.mktemp("physical") / "heavy.h5"
    heavy.save(path)
    return path


def test_non_physical_estimate_warns_everywhere_naming_the_links(heavy, heavy_file, tmp_path, model):
    res = solve_dataset(heavy, SolveSettings(method="lsqlin"), model=model)
    assert not all_links_physical(res.theta_links).any()  # the truth this test stands on
    out = tmp_path / "lsq.h5"
    r = invoke("-q", "solve", heavy_file, "--method", "lsqlin", "--out", out)
    assert r.exit_code == 0, r.output
    (line,) = [w for w in warnings_of(r) if "rigid body" in w]
    for text in ("the lsqlin estimate is not a rigid body for upper_arm (", "forearm (", "--method consistent"):
        assert text in line, line
    assert "smallest pseudo-inertia eigenvalue -" in line and "in 3 of 3 configurations" in line
    recorded = load_results(out).meta["warnings"]
    assert {"code": "non_physical", "message": line} in recorded
    info = invoke("results", "info", out)
    assert info.exit_code == 0 and "forearm (smallest pseudo-inertia eigenvalue" in info.output


def test_a_completion_that_is_no_rigid_body_is_a_note(heavy_file, tmp_path):
    """nonlinear completes the base estimate by the linear rule: its base estimate has physical completions (no
    warning), its own completion is none (a note in the summary, naming --method consistent)."""
    r = invoke("solve", heavy_file, "--method", "nonlinear", "--out", tmp_path / "nl.h5")
    assert r.exit_code == 0 and not [w for w in warnings_of(r) if "rigid body" in w], r.stderr
    assert "note: the nonlinear method's standard parameters (the base estimate completed nearest the prior)" in (
        " ".join(r.stdout.split())
    )
    assert "--method consistent gives the rigid bodies nearest the data" in " ".join(r.stdout.split())
    (note,) = load_results(tmp_path / "nl.h5").meta["notes"]  # kept with the results, and shown by results info
    assert note.startswith("the nonlinear method's standard parameters") and "forearm" in note
    info = invoke("results", "info", tmp_path / "nl.h5")
    assert info.exit_code == 0 and f"note: {note}" in info.output


def test_consistent_estimate_is_silent(heavy_file, tmp_path):
    out = tmp_path / "con.h5"
    r = invoke("-q", "solve", heavy_file, "--method", "consistent", "--out", out)
    assert r.exit_code == 0, r.output
    assert not [w for w in warnings_of(r) if "rigid body" in w]
    assert all(w["code"] != "non_physical" for w in load_results(out).meta["warnings"])


def test_linear_warns_when_the_base_estimate_rules_out_rigid_bodies(heavy, model):
    res = solve_dataset(heavy, SolveSettings(), model=model)
    k = res.base.names.index("forearm.Iyy")  # a moment about the link origin alone: >= 0 for any rigid body
    assert check_physical_estimates(res) is None  # these base estimates have physical completions
    note = linear_completion_note(res)
    assert note is not None and "not a rigid body for upper_arm" in note and "--method consistent" in note
    beta = res.base_hat.copy()
    beta[1, k] = -2.0 * res.base_std[1, k]  # within the noise of a rigid body: no proof
    assert sign_certificates(dataclasses.replace(res, base_hat=beta)) == []
    beta[1, k] = -5.0 * res.base_std[1, k]
    bad = dataclasses.replace(res, base_hat=beta)
    (proof,) = sign_certificates(bad)
    assert proof == f"forearm.Iyy = {beta[1, k]:.3g} (5 std beyond 0)"
    found = check_physical_estimates(bad)
    assert found.code == "non_physical" and "forearm.Iyy" in found.message and "--method consistent" in found.message


def test_negative_friction_is_named(model):
    from ineid.channels import ChannelSet, JointTorque

    ds = generate_dataset(
        model,
        DatasetSpec(Combination("random", n_configs=1), n_frames=40, seed=2, channels=ChannelSet.of(JointTorque())),
    )
    res = solve_dataset(ds, SolveSettings(friction=("viscous",)), model=model)
    names = [n for n in res.param_names if n.endswith(".fv")]
    assert check_physical_estimates(res) is None or "fv" not in check_physical_estimates(res).message
    theta = res.theta_hat.copy()
    theta[0, res.param_names.index(names[0])] = -0.3
    found = check_physical_estimates(dataclasses.replace(res, theta_hat=theta))
    assert found is not None and f"friction or armature below 0 for {names[0]} -0.3" in found.message


def test_negative_mass_from_torques_names_the_torques(tmp_path):
    data, out = tmp_path / "t.h5", tmp_path / "r.h5"
    r = invoke(
        "-q", "data", "generate", "--n-configs", "2", "--n-frames", "30", "--seed", "4", "--channels",
        "wrench,torque", "--out", data,
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    with h5py.File(data, "r+") as f:
        f["tau"][...] = -f["tau"][()]
    r = invoke("-q", "solve", data, "--use", "torque", "--out", out)
    assert r.exit_code == 0, r.output
    (line,) = [w for w in warnings_of(r) if "total mass" in w]
    assert "is negative" in line and "only torque (tau) fitted" in line and "wrench" not in line, line


def test_negative_mass_with_a_wrench_still_names_the_wrench(heavy, model):
    res = solve_dataset(heavy, SolveSettings(), model=model)
    flipped = dataclasses.replace(res, theta_hat=-res.theta_hat)
    found = check_total_mass(flipped, model)
    assert found.code == "total_mass_negative" and "--flip-wrench" in found.message
    assert np.all(np.isfinite(res.theta_hat))


def test_a_solve_stopped_at_the_cap_is_a_warning(heavy, model):
    from ineid.identify.physical_checks import check_iteration_cap

    res = solve_dataset(heavy, SolveSettings(), model=model)
    assert check_iteration_cap(res) is None
    status = res.status.copy()
    status[1] = "Maximum_Iterations_Exceeded"
    found = check_iteration_cap(dataclasses.replace(res, status=status))
    assert found.code == "iteration_cap" and "cap of 3000 iterations in 1 of 3 configurations" in found.message


@pytest.mark.slow  # a MuJoCo recording of UR5, imported and solved: about a minute
def test_consistent_converges_on_a_ur5_recording(tmp_path):
    """8 s at 1 kHz of UR5 (angles and a tared wrench with sensor noise): consistent took 625 IPOPT iterations
    (a cap of 500 stopped it); it converges to rigid bodies whose base parameters are within 1 % of the truth."""
    import ineid
    from ineid.data import load_dataset
    from ineid.data.synthesis.sampling import sample_link_parameters
    from ineid.studies.mujoco_sim import simulate

    from .bag_files import write_angles_csv
    from .zoo import ZOO

    arm = ZOO["ur5"]
    model = ineid.load_robot(arm.path)
    rng = np.random.default_rng(1)
    theta = model.theta_cad.copy()
    for i, link in enumerate(model.link_names):
        if link in model.unknown_links:
            theta[10 * i : 10 * i + 10] = sample_link_parameters(model.theta_cad[10 * i : 10 * i + 10], 1, rng)[0]
    root = np.array([1.0, 0, 0, 0, 0.01, 0, 0.01, 0, 0, 0.01])  # UR5's root is the world: any body, tared below
    sim = simulate(model, theta, None, 8.0, seed=1, root_theta=root)
    g = model.gravity
    tared = sim.wrench_sensor - np.concatenate([root[0] * g, np.cross(root[1:4], g)])
    noisy = tared + rng.normal(size=tared.shape) * np.array([0.5] * 3 + [0.02] * 3)
    csv = write_angles_csv(tmp_path / "ur5.csv", sim.time, sim.q, noisy)
    rec = tmp_path / "ur5.h5"
    assert invoke("-q", "data", "import", csv, "--robot", *arm.robot_args(), "--out", rec).exit_code == 0
    ds = load_dataset(rec, clean=False)
    res = solve_dataset(ds, SolveSettings(method="consistent"), model=ds.model())
    assert res.success.all(), res.status
    assert all_links_physical(res.theta_links).all()
    truth = theta[ds.model().unknown_index] @ res.base.B.T
    assert np.linalg.norm(res.base_hat[0] - truth) < 0.01 * np.linalg.norm(truth)


def test_a_recording_defaults_to_consistent(lab, tmp_path):
    """The session's MuJoCo recording (tared, its first 3 s), imported: solve without --method runs consistent
    and says so; --method linear is kept, with the note on its completion where it is no rigid body."""
    from .bag_files import write_angles_csv

    n = 3000
    csv = write_angles_csv(tmp_path / "lab.csv", lab.sim.time[:n], lab.sim.q[:n], lab.tared[:n])
    rec = tmp_path / "rec.h5"
    pose = ",".join(f"{v:g}" for v in (*lab.pose.xyz, *lab.pose.rpy))
    r = invoke("-q", "data", "import", csv, "--robot", "sweaty-arm", "--sensor-pose", pose, "--out", rec)
    assert r.exit_code == 0, r.output
    r = invoke("solve", rec, "--out", tmp_path / "c.h5")
    assert r.exit_code == 0, r.output
    assert "method consistent: the default for recordings" in " ".join(r.stdout.split())
    res = load_results(tmp_path / "c.h5")
    assert res.settings.method == "consistent" and all_links_physical(res.theta_links).all()
    truth = lab.theta_unknown @ res.base.B.T
    assert np.linalg.norm(res.base_hat[0] - truth) < 0.05 * np.linalg.norm(truth), res.base_hat[0] - truth
    r = invoke("solve", rec, "--method", "linear", "--out", tmp_path / "l.h5")
    assert r.exit_code == 0 and "the default for recordings" not in r.stdout
    assert load_results(tmp_path / "l.h5").settings.method == "linear"
