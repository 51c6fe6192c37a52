"""The gaps closed after the first round: the link IMU streams' time stamps audited like the joints' and the
wrench's; the mixed-filters check on the library path; a coupling's per-motor columns named after the motors;
the MJCF writer's non-physical links, the report's friction check on coupled channels, Stribeck friction in
``data generate --friction-truth``."""

from __future__ import annotations

import numpy as np
import pytest

from ineid import DatasetError
from tests.test_recordings_imus import DURATION, FOREARM_POSE, check_fused, trajectory

IMU_H = 4e-3
"""s, the forearm IMU's nominal step (250 Hz)."""


def jittery_imu(model, rng: np.random.Generator, gap: tuple[float, float] | None = None):
    """``(stamps, readings, held)`` of a forearm IMU (all kinds, at a pose) logged at 250 Hz by a loop that wakes
    0 to 1.6 ms late (steps 2.4 to 5.6 ms), misses cycles in runs of 2 to 4, and writes the value it holds again
    under a new stamp in 5 % of its rows (``held`` of them); ``gap`` drops the stamps within it."""
    from ineid.channels.pose import parse_sensor_pose
    from ineid.data.imu.readings import ImuMount, imu_readings

    k = np.arange(int((DURATION - 0.01) / IMU_H))
    t = k * IMU_H + rng.uniform(0.0, 1.6e-3, len(k))
    missed = np.zeros(len(k), dtype=bool)
    for start in rng.choice(np.arange(20, len(k) - 20), 6, replace=False):
        missed[start : start + rng.integers(2, 5)] = True
    if gap is not None:
        missed |= (t > gap[0]) & (t < gap[1])
    t = t[~missed]
    mount = ImuMount("forearm", parse_sensor_pose(FOREARM_POSE))
    r = imu_readings(model, [mount], *trajectory(t))["forearm"]
    held = np.zeros(len(t), dtype=bool)
    held[rng.choice(np.arange(10, len(t) - 10), int(0.05 * len(t)), replace=False)] = True
    held &= ~np.roll(held, 1)  # single held rows: each repeats a measured one
    for kind in r:
        for i in np.flatnonzero(held):
            r[kind][i] = r[kind][i - 1]
    return t, r, int(held.sum())


def imu_import(model, t, r, **settings):
    """``recording_dataset`` of the arm's joints and wrench at 200 Hz (uniform) and the forearm IMU ``(t, r)``."""
    from ineid.data.recordings.pipeline import recording_dataset
    from ineid.data.recordings.settings import ImportSettings
    from ineid.data.recordings.streams import ImuStream, Streams

    tq = np.arange(0.0, DURATION, 1 / 200.0)
    q, qd, qdd = trajectory(tq)
    streams = Streams(
        tq, q, None, None, tq, model.base_wrench(q, qd, qdd), "lab.csv", imus=(ImuStream("forearm", t, r),)
    )
    return recording_dataset(streams, model, ImportSettings(cutoff=20.0, imus=(f"forearm:{FOREARM_POSE}",), **settings))


def test_imu_stream_audited_nominal_rate_held_rows_warnings(model):
    from ineid.data.recordings.timing import TimingReport

    t, r, held = jittery_imu(model, np.random.default_rng(3))
    ds, summary = imu_import(model, t, r)
    record = TimingReport.from_dict(ds.meta.origin["import"]["timing"])
    imu = next(s for s in record.streams if s.name == "IMU 'forearm'")
    assert imu.rate == 250.0 and imu.how == "snapped" and imu.held == held and imu.gaps > 0
    assert imu.jitter > 0.25
    assert ds.meta.origin["imu"]["rates"] == {"forearm.gyro+accel+alpha": 250.0}
    line = next(x for x in summary.lines() if x.startswith("IMU 'forearm' time stamps"))
    assert "250 Hz nominal" in line and f"{held} rows" in line and "dropped as missing" in line
    codes = {c: m for c, m in record.warnings}
    assert "IMU 'forearm'" in codes["timing_jitter"] and "IMU 'forearm'" in codes["timing_repeats"]
    check_fused(ds, tol=4e-3)
    _, summary = imu_import(model, t, r, keep_repeats=True)
    assert "kept as data" in next(x for x in summary.lines() if x.startswith("IMU 'forearm'"))


def test_imu_gap_longer_than_the_filter_is_an_error_unless_allowed(model):
    t, r, _ = jittery_imu(model, np.random.default_rng(4), gap=(1.2, 1.4))
    with pytest.raises(DatasetError, match=r"the IMU 'forearm' stream has a gap of .*--allow-gaps"):
        imu_import(model, t, r)
    ds, _ = imu_import(model, t, r, allow_gaps=True)
    warnings = {w["code"]: w["message"] for w in ds.meta.origin["import"]["timing"]["warnings"]}
    assert "IMU 'forearm'" in warnings["timing_gaps"]


# -- the mixed-filters check on the library path ----------------------------------------------------------


