"""One filter per experiment (:mod:`ineid.data.recordings.experiment`, :mod:`ineid.data.recordings.filters`) and
the cut-off rule on coarse encoders (:func:`ineid.data.recordings.signals.choose_cutoff`), against the truth.

Three runs of one experiment: ``sweaty-arm`` with one set of parameters, three Fourier motions of different
amplitudes read by 12-bit encoders at 500 Hz, the base wrench from ineid's model of the exact states, written as
the CSV a lab brings (time, angles, wrench). Imported alone, each run gets its own cut-off."""

from __future__ import annotations

import numpy as np
import pytest

from ineid import DatasetError
from ineid.data import load_dataset
from ineid.data.recordings.experiment import import_experiment
from ineid.data.recordings.filters import check_filters, mixed_filters
from ineid.data.recordings.pipeline import import_recording
from ineid.data.recordings.settings import ImportSettings
from ineid.identify import SolveSettings, solve_dataset
from ineid.identify.joint import solve_recordings
from tests.bag_files import write_angles_csv

RATE, BITS, SECONDS = 500.0, 12, 5.0
AMPLITUDES = (1.0, 0.45, 0.2)
"""Each run's motion, scaled: smaller motions read by the same encoders call for lower cut-offs."""
LATE = 0.003
"""s, how late the wrench of the ``late`` runs is stamped."""
TOL_FIT = 0.03
"""Base-parameter error of two runs fitted at the experiment's shared cut-off: measured 0.020 (8.6 Hz; each run at
its own cut-off, 10.1, 7.9 Hz: 0.014; all three at 5.9 Hz, the lowest: 0.11)."""


def fourier_states(model, rng, scale: float, f0: float = 0.4, harmonics: int = 4, shift: float = 0.0):
    """``(t, q, qd, qdd)``: time stamps at :data:`RATE` and a Fourier motion's exact states at ``t - shift``."""
    t = np.arange(int(SECONDS * RATE)) / RATE
    k = np.arange(1, harmonics + 1)
    a = scale * rng.uniform(0.3, 1.0, (model.n_dof, harmonics)) / k
    phase = rng.uniform(0, 2 * np.pi, a.shape)
    w = 2 * np.pi * f0 * k
    arg = w[None, None, :] * (t - shift)[:, None, None] + phase[None]
    q = 0.3 + np.sum(a * np.sin(arg), axis=2)
    qd = np.sum(a * w * np.cos(arg), axis=2)
    qdd = -np.sum(a * w**2 * np.sin(arg), axis=2)
    return t, q, qd, qdd


def base_error(res, theta_unknown, row: int = 0) -> float:
    """The largest ``|beta_hat - beta| / max(|beta|, scale)`` over the base parameters."""
    b = res.base
    truth = theta_unknown @ b.B.T
    return float(np.max(np.abs(res.base_hat[row] - truth) / np.maximum(np.abs(truth), b.scales[b.base_index])))


@pytest.fixture(scope="module")
def runs(model, tmp_path_factory):
    """``(paths, theta_unknown)``: the three runs' CSVs and the truth."""
    from ineid.data.synthesis.sampling import sample_link_parameters

    folder = tmp_path_factory.mktemp("experiment")
    rng = np.random.default_rng(5)
    theta = np.array(model.theta_cad, dtype=np.float64)
    for link in model.unknown_links:
        i = model.link_names.index(link)
        theta[10 * i : 10 * i + 10] = sample_link_parameters(theta[10 * i : 10 * i + 10], 1, rng)[0]
    step = 2 * np.pi / 2**BITS
    paths = []
    for k, scale in enumerate(AMPLITUDES):
        t, q, qd, qdd = fourier_states(model, rng, scale)
        w = np.asarray(model.base_wrench(q, qd, qdd, theta))
        paths.append(write_angles_csv(folder / f"run{k + 1}.csv", t, np.round(q / step) * step, w))
        if k < 2:  # a run whose wrench is stamped LATE s late: the wrench of the states at t - LATE
            _, q, _, _ = fourier_states(model, np.random.default_rng(100 + k), scale)
            late = fourier_states(model, np.random.default_rng(100 + k), scale, shift=LATE)
            w = np.asarray(model.base_wrench(*late[1:], theta))
            write_angles_csv(folder / f"late{k + 1}.csv", t, np.round(q / step) * step, w)
    return paths, theta[model.unknown_index]


@pytest.fixture(scope="module")
def alone(model, runs):
    """Each run imported alone."""
    return [import_recording(p, model)[0] for p in runs[0]]


def cutoff_of(ds) -> float:
    return ds.meta.origin["import"]["cutoff"]


