"""Measurement channels (:mod:`ineid.channels`): rows, predictions, records, and stacking.

The base wrench channel must be the model's own regressor (times the sensor transform);
a set of channels must stack any channels, whatever their number of axes, extra columns
or transforms: a test-only channel with one axis per joint and cheap rows (the generated
regressor takes seconds to compile) proves it is generic.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass

import numpy as np
import pytest

from ineid.channels import (
    BaseWrench,
    Channel,
    ChannelSet,
    SensorPose,
    channel_from_dict,
    channel_kinds,
    register,
    wrench_transform,
)
from ineid.data.dataset.meta import VERSION
from ineid.errors import DatasetError
from tests.conftest import random_states, rel_err

POSE = SensorPose((0.03, -0.02, -0.05), (3.1, 0.2, 0.7), frame="ft_sensor", frame_id="ft")


@functools.cache
def _pull_entries(n_dof: int):
    """Row ``j`` of a :class:`Pull`: ``qdd_j`` at link ``j``'s mass, ``qd_j^2 cos q_j`` at its ``mx``."""

    def entries(q, qd, qdd, gravity):
        n_cols = 10 * n_dof
        out: list = [0] * (n_dof * n_cols)
        for j in range(n_dof):
            out[j * n_cols + 10 * j] = qdd[..., j]
            out[j * n_cols + 10 * j + 1] = qd[..., j] ** 2 * _cos(q[..., j])
        return tuple(out)

    return entries


def _cos(x):
    import jax.numpy as jnp

    return jnp.cos(x)


def pull_rows(model, q, qd, qdd) -> np.ndarray:
    """What a :class:`Pull` channel's rows are, in NumPy: (..., n_dof, 10 n_dof)."""
    n = model.n_dof
    out = np.zeros(q.shape[:-1] + (n, 10 * n))
    for j in range(n):
        out[..., j, 10 * j] = qdd[..., j]
        out[..., j, 10 * j + 1] = qd[..., j] ** 2 * np.cos(q[..., j])
    return out


@register
@dataclass(frozen=True, kw_only=True)
class Pull(Channel):
    """Test-only stand-in for a per-joint sensor (cheap to compile, unlike the generated regressor):
    ``n_dof`` axes, rows :func:`pull_rows`; with ``drift`` one extra kept column per axis
    (``y_j = ... + x_j qd_j``), so the set's block layout of extras is exercised."""

    key: str = "pull"
    drift: bool = False

    kind = "test-pull"
    RECORD_FIELDS = ("drift",)

    def axes(self, model):
        return tuple(f"{j}" for j in model.joint_names)

    def units(self, model):
        return ("N*m",) * model.n_dof

    def describe(self) -> str:
        return "a test-only pull on every joint"

    def entries_function(self, model):
        return _pull_entries(model.n_dof)

    def nonzero(self, model):
        return tuple((10 * j, 10 * j + 1) for j in range(model.n_dof))

    def casadi_function(self, model):
        import casadi as ca

        q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
        y = ca.SX.zeros(model.n_dof, 10 * model.n_dof)
        for j in range(model.n_dof):
            y[j, 10 * j] = qdd[j]
            y[j, 10 * j + 1] = qd[j] ** 2 * ca.cos(q[j])
        return ca.Function("pull", [q, qd, qdd], [y])

    def extra_names(self, model):
        return tuple(f"{self.key}.{j}.drift" for j in model.joint_names) if self.drift else ()

    def extra_rows_function(self, model):
        return _drift_rows if self.drift else None

    def casadi_extra_function(self, model):
        if not self.drift:
            return None
        import casadi as ca

        q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
        return ca.Function("drift", [q, qd, qdd], [ca.diag(qd)])


def _drift_rows(q, qd, qdd):
    import jax.numpy as jnp

    return jnp.eye(qd.shape[-1], dtype=qd.dtype) * qd[..., None, :]


@register
@dataclass(frozen=True, kw_only=True)
class _Clash(Pull):
    """Test-only: a second pull whose extra columns take :class:`Pull`'s names."""

    key: str = "pull_b"
    kind = "test-pull-clash"

    def extra_names(self, model):
        return tuple(f"pull.{j}.drift" for j in model.joint_names) if self.drift else ()