@pytest.fixture(scope="module")
def two_filters(model, tmp_path_factory):
    """``(a, b, c)``: two Fourier runs of the arm (CAD parameters, 12-bit encoders, 500 Hz) imported at 6 Hz, and
    the second imported again at 9 Hz."""
    from ineid.data.recordings.pipeline import import_recording
    from ineid.data.recordings.settings import ImportSettings
    from tests.bag_files import write_angles_csv
    from tests.test_filters_experiment import fourier_states

    folder = tmp_path_factory.mktemp("filters")
    rng = np.random.default_rng(8)
    step = 2 * np.pi / 2**12
    paths = []
    for k in range(2):
        t, q, qd, qdd = fourier_states(model, rng, 0.8)
        w = np.asarray(model.base_wrench(q, qd, qdd, model.theta_cad))
        paths.append(write_angles_csv(folder / f"run{k + 1}.csv", t, np.round(q / step) * step, w))
    a, b = (import_recording(p, model, ImportSettings(cutoff=6.0))[0] for p in paths)
    c = import_recording(paths[1], model, ImportSettings(cutoff=9.0))[0]
    return a, b, c


def test_solve_recordings_from_python_refuses_mixed_filters(model, two_filters):
    from ineid.identify import SolveSettings
    from ineid.identify.joint import solve_recordings

    a, b, c = two_filters
    settings = SolveSettings(method="linear")
    with pytest.raises(DatasetError, match=r"different cut-offs: .*run1.csv 6 Hz, .*run2.csv 9 Hz.*--mixed-filters"):
        solve_recordings([a, c], settings, model=model)
    with pytest.raises(DatasetError, match=r"different cut-offs: .*run2.csv 6 Hz, .*run2.csv 9 Hz"):
        solve_recordings([a, b], settings, model=model, validate=c)
    res = solve_recordings([a, b], settings, model=model, validate=c, mixed_filters=True)
    assert "different cut-offs" in res.meta["mixed_filters"] and np.isfinite(res.validation_rel).all()
    res = solve_recordings([a, b], settings, model=model)
    assert "mixed_filters" not in res.meta


# -- a coupling's per-motor columns by name ------------------------------------------------------------------


def test_per_motor_columns_named_after_the_coupling_motors(model, tmp_path):
    """``tau_<motor>`` and ``i_<motor>`` columns, in any order, read as the numbered columns in the motors' order."""
    import json

    from ineid.data.recordings.pipeline import import_recording
    from ineid.data.recordings.settings import ImportSettings
    from tests.test_actuation_coupling import MOTORS, TENDONS

    t = np.arange(0, 2.0, 2e-3)
    f = np.array([0.3, 0.5, 0.7, 0.4])
    q = 0.5 * np.sin(2 * np.pi * f * t[:, None])
    per_motor = np.cos(2 * np.pi * f * t[:, None]) * np.array([1.0, 2.0, 3.0, 4.0])
    coupling = tmp_path / "c.json"
    coupling.write_text(
        json.dumps({"joints": list(model.joint_names), "motors": list(MOTORS), "matrix": TENDONS.tolist()})
    )

    def write(name: str, columns: list[str], order: list[int]) -> str:
        header = "time," + ",".join(f"q{i}" for i in range(1, 5)) + "," + ",".join(columns[k] for k in order)
        rows = np.column_stack([t, q, per_motor[:, order]])
        (tmp_path / name).write_text(header + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows))
        return tmp_path / name

    order = [2, 0, 3, 1]
    settings = ImportSettings(cutoff=10.0, coupling=str(coupling))
    numbered = import_recording(write("n.csv", [f"tau{i}" for i in range(1, 5)], [0, 1, 2, 3]), model, settings)[0]
    named = import_recording(write("t.csv", [f"tau_{m.upper()}" for m in MOTORS], order), model, settings)[0]
    assert named.meta.channels["tau"].motors == MOTORS
    assert np.array_equal(named.channel_values["tau"], numbered.channel_values["tau"])
    truth = np.stack([np.interp(named.time[0], t, c) for c in per_motor.T], axis=1)  # each motor's column, by name
    assert np.abs(named.channel_values["tau"][0] - truth).max() < 1e-3 * np.abs(truth).max()

    drives = ImportSettings(cutoff=10.0, coupling=str(coupling), torque_constant=(0.1,), gear_ratio=(50.0,))
    current = import_recording(write("i.csv", [f"i_{m}" for m in MOTORS], order), model, drives)[0]
    (key,) = [k for k in current.channel_values if k != "tau"]
    assert current.meta.channels[key].motors == MOTORS
    assert np.array_equal(current.channel_values[key], numbered.channel_values["tau"])

    joints = write("j.csv", [f"tau_{j}" for j in model.joint_names], [0, 1, 2, 3])
    with pytest.raises(DatasetError, match=r"names no motor of the coupling \(--coupling\); .*\(tau_m1, tau_m2"):
        import_recording(joints, model, settings)
    assert import_recording(joints, model, ImportSettings(cutoff=10.0))[0].channel_values["tau"].shape[-1] == 4


# -- small mends ------------------------------------------------------------------------------------------------


