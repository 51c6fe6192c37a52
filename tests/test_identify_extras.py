"""Identification with the channels' extra kept columns ``E x`` (:mod:`ineid.identify.extras`): friction,
armature, torque offsets.

A test-only joint-torque channel (:class:`FakeTorque`, the ``JointTorque`` contract's fields and
extra columns, with cheap rows so nothing slow compiles) is simulated with known extra
parameters ``x``; every route must recover ``theta``'s base parameters and ``x`` exactly on
clean data, the fused normal equations must equal the QR stacks, and an extra column
collinear with a link direction (the armature ``qdd_j`` against link ``j``'s mass in these
rows) must become a combined base parameter.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
import pytest

from ineid.channels import BaseWrench, Channel, ChannelSet, register
from ineid.data import Combination, DatasetSpec, generate_dataset
from ineid.errors import IdentificationError
from ineid.identify import SolveSettings, base_parameters, export_urdf, load_results, save_results, solve_dataset
from ineid.identify.steps import predicted_wrench
from tests.conftest import SEED, rel_err

# -- a test-only joint-torque channel --------------------------------------------------------


@functools.cache
def _entries(n_dof: int):
    """Row ``j``: ``qdd_j`` at link ``j``'s mass, ``qd_j^2 cos q_j`` at its ``mx``, ``sin q_j`` at its ``my``."""

    def entries(q, qd, qdd, gravity):
        import jax.numpy as jnp

        n_cols = 10 * n_dof
        out: list = [0] * (n_dof * n_cols)
        for j in range(n_dof):
            out[j * n_cols + 10 * j] = qdd[..., j]
            out[j * n_cols + 10 * j + 1] = qd[..., j] ** 2 * jnp.cos(q[..., j])
            out[j * n_cols + 10 * j + 2] = jnp.sin(q[..., j])
        return tuple(out)

    return entries


def _terms(channel) -> tuple[str, ...]:
    """The extra terms per joint, in the contract's order (fv, fc, offset, Ia; split per direction if asymmetric)."""
    out: list[str] = []
    for f, short in (("viscous", "fv"), ("coulomb", "fc")):
        if f in channel.friction:
            out += [f"{short}+", f"{short}-"] if channel.asymmetric else [short]
    return tuple(out + ["offset"] * channel.torque_offset + ["Ia"] * channel.armature)


def _term(term: str, q, qd, qdd, zone: float, xp):
    s = xp.tanh(qd / zone) if zone > 0 else xp.sign(qd)
    return {
        "fv": qd,
        "fv+": xp.maximum(qd, 0),
        "fv-": xp.minimum(qd, 0),
        "fc": s,
        "fc+": xp.maximum(s, 0) if zone > 0 else (qd > 0) * 1.0,
        "fc-": xp.minimum(s, 0) if zone > 0 else (qd < 0) * -1.0,
        "offset": qd * 0 + 1.0,
        "Ia": qdd,
    }[term]


@functools.cache
def _extra_fn(terms: tuple[str, ...], zone: float, n_dof: int):
    def extra(q, qd, qdd):
        import jax.numpy as jnp

        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        out = jnp.zeros(batch + (n_dof, n_dof * len(terms)), dtype=q.dtype)
        for j in range(n_dof):
            for k, t in enumerate(terms):
                out = out.at[..., j, j * len(terms) + k].set(_term(t, q[..., j], qd[..., j], qdd[..., j], zone, jnp))
        return out

    return extra