@pytest.fixture(scope="module")
def states(model):
    return random_states(model, 7, np.random.default_rng(7))


def test_base_wrench_rows_are_the_models_regressor(model, states):
    psi = model.regressor(*states)
    x = wrench_transform(POSE.base_R_sensor, POSE.base_p_sensor)
    assert np.array_equal(x, POSE.transform())
    for channel, expected in ((BaseWrench(), psi), (BaseWrench(sensor=POSE), x @ psi)):
        assert np.array_equal(channel.rows(model, *states), expected)  # the model's evaluator, X as before: bit for bit
        u, k = channel.rows_split(model, *states)
        assert np.array_equal(u, expected[..., model.unknown_index])
        assert np.array_equal(k, expected[..., model.known_index])
        assert rel_err(ChannelSet.of(channel).casadi_rows(model)(*(s[0] for s in states)), expected[0]) < 1e-12
    # the jit-safe rows (the generated base_wrench_regressor, X baked in), evaluated op by op
    jax_rows = BaseWrench(sensor=POSE).jax_rows_function(model)(*states, model.gravity)
    assert rel_err(np.asarray(jax_rows), x @ psi) < 1e-13
    assert BaseWrench().jax_rows_function(model) is model.jax_regressor
    assert BaseWrench(sensor=SensorPose()).transform() is None  # the identity pose is the base frame
    # structural zeros: every entry outside nonzero() is exactly zero on random states
    for a, cols in enumerate(BaseWrench().nonzero(model)):
        assert np.all(np.delete(psi[:, a], cols, axis=-1) == 0.0)


def test_base_wrench_predicts_through_base_wrench(model, states, rng):
    theta = model.theta_cad * rng.uniform(0.5, 1.5, model.theta_cad.shape)
    psi = model.regressor(*states)
    x = POSE.transform()
    assert np.array_equal(BaseWrench().predict(model, *states, theta), model.base_wrench(*states, theta))
    sensor = BaseWrench(sensor=POSE)
    assert rel_err(sensor.predict(model, *states, theta), x @ psi @ theta) < 1e-12
    predicted = sensor.jax_predict_function(model)(*states, model.gravity, theta)
    assert rel_err(np.asarray(predicted), x @ psi @ theta) < 1e-12
    assert BaseWrench().jax_predict_function(model) is model.jax_base_wrench


def test_the_generic_evaluators_follow_the_entries(model, states, rng):
    channel = Pull()
    expected = pull_rows(model, *states)
    assert rel_err(channel.rows(model, *states), expected) < 1e-15
    assert rel_err(np.asarray(channel.jax_rows_function(model)(*states, model.gravity)), expected) < 1e-15
    assert rel_err(ChannelSet.of(channel).casadi_rows(model)(*(s[0] for s in states)), expected[0]) < 1e-15
    theta = rng.normal(size=10 * model.n_links)
    per_frame = rng.normal(size=(len(states[0]), 10 * model.n_links))
    assert rel_err(channel.predict(model, *states, theta), expected @ theta) < 1e-14
    assert rel_err(channel.predict(model, *states, per_frame), np.einsum("fap,fp->fa", expected, per_frame)) < 1e-14
    many = [s[None].repeat(3, axis=0) for s in states]  # leading shapes broadcast: (3, 7, n_dof)
    assert channel.rows(model, *many).shape == (3, 7, model.n_dof, 10 * model.n_links)
    assert channel.extra_names(model) == () and channel.extra_rows(model, *states).shape == (7, model.n_dof, 0)


def test_records_round_trip_through_json():
    channels = ChannelSet.of(BaseWrench(sensor=POSE, offsets=True), BaseWrench(key="wrench_base"), Pull(drift=True))
    back = ChannelSet.from_list(json.loads(json.dumps(channels.to_list())))
    assert back == channels and hash(back) == hash(channels) and back.key_tuple() == channels.key_tuple()
    assert back["wrench"].sensor == POSE and back["wrench"].offsets and back["pull"].drift
    assert {"wrench", "test-pull"} <= set(channel_kinds())
    assert channel_from_dict({"kind": "wrench", "key": "wrench"}) == BaseWrench()  # optional fields default
    assert BaseWrench(sensor=POSE).with_offsets(True) == back["wrench"]
    assert "sensor frame xyz=(0.03, -0.02, -0.05) m" in back["wrench"].describe()


