"""Datasets: sampling validity, wrenches against Pinocchio, determinism, the file format."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

import ineid
from ineid import DatasetError, OutputExistsError, PhysicalConsistencyError, check_physical, is_physical
from ineid.data import (
    Combination,
    DatasetSpec,
    DatasetWriter,
    FrameSampling,
    NoiseModel,
    ParameterSampling,
    generate_dataset,
    load_dataset,
    read_recording_csv,
    sample_configurations,
    sample_frames,
    sample_link_parameters,
    write_dataset,
    write_recording_csv,
)
from ineid.data.dataset.meta import VERSION
from ineid.data.synthesis.sampling import random_rotations
from ineid.params import inertial_from_theta, pseudo_inertia
from ineid.reference import pinocchio_base_wrench, pinocchio_model

from .conftest import FIXTURES, SEED, rel_err


def small_spec(**kw) -> DatasetSpec:
    base = {"combination": Combination("factorial", per_link=6), "n_frames": 12, "seed": SEED}
    base.update(kw)
    return DatasetSpec(**base)


@pytest.fixture(scope="module")
def small(model):
    return generate_dataset(model, small_spec())


# -- parameter sampling --------------------------------------------------------------


@pytest.mark.parametrize(
    "bands",
    [ParameterSampling(), ParameterSampling(0.5, 0.05, 0.95, 180.0), ParameterSampling(0.0, 0.0, 0.0, 0.0)],
    ids=["default", "wide", "cad"],
)
def test_every_sampled_set_is_physical(model, bands):
    for k, link in enumerate(model.unknown_links):
        cad = model.theta_cad[model.unknown_index][10 * k : 10 * k + 10]
        sets = sample_link_parameters(cad, 2000, np.random.default_rng(k), bands)
        assert is_physical(sets).all(), link
        assert np.linalg.eigvalsh(pseudo_inertia(sets)).min() > 0
        for t in sets[:50]:
            check_physical(t, [link])
        m_cad, c_cad, _ = inertial_from_theta(cad)
        m, c, _ = inertial_from_theta(sets)
        assert np.all(np.abs(m / m_cad - 1) <= bands.mass_rel + 1e-12)
        assert np.all(np.abs(c - c_cad) <= bands.com_box + 1e-12)
    if bands.mass_rel == 0 and bands.com_box == 0 and bands.inertia_rel == 0 and bands.orientation_deg == 0:
        np.testing.assert_allclose(sets, np.broadcast_to(cad, sets.shape), rtol=1e-10, atol=1e-15)


def test_the_checker_rejects_what_the_sampler_never_makes(model):
    cad = model.theta_cad[model.unknown_index][:10]
    good = sample_link_parameters(cad, 5, np.random.default_rng(0))
    m, c, ic = inertial_from_theta(good[0])
    w, v = np.linalg.eigh(ic)
    bad_triangle = ineid.theta_from_inertial(m, c, v @ np.diag([w[0], w[1], w[0] + w[1] + 1e-4]) @ v.T)
    bad_mass = good[1].copy()
    bad_mass[0] = -bad_mass[0]
    bad_pd = ineid.theta_from_inertial(m, c, v @ np.diag([-1e-5, w[1], w[2]]) @ v.T)
    assert is_physical(np.stack([good[0], bad_triangle, bad_mass, bad_pd])).tolist() == [True, False, False, False]
    with pytest.raises(PhysicalConsistencyError, match="triangle inequality"):
        check_physical(bad_triangle, ["forearm"])


def test_rotations_are_proper(rng):
    for deg in (0.0, 30.0, 180.0):
        r = random_rotations(rng, 100, deg)
        np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
        angle = np.degrees(np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        assert angle.max() <= min(deg, 180.0) + 1e-6


def test_factorial_and_random_pairing(model):
    cad = model.theta_cad[model.unknown_index]
    theta, index = sample_configurations(cad, Combination("factorial", per_link=4), seed=1)
    assert theta.shape == (16, 20) and index.tolist()[:5] == [[0, 0], [0, 1], [0, 2], [0, 3], [1, 0]]
    for i, (a, b) in enumerate(index):  # same set index -> same link parameters
        assert np.array_equal(theta[i, :10], theta[4 * a, :10]) and np.array_equal(theta[i, 10:], theta[b, 10:])
    bigger, _ = sample_configurations(cad, Combination("factorial", per_link=7), seed=1)
    assert np.array_equal(bigger[0, :10], theta[0, :10])  # set k does not depend on the count
    pooled, pidx = sample_configurations(cad, Combination("random", per_link=3, n_configs=50), seed=1)
    assert pooled.shape == (50, 20) and set(np.unique(pidx)) <= {0, 1, 2}
    assert len(np.unique(pooled[:, 0])) <= 3
    fresh, fidx = sample_configurations(cad, Combination("random", per_link=None, n_configs=50), seed=1)
    assert len(np.unique(fresh[:, 0])) == 50 and np.array_equal(fidx[:, 0], np.arange(50))
    with pytest.raises(ValueError, match="per_link"):
        Combination("factorial", per_link=0)


# -- frames --------------------------------------------------------------------------


def test_uniform_frames_within_bounds(model, rng):
    q, qd, qdd, t = sample_frames(30, 40, model.q_lower, model.q_upper, model.qd_max, model.qdd_max, rng)
    assert t is None and q.shape == (30, 40, 4)
    assert np.all((q >= model.q_lower) & (q <= model.q_upper))
    assert np.all(np.abs(qd) <= model.qd_max) and np.all(np.abs(qdd) <= model.qdd_max)


def test_fourier_frames_are_smooth_consistent_and_bounded(model, rng):
    spec = FrameSampling("fourier", harmonics=4, base_frequency=0.2)
    n = 4000
    q, qd, qdd, t = sample_frames(8, n, model.q_lower, model.q_upper, model.qd_max, model.qdd_max, rng, spec)
    assert np.all((q >= model.q_lower) & (q <= model.q_upper))
    assert np.all(np.abs(qd) <= model.qd_max + 1e-12) and np.all(np.abs(qdd) <= model.qdd_max + 1e-12)
    dt = t[0, 1] - t[0, 0]
    assert np.isclose(t[0, -1] + dt, 5.0)  # one period of 0.2 Hz
    # analytic derivatives agree with central differences of the sampled signal
    fd_qd = (q[:, 2:] - q[:, :-2]) / (2 * dt)
    fd_qdd = (qd[:, 2:] - qd[:, :-2]) / (2 * dt)
    assert rel_err(fd_qd, qd[:, 1:-1]) < 1e-4 and rel_err(fd_qdd, qdd[:, 1:-1]) < 1e-4
    # periodic: the trajectory closes on itself
    assert rel_err(q[:, -1] + qd[:, -1] * dt, q[:, 0]) < 1e-3
    # some joint uses most of its admissible range (the scaling is not over-conservative)
    assert np.max(np.abs(qd) / model.qd_max) > 0.3


# -- wrenches against an independent engine -------------------------------------------


def pinocchio_wrenches(urdf_path, theta_full, q, qd, qdd, gravity=(0, 0, -9.81), locked=None):
    import pinocchio as pin

    pm = pinocchio_model(urdf_path, gravity, locked)
    for i in range(1, pm.njoints):
        pm.inertias[i] = pin.Inertia.FromDynamicParameters(theta_full[10 * (i - 1) : 10 * i])
    return pinocchio_base_wrench(pm, q, qd, qdd)


def test_file_wrenches_agree_with_pinocchio(model, tmp_path, rng):
    path = write_dataset(model, small_spec(frames=FrameSampling("fourier")), tmp_path / "d.h5")
    ds = load_dataset(path)
    theta = ds.theta()
    for c in rng.choice(ds.n_configs, 6, replace=False):
        ref = pinocchio_wrenches(model.urdf_path, theta[c], ds.q[c], ds.qd[c], ds.qdd[c])
        assert rel_err(ds.wrench[c], ref) < 1e-10


def test_urdf_robot_dataset_carries_its_model(tmp_path, rng):
    urdf = FIXTURES / "mixed_chain.urdf"
    m = ineid.load_robot(urdf, unknown_links=["l3"], gravity=(0.3, 0.0, -9.7))
    path = write_dataset(m, DatasetSpec(Combination("random", n_configs=5), n_frames=7, seed=2), tmp_path / "m.h5")
    ds = load_dataset(path)
    again = ds.model()
    assert again.joint_names == m.joint_names and np.allclose(again.gravity, (0.3, 0.0, -9.7))
    assert again.unknown_links == ("l3",)
    theta = ds.theta()
    ref = pinocchio_wrenches(urdf, theta[3], ds.q[3], ds.qd[3], ds.qdd[3], gravity=(0.3, 0.0, -9.7))
    assert rel_err(ds.wrench[3], ref) < 1e-10


# -- determinism and streaming ---------------------------------------------------------


def test_same_seed_bit_identical_in_memory_and_on_disk(model, small, tmp_path):
    again = generate_dataset(model, small_spec())
    on_disk = load_dataset(write_dataset(model, small_spec(), tmp_path / "a.h5"))
    for name, arr in small.arrays().items():
        assert np.array_equal(arr, again.arrays()[name]), name
        assert np.array_equal(arr, on_disk.arrays()[name]), name
    other = generate_dataset(model, small_spec(seed=SEED + 1))
    assert not np.array_equal(other.q, small.q)


def test_draws_do_not_depend_on_chunking_or_count(model):
    a = generate_dataset(model, small_spec(combination=Combination("random", n_configs=70), n_frames=5))
    b = generate_dataset(model, small_spec(combination=Combination("random", n_configs=200), n_frames=5))
    assert np.array_equal(a.q, b.q[:70]) and np.array_equal(a.wrench, b.wrench[:70])


def test_noise_is_recorded_and_leaves_the_clean_data_alone(model, small):
    noise = NoiseModel.create(4, force=0.5, moment=0.05, q=1e-3, qd=0.01, qdd=0.1)
    ds = generate_dataset(model, small_spec(noise=noise, combination=Combination("factorial", per_link=20)))
    assert set(ds.clean) == {"q", "qd", "qdd", "wrench"}
    assert np.array_equal(ds.clean["q"][:36], small.q)  # frames depend on position and seed only
    head = generate_dataset(model, small_spec(noise=noise))
    for k in ("q", "qd", "qdd", "wrench"):
        assert np.array_equal(head.clean[k], getattr(small, k)), k
    std = np.std(ds.wrench - ds.clean["wrench"], axis=(0, 1))
    np.testing.assert_allclose(std, [0.5] * 3 + [0.05] * 3, rtol=0.05)
    np.testing.assert_allclose(np.std(ds.qdd - ds.clean["qdd"]), 0.1, rtol=0.05)
    assert ds.meta.noise["wrench"] == [0.5] * 3 + [0.05] * 3


def test_chunked_generation_streams(model, tmp_path):
    """Several chunks, the last one short; memory holds one chunk at a time."""
    from ineid.data.synthesis.generate import GenerationPlan

    spec = small_spec(combination=Combination("random", n_configs=1000), n_frames=300)
    plan = GenerationPlan(model, spec)
    assert plan.rows < plan.n_configs and plan.n_configs % plan.rows != 0
    ds = load_dataset(write_dataset(model, spec, tmp_path / "big.h5"))
    assert np.array_equal(ds.wrench[-3:], generate_dataset(model, spec).wrench[-3:])


@pytest.mark.slow
def test_100k_configurations_in_bounded_memory(tmp_path):
    """The scale ineid is built for: 100,000 x 100 frames with a bounded peak RSS."""
    code = (
        "import resource, ineid; from ineid.data import *;"
        "m = ineid.load_robot('sweaty-arm');"
        f"write_dataset(m, DatasetSpec(Combination('random', n_configs=100_000)), {str(tmp_path / 'x.h5')!r});"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    peak_mb = int(out.stdout.split()[-1]) / 1024
    frames_mb = 100_000 * 100 * 18 * 8 / 2**20  # what holding all frames would cost
    assert peak_mb < 0.5 * frames_mb, f"peak RSS {peak_mb:.0f} MB vs {frames_mb:.0f} MB of frames"


# -- the file format ---------------------------------------------------------------------


def test_round_trip_and_selection(small, tmp_path):
    path = small.save(tmp_path / "s.h5")
    back = load_dataset(path)
    assert back.meta.robot == "sweaty-arm" and back.meta.seed == SEED and back.meta.source == "synthetic"
    assert back.meta.unknown_links == ("upper_arm", "forearm") and back.meta.version == VERSION
    with h5py.File(path) as f:
        assert f.attrs["format"] == "ineid-dataset" and "<robot" in f.attrs["urdf"]
        assert list(f.attrs["param_order"]) == list(ineid.PARAM_NAMES)
        assert f["wrench"].compression == "gzip" and f["wrench"].shuffle and f["wrench"].chunks is not None
    sel = load_dataset(path, configs=[7, 2, 30], frames=slice(0, 5))
    assert sel.q.shape == (3, 5, 4) and sel.config_index.tolist() == [7, 2, 30]
    assert np.array_equal(sel.wrench, small.wrench[[7, 2, 30], :5])
    assert np.array_equal(sel.theta_unknown, small.theta_unknown[[7, 2, 30]])
    assert np.array_equal(small.select([7, 2, 30], slice(0, 5)).q, sel.q)
    with pytest.raises(DatasetError, match="out of range"):
        load_dataset(path, configs=[36])


def test_refuses_to_overwrite_and_leaves_no_partial_file(model, small, tmp_path):
    path = small.save(tmp_path / "s.h5")
    with pytest.raises(OutputExistsError, match=r"s\.h5 exists; pass --overwrite to replace it$"):
        small.save(path)
    before = path.read_bytes()

    class Boom(Exception):
        pass

    with pytest.raises(Boom):
        with DatasetWriter(path, small.meta, 36, 12, ["q"], rows=6, overwrite=True) as w:
            w.write("q", 0, small.q[:6])
            raise Boom  # e.g. Ctrl-C in the middle of a run
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]

    def interrupt(done, total):
        raise KeyboardInterrupt

    target = tmp_path / "new.h5"
    with pytest.raises(KeyboardInterrupt):
        write_dataset(model, small_spec(combination=Combination("random", n_configs=500)), target, progress=interrupt)
    assert not target.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


def test_damaged_files_give_clear_errors(small, tmp_path):
    path = small.save(tmp_path / "good.h5")
    raw = path.read_bytes()

    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DatasetError, match="truncated or corrupt"):
        load_dataset(truncated)

    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not an hdf5 file at all" * 10)
    with pytest.raises(DatasetError, match="not a readable HDF5 file"):
        load_dataset(garbage)

    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset(tmp_path / "missing.h5")

    def variant(name, edit):
        p = tmp_path / name
        p.write_bytes(raw)
        with h5py.File(p, "r+") as f:
            edit(f)
        return p

    with pytest.raises(DatasetError, match="not an ineid dataset"):
        load_dataset(variant("other.h5", lambda f: f.attrs.__setitem__("format", "something-else")))
    with pytest.raises(DatasetError, match="format version 99 is not supported"):
        load_dataset(variant("newer.h5", lambda f: f.attrs.__setitem__("version", 99)))

    def put_nan(f):
        w = f["wrench"][()]
        w[3, 5, 2] = np.nan
        del f["wrench"]
        f.create_dataset("wrench", data=w)

    with pytest.raises(DatasetError, match=r"wrench holds NaN \(1 entries; first at config 3, frame 5, column 2\)"):
        load_dataset(variant("nan.h5", put_nan))
    with pytest.raises(DatasetError, match=r"config 3, frame 5"):  # reported in file numbering
        load_dataset(tmp_path / "nan.h5", configs=[0, 3])

    def bad_shape(f):
        del f["theta_unknown"]
        f.create_dataset("theta_unknown", data=np.zeros((36, 19)))

    with pytest.raises(DatasetError, match=r"theta_unknown has shape \(36, 19\), expected \(36, 20\)"):
        load_dataset(variant("shape.h5", bad_shape))
    with pytest.raises(DatasetError, match="'qdd' is missing"):
        load_dataset(variant("missing_qdd.h5", lambda f: f.__delitem__("qdd")))

    # a chunk whose compressed bytes are damaged on disk
    flipped = bytearray(raw)
    with h5py.File(path) as f:
        offset = f["wrench"].id.get_chunk_info(0).byte_offset
    flipped[offset + 10 : offset + 400] = bytes(390)
    damaged = tmp_path / "chunk.h5"
    damaged.write_bytes(bytes(flipped))
    with pytest.raises(DatasetError, match="(cannot be read|holds)"):
        load_dataset(damaged)


# -- CSV recordings ------------------------------------------------------------------------


def test_csv_import_round_trip(model, small, tmp_path):
    src = generate_dataset(model, small_spec(frames=FrameSampling("fourier"), n_frames=40))
    csv_path = write_recording_csv(tmp_path / "rec.csv", src, config=4)
    rec = read_recording_csv(csv_path, model)
    assert rec.n_configs == 1 and rec.n_frames == 40 and not rec.has_truth and rec.meta.source == "recording"
    for k in ("q", "qd", "qdd", "wrench", "time"):
        assert np.array_equal(getattr(rec, k)[0], getattr(src, k)[4]), k
    flipped = read_recording_csv(write_recording_csv(tmp_path / "flip.csv", src, 4, flip_wrench=True), model, True)
    assert np.array_equal(flipped.wrench, rec.wrench)
    back = load_dataset(rec.save(tmp_path / "rec.h5"))
    assert back.theta_unknown is None and np.array_equal(back.wrench, rec.wrench)
    with pytest.raises(DatasetError, match="recording"):
        back.theta()
    # column order, case and extra columns do not matter
    text = csv_path.read_text().splitlines()
    cols = text[0].split(",")
    perm = list(reversed(range(len(cols))))
    shuffled = [",".join([c.upper() for c in (cols[i] for i in perm)] + ["note"])]
    shuffled += [",".join([line.split(",")[i] for i in perm] + ["x"]) for line in text[1:]]
    (tmp_path / "shuffled.csv").write_text("# exported by a logger\n" + "\n".join(shuffled) + "\n")
    assert np.array_equal(read_recording_csv(tmp_path / "shuffled.csv", model).q, rec.q)
    # a UTF-8 byte-order mark (spreadsheet exports) is not part of the first column's name
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + csv_path.read_bytes())
    assert np.array_equal(read_recording_csv(tmp_path / "bom.csv", model).time, rec.time)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda h, r: (h.replace(",fz", ""), [",".join(x.split(",")[:-4] + x.split(",")[-3:]) for x in r]),
            "missing column fz",
        ),
        (lambda h, r: (h, [r[0].replace(r[0].split(",")[2], "abc", 1)] + r[1:]), "line 2, column 'q2': 'abc' is not"),
        (lambda h, r: (h, [r[0].replace(r[0].split(",")[3], "nan", 1)] + r[1:]), "values must be finite"),
        (lambda h, r: (h, r[1:2] + r[0:1] + r[2:]), "time does not increase at line 3"),
        (lambda h, r: (h, []), "no data rows"),
        (lambda h, r: (h, [r[0] + ",1"] + r[1:]), "line 2 has 20 cells, the header has 19"),
    ],
    ids=["missing-column", "non-numeric", "nan", "time", "empty", "ragged"],
)
def test_csv_import_errors(model, small, tmp_path, edit, message):
    text = write_recording_csv(tmp_path / "ok.csv", small).read_text().splitlines()
    header, rows = edit(text[0], text[1:])
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    with pytest.raises(DatasetError, match=message):
        read_recording_csv(path, model)


def test_csv_import_wrong_joint_count(model, tmp_path):
    three = "time,q1,q2,q3,qd1,qd2,qd3,qdd1,qdd2,qdd3,fx,fy,fz,mx,my,mz\n" + ",".join(["0"] * 16) + "\n"
    (tmp_path / "three.csv").write_text(three)
    with pytest.raises(DatasetError, match="columns are for 3 joints .* but sweaty-arm has 4"):
        read_recording_csv(tmp_path / "three.csv", model)
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DatasetError, match="empty"):
        read_recording_csv(tmp_path / "empty.csv", model)


def test_importing_data_never_imports_sympy():
    code = (
        "import sys, ineid.data; import ineid.data.synthesis.generate; "
        "assert 'sympy' not in sys.modules, 'sympy imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "PYTHONHASHSEED": "0"})


def test_paths_are_strings_or_paths(small, tmp_path):
    p = small.save(str(tmp_path / "str.h5"))
    assert isinstance(load_dataset(str(p)), type(small)) and Path(p).is_file()


def test_csv_errors_name_the_physical_line(model, small, tmp_path):
    text = write_recording_csv(tmp_path / "ok.csv", small).read_text().splitlines()
    bad = text[1].split(",")
    bad[5] = "oops"
    lines = ["# logger v2", "", text[0], text[0 + 1], "# pause", ",".join(bad)]
    (tmp_path / "c.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="line 6, column 'q4'|line 6, column 'qd1'"):
        read_recording_csv(tmp_path / "c.csv", model)


def test_parallel_chunk_reads_equal_h5py(small, tmp_path):
    """Arrays ineid wrote are inflated on all cores; any row range equals h5py's own read,
    and a file with other filters (no shuffle) goes through h5py."""
    from ineid.data.dataset import read
    from ineid.data.dataset.write import DatasetWriter

    path = tmp_path / "s.h5"
    per_config = [k for k in small.arrays() if k != "theta_known"]
    with DatasetWriter(path, small.meta, small.n_configs, small.n_frames, per_config, rows=8) as w:
        w.write_constant("theta_known", small.theta_known)
        for name in per_config:
            w.write(name, 0, small.arrays()[name])
    with h5py.File(path) as f:
        dset = f["wrench"]
        assert read._own_chunks(dset) and dset.chunks[0] == 8
        for start, stop in [(0, 36), (1, 35), (7, 9), (5, 6), (32, 36), (8, 16)]:  # 36 = 4 x 8 + 4
            assert np.array_equal(read._read_chunks_parallel(dset, start, stop), dset[start:stop])
    plain = tmp_path / "plain.h5"
    with h5py.File(path) as src, h5py.File(plain, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        for name in src:
            data = src[name][()]
            kw = {"chunks": (7, *data.shape[1:]), "compression": "gzip"} if data.ndim > 1 else {}
            dst.create_dataset(name, data=data, **kw)
        assert not read._own_chunks(dst["wrench"])
    back, mine = load_dataset(plain, configs=slice(3, 30)), load_dataset(path, configs=slice(3, 30))
    for k in ("q", "qd", "qdd", "wrench", "theta_unknown"):
        assert np.array_equal(getattr(back, k), getattr(mine, k)) and np.array_equal(
            getattr(mine, k), getattr(small, k)[3:30]
        )


def test_clean_copies_are_read_on_request(model, tmp_path):
    noise = NoiseModel.create(4, force=0.5, moment=0.05)
    path = generate_dataset(model, small_spec(noise=noise)).save(tmp_path / "n.h5")
    assert set(load_dataset(path).clean) == {"wrench"}
    lean = load_dataset(path, clean=False)
    assert lean.clean == {} and np.array_equal(lean.wrench, load_dataset(path).wrench)