def test_an_experiment_imported_together_shares_one_filter_and_fits_the_truth(model, runs, alone):
    paths, truth = runs
    own = [cutoff_of(d) for d in alone]
    assert max(own) > 1.3 * min(own)  # three natural cut-offs, far apart
    exp = import_experiment(paths, model)
    assert exp.cutoff_rule == "pooled" and exp.own_cutoffs == pytest.approx(own, rel=1e-12)
    assert min(own) <= exp.cutoff <= max(own)
    assert [cutoff_of(d) for d in exp.datasets] == [exp.cutoff] * 3
    head = exp.lines()[0]
    assert f"at {exp.cutoff:.3g} Hz" in head and all(f"run{k + 1}.csv {c:.3g} Hz" in head for k, c in enumerate(own))
    assert any("shared by the experiment's 3 recordings" in line for line in exp.summaries[1].lines())
    assert "shared by the experiment's 3 recordings" in exp.datasets[1].meta.origin["import"]["cutoff_note"]
    labelled = [(p.name, d) for p, d in zip(paths, exp.datasets, strict=True)]
    assert check_filters(labelled) is None
    res = solve_recordings(exp.datasets[:2], SolveSettings(), model=model, validate=exp.datasets[2])
    assert base_error(res, truth) < TOL_FIT
    assert res.meta["validation"]["rel"] < 1e-2
    with pytest.raises(DatasetError, match="different cut-offs"):
        check_filters([(p.name, d) for p, d in zip(paths, alone, strict=True)])


def test_a_given_cutoff_and_an_estimated_delay_are_shared(model, runs):
    paths, _ = runs
    exp = import_experiment(paths[:2], model, ImportSettings(cutoff=9.0))
    assert exp.cutoff == 9.0 and exp.cutoff_rule == "given" and all(cutoff_of(d) == 9.0 for d in exp.datasets)
    assert "9 Hz, given" in exp.lines()[0]
    estimated = [
        {"cutoff": 9.0, "delay": d, "delay_estimated": True} for d in (0.002, 0.0031)
    ]  # two runs' delays estimated each alone
    labelled = []
    for k, record in enumerate(estimated):
        ds = exp.datasets[k]
        ds.meta.origin["import"].update(record)
        labelled.append((f"r{k}", ds))
    assert "wrench delays, each estimated on its own" in mixed_filters(labelled)
    assert "r1 9 Hz (delay 3.1 ms, estimated)" in mixed_filters(labelled)


def test_an_estimated_delay_is_the_median_of_the_runs_estimates(model, runs):
    from ineid.workflow import import_experiment as import_with_delay

    late = [runs[0][0].parent / f"late{k}.csv" for k in (1, 2)]
    exp = import_with_delay(late, model, ImportSettings(estimate_delay=True))
    each = [e.delay for e in exp.delay_estimates]
    assert np.allclose(each, LATE, atol=5e-5) and exp.delay == pytest.approx(np.median(each), abs=1e-15)
    assert all(d.meta.origin["import"]["delay"] == exp.delay for d in exp.datasets)
    assert (
        len({cutoff_of(d) for d in exp.datasets}) == 1
        and check_filters([("a", exp.datasets[0]), ("b", exp.datasets[1])]) is None
    )
    assert exp.lines()[1].startswith(f"one wrench delay for the 2 recordings: {1e3 * exp.delay:.4g} ms, the median")


def test_what_is_not_a_filtered_recording_takes_no_part(model, alone, tmp_path):
    from ineid.data import Combination, DatasetSpec, generate_dataset

    generated = generate_dataset(model, DatasetSpec(Combination("random", n_configs=1), n_frames=50, seed=0))
    assert check_filters([("generated", generated), ("run1", alone[0])]) is None
    t, q, qd, qdd = fourier_states(model, np.random.default_rng(0), 0.5)
    w = np.asarray(model.base_wrench(q, qd, qdd, model.theta_cad))
    path = tmp_path / "measured.csv"
    n = model.n_dof
    header = ["time", *(f"{k}{j}" for k in ("q", "qd", "qdd") for j in range(1, n + 1)), "fx", "fy", "fz", "mx"]
    np.savetxt(
        path, np.column_stack([t, q, qd, qdd, w]), delimiter=",", header=",".join([*header, "my", "mz"]), comments=""
    )
    measured = import_recording(path, model)[0]
    assert measured.meta.origin["import"]["cutoff"] is None
    assert check_filters([("measured", measured), ("run1", alone[0])]) is None