def test_a_set_stacks_any_channels(model, states, rng):
    sensor = BaseWrench(key="wrench_sensor", sensor=POSE, offsets=True)
    channels = ChannelSet.of(BaseWrench(), Pull(), sensor)
    nd = model.n_dof
    n = channels.n_axes(model)
    assert n == 12 + nd and [(b.start, b.stop) for b in channels.blocks(model)] == [(0, 6), (6, 6 + nd), (6 + nd, n)]
    assert channels.axes(model)[5:7] == ("wrench.mz", f"pull.{model.joint_names[0]}")
    assert channels.units(model)[:7] == ("N", "N", "N", "N*m", "N*m", "N*m", "N*m")
    assert channels.offset_mask(model).tolist() == [False] * (6 + nd) + [True] * 6
    assert channels.offset_names(model)[0] == "wrench_sensor.fx.offset"
    assert ChannelSet.of(BaseWrench()).axes(model) == ("fx", "fy", "fz", "mx", "my", "mz")

    psi = model.regressor(*states)
    x = POSE.transform()
    rows = channels.rows(model, *states)
    assert rows.shape == (len(states[0]), n, 10 * model.n_links)
    assert np.array_equal(rows[:, :6], psi) and np.array_equal(rows[:, 6 + nd :], x @ psi)
    assert rel_err(rows[:, 6 : 6 + nd], pull_rows(model, *states)) < 1e-15
    before_t = np.concatenate([psi, pull_rows(model, *states), psi], axis=1)
    assert rel_err(channels.transform(model) @ before_t, rows) < 1e-14
    u, k = channels.rows_split(model, *states)
    assert np.array_equal(u, rows[..., model.unknown_index]) and np.array_equal(k, rows[..., model.known_index])
    assert rel_err(np.asarray(channels.jax_rows_function(model)(*states, model.gravity)), rows) < 1e-13
    assert rel_err(np.asarray(channels.casadi_rows(model)(*(s[0] for s in states))), rows[0]) < 1e-12
    theta = model.theta_cad
    assert rel_err(channels.predict(model, *states, theta), rows @ theta) < 1e-12
    predicted = channels.jax_predict_function(model)(*states, model.gravity, theta)
    assert rel_err(np.asarray(predicted), rows @ theta) < 1e-12
    for a, cols in enumerate(channels.nonzero(model)):  # structural zeros of the stacked T Phi
        assert np.all(np.delete(rows[:, a], cols, axis=-1) == 0.0)

    # values, noise, splitting: per stacked axis
    measured = {
        "wrench": rng.normal(size=(2, 6)),
        "pull": rng.normal(size=(2, nd)),
        "wrench_sensor": rng.normal(size=(2, 6)),
    }
    y = channels.values(measured, model)
    assert y.shape == (2, n) and np.array_equal(channels.split(y, model)["pull"], measured["pull"])
    noise = {"wrench": [0.5, 0.5, 0.5, 0.05, 0.05, 0.05], "pull": 0.2, "wrench_sensor": [1.0] * 6}
    assert channels.noise_std(noise, model).tolist() == noise["wrench"] + [0.2] * nd + [1.0] * 6
    assert channels.noise_std({"wrench": [0.5] * 6}, model) is None  # a channel without recorded noise
    assert channels.noise_std({**noise, "pull": 0.0}, model) is None
    with pytest.raises(DatasetError, match="'pull' has shape"):
        channels.values({**measured, "pull": measured["wrench"]}, model)

    # selection keeps the set's order; no extra columns: zero columns, stacked generically
    picked = channels.select(["wrench_sensor", "wrench"])
    assert picked.keys == ("wrench", "wrench_sensor") and np.array_equal(picked.transform(model)[:6, :6], np.eye(6))
    assert channels.extra_names(model) == () and channels.jax_extra_rows_function(model) is None
    assert channels.extra_rows(model, *states).shape == (len(states[0]), n, 0)
    assert channels.casadi_extra_rows(model) is None
    assert ChannelSet.of(BaseWrench()).transform(model) is None
    assert not channels.with_offsets(False).has_offsets and channels.with_offsets(True).offset_mask(model).all()