@register
@dataclass(frozen=True, kw_only=True)
class FakeTorque(Channel):
    """Test-only: ``n_dof`` axes like joint torques, cheap rows (:func:`_entries`), the contract's actuation fields."""

    key: str = "tau"
    friction: tuple[str, ...] = ()
    coulomb_zone: float = 0.0
    asymmetric: bool = False
    armature: bool = False
    torque_offset: bool = False

    kind = "test-fake-torque"
    RECORD_FIELDS = ("friction", "coulomb_zone", "asymmetric", "armature", "torque_offset")

    @classmethod
    def _parse_record(cls, d, where):
        out = super()._parse_record(d, where)
        if "friction" in out:
            out["friction"] = tuple(out["friction"])
        return out

    def axes(self, model):
        return tuple(model.joint_names)

    def units(self, model):
        return ("N*m",) * model.n_dof

    def describe(self):
        return "a test-only joint torque"

    def entries_function(self, model):
        return _entries(model.n_dof)

    def casadi_function(self, model):
        import casadi as ca

        q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
        y = ca.SX.zeros(model.n_dof, 10 * model.n_dof)
        for j in range(model.n_dof):
            y[j, 10 * j], y[j, 10 * j + 1], y[j, 10 * j + 2] = qdd[j], qd[j] ** 2 * ca.cos(q[j]), ca.sin(q[j])
        return ca.Function("fake_torque", [q, qd, qdd], [y])

    def extra_names(self, model):
        return tuple(f"{j}.{t}" for j in model.joint_names for t in _terms(self))

    def extra_rows_function(self, model):
        return _extra_fn(_terms(self), float(self.coulomb_zone), model.n_dof) if _terms(self) else None

    def casadi_extra_function(self, model):
        terms = _terms(self)
        if not terms:
            return None
        import casadi as ca

        class _Ca:
            tanh, sign = staticmethod(ca.tanh), staticmethod(ca.sign)

            @staticmethod
            def maximum(a, b):
                return ca.fmax(a, b)

            @staticmethod
            def minimum(a, b):
                return ca.fmin(a, b)

        q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
        e = ca.SX.zeros(model.n_dof, model.n_dof * len(terms))
        for j in range(model.n_dof):
            for k, t in enumerate(terms):
                e[j, j * len(terms) + k] = _term(t, q[j], qd[j], qdd[j], float(self.coulomb_zone), _Ca)
        return ca.Function("fake_extra", [q, qd, qdd], [e])


def with_extras(ds, model, channel: FakeTorque, x: np.ndarray):
    """``ds`` with ``E x`` of ``channel`` added to its joint torques (the stored channel stays as measured)."""
    e = channel.extra_rows(model, ds.q, ds.qd, ds.qdd)
    values = dict(ds.channel_values)
    values[channel.key] = values[channel.key] + e @ x
    return dataclasses.replace(ds, channel_values=values)


def truth_x(model, channel, seed=1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.2, 1.5, len(channel.extra_names(model)))


ACTUATION = dict(friction=("viscous", "coulomb"), torque_offset=True)


@pytest.fixture(scope="module")
def torque_only(model):
    ds = generate_dataset(
        model,
        DatasetSpec(Combination("random", n_configs=6), n_frames=40, seed=SEED, channels=ChannelSet.of(FakeTorque())),
    )
    channel = FakeTorque(**ACTUATION)
    x = truth_x(model, channel)
    return with_extras(ds, model, channel, x), x


@pytest.fixture(scope="module")
def both(model):
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=5),
            n_frames=40,
            seed=SEED,
            channels=ChannelSet.of(BaseWrench(), FakeTorque()),
        ),
    )
    channel = FakeTorque(**ACTUATION)
    x = truth_x(model, channel, 2)
    return with_extras(ds, model, channel, x), x


# -- base parameters over [theta_u, x] ----------------------------------------------------------


def test_base_parameters_over_links_and_extras(model):
    plain = base_parameters(model, channels=ChannelSet.of(FakeTorque()))
    channel = FakeTorque(friction=("viscous", "coulomb"), torque_offset=True)
    base = base_parameters(model, channels=ChannelSet.of(channel))
    names = channel.extra_names(model)
    assert base.n_extra == len(names) == 3 * model.n_dof
    assert base.param_names == (*plain.param_names, *names) and base.n_link_params == plain.n_params
    assert base.rank == plain.rank + len(names)  # friction and offsets are independent of these rows
    assert np.all(base.identifiable[base.n_link_params :])
    assert np.all(base.scales > 0) and np.all(np.isfinite(base.scales))
    # the scale of an extra: the typical reading of its axis over its column's RMS (N*m / (rad/s) for fv)
    assert base.scales[base.param_names.index("elbow.fv")] != base.scales[base.param_names.index("elbow.offset")]
    # with the channel's own offsets identified, a torque offset is a constant reading: not identifiable
    centred = base_parameters(model, bias=True, channels=ChannelSet.of(channel))
    offsets = [i for i, n in enumerate(centred.param_names) if n.endswith(".offset")]
    assert centred.rank == base.rank - len(offsets) and not centred.identifiable[offsets].any()


