"""Shared fixtures: float64 JAX, one seed, a private codegen cache, example-robot-data paths."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pytest

import ineid  # turns on jax x64

SEED = 20261121


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    """Generated code of URDF robots goes to a per-session folder, not ~/.cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("INEID_CACHE_DIR", str(tmp_path_factory.mktemp("ineid-cache")))
    yield
    mp.undo()


@pytest.fixture(autouse=True)
def _signal_handlers_as_they_were():
    """Every test starts with SIGINT and SIGTERM handled as the test process started: a test that ran the command in
    this process (it installs ineid's handlers) or a library that ignored SIGINT leaves nothing behind, so the
    signal tests do not depend on what ran before them on the same worker."""
    import signal

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, handler in saved.items():
        if handler is not None and signal.getsignal(s) is not handler:
            signal.signal(s, handler)


@pytest.fixture(scope="session")
def model():
    """The built-in sweaty-arm (links upper_arm and forearm unknown); tests must not mutate it."""
    return ineid.load_robot("sweaty-arm")


@pytest.fixture(scope="session")
def base(model):
    """Its base parameters (:func:`ineid.identify.base_parameters`)."""
    from ineid.identify import base_parameters

    return base_parameters(model)


@pytest.fixture
def run():
    """``run(*args)``: the ``ineid`` command through click's CliRunner (exceptions propagate)."""
    from click.testing import CliRunner

    from ineid.cli import main

    def invoke(*args):
        return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)

    return invoke


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def example_robot_data_dir() -> Path:
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))


FIXTURES = Path(__file__).resolve().parent / "fixtures"

# name -> (URDF path, locked joints)
REAL_ROBOTS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", None),
    "panda": ("panda_description/urdf/panda.urdf", {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}),
    "kinova": ("kinova_description/robots/kinova.urdf", None),
}


def real_robot(name: str) -> tuple[Path, dict | None]:
    rel, locked = REAL_ROBOTS[name]
    return example_robot_data_dir() / rel, locked


def robot_and_pinocchio(name: str, gravity):
    """``(ineid model, Pinocchio model)`` of a test arm: ``sweaty-arm``, ``mixed-chain`` (the fixture) or a
    :data:`REAL_ROBOTS` arm, both with ``gravity``."""
    from ineid.reference import pinocchio_model

    if name == "sweaty-arm":
        model = ineid.load_robot("sweaty-arm", gravity=gravity)
        return model, pinocchio_model(model.urdf_path, gravity=gravity)
    if name == "mixed-chain":
        path = FIXTURES / "mixed_chain.urdf"
        return ineid.load_robot(path, gravity=gravity), pinocchio_model(path, gravity=gravity)
    path, locked = real_robot(name)
    model = ineid.load_robot(path, gravity=gravity, locked_joints=locked)
    return model, pinocchio_model(path, gravity=gravity, locked_joints=locked)


def random_states(model, n: int, rng: np.random.Generator):
    """q within limits, qd and qdd within the sampling bounds: (n, n_dof) each."""
    from ineid.data.synthesis.sampling import model_uniform_states

    return model_uniform_states(model, n, rng)


def rel_err(a, b) -> float:
    """max |a - b| / max |b|, over everything."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.fixture(scope="session")
def lab(tmp_path_factory):
    """A MuJoCo recording of ``sweaty-arm`` on a turned-over F/T sensor, simulated once per session.

    See :class:`tests.mujoco_arm.LabRecording`: 10 s at 1 kHz, joint angles only, sensor-frame
    wrench with offsets; its files (CSV, ROS 1 and ROS 2 bags) are written on first use.
    """
    pytest.importorskip("mujoco")
    from tests.mujoco_arm import LabRecording

    return LabRecording(tmp_path_factory.mktemp("lab"))


def casadi_regressor_frames(model, q: np.ndarray) -> np.ndarray:
    """(T, 6, 10 n_links) ``model.casadi_regressor`` at ``(q_t, q_t, q_t)`` for each row of ``q`` (no compilation)."""
    return np.stack([np.asarray(model.casadi_regressor(qt, qt, qt)) for qt in q])


def regressor_in_another_process(model, q: np.ndarray) -> np.ndarray:
    """:func:`casadi_regressor_frames` computed by a fresh Python that unpickled ``model`` (what a worker process
    gets: its generated code travels with it)."""
    import io
    import pickle
    import subprocess
    import sys

    code = (
        "import pickle, sys, numpy as np\n"
        "m, q = pickle.load(sys.stdin.buffer)\n"
        "y = np.stack([np.asarray(m.casadi_regressor(qt, qt, qt)) for qt in q])\n"
        "np.save(sys.stdout.buffer, y)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], input=pickle.dumps((model, q)), capture_output=True, check=True)
    return np.load(io.BytesIO(done.stdout))