def test_extra_kept_columns_stack_block_diagonally(model, states):
    channels = ChannelSet.of(Pull(drift=True), BaseWrench(), Pull(key="pull2", drift=True))
    nd, qd = model.n_dof, states[1]
    assert channels.extra_names(model) == tuple(f"{k}.{j}.drift" for k in ("pull", "pull2") for j in model.joint_names)
    e = channels.extra_rows(model, *states)
    expected = np.zeros((len(qd), 2 * nd + 6, 2 * nd))
    expected[:, :nd, :nd] = np.eye(nd) * qd[:, None, :]
    expected[:, nd + 6 :, nd:] = np.eye(nd) * qd[:, None, :]
    assert np.array_equal(e, expected)
    assert np.array_equal(np.asarray(channels.jax_extra_rows_function(model)(*states)), expected)
    assert np.array_equal(np.asarray(channels.casadi_extra_rows(model)(*(s[0] for s in states))), expected[0])
    with pytest.raises(DatasetError, match="distinct names"):
        ChannelSet.of(Pull(drift=True), _Clash(drift=True)).extra_names(model)


BAD_RECORDS = [
    ("not a record", "must be a record"),
    ({"key": "wrench"}, "unknown measurement channel kind None"),
    ({"kind": "imu", "key": "imu"}, "unknown measurement channel kind 'imu'"),
    ({"kind": "wrench"}, "has no key"),
    ({"kind": "wrench", "key": "q"}, "cannot name a dataset entry"),
    ({"kind": "wrench", "key": "Wrench"}, "cannot name a dataset entry"),
    ({"kind": "wrench", "key": "wrench_clean"}, "cannot name a dataset entry"),
    ({"kind": "wrench", "key": "wrench", "offsets": "yes"}, "offsets must be true or false"),
    ({"kind": "wrench", "key": "wrench", "sensor": [0, 0, 0]}, "must be a pose record"),
    ({"kind": "wrench", "key": "wrench", "sensor": {"xyz": [0, 0], "rpy": [0, 0, 0]}}, "3 finite numbers"),
    ({"kind": "wrench", "key": "wrench", "sensor": {"rpy": [0, 0, 0]}}, "must hold xyz and rpy"),
    ({"kind": "wrench", "key": "wrench", "gain": 2.0}, "fields this ineid does not know \\(gain\\)"),
]


@pytest.mark.parametrize(("record", "message"), BAD_RECORDS, ids=[f"record{i}" for i in range(len(BAD_RECORDS))])
def test_bad_records_are_one_line(record, message):
    with pytest.raises(DatasetError, match=message) as info:
        ChannelSet.from_list([{"kind": "wrench", "key": "other"}, record], where="dataset x.h5: channels")
    assert "\n" not in str(info.value) and str(info.value).startswith("dataset x.h5: channels[1]")


@pytest.mark.parametrize(
    ("items", "message"),
    [
        ({"kind": "wrench"}, "expected a list"),
        ([], "no measurement channel"),
        ([{"kind": "wrench", "key": "wrench"}, {"kind": "wrench", "key": "wrench"}], "distinct keys"),
    ],
)
def test_bad_sets_are_one_line(items, message):
    with pytest.raises(DatasetError, match=message) as info:
        ChannelSet.from_list(items)
    assert "\n" not in str(info.value)


def test_select_names_what_is_there():
    channels = ChannelSet.of(BaseWrench(), Pull())
    with pytest.raises(DatasetError, match="no torque measurements here .*choose among wrench, pull"):
        channels.select(["torque"])
    assert channels.select(None) is channels


# -- channels through the layers: datasets, identification -----------------------------------------


