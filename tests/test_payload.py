"""Payloads: links welded to a moving link, identified on their own, in their own frame
(:mod:`ineid.robots.payload`, :mod:`ineid.identify.payload`), on URDFs as CAD tools write them.

Numbers are compared with Pinocchio, which loads the same files its own way.
"""

from __future__ import annotations

import numpy as np
import pytest

import ineid
from ineid.identify.identifiability import base_parameters
from ineid.params import theta_from_inertial, transform_matrix
from ineid.reference import pinocchio_base_regressor, pinocchio_base_wrench, pinocchio_model, pinocchio_theta
from ineid.robots.urdf import parse_chain

from .conftest import random_states, real_robot, rel_err

# -- payloads ---------------------------------------------------------------------------------

PAYLOAD = (
    '<link name="payload"><inertial><origin xyz="{c}" rpy="0.1 0.2 0.3"/><mass value="{m}"/>'
    '<inertia ixx="0.004" ixy="0.0001" ixz="0" iyy="0.005" iyz="0" izz="0.003"/></inertial></link>'
    '<joint name="payload_joint" type="fixed"><parent link="tool0"/><child link="payload"/>'
    '<origin xyz="0 0 0.02" rpy="0 0.3 0"/></joint></robot>'
)


def ur5_with_payload(tmp_path, name: str, mass: str = "1.5", com: str = "0.01 -0.02 0.05"):
    path, _ = real_robot("ur5")
    out = tmp_path / name
    out.write_text(path.read_text().replace("</robot>", PAYLOAD.format(m=mass, c=com)))
    return out


def test_transform_matrix_composes_and_folds_like_the_inertial():
    rng = np.random.default_rng(1)
    r, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    p = rng.normal(size=3)
    theta = theta_from_inertial(2.0, np.array([0.1, -0.2, 0.05]), np.diag([0.01, 0.02, 0.025]))
    expected = theta_from_inertial(2.0, r @ np.array([0.1, -0.2, 0.05]) + p, r @ np.diag([0.01, 0.02, 0.025]) @ r.T)
    assert np.allclose(transform_matrix(r, p) @ theta, expected, atol=1e-14)
    assert np.allclose(transform_matrix(r, p) @ transform_matrix(r.T, -r.T @ p), np.eye(10), atol=1e-13)


