"""The backward pass on :class:`ineid.robots.model.RobotModel`: joint torques and the wrench at any link.

The generated Newton-Euler program gives each link's net wrench ``Yn_i theta_i`` (base frame,
moment about the base origin); the wrench a cut transmits is the sum over what lies beyond it
(:mod:`ineid.robots.program`):

- the **joint-torque regressor** ``tau = Y_tau(q, qd, qdd) theta``: the generalized force each
  joint's actuator applies (torque about a revolute axis, force along a prismatic one), as
  Pinocchio's ``rnea`` and ``computeJointTorqueRegressor`` give it;
- the **cut wrench at a link** ``L``: what the links beyond ``L`` (and payloads welded to it)
  exert on ``L``, in ``L``'s frame, moment about ``L``'s origin: what an F/T sensor between
  ``L`` and the rest reads, before its own mount transform.

This module is a mixin of :class:`RobotModel` (the model's file stays one idea): the same
chunked, jitted evaluators as the base regressor, and their pure JAX and CasADi forms.
"""

from __future__ import annotations

import functools

from ineid.errors import RobotModelError
from ineid.robots.chunked import nonzero_flat
from ineid.robots.evaluate import RowsOut, evaluate_contracted, evaluate_rows, tupled_rows


def _program():
    from ineid.robots import program  # the compositions; JAX imported on first use

    return program


@functools.cache
def _structural_nonzero(entries_fn, n_dof: int, n_rows: int, n_cols: int) -> tuple[tuple[int, ...], ...]:
    """Per row, the columns an entries function does not return as the number 0 (its structure)."""
    import jax
    import jax.numpy as jnp

    x = jax.ShapeDtypeStruct((1, n_dof), jnp.float64)
    values = []

    def probe(q, qd, qdd, g):
        out = entries_fn(q, qd, qdd, g)
        values.extend(isinstance(v, (int, float)) and v == 0 for v in out)
        return 0.0

    jax.eval_shape(probe, x, x, x, jax.ShapeDtypeStruct((3,), jnp.float64))
    return tuple(tuple(c for c in range(n_cols) if not values[r * n_cols + c]) for r in range(n_rows))