def test_collinear_extra_is_a_combined_base_parameter(model):
    """The armature column qdd_j equals link j's mass column in these rows: only their sum is seen."""
    base = base_parameters(model, channels=ChannelSet.of(FakeTorque(armature=True)))
    links = model.unknown_links
    joint = model.joint_names[model.link_names.index(links[-1])]
    assert f"{links[-1]}.m + {joint}.Ia" in base.names
    assert not base.identifiable[base.param_names.index(f"{joint}.Ia")]
    assert not base.identifiable[base.param_names.index(f"{links[-1]}.m")]
    # joints of known links: their armature is seen alone
    known_joint = model.joint_names[0]
    assert base.identifiable[base.param_names.index(f"{known_joint}.Ia")]


# -- the linear fits ---------------------------------------------------------------------------


def test_linear_exact_and_fused_equals_qr(model, torque_only):
    ds, x = torque_only
    settings = SolveSettings(weights="none", **_flags(ACTUATION))
    fused = solve_dataset(ds, settings, model=model)
    qr = solve_dataset(ds, dataclasses.replace(settings, backend="casadi"), model=model)
    base = fused.base
    assert fused.success.all() and fused.n_extra == len(x)
    assert fused.param_names[-len(x) :] == FakeTorque(**ACTUATION).extra_names(model)
    assert rel_err(fused.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-10
    truth = np.concatenate([ds.theta_unknown, np.broadcast_to(x, (ds.n_configs, len(x)))], axis=1)
    assert rel_err(fused.base_hat, truth @ base.B.T) < 1e-10
    assert rel_err(qr.theta_hat, fused.theta_hat) < 1e-10
    assert np.all(np.isfinite(fused.theta_std[:, -len(x) :]))
    assert fused.theta_links.shape == ds.theta_unknown.shape
    # the residuals and the prediction carry E x: clean data fit to round-off
    assert np.nanmax(fused.fit_rms) < 1e-9 * np.abs(ds.channel_values["tau"]).max()
    pred = predicted_wrench(model, ds, fused.theta_hat, channels=ChannelSet.of(FakeTorque(**ACTUATION)))
    assert rel_err(pred, ds.channel_values["tau"]) < 1e-10


def test_weighted_and_offsets(model, torque_only):
    ds, x = torque_only
    res = solve_dataset(
        ds, SolveSettings(weights="estimate", bias="estimate", friction=("viscous", "coulomb")), model=model
    )
    assert res.success.all()
    n = len(FakeTorque(friction=("viscous", "coulomb")).extra_names(model))
    keep = [i for i, name in enumerate(FakeTorque(**ACTUATION).extra_names(model)) if not name.endswith("offset")]
    assert rel_err(res.theta_hat[:, -n:], np.broadcast_to(x[keep], (ds.n_configs, n))) < 1e-8
    assert rel_err(res.bias_hat, np.broadcast_to(x[2::3], res.bias_hat.shape)) < 1e-8  # the offsets, as b
    # the centred stacks (QR) agree with the centred blocks, extra columns among them
    qr = solve_dataset(
        ds,
        SolveSettings(weights="estimate", bias="estimate", friction=("viscous", "coulomb"), backend="casadi"),
        model=model,
    )
    assert rel_err(qr.theta_hat, res.theta_hat) < 1e-9 and rel_err(qr.bias_hat, res.bias_hat) < 1e-9
    # the known links' CAD uncertainty gives std on clean data (the round-off's otherwise), estimates unchanged
    wide = solve_dataset(
        ds,
        SolveSettings(
            weights="estimate", bias="estimate", friction=("viscous", "coulomb"), known_uncertainty=(("*", 0.05),)
        ),
        model=model,
    )
    np.testing.assert_array_equal(wide.theta_hat, res.theta_hat)
    assert np.nanmax(res.base_std) < 1e-10 < np.nanmax(wide.base_std)


def test_large_job_residual_kernel(model):
    """More than SMALL_JOB_FRAMES frames: the compiled residual kernel adds E x too."""
    ds = generate_dataset(
        model,
        DatasetSpec(Combination("random", n_configs=45), n_frames=240, seed=3, channels=ChannelSet.of(FakeTorque())),
    )
    channel = FakeTorque(friction=("viscous",))
    x = truth_x(model, channel, 4)
    ds = with_extras(ds, model, channel, x)
    res = solve_dataset(ds, SolveSettings(weights="none", friction=("viscous",)), model=model)
    assert rel_err(res.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-10
    assert np.nanmax(res.fit_rms) < 1e-9 * np.abs(ds.channel_values["tau"]).max()


# -- nonlinear and consistent ---------------------------------------------------------------------


@pytest.mark.parametrize("method", ["nonlinear", "consistent"])
def test_ipopt_methods_recover_extras(model, torque_only, method, tmp_path):
    ds, x = torque_only
    sub = ds.select(slice(0, 3))
    res = solve_dataset(sub, SolveSettings(method=method, **_flags(ACTUATION)), model=model)
    assert res.success.all(), res.status
    # consistent: the noise-free floor (1e-3 of the data) and the entropic barrier leave ~1e-4 (as for the links)
    tol = 1e-6 if method == "nonlinear" else 1e-3
    x_all = np.broadcast_to(x, (sub.n_configs, len(x)))
    assert rel_err(res.theta_hat[:, -len(x) :], x_all) < tol
    truth = np.concatenate([sub.theta_unknown, x_all], axis=1)
    assert rel_err(res.base_hat, truth @ res.base.B.T) < tol
    assert np.median(np.abs(res.theta_hat[:, -len(x) :] / x_all - 1)) < tol / 10
    if method == "consistent":  # a URDF of the links only
        export_urdf(res, int(res.config_index[0]), tmp_path / "r.urdf")
        assert "Ia" not in (tmp_path / "r.urdf").read_text()


def test_consistent_bounds_dissipative_extras(model, torque_only):
    """Negative true friction: consistent keeps fv, fc >= 0, the offsets stay free."""
    ds, _ = torque_only
    channel = FakeTorque(**ACTUATION)
    x = -truth_x(model, channel)
    base_ds = generate_dataset(
        model,
        DatasetSpec(Combination("random", n_configs=2), n_frames=40, seed=SEED, channels=ChannelSet.of(FakeTorque())),
    )
    neg = with_extras(base_ds, model, channel, x)
    res = solve_dataset(neg, SolveSettings(method="consistent", **_flags(ACTUATION)), model=model)
    extras = res.theta_hat[:, -len(x) :]
    names = channel.extra_names(model)
    friction = [i for i, n in enumerate(names) if not n.endswith("offset")]
    assert np.all(extras[:, friction] >= -1e-9)


# -- wrench and torques together, the two steps, the choice of channels -------------------------------


def test_wrench_and_torque_together(model, both, monkeypatch):
    from ineid.identify import two_step

    monkeypatch.setattr(two_step, "CHUNK_ROWS", 1)  # step 2 one configuration at a time
    ds, x = both
    joint = solve_dataset(ds, SolveSettings(weights="none", backend="casadi", **_flags(ACTUATION)), model=model)
    truth = np.concatenate([ds.theta_unknown, np.broadcast_to(x, (ds.n_configs, len(x)))], axis=1)
    assert joint.success.all()
    assert rel_err(joint.base_hat, truth @ joint.base.B.T) < 1e-10
    assert joint.axes == (
        *(f"wrench.{a}" for a in ("fx", "fy", "fz", "mx", "my", "mz")),
        *(f"tau.{j}" for j in model.joint_names),
    )
    # the two steps: the links from the wrench alone (the same as --use wrench) ...
    # (the QR route: no second kernel to compile)
    two = solve_dataset(
        ds, SolveSettings(weights="none", two_step=True, backend="casadi", **_flags(ACTUATION)), model=model
    )
    assert two.success.all() and two.param_names == joint.param_names
    wrench = solve_dataset(ds, SolveSettings(weights="none", use=("wrench",), backend="casadi"), model=model)
    assert wrench.n_extra == 0 and wrench.axes == ("fx", "fy", "fz", "mx", "my", "mz")
    np.testing.assert_allclose(two.theta_hat[:, : -len(x)], wrench.theta_hat, rtol=0, atol=1e-12)
    # ... then x from the torques' residual at those links: the least squares of that residual
    channel = FakeTorque(**ACTUATION)
    theta = model.full_theta(wrench.theta_hat, ds.theta_known)
    n_fit = two.n_frames_fit
    rows = ChannelSet.of(channel).rows(model, ds.q, ds.qd, ds.qdd)[:, :n_fit]
    e = channel.extra_rows(model, ds.q, ds.qd, ds.qdd)[:, :n_fit]
    resid = ds.channel_values["tau"][:, :n_fit] - np.einsum("cfap,cp->cfa", rows, theta)
    for c in range(ds.n_configs):
        ls = np.linalg.lstsq(e[c].reshape(-1, len(x)), resid[c].ravel(), rcond=None)[0]
        assert rel_err(two.theta_hat[c, -len(x) :], ls) < 1e-9
    # exact where the wrench determines all the torques see: the joints of the known links
    names = channel.extra_names(model)
    known = [i for i, n in enumerate(names) if n.split(".")[0] in model.joint_names[:2]]
    assert rel_err(two.theta_hat[:, -len(x) :][:, known], np.broadcast_to(x[known], (ds.n_configs, len(known)))) < 1e-9


def test_several_recordings_fitted_jointly(model, torque_only):
    from ineid.identify.joint import solve_recordings

    ds, x = torque_only
    a, b = ds.select(frames=slice(0, 20)), ds.select(frames=slice(20, 40))
    res = solve_recordings([a, b], SolveSettings(weights="none", **_flags(ACTUATION)), model=model)
    assert res.success.all()
    assert rel_err(res.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-10


def test_results_round_trip(model, torque_only, tmp_path):
    ds, x = torque_only
    res = solve_dataset(ds, SolveSettings(**_flags(ACTUATION)), model=model)
    back = load_results(save_results(res, tmp_path / "r.h5"))
    assert back.param_names == res.param_names and back.n_extra == res.n_extra == len(x)
    assert back.settings == res.settings
    np.testing.assert_array_equal(back.theta_hat, res.theta_hat)
    np.testing.assert_array_equal(back.base.B, res.base.B)


def test_bad_choices_are_one_line(model, torque_only, both):
    ds, _ = torque_only
    wrench_only = generate_dataset(model, DatasetSpec(Combination("random", n_configs=1), n_frames=20, seed=SEED))
    cases = [
        (wrench_only, SolveSettings(use=("torque",)), "no joint torques"),
        (wrench_only, SolveSettings(friction=("viscous",)), "have none"),
        (wrench_only, SolveSettings(use=("gyro",)), "no channel named 'gyro'"),
        (ds, SolveSettings(two_step=True, friction=("viscous",)), "lack a wrench"),
        (both[0], SolveSettings(use=("wrench",), armature=True), "have none"),
        (both[0], SolveSettings(two_step=True), "give at least one"),
        (ds, SolveSettings(backend="casadi-c", friction=("viscous",)), "does not fit extra parameters"),
    ]
    for data, settings, text in cases:
        with pytest.raises(IdentificationError, match=text.replace("'", ".")) as e:
            solve_dataset(data, settings, model=model)
        assert "\n" not in str(e.value)
    for bad in (dict(friction=("stribeck",)), dict(coulomb_zone=0.1), dict(asymmetric_friction=True)):
        with pytest.raises(ValueError):
            SolveSettings(**bad)


def _flags(actuation: dict) -> dict:
    """SolveSettings' names of a channel's actuation fields."""
    return {("asymmetric_friction" if k == "asymmetric" else k): v for k, v in actuation.items()}


# -- the command line ------------------------------------------------------------------------------


def _one_line(result, code):
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    return [line for line in result.output.splitlines() if line.strip()][-1]


def test_cli_solve_with_friction(run, model, both, tmp_path):
    ds, x = both
    data = ds.select(slice(0, 2)).save(tmp_path / "both.h5")
    out = tmp_path / "r.h5"
    r = run(
        "solve",
        data,
        "--use",
        "wrench,tau",
        "--friction",
        "viscous,coulomb",
        "--torque-offset",
        "--weights",
        "none",
        "--backend",
        "casadi",
        "--out",
        out,
    )
    assert r.exit_code == 0, r.output
    res = load_results(out)
    assert res.param_names[-len(x) :] == FakeTorque(**ACTUATION).extra_names(model)
    assert res.settings.friction == ("viscous", "coulomb") and res.settings.use == ("wrench", "tau")
    info = run("results", "info", out)
    assert info.exit_code == 0 and "extra parameters (after the links'): shoulder_pitch.fv" in info.output
    r = run(
        "solve",
        data,
        "--use",
        "wrench,tau",
        "--friction",
        "viscous",
        "--two-step",
        "--backend",
        "casadi",
        "--weights",
        "none",
        "--out",
        tmp_path / "two.h5",
    )
    assert r.exit_code == 0, r.output
    two = load_results(tmp_path / "two.h5")
    assert two.settings.two_step and two.success.all() and two.n_extra == model.n_dof


def test_cli_bad_channel_choices_are_one_line(run, model, torque_only, tmp_path):
    wrench_only = generate_dataset(model, DatasetSpec(Combination("random", n_configs=1), n_frames=20, seed=SEED))
    wrench = wrench_only.save(tmp_path / "w.h5")
    tau = torque_only[0].select(slice(0, 1)).save(tmp_path / "t.h5")
    out = tmp_path / "r.h5"
    for args, text in (
        ((wrench, "--use", "torque"), "no joint torques"),
        ((wrench, "--friction", "viscous"), "have none"),
        ((wrench, "--armature"), "have none"),
        ((wrench, "--use", "gyro"), "no channel named 'gyro'"),
        ((tau, "--two-step", "--friction", "viscous"), "lack a wrench"),
    ):
        assert text in _one_line(run("solve", *args, "--out", out), 1)
        assert not out.exists()
    assert "coulomb" in _one_line(run("solve", wrench, "--coulomb-zone", "0.1", "--out", out), 2)
    assert "--friction" in _one_line(run("solve", wrench, "--friction", "stribeck", "--out", out), 2)
    assert not out.exists()


def test_cli_identifiability_follows_the_channels(run, torque_only, tmp_path):
    tau = torque_only[0].select(slice(0, 1)).save(tmp_path / "t.h5")
    r = run("identifiability", "sweaty-arm", "--data", tau, "--armature")
    assert r.exit_code == 0, r.output
    assert "forearm.m + elbow.Ia" in r.output and "extra parameters: shoulder_pitch.Ia" in r.output
    assert "have none" in _one_line(run("identifiability", "sweaty-arm", "--friction", "viscous"), 1)
    r = run("identifiability", "sweaty-arm", "--use", "wrench")
    assert r.exit_code == 0 and "channels: base wrench" in r.output


# -- the joint-torque channel (ineid.channels.torque) against Pinocchio ----------------------------------


def _friction_truth(model, seed=5) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    return {f"{j}.{t}": float(rng.uniform(0.05, 0.5)) for j in model.joint_names for t in ("fv", "fc")}


@pytest.fixture(scope="module")
def pin_both(model):
    """Base wrench and joint torques of the same frames: the torques from Pinocchio's ``rnea`` with each
    configuration's true parameters, plus viscous and Coulomb friction (the contract's columns, in NumPy)."""
    torque = pytest.importorskip("ineid.channels.torque", reason="the JointTorque channel is not on this branch yet")
    pin = pytest.importorskip("pinocchio")
    from ineid.reference import pinocchio_model, pinocchio_q

    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=4),
            n_frames=40,
            seed=SEED,
            channels=ChannelSet.of(BaseWrench(), torque.JointTorque()),
        ),
    )
    pm = pinocchio_model(model.urdf_path, gravity=model.gravity)
    data = pm.createData()
    tau = np.empty_like(ds.channel_values["tau"])
    for c in range(ds.n_configs):
        theta = model.full_theta(ds.theta_unknown[c], ds.theta_known)
        for i in range(1, pm.njoints):
            pm.inertias[i] = pin.Inertia.FromDynamicParameters(theta[10 * (i - 1) : 10 * i])
        for k in range(ds.n_frames):
            tau[c, k] = pin.rnea(pm, data, pinocchio_q(pm, ds.q[c, k]), ds.qd[c, k], ds.qdd[c, k])
    assert rel_err(ds.channel_values["tau"], tau) < 1e-10  # the channel's rows are Pinocchio's torques
    truth = _friction_truth(model)
    for j, name in enumerate(model.joint_names):
        tau[..., j] += truth[f"{name}.fv"] * ds.qd[..., j] + truth[f"{name}.fc"] * np.sign(ds.qd[..., j])
    return dataclasses.replace(ds, channel_values={**ds.channel_values, "tau": tau}), truth


