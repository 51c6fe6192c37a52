"""RobotModel: a robot on a fixed base (a serial arm or a kinematic tree), its parameters, and its generated
Newton-Euler program and regressors."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cached_property
from pathlib import Path
from types import ModuleType

import numpy as np

from ineid.chain import Chain
from ineid.errors import CodegenError, RobotModelError
from ineid.params import full_theta, param_names
from ineid.robots.chunked import (  # noqa: F401  (CHUNK_FRAMES, SMALL_FRAMES, SMALL_JOB_FRAMES: importable here too)
    CHUNK_FRAMES,
    SMALL_FRAMES,
    SMALL_JOB_FRAMES,
    nonzero_flat,
)
from ineid.robots.cuts import CutRegressors
from ineid.robots.evaluate import RowsOut, evaluate_contracted, evaluate_rows, split_columns, tupled_rows
from ineid.robots.payload import extended_links, extended_theta_cad, payload_modules, resolve_payloads

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
"""m/s^2 in the base frame: z up."""


class RobotModel(CutRegressors):
    """A robot on a force/torque sensor (a serial arm, or a tree of branches on one base), with the regressor
    of its base wrench.

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
        model_path: Path | None = None,
    ) -> None:
        if urdf_path is None and urdf_text is None:
            raise ValueError("RobotModel needs urdf_path or urdf_text")
        self.chain = chain
        self.locked_joints: dict[str, float] = dict(locked_joints or {})
        self.urdf_path = None if urdf_path is None else Path(urdf_path)
        """The URDF file, or None for a model rebuilt from a dataset's URDF text (or read from an MJCF)."""
        self.model_path = self.urdf_path if model_path is None else Path(model_path)
        """The robot file the model was loaded from: the URDF, or the MJCF whose URDF ``urdf_text`` is."""
        self._urdf_text = urdf_text
        self.name = name
        self.gravity = np.asarray(gravity, dtype=np.float64)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise RobotModelError(f"gravity must be 3 finite numbers (m/s^2, base frame), got {gravity!r}")
        unknown = list(dict.fromkeys(unknown_links))
        self.payloads = resolve_payloads(chain, unknown, name)
        """Welded links identified on their own (:mod:`ineid.robots.payload`); after their body in ``link_names``."""
        self._links = extended_links(chain, self.payloads)
        links = self.link_names
        # Keep chain order whatever order the caller gave.
        self.unknown_links: tuple[str, ...] = tuple(name for name in links if name in unknown)
        self.known_links: tuple[str, ...] = tuple(name for name in links if name not in unknown)
        for module in (jax_module, casadi_module):
            if module.KINEMATIC_FINGERPRINT != chain.kinematic_fingerprint():
                raise CodegenError(
                    f"generated code {module.__name__} is stale for {name} (fingerprint "
                    f"{module.KINEMATIC_FINGERPRINT}, model {chain.kinematic_fingerprint()}); regenerate it"
                )
        self._generated = (jax_module, casadi_module)  # as loaded: what a copy in another process loads again
        if self.payloads:  # the regressor's columns seen through theta = M theta_ext
            jax_module, casadi_module = payload_modules(jax_module, casadi_module, chain, self.payloads)
        self._jax = jax_module
        self._casadi = casadi_module

    def __reduce__(self):
        """Pickled for a worker process (spawned, as :mod:`ineid.excite.lanes` does): the chain, the settings and the
        generated modules by reference (:func:`ineid.generated.module_reference`: a built-in's name, or the bytes
        ineid checked when it loaded them), so the copy is the same model without deriving or reading anything."""
        from ineid.generated import module_reference

        state = dict(
            chain=self.chain,
            urdf_path=self.urdf_path,
            name=self.name,
            gravity=self.gravity.tolist(),
            unknown_links=list(self.unknown_links),
            modules=tuple(module_reference(m) for m in self._generated),
            locked_joints=self.locked_joints,
            urdf_text=self._urdf_text,
            model_path=self.model_path,
        )
        return _model_from_state, (state,)

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
        """Parameter blocks: the moving links (one per moving joint) and the payloads."""
        return len(self._links)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.chain.joints)

    @property
    def joint_types(self) -> tuple[str, ...]:
        return tuple("continuous" if j.continuous else j.type for j in self.chain.joints)

    @property
    def link_names(self) -> tuple[str, ...]:
        """Moving links in chain order (the child link of each moving joint), each followed by its payloads."""
        return self._links

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
        idx = [self.link_names.index(name) for name in links]
        return np.array([10 * i + k for i in idx for k in range(10)], dtype=np.int64)

    # -- parameters and bounds -------------------------------------------------------
    @property
    def theta_cad(self) -> np.ndarray:
        """(10 * n_links,) the URDF's parameters, fixed links folded in, Pinocchio order (a payload's
        own, in its frame; its body's without it)."""
        if self.payloads:
            return extended_theta_cad(self.chain, self.payloads)
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
        """Arithmetic operations of the generated program (the Newton-Euler recursion, every output)."""
        return int(self._jax.OP_COUNT)

    # -- regressor -------------------------------------------------------------------
    @property
    def regressor_nonzero(self) -> tuple[tuple[int, ...], ...]:
        """Per row of ``Psi`` (6), the columns that are not identically zero."""
        return tuple(tuple(cols) for cols in self._jax.NONZERO)

    @property
    def jax_regressor_entries(self):
        """The pure function ``f(q, qd, qdd, gravity) -> (Psi_00, Psi_01, ..., Psi_5m)``.

        The ``6 * 10 n_links`` entries of ``Psi`` in row-major order, each of the batch shape
        (or the number 0 where identically zero), all from one evaluation of the generated
        program: ``jnp.stack(f(...), -1).reshape(..., 6, 10 n_links) == jax_regressor(...)``.
        Stacking only the entries needed, frames last, is what XLA:CPU evaluates fastest (the
        public evaluators and the fused identification do). The same object for every model
        of the robot, so it can key compilation caches.
        """
        return _jax_functions(self._jax).entries

    @property
    def jax_program(self):
        """The generated program, ``f(q, qd, qdd, gravity) -> {output: nested tuples}``, pure and jit-safe.

        The building block of every regressor (see ``docs/regressor.md`` and
        :mod:`ineid.robots.program`): per link ``"R"`` (``base_R_i``, 3 x 3 row-major),
        ``"p"`` (``base_p_i``), ``"w"``, ``"wd"``, ``"a"`` (link frame, ``a`` minus gravity),
        ``"Yn"`` (6 x 10: the columns of the link's net wrench, base frame, about the base
        origin); per joint ``"axis"`` (``z_j``) and ``"moment"`` (``p_j x z_j``), base frame.
        Each entry an array of the batch shape or a Python number.
        """
        return self._jax.program

    @property
    def casadi_program(self):
        """The same program on CasADi symbols (``q, qd, qdd`` n x 1, ``gravity`` 3 x 1 ``SX``), same outputs."""
        return self._casadi.program

    @property
    def jax_link_poses(self):
        """Pure, jit-safe ``f(q) -> (base_R (..., n_links, 3, 3), base_p (..., n_links, 3))``.

        Every moving link's frame in the base frame (``x_base = base_R @ x_link + base_p``),
        links in chain order, for ``q`` (..., n_dof); differentiable (forward and reverse).
        """
        return _jax_functions(self._jax).link_poses

    def _entry_order(self) -> tuple[np.ndarray, int]:
        """Flat indices of the nonzero entries of ``Psi``, unknown links' columns first, and how many of those."""
        n_cols = 10 * self.n_links
        nonzero = nonzero_flat(self.regressor_nonzero, n_cols)
        unknown = np.isin(nonzero % n_cols, self.unknown_index)
        return np.concatenate([nonzero[unknown], nonzero[~unknown]]), int(unknown.sum())

    def regressor(self, q, qd, qdd):
        """``Psi(q, qd, qdd)``: ``[F; M] = Psi @ theta`` with the model's gravity.

        Args:
            q, qd, qdd: (..., n_dof) joint positions, velocities, accelerations (SI), NumPy
                or JAX arrays; leading shapes broadcast.

        Returns:
            (..., 6, 10 n_links) float64: the wrench the moving links exert on the fixture
            (base frame, moment about the base origin) is ``Psi @ theta`` for any parameters
            ``theta`` (Pinocchio's order, about each link origin). A NumPy array; a
            ``jax.Array`` on their device when ``q``, ``qd`` and ``qdd`` are all JAX arrays
            (traced inside a caller's ``jax.jit``), see :mod:`ineid.robots.device`.

        NumPy states are evaluated by the generated code, compiled once per robot and link
        split and streamed over chunks of frames from a few threads, written straight into
        the result (:mod:`ineid.robots.chunked`).
        """
        fns = _jax_functions(self._jax)
        order, _ = self._entry_order()
        out = RowsOut((6, 10 * self.n_links), slice(None), order)
        return evaluate_rows(self, fns.entries, order, [out], tupled_rows(fns.regressor), (q, qd, qdd))[0]

    def regressor_split(self, q, qd, qdd):
        """``(Psi_u, Psi_k)``: the regressor's columns of the unknown and of the known links.

        ``[F; M] = Psi_u @ theta[unknown_index] + Psi_k @ theta[known_index]``; shapes
        (..., 6, 10 n_unknown) and (..., 6, 10 n_known), float64, NumPy or on the states'
        device like :meth:`regressor`. Same evaluation, written into the two results directly.
        """
        fns = _jax_functions(self._jax)
        n_cols = 10 * self.n_links
        order, n_u = self._entry_order()
        outs = []
        for index, rows in ((self.unknown_index, slice(0, n_u)), (self.known_index, slice(n_u, None))):
            column = {int(c): k for k, c in enumerate(index)}
            dest = [(e // n_cols) * len(index) + column[int(e % n_cols)] for e in order[rows]]
            outs.append(RowsOut((6, len(index)), rows, np.array(dest, dtype=np.int64)))
        groups = (tuple(int(c) for c in self.unknown_index), tuple(int(c) for c in self.known_index))
        return evaluate_rows(self, fns.entries, order, outs, split_columns(fns.regressor, groups), (q, qd, qdd))

    def base_wrench(self, q, qd, qdd, theta=None):
        """``[F; M] = Psi(q, qd, qdd) @ theta``: the wrench on the fixture, (..., 6) float64.

        Force (N) and moment about the base origin (N*m), base frame. ``theta`` (10 n_links,)
        or (..., 10 n_links) broadcasting with the states; default :attr:`theta_cad`.
        Evaluated by :attr:`jax_base_wrench`, which contracts with ``theta`` link by link
        instead of forming ``Psi`` (several times faster), compiled once per robot and
        chunked like :meth:`regressor`; NumPy, or a ``jax.Array`` on the states' device like it.
        """
        return evaluate_contracted(self, _jax_functions(self._jax).wrench, 6, (q, qd, qdd), theta)

    @property
    def jax_base_wrench(self):
        """Pure function ``f(q, qd, qdd, gravity, theta) -> (..., 6)``, for use inside ``jax.jit``.

        ``f(q, qd, qdd, g, theta) == jax_regressor(q, qd, qdd, g) @ theta`` (round-off), without
        forming ``Psi`` (:func:`ineid.robots.program.base_wrench`). The same object for every
        model of the robot.
        """
        return _jax_functions(self._jax).wrench

    @property
    def jax_regressor(self):
        """Pure function ``f(q, qd, qdd, gravity) -> (..., 6, 10 * n_links)``, for use inside ``jax.jit``.

        ``f(q, qd, qdd, g) @ theta`` is the base wrench; :meth:`regressor` is the same with
        ``g`` the model's gravity, evaluated eagerly into NumPy. The same object for every
        model of the robot.
        """
        return _jax_functions(self._jax).regressor

    @cached_property
    def casadi_regressor(self):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (n_dof x 1 each -> 6 x 10 n_links), gravity applied.

        ``Y(q, qd, qdd) == regressor(q, qd, qdd)`` for one frame (round-off).
        """
        import casadi as ca

        full = _casadi_functions(self._casadi).regressor
        q, qd, qdd = (ca.SX.sym(s, self.n_dof) for s in ("q", "qd", "qdd"))
        y = full(q, qd, qdd, ca.DM(self.gravity))
        return ca.Function("base_wrench_regressor", [q, qd, qdd], [y], ["q", "qd", "qdd"], ["Y"])

    @cached_property
    def casadi_base_wrench(self):
        """``casadi.Function`` ``(q, qd, qdd, theta) -> w`` (n_dof x 1, 10 n_links x 1 -> 6 x 1), gravity applied.

        ``w == Y(q, qd, qdd) @ theta`` (round-off), without forming ``Y``.
        """
        import casadi as ca

        full = _casadi_functions(self._casadi).wrench
        q, qd, qdd = (ca.SX.sym(s, self.n_dof) for s in ("q", "qd", "qdd"))
        theta = ca.SX.sym("theta", 10 * self.n_links)
        w = full(q, qd, qdd, ca.DM(self.gravity), theta)
        return ca.Function("base_wrench", [q, qd, qdd, theta], [w], ["q", "qd", "qdd", "theta"], ["w"])


def _jax_functions(module):
    from ineid.robots.program import jax_functions

    return jax_functions(module)


def _casadi_functions(module):
    from ineid.robots.program import casadi_functions

    return casadi_functions(module)


def _model_from_state(state: dict) -> RobotModel:
    """The :class:`RobotModel` that :meth:`RobotModel.__reduce__` pickled."""
    from ineid.generated import module_from_reference

    jax_module, casadi_module = (module_from_reference(r) for r in state["modules"])
    return RobotModel(
        state["chain"],
        state["urdf_path"],
        state["name"],
        state["gravity"],
        state["unknown_links"],
        jax_module,
        casadi_module,
        state["locked_joints"],
        urdf_text=state["urdf_text"],
        model_path=state["model_path"],
    )
