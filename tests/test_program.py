"""The structured Newton-Euler program on a 12-joint chain, output by output, against Pinocchio.

A chain this long took hours with the former flattened derivation; the structured one derives
in about a second. Each output of the generated program (link pose, motion, joint axis and
moment, the net-wrench columns) and what :mod:`ineid.robots.program` composes from them (the
base regressor and the base wrench, by CasADi, which needs no compilation) is compared with
Pinocchio's own kinematics and dynamics at 1e-13 relative (round-off is ~1e-15). The JAX
module prints the same lines (tests/test_codegen.py); compiling it for 12 joints would cost
seconds here, and the real 7-joint arms check it in tests/test_symbolic.py.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import ineid
from ineid.reference import pinocchio_base_regressor, pinocchio_base_wrench, pinocchio_model, pinocchio_q

from .conftest import rel_err
from .test_codegen import chain_urdf

N_JOINTS = 12
TOL = 1e-13
GRAVITY = (0.3, -0.4, -9.81)


@pytest.fixture(scope="module")
def chain12(tmp_path_factory):
    folder = tmp_path_factory.mktemp("chain12")
    path = folder / "chain12.urdf"
    path.write_text(chain_urdf(N_JOINTS))
    model = ineid.load_robot(path, gravity=GRAVITY, codegen_dir=folder / "gen")
    pin_model = pinocchio_model(path, gravity=GRAVITY)
    rng = np.random.default_rng(12)
    q, qd, qdd = (rng.uniform(-1.5, 1.5, (8, N_JOINTS)) for _ in range(3))
    return model, pin_model, (q, qd, qdd)


def _numeric_program(model):
    """The generated CasADi program as one ``casadi.Function``: ``(q, qd, qdd, gravity) -> {output: flat
    column}`` (Python numbers of the program kept as constants)."""
    import casadi as ca

    from ineid.robots.program import OUTPUTS

    def flat(x):
        return [e for v in x for e in flat(v)] if isinstance(x, tuple) else [x]

    q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
    g = ca.SX.sym("g", 3)
    out = model.casadi_program(q, qd, qdd, g)
    cols = [ca.vertcat(*(ca.SX(e) if isinstance(e, (int, float)) else e for e in flat(out[k]))) for k in OUTPUTS]
    return ca.Function("program", [q, qd, qdd, g], cols, ["q", "qd", "qdd", "g"], list(OUTPUTS))


def test_program_outputs_equal_pinocchio_kinematics(chain12):
    """Per link R, p (base frame), w, wd, a - g (link frame); per joint z and p x z (base frame)."""
    import pinocchio as pin

    model, pin_model, (q, qd, qdd) = chain12
    program = _numeric_program(model)
    data = pin_model.createData()
    for k in range(len(q)):
        pq = pinocchio_q(pin_model, q[k])
        pin.rnea(pin_model, data, pq, qd[k], qdd[k])  # v, a_gf (a minus gravity), link frames
        pin.forwardKinematics(pin_model, data, pq)  # oMi (after rnea: v, a would be overwritten otherwise)
        out = {
            key: np.asarray(v).ravel()
            for key, v in program.call({"q": q[k], "qd": qd[k], "qdd": qdd[k], "g": np.asarray(GRAVITY)}).items()
        }
        for i in range(N_JOINTS):
            placement, v, a_gf = data.oMi[i + 1], data.v[i + 1], data.a_gf[i + 1]
            z = placement.rotation @ model.chain.joints[i].axis
            want = {
                "R": placement.rotation.ravel(),
                "p": placement.translation,
                "w": v.angular,
                "wd": a_gf.angular,
                "a": a_gf.linear + np.cross(v.angular, v.linear),  # the origin's, from the spatial one
                "axis": z,
                "moment": np.cross(placement.translation, z),
            }
            for key, ref in want.items():
                got = out[key][i * len(ref) : (i + 1) * len(ref)]
                assert np.abs(got - ref).max() < TOL * max(1.0, np.abs(ref).max()), (key, i)


def test_composed_regressor_and_wrench_equal_pinocchio(chain12):
    """Psi = -[Yn_1 ... Yn_n] and Psi theta without Psi, through CasADi (no compilation)."""
    model, pin_model, (q, qd, qdd) = chain12
    n = len(q)
    y_ref = pinocchio_base_regressor(pin_model, q, qd, qdd)
    y = np.asarray(model.casadi_regressor.map(n)(q.T, qd.T, qdd.T)).reshape(6, n, -1).transpose(1, 0, 2)
    assert rel_err(y, y_ref) < TOL
    w_ref = pinocchio_base_wrench(pin_model, q, qd, qdd)
    w = np.asarray(model.casadi_base_wrench.map(n)(q.T, qd.T, qdd.T, np.tile(model.theta_cad, (n, 1)).T)).T
    assert rel_err(w, w_ref) < TOL


def test_xla_log_lines_are_silenced_below_vv(monkeypatch):
    """XLA's C++ log (slow_operation_alarm and the like) is set to FATAL before JAX is imported; -vv leaves it."""
    code = (
        "import os; from ineid.cli import configure_logging; configure_logging(0); import jax; "
        "jax.jit(lambda x: x + 1)(1.0); print(os.environ['TF_CPP_MIN_LOG_LEVEL'])"
    )
    env = {k: v for k, v in os.environ.items() if k != "TF_CPP_MIN_LOG_LEVEL"}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "3" and r.stderr == "", r.stderr
    from ineid.cli import configure_logging

    monkeypatch.delenv("TF_CPP_MIN_LOG_LEVEL", raising=False)
    monkeypatch.delenv("JAX_LOG_COMPILES", raising=False)
    monkeypatch.delitem(sys.modules, "jax")  # as in a fresh process: the level would still be settable
    configure_logging(2)
    assert "TF_CPP_MIN_LOG_LEVEL" not in os.environ and os.environ["JAX_LOG_COMPILES"] == "1"
    configure_logging(0)
    assert os.environ["TF_CPP_MIN_LOG_LEVEL"] == "3"