@pytest.fixture(scope="module")
def two_channels(model, tmp_path_factory):
    """A clean synthetic dataset of two channels: the base wrench in the base frame (``wrench``) and the
    same wrench in a sensor frame (``wrench_sensor``), written to a file and read back."""
    from ineid.data import Combination, DatasetSpec, generate_dataset, load_dataset

    channels = ChannelSet.of(BaseWrench(), BaseWrench(key="wrench_sensor", sensor=POSE))
    ds = generate_dataset(
        model, DatasetSpec(Combination("random", n_configs=4), n_frames=30, seed=3, channels=channels)
    )
    return load_dataset(ds.save(tmp_path_factory.mktemp("two") / "two.h5"))


def test_a_dataset_of_two_channels_solves_like_one(model, two_channels):
    from ineid.identify import SolveSettings, base_parameters, solve_dataset
    from ineid.identify.linear import fit_base
    from ineid.identify.systems import stack_casadi

    ds = two_channels
    assert ds.meta.version == VERSION and ds.meta.channels.keys == ("wrench", "wrench_sensor")
    assert np.allclose(ds.channel_values["wrench_sensor"], ds.wrench @ POSE.transform().T, rtol=1e-12, atol=1e-12)
    both = solve_dataset(ds, SolveSettings(), model=model)
    # the one-channel estimate of the same frames by the independent route (CasADi's stacks, QR: no compilation)
    one = dataclasses.replace(ds, meta=ds.meta.with_channels(ChannelSet.of(BaseWrench())), channel_values={})
    fit = slice(0, both.n_frames_fit)
    stacks = [
        stack_casadi(model, *(a[i, fit] for a in (one.q, one.qd, one.qdd, one.wrench)), one.theta_known)
        for i in range(one.n_configs)
    ]
    single = fit_base(np.stack([w for w, _ in stacks]), np.stack([y for _, y in stacks]), both.base).beta
    scales = both.base.scales[both.base.base_index]
    assert both.base.names == base_parameters(model).names and both.success.all()
    assert np.abs((both.base_hat - single) / scales).max() < 1e-10  # clean data: both exact
    assert np.abs((both.base_hat - both.base_true) / scales).max() < 1e-10
    assert both.axes[6:8] == ("wrench_sensor.fx", "wrench_sensor.fy") and both.fit_rms.shape == (4, 12)
    assert both.meta["channels"] == ds.meta.channels.to_list() and both.units[3] == "N*m"


def test_old_layouts_and_bad_records_read_as_one_line(model, two_channels, tmp_path):
    import h5py

    from ineid.data import load_dataset

    path = two_channels.save(tmp_path / "v2.h5")
    with h5py.File(path, "r+") as f:  # the layout of versions 1 and 2: one wrench, its pose in `sensor`
        del f["wrench_sensor"], f.attrs["channels"]
        f.attrs["version"] = 2
        f.attrs["sensor"] = json.dumps(POSE.to_dict())
    v2 = load_dataset(path)
    assert v2.meta.version == 2 and v2.meta.channels == ChannelSet.of(BaseWrench(sensor=POSE))
    assert v2.meta.sensor == POSE.to_dict() and np.array_equal(v2.wrench, two_channels.wrench)
    with h5py.File(path, "r+") as f:
        f.attrs["version"] = 1
        del f.attrs["sensor"]
    assert load_dataset(path).meta.channels == ChannelSet.of(BaseWrench())
    bad = [
        ({"channels": json.dumps([{"kind": "imu", "key": "imu"}])}, "channels\\[0\\]: unknown measurement channel"),
        ({"channels": json.dumps([{"kind": "wrench", "key": "wrench", "offsets": 1}])}, "true or false"),
        ({"channels": "[]"}, "no measurement channel"),
        (
            {"channels": json.dumps([{"kind": "wrench", "key": "wrench"}, {"kind": "wrench", "key": "more"}])},
            "'more' is missing",
        ),
    ]
    for attrs, message in bad:
        with h5py.File(path, "r+") as f:
            f.attrs["version"] = 3
            f.attrs.update(attrs)
        with pytest.raises(DatasetError, match=message) as info:
            load_dataset(path)
        assert "\n" not in str(info.value) and str(path) in str(info.value)
