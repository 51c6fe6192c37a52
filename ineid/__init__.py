"""ineid: identify a robot arm's inertial parameters from the wrench under its base.

``wrench = Psi(q, qd, qdd) @ theta`` (Newton-Euler, base frame). Importing ineid turns on
JAX's 64-bit mode: ineid computes in float64 throughout.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

from ineid.errors import (  # noqa: E402
    CodegenError,
    DatasetError,
    IdentificationError,
    IneidError,
    PhysicalConsistencyError,
    RobotModelError,
)
from ineid.params import (  # noqa: E402
    PARAM_NAMES,
    check_physical,
    inertial_from_theta,
    is_physical,
    param_names,
    physical_violations,
    pseudo_inertia,
    theta_from_inertial,
)
from ineid.robots import BUILTIN_ROBOTS, RobotModel, load_robot  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BUILTIN_ROBOTS",
    "PARAM_NAMES",
    "CodegenError",
    "DatasetError",
    "IdentificationError",
    "IneidError",
    "PhysicalConsistencyError",
    "RobotModel",
    "RobotModelError",
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