def test_solve_refuses_runs_imported_alone_and_takes_them_imported_together(model, runs, alone, run, tmp_path):
    paths, _ = runs
    files = []
    for p in paths:  # imported alone, each at its own cut-off
        files.append(tmp_path / f"{p.stem}.h5")
        r = run("-q", "data", "import", p, "--robot", "sweaty-arm", "--out", files[-1])
        assert r.exit_code == 0, r.output
    own = [cutoff_of(load_dataset(f)) for f in files]
    args = ("-q", "solve", files[0], files[1], "--validate", files[2])
    r = run(*args, "--out", tmp_path / "mixed.h5")
    assert r.exit_code == 1 and "Traceback" not in r.output
    line = [x for x in r.output.splitlines() if x.strip()][-1]
    assert "different cut-offs" in line and "import them together" in line and "--mixed-filters" in line
    assert all(f"{f} {c:.4g} Hz" in line for f, c in zip(files, own, strict=True)), line
    assert not (tmp_path / "mixed.h5").exists()
    r = run(*args, "--mixed-filters", "--out", tmp_path / "mixed.h5")
    assert r.exit_code == 0, r.output
    assert "warning: the recordings fitted and validated together were imported with different cut-offs" in r.output
    # imported together: one cut-off, no refusal
    folder = tmp_path / "together"
    r = run("data", "import", *paths, "--robot", "sweaty-arm", "--out", folder)
    assert r.exit_code == 0, r.output
    assert "one filter for the 3 recordings" in r.output and "the cut-off rule on their pooled spectra" in r.output
    together = [folder / f"{p.stem}.h5" for p in paths]
    assert len({cutoff_of(load_dataset(f)) for f in together}) == 1
    r = run("-q", "solve", together[0], together[1], "--validate", together[2], "--out", tmp_path / "one.h5")
    assert r.exit_code == 0 and "mixed" not in r.output, r.output


def test_several_recordings_need_a_folder_and_distinct_names(runs, run, tmp_path):
    paths, _ = runs
    (tmp_path / "file.h5").write_text("")
    r = run("data", "import", *paths[:2], "--robot", "sweaty-arm", "--out", tmp_path / "file.h5")
    assert r.exit_code == 2 and "go to a folder" in r.output
    r = run("data", "import", *paths[:2], "--robot", "sweaty-arm", "--out", tmp_path / "new.h5")
    assert r.exit_code == 2 and "go to a folder" in r.output and not (tmp_path / "new.h5").exists()
    r = run("data", "import", paths[0], paths[0], "--robot", "sweaty-arm", "--out", tmp_path / "out")
    assert r.exit_code == 2 and "several recordings are named 'run1'" in r.output


def test_the_cutoff_rule_keeps_the_motion_of_coarse_encoders(model):
    """10-bit encoders at 200 Hz on a 2 Hz motion (MuJoCo, joint friction): the noise rule alone cut at 5.6 Hz
    (base error 0.225); three times the motion's band, 13.5 Hz, gives 0.042 (the best of the cut-offs tried:
    0.042-0.047 at 13.5-14 Hz)."""
    pytest.importorskip("mujoco")
    from ineid.channels.pose import SensorPose
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.signals import choose_cutoff
    from ineid.data.recordings.streams import Streams
    from ineid.data.synthesis.sampling import sample_link_parameters
    from ineid.studies.mujoco_sim import Reference, simulate

    rng = np.random.default_rng(11)
    theta = np.array(model.theta_cad, dtype=np.float64)
    for link in model.unknown_links:
        i = model.link_names.index(link)
        theta[10 * i : 10 * i + 10] = sample_link_parameters(theta[10 * i : 10 * i + 10], 1, rng)[0]
    pose = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7))
    sim = simulate(
        model, theta, pose, 10.0, rate=200.0, reference=Reference.random(model, np.random.default_rng(3), 0.5, 4)
    )
    rt, g = sim.root_theta, model.gravity
    wrench = sim.wrench_sensor - pose.transform() @ np.concatenate([rt[0] * g, np.cross(rt[1:4], g)])
    step = 2 * np.pi / 2**10
    q = np.round(sim.q / step) * step
    choice = choose_cutoff(q, 200.0)
    assert choice.limited == "motion" and choice.cutoff > 2 * choice.noise_cutoff
    streams = Streams(sim.time, q, None, None, sim.time, wrench, "coarse")
    errors = {}
    for name, cutoff in (("rule", None), ("noise rule", choice.noise_cutoff)):
        settings = ImportSettings(sensor_pose="0.03,-0.02,-0.05,3.1,0.2,0.7", cutoff=cutoff)
        ds, summary = recording_dataset(streams, model, settings)
        res = solve_dataset(ds, SolveSettings(), model=model)
        errors[name] = base_error(res, theta[model.unknown_index])
    assert summary.cutoff == pytest.approx(choice.noise_cutoff)
    assert errors["rule"] < 0.07 and errors["noise rule"] > 3 * errors["rule"], errors