def test_mjcf_export_names_every_non_physical_link_as_the_urdf_export(tmp_path):
    import ineid
    from ineid.errors import IdentificationError
    from ineid.robots.mjcf_write import mjcf_with_inertials
    from ineid.robots.urdf_write import urdf_with_inertials
    from tests.test_mjcf import MENAGERIE

    path = tmp_path / "menagerie.xml"
    path.write_text(MENAGERIE)
    model = ineid.load_robot(path, unknown_links=["link2", "link3"])
    bad = {}
    for link, k in (("link2", 4), ("link3", 0)):  # Ixx < 0; a negative mass
        i = model.link_names.index(link)
        bad[link] = model.theta_cad[10 * i : 10 * i + 10].copy()
        bad[link][k] = -1.0
    messages = []
    for write in (lambda: mjcf_with_inertials(path, bad), lambda: urdf_with_inertials(model.urdf_text, bad)):
        with pytest.raises(IdentificationError) as e:
            write()
        messages.append(str(e.value))
        assert e.value.status == "non_physical"
    for m in messages:
        assert "not a rigid body for 2 of 2 links, link 'link2' (" in m and "link 'link3' (" in m
        assert "--method consistent" in m
    assert messages[0].replace("an MJCF", "a URDF") == messages[1]


def test_friction_check_of_a_coupled_channel_follows_the_motors_velocities():
    """A differential (``qd_joint = C qd_motor``) whose motors' Coulomb friction the model lacks: each motor axis's
    residual follows its motor's velocity ``C^-1 qd_joint``, which the check finds with the coupling given; paired
    with the joints' velocities by position it explains far less."""
    from ineid.report.residuals import check_residual

    rng = np.random.default_rng(2)
    t = np.arange(600) / 100.0
    qd = np.column_stack([np.cos(1.3 * t), 0.8 * np.cos(0.7 * t + 1)])
    c = np.array([[0.5, 0.5], [0.5, -0.5]])
    motors = np.linalg.solve(c, qd.T).T
    pred = np.column_stack([np.sin(2.9 * t) + t / 6, 0.5 * np.sin(0.4 * t + 1)])
    meas = pred + 0.05 * rng.standard_normal(pred.shape) + 0.3 * np.sign(motors)
    args = (t, meas, pred, ("m1", "m2"), ("N*m", "N*m"), (("tau", 0, 2, "joint_torque"),), qd, np.full(2, 0.05))
    coupled = check_residual(*args, couplings={"tau": c})
    by_position = check_residual(*args)
    assert all(a.friction_share > 0.9 for a in coupled.axes) and "friction" in {w.code for w in coupled.warnings}
    shares = [a.friction_share for a in by_position.axes]  # measured 0.71, 0.13
    assert max(shares) < 0.8 and min(shares) < 0.2


def test_generate_with_stribeck_truth_and_identify_it_back(run, tmp_path):
    """``data generate --friction-truth ...,fs=,vs=``: the joint torques carry ``fs exp(-(qd/vs)^2) sign(qd)``; a solve
    with the Stribeck term at the given velocity finds fs (clean data: to round-off), and with the velocity
    identified finds it too."""
    from ineid.data import load_dataset
    from ineid.identify import load_results

    out = tmp_path / "stribeck.h5"
    truth = "fv=0.05,fc=0.2,fs=0.15,elbow.fs=0.1,vs=0.4"
    r = run(*r_args(out, truth))
    assert r.exit_code == 0, r.output
    extra = load_dataset(out).meta.extra_truth
    assert extra["stribeck_velocity"] == 0.4 and extra["elbow.fs"] == 0.1 and extra["shoulder_pitch.fs"] == 0.15
    solve = ("-q", "solve", out, "--use", "torque", "--friction", "viscous,coulomb,stribeck", "--method", "linear")
    r = run(*solve, "--stribeck-velocity", "0.4", "--out", tmp_path / "given.h5")
    assert r.exit_code == 0, r.output
    res = load_results(tmp_path / "given.h5")
    got = dict(zip(res.param_names, res.theta_hat[0], strict=True))
    for name, value in extra.items():
        if name != "stribeck_velocity":
            assert abs(got[name] - value) < 1e-6, (name, got[name], value)
    r = run(*solve, "--stribeck-velocity", "identify", "--backend", "casadi", "--out", tmp_path / "found.h5")
    assert r.exit_code == 0, r.output
    (record,) = load_results(tmp_path / "found.h5").meta["channels"]
    assert abs(record["stribeck_velocity"] / 0.4 - 1) < 1e-4, record
    bad = run(*r_args(tmp_path / "bad.h5", "fs=0.1"))
    assert bad.exit_code != 0 and "need the Stribeck velocity: vs=" in bad.output
    bad = run(*r_args(tmp_path / "bad.h5", "elbow.vs=0.1"))
    assert bad.exit_code != 0 and "one positive value (rad/s) for every joint" in bad.output


def r_args(out, truth: str) -> tuple:
    """``data generate`` of sweaty-arm's joint torques (one configuration, 150 frames) with ``--friction-truth``."""
    return ("-q", "data", "generate", "--n-configs", "1", "--n-frames", "150", "--channels", "torque",
            "--friction-truth", truth, "--seed", "4", "--out", out)  # fmt: skip
