"""RobotModel: a serial arm, its parameters, and its generated base-wrench regressor."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cached_property
from pathlib import Path
from types import ModuleType

import numpy as np

from ineid.errors import CodegenError, RobotModelError
from ineid.params import full_theta, param_names
from ineid.robots.urdf import Chain

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
"""m/s^2 in the base frame: z up."""


class RobotModel:
    """A serial arm on a force/torque sensor, with the regressor of its base wrench.

    ``[F; M] = Psi(q, qd, qdd) @ theta``: ``[F; M]`` the wrench the moving links exert on
    the fixture (the sensor reading), base frame, moment about the base origin; ``theta``
    each moving link's ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` about its frame
    origin, links in chain order. Build one with :func:`ineid.load_robot`.
    """

    def __init__(
        self,
        chain: Chain,
        urdf_path: Path | None,
        name: str,
        gravity: Sequence[float],
        unknown_links: Sequence[str],
        jax_module: ModuleType,
        casadi_module: ModuleType,
        locked_joints: Mapping[str, float] | None = None,
        urdf_text: str | None = None,
    ) -> None:
        if urdf_path is None and urdf_text is None:
            raise ValueError("RobotModel needs urdf_path or urdf_text")
        self.chain = chain
        self.locked_joints: dict[str, float] = dict(locked_joints or {})
        self.urdf_path = None if urdf_path is None else Path(urdf_path)
        """The URDF file, or None for a model rebuilt from a dataset's URDF text."""
        self._urdf_text = urdf_text
        self.name = name
        self.gravity = np.asarray(gravity, dtype=np.float64)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise RobotModelError(f"gravity must be 3 finite numbers (m/s^2, base frame), got {gravity!r}")
        links = self.link_names
        unknown = list(dict.fromkeys(unknown_links))
        for link in unknown:
            if link not in links:
                raise RobotModelError(
                    f"unknown link {link!r} is not a moving link of {name}; choose from {', '.join(links)}"
                )
        # Keep chain order whatever order the caller gave.
        self.unknown_links: tuple[str, ...] = tuple(l for l in links if l in unknown)
        self.known_links: tuple[str, ...] = tuple(l for l in links if l not in unknown)
        for module in (jax_module, casadi_module):
            if module.KINEMATIC_FINGERPRINT != chain.kinematic_fingerprint():
                raise CodegenError(
                    f"generated code {module.__name__} is stale for {name} (fingerprint "
                    f"{module.KINEMATIC_FINGERPRINT}, model {chain.kinematic_fingerprint()}); regenerate it"
                )
        self._jax = jax_module
        self._casadi = casadi_module

    def __repr__(self) -> str:
        return (
            f"RobotModel({self.name!r}, n_dof={self.n_dof}, unknown_links={list(self.unknown_links)}, "
            f"gravity={self.gravity.tolist()})"
        )

    @property
    def urdf_text(self) -> str:
        """The URDF the model was built from."""
        if self._urdf_text is None:
            self._urdf_text = self.urdf_path.read_text()
        return self._urdf_text

    # -- structure -------------------------------------------------------------------
    @property
    def n_dof(self) -> int:
        return self.chain.n_dof

    @property
    def n_links(self) -> int:
        """Moving links (bodies), one per moving joint."""
        return self.chain.n_dof

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.chain.joints)

    @property
    def joint_types(self) -> tuple[str, ...]:
        return tuple("continuous" if j.continuous else j.type for j in self.chain.joints)

    @property
    def link_names(self) -> tuple[str, ...]:
        """Moving links in chain order: the child link of each moving joint."""
        return tuple(j.link for j in self.chain.joints)

    @property
    def param_names(self) -> list[str]:
        """``"<link>.<param>"`` for all ``10 * n_links`` parameters."""
        return param_names(self.link_names)

    @property
    def unknown_index(self) -> np.ndarray:
        """Columns of ``Psi`` (entries of ``theta``) that belong to the unknown links."""
        return self._columns(self.unknown_links)

    @property
    def known_index(self) -> np.ndarray:
        return self._columns(self.known_links)

    def _columns(self, links: Sequence[str]) -> np.ndarray:
        idx = [self.link_names.index(l) for l in links]
        return np.array([10 * i + k for i in idx for k in range(10)], dtype=np.int64)

    # -- parameters and bounds -------------------------------------------------------
    @property
    def theta_cad(self) -> np.ndarray:
        """(10 * n_links,) the URDF's parameters, fixed links folded in, Pinocchio order."""
        return np.concatenate([j.theta for j in self.chain.joints])

    def full_theta(self, theta_unknown: np.ndarray, theta_known: np.ndarray | None = None) -> np.ndarray:
        """(..., 10 * n_links): the unknown links' ``theta_unknown`` and the known links' (default CAD) in chain order.

        ``full_theta(theta_unknown)[..., unknown_index] == theta_unknown``.
        """
        known = self.theta_cad[self.known_index] if theta_known is None else theta_known
        return full_theta(self.link_names, self.unknown_links, theta_unknown, known)

    @property
    def q_lower(self) -> np.ndarray:
        return np.array([j.q_lower for j in self.chain.joints])

    @property
    def q_upper(self) -> np.ndarray:
        return np.array([j.q_upper for j in self.chain.joints])

    @property
    def qd_max(self) -> np.ndarray:
        """Velocity bound for sampling, rad/s (m/s for prismatic joints)."""
        return np.array([j.qd_max for j in self.chain.joints])

    @property
    def qdd_max(self) -> np.ndarray:
        """Acceleration bound for sampling, rad/s^2 (m/s^2 for prismatic joints)."""
        return np.array([j.qdd_max for j in self.chain.joints])

    @property
    def op_count(self) -> int:
        """Arithmetic operations of the generated regressor after CSE."""
        return int(self._jax.OP_COUNT)

    # -- regressor -------------------------------------------------------------------
    def _check_states(self, q, qd, qdd):
        import jax.numpy as jnp  # noqa: PLC0415

        arrays = []
        for label, x in (("q", q), ("qd", qd), ("qdd", qdd)):
            x = jnp.asarray(x, dtype=jnp.float64)
            if x.ndim == 0 or x.shape[-1] != self.n_dof:
                raise ValueError(f"{label} must have shape (..., {self.n_dof}), got {tuple(x.shape)}")
            arrays.append(x)
        return arrays

    def regressor(self, q, qd, qdd):
        """``Psi(q, qd, qdd)`` with the model's gravity; (..., n_dof) -> (..., 6, 10 * n_links), JAX."""
        q, qd, qdd = self._check_states(q, qd, qdd)
        return self._jax.base_wrench_regressor(q, qd, qdd, self.gravity)

    def regressor_split(self, q, qd, qdd):
        """``(Psi_unknown, Psi_known)``: the regressor's columns of the unknown and known links.

        ``wrench = Psi_unknown @ theta_unknown + Psi_known @ theta_known``.
        """
        y = self.regressor(q, qd, qdd)
        return y[..., self.unknown_index], y[..., self.known_index]

    def base_wrench(self, q, qd, qdd, theta=None):
        """``[F; M] = Psi(q, qd, qdd) @ theta``, (..., 6); ``theta`` defaults to :attr:`theta_cad`.

        Evaluated by the generated ``base_wrench``, which contracts with ``theta`` inside
        one fused loop instead of forming ``Psi`` (several times faster on the CPU).
        """
        import jax.numpy as jnp  # noqa: PLC0415

        theta = self.theta_cad if theta is None else theta
        theta = jnp.asarray(theta, dtype=jnp.float64)
        if theta.shape[-1:] != (10 * self.n_links,):
            raise ValueError(f"theta must have shape (..., {10 * self.n_links}), got {tuple(theta.shape)}")
        q, qd, qdd = self._check_states(q, qd, qdd)
        return self._jax.base_wrench(q, qd, qdd, self.gravity, theta)

    @property
    def jax_base_wrench(self):
        """The generated pure function ``f(q, qd, qdd, gravity, theta) -> (..., 6)``."""
        return self._jax.base_wrench

    @property
    def jax_regressor(self):
        """The generated pure function ``f(q, qd, qdd, gravity) -> (..., 6, 10 * n_links)``."""
        return self._jax.base_wrench_regressor

    @cached_property
    def casadi_regressor(self):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (n_dof x 1 each -> 6 x 10 n_links), gravity applied."""
        import casadi as ca  # noqa: PLC0415

        full = self._casadi.base_wrench_regressor
        q, qd, qdd = (ca.SX.sym(s, self.n_dof) for s in ("q", "qd", "qdd"))
        y = full(q, qd, qdd, ca.DM(self.gravity))
        return ca.Function("base_wrench_regressor", [q, qd, qdd], [y], ["q", "qd", "qdd"], ["Y"])
