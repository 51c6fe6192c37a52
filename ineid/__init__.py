"""ineid: identify a robot arm's inertial parameters from the wrench under its base.

``wrench = Psi(q, qd, qdd) @ theta`` (Newton-Euler, base frame). ineid computes in float64
throughout: importing it turns on JAX's 64-bit mode (through ``JAX_ENABLE_X64`` before JAX
is imported, or JAX's config if it already was). Importing ``ineid`` itself is light (no
JAX); :func:`load_robot` and :class:`RobotModel` load their modules on first use.

Importing ``ineid`` before NumPy also sets ``OPENBLAS_NUM_THREADS=1`` unless it is set: ineid runs its
batches of small factorizations (NumPy's and JAX's LAPACK calls) from threads of its own, and OpenBLAS's
threads on top of them wait on each other, a batched QR taking ten to a hundred times longer on busy cores.
Set the variable yourself to choose otherwise.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("JAX_ENABLE_X64", "1")
if "numpy" not in sys.modules:  # read once, when OpenBLAS loads
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
if "jax" in sys.modules:  # imported before ineid: the variable came too late
    sys.modules["jax"].config.update("jax_enable_x64", True)

from ineid import _moved
from ineid._version import __version__
from ineid.errors import (
    CodegenError,
    DatasetError,
    IdentificationError,
    IneidError,
    InputFileError,
    OutputExistsError,
    PhysicalConsistencyError,
    RobotModelError,
    TrainingError,
)
from ineid.params import (
    PARAM_NAMES,
    check_physical,
    inertial_from_theta,
    is_physical,
    param_names,
    physical_violations,
    pseudo_inertia,
    theta_from_inertial,
)

_moved.install()  # the old import paths of moved modules, for one release

_LAZY = {
    "BUILTIN_ROBOTS": "ineid.robots",
    "RobotModel": "ineid.robots",
    "load_robot": "ineid.robots.load",
}


def __getattr__(name: str):
    """Import the robot-model entry points on first use (they pull in yourdfpy)."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'ineid' has no attribute {name!r}")


__all__ = [
    "BUILTIN_ROBOTS",
    "PARAM_NAMES",
    "CodegenError",
    "DatasetError",
    "IdentificationError",
    "IneidError",
    "InputFileError",
    "OutputExistsError",
    "PhysicalConsistencyError",
    "RobotModel",
    "RobotModelError",
    "TrainingError",
    "__version__",
    "check_physical",
    "inertial_from_theta",
    "is_physical",
    "load_robot",
    "param_names",
    "physical_violations",
    "pseudo_inertia",
    "theta_from_inertial",
]