@pytest.mark.parametrize("use", [("wrench",), ("torque",), ("wrench", "torque")])
def test_joint_torques_every_combination_exact(model, pin_both, use):
    ds, truth = pin_both
    friction = ("viscous", "coulomb") if "torque" in use else ()
    # the QR route (CasADi, no kernel to compile); the fused kernel of both channels beside it
    res = solve_dataset(ds, SolveSettings(weights="none", use=use, friction=friction, backend="casadi"), model=model)
    assert res.success.all(), res.status
    if len(use) == 2:
        fused = solve_dataset(ds, SolveSettings(weights="none", use=use, friction=friction), model=model)
        assert rel_err(fused.theta_hat, res.theta_hat) < 1e-10
    x = np.array([truth[n] for n in res.param_names[res.base.n_link_params :]])
    full = np.concatenate([ds.theta_unknown, np.broadcast_to(x, (ds.n_configs, len(x)))], axis=1)
    assert rel_err(res.base_hat, full @ res.base.B.T) < 1e-9
    if friction:  # the friction coefficients themselves
        assert rel_err(res.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-9
    assert np.nanmax(res.fit_rms) < 1e-8 * np.abs(ds.measured(ds.meta.channels)).max()


def test_cli_identifiability_with_joint_torques(run):
    pytest.importorskip("ineid.channels.torque", reason="the JointTorque channel is not on this branch yet")
    r = run("identifiability", "sweaty-arm", "--use", "torque", "--armature", "--friction", "viscous")
    assert r.exit_code == 0, r.output
    for text in (
        "(20 standard parameters, 8 extra)",
        "structural rank 24",
        "shoulder_pitch.fv, shoulder_pitch.Ia",
        "invisible in the measurements",
    ):
        assert text in r.output.replace("\n", " "), text
    r = run("identifiability", "sweaty-arm", "--use", "wrench,torque")
    assert r.exit_code == 0 and "structural rank 17" in r.output  # the torques add no direction (docs)
    r = run("identifiability", "sweaty-arm", "--use", "torque")
    assert r.exit_code == 0 and "structural rank 16" in r.output


def test_truth_of_extra_parameters(model, torque_only):
    """A synthetic dataset's extra_truth fills the extras' truth; base parameters involving an unknown truth are NaN."""
    from types import SimpleNamespace

    from ineid.identify.solve import truth_with_extras

    ds, x = torque_only
    res = solve_dataset(ds, SolveSettings(weights="none", armature=True, friction=("viscous",)), model=model)
    names = res.param_names[res.base.n_link_params :]
    given = {n: 1.0 for n in names if not n.startswith("elbow.")}  # the elbow's truth unknown
    fake = SimpleNamespace(theta_unknown=ds.theta_unknown, meta=SimpleNamespace(extra_truth=given))
    res.theta_true = truth_with_extras(fake, res.base)
    extras = res.theta_true[:, res.base.n_link_params :]
    assert np.all(np.isnan(extras[:, [n.startswith("elbow.") for n in names]]))
    assert np.all(extras[:, [not n.startswith("elbow.") for n in names]] == 1.0)
    unknown = [("elbow." in b) for b in res.base.names]  # forearm.m + elbow.Ia among them
    assert any("forearm.m + elbow.Ia" == b for b in res.base.names)
    assert np.all(np.isnan(res.base_true[:, unknown])) and np.all(np.isfinite(res.base_true[:, ~np.array(unknown)]))


def test_asymmetric_and_smooth_friction_with_joint_torques(model):
    """The joint-torque channel's asymmetric viscous and smooth Coulomb columns (the contract's), recovered."""
    torque = pytest.importorskip("ineid.channels.torque", reason="the JointTorque channel is not on this branch yet")
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=3), n_frames=60, seed=SEED, channels=ChannelSet.of(torque.JointTorque())
        ),
    )
    zone = 0.2
    rng = np.random.default_rng(9)
    truth = {f"{j}.{t}": float(rng.uniform(0.1, 1.0)) for j in model.joint_names for t in ("fv+", "fv-", "fc+", "fc-")}
    tau = ds.channel_values["tau"].copy()
    for j, name in enumerate(model.joint_names):
        qd = ds.qd[..., j]
        s = np.tanh(qd / zone)
        tau[..., j] += (
            truth[f"{name}.fv+"] * np.maximum(qd, 0)
            + truth[f"{name}.fv-"] * np.minimum(qd, 0)
            + truth[f"{name}.fc+"] * np.maximum(s, 0)
            + truth[f"{name}.fc-"] * np.minimum(s, 0)
        )
    ds = dataclasses.replace(ds, channel_values={"tau": tau})
    res = solve_dataset(
        ds,
        SolveSettings(
            weights="none",
            friction=("viscous", "coulomb"),
            coulomb_zone=zone,
            asymmetric_friction=True,
            backend="casadi",
        ),
        model=model,
    )
    names = res.param_names[res.base.n_link_params :]
    assert set(names) == set(truth)
    x = np.array([truth[n] for n in names])
    assert rel_err(res.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-9


def test_motor_currents_with_friction(model):
    """Currents read through the drives (T = diag(1 / (k G))): friction in torque units, recovered."""
    torque = pytest.importorskip("ineid.channels.torque", reason="the MotorCurrent channel is not on this branch yet")
    drives = dict(torque_constant=(0.1, 0.12, 0.08, 0.05), gear_ratio=(100.0, -80.0, 50.0, 30.0))
    ds = generate_dataset(
        model,
        DatasetSpec(
            Combination("random", n_configs=2),
            n_frames=50,
            seed=SEED,
            channels=ChannelSet.of(torque.MotorCurrent(**drives)),
        ),
    )
    channel = torque.MotorCurrent(**drives, friction=("viscous", "coulomb"))
    x = truth_x(model, channel, 6)
    current = ds.channel_values["current"] + channel.extra_rows(model, ds.q, ds.qd, ds.qdd) @ x
    ds = dataclasses.replace(ds, channel_values={"current": current})
    res = solve_dataset(
        ds,
        SolveSettings(weights="none", use=("current",), friction=("viscous", "coulomb"), backend="casadi"),
        model=model,
    )
    assert res.param_names[-len(x) :] == channel.extra_names(model)
    assert rel_err(res.theta_hat[:, -len(x) :], np.broadcast_to(x, (ds.n_configs, len(x)))) < 1e-9


def test_two_steps_with_offsets(model, both):
    ds, x = both  # x holds torque offsets (every third): the channel's offsets take them, and the shift
    shift = np.linspace(0.5, 1.0, model.n_dof)
    shifted = dataclasses.replace(ds, channel_values={"tau": ds.channel_values["tau"] + shift})
    res = solve_dataset(
        shifted,
        SolveSettings(
            weights="none", two_step=True, bias="estimate", backend="casadi", friction=("viscous", "coulomb")
        ),
        model=model,
    )
    assert res.success.all() and res.bias_hat.shape == (ds.n_configs, 6 + model.n_dof)
    assert np.all(np.isfinite(res.bias_std))
    direct = solve_dataset(
        shifted,
        SolveSettings(weights="none", bias="estimate", backend="casadi", friction=("viscous", "coulomb")),
        model=model,
    )
    # the torque axes' offsets: what the joint fit finds where the wrench determines what the torques see
    assert rel_err(res.bias_hat[:, 6:8], direct.bias_hat[:, 6:8]) < 1e-8
    assert rel_err(direct.bias_hat[:, 6:], np.broadcast_to(shift + x[2::3], (ds.n_configs, model.n_dof))) < 1e-8