@pytest.fixture(scope="module")
def payload_case(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("payload")
    cad, truth = ur5_with_payload(tmp, "cad.urdf"), ur5_with_payload(tmp, "truth.urdf", "2.25", "0.03 0.01 0.08")
    model = ineid.load_robot(cad, unknown_links=["payload"])
    return model, cad, truth


def casadi_rows(model, q, qd, qdd) -> np.ndarray:
    """The model's regressor through its CasADi view, (F, 6, 10 n_links): no JAX compilation."""
    f = len(q)
    return np.array(model.casadi_regressor.map(f)(q.T, qd.T, qdd.T)).reshape(6, f, -1).transpose(1, 0, 2)


def test_payload_columns_are_the_bodys_through_the_fold(payload_case):
    model, cad, _ = payload_case
    assert model.link_names[-2:] == ("wrist_3_link", "payload") and model.unknown_links == ("payload",)
    pin = pinocchio_model(cad)
    q, qd, qdd = random_states(model, 30, np.random.default_rng(2))
    y = casadi_rows(model, q, qd, qdd)
    y_pin = pinocchio_base_regressor(pin, q, qd, qdd)
    link = model.chain.body_links["payload"]
    fold = transform_matrix(link.body_R_link, link.body_p_link)
    assert rel_err(y[..., 60:], y_pin[..., 50:] @ fold) < 1e-10  # the payload's columns
    assert rel_err(y @ model.theta_cad, pinocchio_base_wrench(pin, q, qd, qdd)) < 1e-10  # wrist_3 keeps the rest
    assert base_parameters(model).rank == 10  # every payload parameter, on a 6-DOF arm


def test_robot_show_lists_the_welded_links(payload_case, run):
    _, cad, _ = payload_case
    shown = run("robot", "show", cad, "--unknown-links", "payload").output
    rows = {line.split("│")[1].strip(): line for line in shown.splitlines() if line.count("│") == 6}
    assert "unknown (payload)" in rows["payload"] and "wrist_3_link" in rows["payload"]
    assert "frame" in rows["ee_link"] and "frame" in rows["tool0"]


def test_payload_is_recovered_exactly_and_exported_in_place(payload_case, tmp_path):
    from ineid.identify.systems import stack_casadi
    from ineid.robots.urdf_write import urdf_with_inertials

    model, _, truth = payload_case
    pin_truth = pinocchio_model(truth)
    q, qd, qdd = random_states(model, 40, np.random.default_rng(4))
    w, y = stack_casadi(
        model, q, qd, qdd, pinocchio_base_wrench(pin_truth, q, qd, qdd), model.theta_cad[model.known_index]
    )
    theta_hat = np.linalg.lstsq(w, y, rcond=None)[0]
    assert rel_err(theta_hat, parse_chain(truth.read_bytes()).body_links["payload"].theta) < 1e-8
    text = urdf_with_inertials(model.urdf_text, {"payload": theta_hat})
    out = tmp_path / "exported.urdf"
    out.write_text(text)
    assert np.allclose(pinocchio_theta(pinocchio_model(out)), pinocchio_theta(pin_truth), rtol=0, atol=1e-9)
    assert "identified by ineid" in text.split('<link name="payload">')[1].split("</link>")[0]
    assert text.count("identified by ineid") == 1 and "inertial folded by ineid" not in text


@pytest.mark.slow  # ~25 s of JAX compilation for the folded evaluators and the fused solve
def test_a_welded_hand_solves_and_reports_its_payload_section(tmp_path, run):
    """The built-in arm's hand (welded to the forearm) as a payload: the JAX evaluators through the
    fold, ``ineid solve``'s exact recovery on noise-free data, the payload section saved and shown."""
    from ineid.data.dataset.schema import Dataset, DatasetMeta
    from ineid.identify import load_results, save_results
    from ineid.identify.solve import SolveSettings, solve_dataset

    model = ineid.load_robot("sweaty-arm", unknown_links=["hand"])
    assert model.link_names == ("shoulder_pitch_link", "shoulder_roll_link", "upper_arm", "forearm", "hand")
    q, qd, qdd = random_states(model, 60, np.random.default_rng(6))
    y = casadi_rows(model, q, qd, qdd)
    assert rel_err(model.regressor(q, qd, qdd), y) < 1e-12
    psi_u, psi_k = model.regressor_split(q, qd, qdd)
    assert np.array_equal(psi_u, y[..., 40:]) or rel_err(psi_u, y[..., 40:]) < 1e-12
    plain = ineid.load_robot("sweaty-arm")
    assert rel_err(model.base_wrench(q, qd, qdd), plain.base_wrench(q, qd, qdd)) < 1e-12
    truth = model.theta_cad.copy()
    truth[40:] = theta_from_inertial(0.9, np.array([0.01, 0.02, -0.06]), np.diag([2e-3, 1.5e-3, 1e-3]))
    ds = Dataset(
        DatasetMeta.for_model(model, source="recording"),
        q[None],
        qd[None],
        qdd[None],
        (y @ truth)[None],
        theta_known=model.theta_cad[model.known_index],
    )
    res = solve_dataset(ds, SolveSettings(method="linear", frames=60), model=model)
    assert res.success[0] and rel_err(res.theta_hat[0], truth[40:]) < 1e-8
    section = res.payload["hand"]
    assert section["mass"][0] == pytest.approx(0.9, rel=1e-9)
    assert np.allclose(section["com"][0], [0.01, 0.02, -0.06], atol=1e-9)
    assert np.allclose(section["inertia"][0], [2e-3, 0, 1.5e-3, 0, 0, 1e-3], atol=1e-9)
    assert section["mass_std"][0] == pytest.approx(res.theta_std[0, 0], rel=1e-9, abs=1e-300)
    path = save_results(res, tmp_path / "r.h5")
    back = load_results(path).payload["hand"]
    assert all(np.array_equal(back[k], section[k], equal_nan=True) for k in section)
    shown = run("results", "info", path).output
    assert "Payload hand, configuration 0" in shown and "Izz about com" in shown


def test_payload_std_by_the_delta_method_matches_monte_carlo(payload_case):
    """The payload section's std from the fit's covariance: the mass's is theta_std's, the centre of
    mass's and the inertia's agree with sampling the estimate's Gaussian (first order is enough here)."""
    from ineid.identify.linear import prior_map, standard_from_base, standard_std
    from ineid.identify.payload import payload_section, physical_quantities
    from ineid.identify.systems import stack_casadi

    model, _, _ = payload_case
    base = base_parameters(model)
    rng = np.random.default_rng(9)
    q, qd, qdd = random_states(model, 80, rng)
    noise = rng.normal(0, [0.5, 0.5, 0.5, 0.05, 0.05, 0.05], (80, 6))  # N, N*m
    wrench = casadi_rows(model, q, qd, qdd) @ model.theta_cad + noise
    w, y = stack_casadi(model, q, qd, qdd, wrench, model.theta_cad[model.known_index])
    wb = w[:, base.base_index]
    beta = np.linalg.lstsq(wb, y, rcond=None)[0]
    s2 = float(np.sum((y - wb @ beta) ** 2) / (len(y) - base.rank))
    cov = s2 * np.linalg.inv(wb.T @ wb)
    theta = standard_from_base(beta, base, model.theta_cad[model.unknown_index])
    section = payload_section(model, base, theta[None], cov[None], np.array([True]))["payload"]
    assert section["mass_std"][0] == pytest.approx(standard_std(cov[None], base)[0, 0], rel=1e-12)
    t = prior_map(base)
    draws = rng.multivariate_normal(theta, t @ cov @ t.T, 20000)
    sampled = np.array([physical_quantities(d)[0] for d in draws]).std(axis=0)
    reported = np.concatenate([section["mass_std"][:1], section["com_std"][0], section["inertia_std"][0]])
    assert np.allclose(reported, sampled, rtol=0.05)


def test_payload_delta_method_jacobian_matches_finite_differences():
    from ineid.identify.payload import physical_quantities

    theta = theta_from_inertial(
        1.7, np.array([0.02, -0.01, 0.07]), np.array([[0.004, 1e-4, 2e-5], [1e-4, 0.005, -3e-5], [2e-5, -3e-5, 0.003]])
    )
    q, jac = physical_quantities(theta)
    m, c, ic = ineid.params.inertial_from_theta(theta)
    assert np.allclose(q, [m, *c, ic[0, 0], ic[0, 1], ic[1, 1], ic[0, 2], ic[1, 2], ic[2, 2]], atol=1e-15)
    step = 1e-6 * np.maximum(np.abs(theta), 1e-3)
    numeric = np.column_stack(
        [
            (
                physical_quantities(theta + np.eye(10)[k] * step[k])[0]
                - physical_quantities(theta - np.eye(10)[k] * step[k])[0]
            )
            / (2 * step[k])
            for k in range(10)
        ]
    )
    assert np.allclose(jac, numeric, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize(
    ("links", "message"),
    [
        (["nope"], "unknown link 'nope' is not a moving link of ur5; choose from shoulder_link.*payload"),
        (["base_link"], "link 'base_link' is welded to the root link .*tared"),
        (["payload", "wrist_3_link"], "payload link 'payload' is welded to 'wrist_3_link', which is unknown too"),
        (["tool0", "payload"], "payload links 'tool0' and 'payload' are both welded to 'wrist_3_link'"),
    ],
)
def test_bad_payload_names_are_refused_in_one_line_and_write_nothing(payload_case, run, tmp_path, links, message):
    import re

    _, cad, _ = payload_case
    out = tmp_path / "g.h5"
    result = run(
        "data",
        "generate",
        str(cad),
        "--unknown-links",
        ",".join(links),
        "--n-configs",
        "1",
        "--n-frames",
        "10",
        "--out",
        str(out),
    )
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and re.search(message, lines[0]), result.output
    assert not out.exists()


def test_a_model_with_a_payload_pickles_for_a_worker(payload_case, rng):
    """The payload's columns survive the trip to another process (the fold is rebuilt from the unknown links)."""
    from .conftest import casadi_regressor_frames, regressor_in_another_process

    model = payload_case[0]
    q = rng.uniform(-1.0, 1.0, (3, model.n_dof))
    np.testing.assert_array_equal(regressor_in_another_process(model, q), casadi_regressor_frames(model, q))