class CutRegressors:
    """Joint torques and link wrenches of a :class:`ineid.robots.model.RobotModel` (mixin)."""

    # -- joint torques ------------------------------------------------------------------
    @property
    def jax_joint_torque_entries(self):
        """Pure ``f(q, qd, qdd, gravity) -> (Y_00, ..., )``: the ``n_dof x 10 n_links`` entries of the
        joint-torque regressor, row-major, each of the batch shape or the number 0 (structurally zero).
        The same object for every model of the robot (it keys compile caches)."""
        return _program().jax_functions(self._jax).torque_entries

    @property
    def jax_joint_torque_regressor(self):
        """Pure, jit-safe ``f(q, qd, qdd, gravity) -> (..., n_dof, 10 n_links)``: ``tau = f(...) @ theta``."""
        return _program().jax_functions(self._jax).torque_regressor

    @property
    def jax_joint_torques(self):
        """Pure, jit-safe ``f(q, qd, qdd, gravity, theta) -> (..., n_dof)``, ``== jax_joint_torque_regressor(...) @
        theta`` (round-off) without forming the regressor: inverse dynamics, O(n)."""
        return _program().jax_functions(self._jax).torques

    @property
    def joint_torque_nonzero(self) -> tuple[tuple[int, ...], ...]:
        """Per joint, the columns of the joint-torque regressor that are not structurally zero."""
        return _structural_nonzero(self.jax_joint_torque_entries, self.n_dof, self.n_dof, 10 * self.n_links)

    @functools.cached_property
    def casadi_joint_torque_regressor(self):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (n_dof x 1 each -> n_dof x 10 n_links), the model's gravity."""
        return self._with_gravity(
            _program().casadi_torque_functions(self._casadi).regressor, "joint_torque_regressor", "Y"
        )

    @functools.cached_property
    def casadi_joint_torques(self):
        """``casadi.Function`` ``(q, qd, qdd, theta) -> tau`` (n_dof x 1), the model's gravity."""
        return self._with_gravity(
            _program().casadi_torque_functions(self._casadi).torques, "joint_torques", "tau", theta=True
        )

    def joint_torque_regressor(self, q, qd, qdd):
        """``Y_tau(q, qd, qdd)``: ``tau = Y_tau @ theta`` with the model's gravity.

        Args:
            q, qd, qdd: (..., n_dof) joint positions, velocities, accelerations (SI); leading shapes broadcast.

        Returns:
            (..., n_dof, 10 n_links) float64: row ``j`` times ``theta`` is the torque (N*m;
            force in N for a prismatic joint) joint ``j``'s actuator applies, the projection on its
            axis of the wrench it transmits to the links beyond it (Pinocchio's ``rnea``).
            Jitted once per robot, evaluated like :meth:`regressor`: NumPy, or a ``jax.Array`` on
            the states' device when they are all JAX arrays.
        """
        return self._chunked_regressor(
            self.jax_joint_torque_entries, self.joint_torque_nonzero, self.jax_joint_torque_regressor, q, qd, qdd
        )

    def joint_torques(self, q, qd, qdd, theta=None):
        """``tau = Y_tau(q, qd, qdd) @ theta`` (..., n_dof) float64, never forming ``Y_tau``;
        ``theta`` (10 n_links,) or per frame (..., 10 n_links), default :attr:`theta_cad`. NumPy, or a
        ``jax.Array`` on the states' device like :meth:`regressor`."""
        return self._chunked_contracted(self.jax_joint_torques, self.n_dof, q, qd, qdd, theta)

    # -- the wrench at a link ---------------------------------------------------------------
    def link_block(self, link: str) -> int:
        """The parameter block of moving link ``link`` (its index in :attr:`link_names`).

        Raises:
            RobotModelError: ``link`` is not a moving link (one line naming the choices).
        """
        moving = [j.link for j in self.chain.joints]
        if link not in moving:
            raise RobotModelError(f"{link!r} is not a moving link of {self.name}; choose from {', '.join(moving)}")
        return self.link_names.index(link)

    def jax_link_wrench_functions(self, link: str):
        """``(entries, regressor, wrench)``: pure JAX functions of the wrench at ``link``
        (:mod:`ineid.robots.program`'s ``LinkWrenchFunctions``), the same objects on every call."""
        return _program().jax_link_wrench_functions(self._jax, self.link_block(link))

    def link_wrench_nonzero(self, link: str) -> tuple[tuple[int, ...], ...]:
        """Per row of the wrench at ``link``, the columns that are not structurally zero."""
        return _structural_nonzero(self.jax_link_wrench_functions(link).entries, self.n_dof, 6, 10 * self.n_links)

    def casadi_link_wrench_regressor(self, link: str):
        """``casadi.Function`` ``(q, qd, qdd) -> Y`` (6 x 10 n_links): the wrench at ``link``, the model's gravity."""
        fns = _program().casadi_link_wrench_functions(self._casadi, self.link_block(link))
        return self._with_gravity(fns.regressor, "link_wrench_regressor", "Y")

    def link_wrench_regressor(self, q, qd, qdd, link: str):
        """``Y_L(q, qd, qdd)``: ``[F; M]_L = Y_L @ theta``, the wrench the links beyond ``link`` (and the
        payloads welded to it) exert on it, in its frame, moment about its origin; (..., 6, 10 n_links).

        With ``link`` the last link and a payload welded to it, this is what a wrist F/T sensor
        at the link's origin reads (before its mount transform).
        """
        fns = self.jax_link_wrench_functions(link)
        return self._chunked_regressor(fns.entries, self.link_wrench_nonzero(link), fns.regressor, q, qd, qdd)

    def link_wrench(self, q, qd, qdd, link: str, theta=None):
        """``Y_L @ theta`` (..., 6) float64 without forming ``Y_L`` (see :meth:`link_wrench_regressor`)."""
        return self._chunked_contracted(self.jax_link_wrench_functions(link).wrench, 6, q, qd, qdd, theta)

    # -- shared evaluators ------------------------------------------------------------------
    def _with_gravity(self, full, name: str, output: str, theta: bool = False):
        import casadi as ca

        q, qd, qdd = (ca.SX.sym(s, self.n_dof) for s in ("q", "qd", "qdd"))
        args, names = [q, qd, qdd], ["q", "qd", "qdd"]
        if theta:
            args.append(ca.SX.sym("theta", 10 * self.n_links))
            names.append("theta")
        y = full(q, qd, qdd, ca.DM(self.gravity), *args[3:])
        return ca.Function(name, args, [y], names, [output])

    def _chunked_regressor(self, entries_fn, nonzero, regressor_fn, q, qd, qdd):
        n_rows, n_cols = len(nonzero), 10 * self.n_links
        order = nonzero_flat(nonzero, n_cols)
        out = RowsOut((n_rows, n_cols), slice(None), order)
        return evaluate_rows(self, entries_fn, order, [out], tupled_rows(regressor_fn), (q, qd, qdd))[0]

    def _chunked_contracted(self, fn, width: int, q, qd, qdd, theta):
        return evaluate_contracted(self, fn, width, (q, qd, qdd), theta)
