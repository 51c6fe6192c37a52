"""Joint torques and motor currents: the classical measurement, with the actuation model as extra columns.

What joint ``j``'s actuator applies is the projection on its axis of the wrench it transmits to
the links beyond it (the backward pass of Newton-Euler, :mod:`ineid.robots.cuts`), plus what
the drive itself adds: friction, rotor inertia, an offset. Per frame (the paper's eq. 1-2,
with the actuation terms of the peers: FIGAROH, FloBaRoID, BIRDy, SymPyBotics)::

    tau_j = Y_tau,j(q, qd, qdd) theta + fv_j qd_j + fc_j c(qd_j) + Ia_j qdd_j + o_j

``Phi = Y_tau`` (``n_dof`` rows, ``T`` the identity) and the actuation terms are the channel's
*extra kept columns* ``E x`` (row ``j`` only), named ``<joint>.fv`` (viscous, N*m*s/rad),
``<joint>.fc`` (Coulomb, N*m), ``<joint>.offset`` (N*m), ``<joint>.Ia`` (armature, the rotor
inertia reflected through the gear, kg*m^2), in that order per joint (N, N*s/m and kg for a
prismatic joint). ``c(qd) = sign(qd)``, or ``tanh(qd / zone)`` with a smooth zone (a
Coulomb model that does not jump at rest, where the sign of a measured velocity is noise).
With ``asymmetric``, viscous and Coulomb friction take one coefficient per direction:
``fv+ max(qd, 0) + fv- min(qd, 0)`` and ``fc+ [qd > 0] - fc- [qd < 0]`` (smooth: the positive
and negative parts of ``tanh``), all four positive for a passive drive. With ``"stribeck"`` friction a
Stribeck term ``fs_j exp(-(qd_j / vs)^2) c(qd_j)`` (``<joint>.fs``, N*m: the static friction's excess
over ``fc``) at the Stribeck velocity ``vs`` (``stribeck_velocity``, rad/s); the columns and their forms are
:mod:`ineid.channels.friction`'s, and :mod:`ineid.identify.friction_search` finds ``zone`` and ``vs`` when they
are not given (``identified`` records their std).

With a coupled transmission (``coupling``, :mod:`ineid.channels.transmission`: ``qd_joint = C qd_motor``)
the channel reads one torque per motor, ``tau_motor = C^T tau_joint + E(C^-1 qd, C^-1 qdd) x``: ``T = C^T``,
its axes are the motors and the actuation coefficients are the motors' (``<motor>.fv``, ...).

:class:`MotorCurrent` is the same model read through the drive: ``i_j = tau_j / (k_j G_j)``
with the torque constant ``k_j`` (N*m/A, motor side) and gear ratio ``G_j`` given, so its
``T = diag(1 / (k G))`` (``diag(1 / (k G)) C^T`` with a coupling, ``k`` and ``G`` then per motor) and the
actuation coefficients keep their joint-side units. With
``identify_k`` the torque constants are identified as well (``<joint>.k``, N*m/A, around the given
ones), in the second of two steps (:mod:`ineid.identify.two_step`).

References:
    Atkeson, An, Hollerbach (1986): linearity in the parameters.
    Khalil, Dombre (2002), Modeling, Identification and Control of Robots, ch. 12 (friction, offsets, armature).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ineid.channels.base import Channel, register
from ineid.channels.friction import (
    EXTRA_UNITS,
    FRICTION_TERMS,
    actuation_column,
    actuation_terms,
    drive_columns,
    extra_unit,
    jax_extra,
)
from ineid.channels.transmission import check_coupling
from ineid.errors import DatasetError

__all__ = ["EXTRA_UNITS", "FRICTION_TERMS", "JointTorque", "MotorCurrent", "extra_unit"]


@register
@dataclass(frozen=True, kw_only=True)
class JointTorque(Channel):
    """The torque (force, prismatic) each joint's actuator applies, with its actuation model (module docstring).

    Attributes:
        key: where its values are stored (default ``"tau"``), (C, F, n_dof), N*m or N.
        friction: the friction terms identified, any of :data:`FRICTION_TERMS` (in that order).
        coulomb_zone: rad/s (m/s): 0 gives ``sign(qd)``; above 0, ``tanh(qd / zone)``.
        stribeck_velocity: ``vs`` of the Stribeck term ``fs exp(-(qd / vs)^2) c(qd)``, rad/s (> 0 with
            ``"stribeck"`` friction).
        identified: ``(name, std)`` of the nonlinear friction velocities (``"coulomb_zone"``,
            ``"stribeck_velocity"``) found by :mod:`ineid.identify.friction_search`, with their std (rad/s).
        asymmetric: one viscous and one Coulomb coefficient per direction of motion.
        armature: the rotor inertia ``<joint>.Ia`` (times ``qdd``) is identified.
        torque_offset: a constant ``<joint>.offset`` per joint is identified (a column of ones; unlike
            ``offsets``, which removes constants by centring, it is reported with its std).
        coupling: ``C`` (joints x motors, :mod:`ineid.channels.transmission`): the channel reads per motor,
            ``tau_motor = C^T tau_joint`` plus the actuation terms at the motors' velocities ``C^-1 qd``;
            empty: one drive per joint.
        motors: the motors' names (the axes with a coupling), in the order of ``coupling``'s columns.
        offsets: per-axis constants removed by centring (as for a wrench), named ``<key>.<joint>.offset``.
    """

    key: str = "tau"
    friction: tuple[str, ...] = ()
    coulomb_zone: float = 0.0
    stribeck_velocity: float = 0.0
    identified: tuple[tuple[str, float], ...] = ()
    asymmetric: bool = False
    armature: bool = False
    torque_offset: bool = False
    coupling: tuple[tuple[float, ...], ...] = ()
    motors: tuple[str, ...] = ()

    kind = "joint_torque"
    RECORD_FIELDS = (
        "friction",
        "coulomb_zone",
        "asymmetric",
        "armature",
        "torque_offset",
        "stribeck_velocity",
        "identified",
        "coupling",
        "motors",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        friction = tuple(self.friction) if isinstance(self.friction, (list, tuple)) else self.friction
        if (
            not isinstance(friction, tuple)
            or any(f not in FRICTION_TERMS for f in friction)
            or len(set(friction)) != len(friction)
        ):
            raise DatasetError(
                f"joint-torque channel {self.key!r}: friction must be a list of "
                f"{', '.join(FRICTION_TERMS)}, got {self.friction!r}"
            )
        object.__setattr__(self, "friction", tuple(f for f in FRICTION_TERMS if f in friction))
        for name, what in (("coulomb_zone", "the Coulomb zone"), ("stribeck_velocity", "the Stribeck velocity")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise DatasetError(
                    f"joint-torque channel {self.key!r}: {what} must be a finite number >= 0 "
                    f"(rad/s; 0 for sign(qd)), got {v!r}"
                )
            object.__setattr__(self, name, float(v))
        if ("stribeck" in self.friction) != (self.stribeck_velocity > 0):
            raise DatasetError(
                f"joint-torque channel {self.key!r}: Stribeck friction needs a Stribeck velocity > 0 rad/s, "
                f"and the velocity goes with it (friction {', '.join(self.friction) or 'none'}, "
                f"velocity {self.stribeck_velocity:g})"
            )
        self._check_identified()
        for name in ("asymmetric", "armature", "torque_offset"):
            if not isinstance(getattr(self, name), bool):
                raise DatasetError(
                    f"joint-torque channel {self.key!r}: {name} must be true or false, got {getattr(self, name)!r}"
                )
        if self.coupling or self.motors:
            c, m = check_coupling(self.coupling, self.motors, f"joint-torque channel {self.key!r}")
            object.__setattr__(self, "coupling", c)
            object.__setattr__(self, "motors", m)

    def _check_identified(self) -> None:
        try:
            pairs = tuple((str(n), float(s)) for n, s in dict(self.identified).items())
        except (TypeError, ValueError):
            raise DatasetError(
                f"joint-torque channel {self.key!r}: identified must map coulomb_zone or stribeck_velocity "
                f"to a std, got {self.identified!r}"
            ) from None
        if any(n not in ("coulomb_zone", "stribeck_velocity") for n, _ in pairs):
            raise DatasetError(
                f"joint-torque channel {self.key!r}: identified names coulomb_zone or stribeck_velocity, "
                f"got {', '.join(n for n, _ in pairs)}"
            )
        object.__setattr__(self, "identified", pairs)

    # -- what it measures ------------------------------------------------------------------
    def axes(self, model) -> tuple[str, ...]:
        if self.coupling:
            self._check_joints_coupled(model)
            return self.motors
        return tuple(model.joint_names)

    def units(self, model) -> tuple[str, ...]:
        return tuple("N" if t == "prismatic" else "N*m" for t in self._drive_types(model))

    def _drive_types(self, model) -> tuple[str, ...]:
        """Each drive's joint type (a coupled transmission's motors: revolute)."""
        return ("revolute",) * len(self.motors) if self.coupling else _joint_types(model)

    def _check_joints_coupled(self, model) -> None:
        if len(self.coupling) != model.n_dof:
            raise DatasetError(
                f"joint-torque channel {self.key!r}: the coupling has {len(self.coupling)} joints' rows and the "
                f"model {model.n_dof} joints ({', '.join(model.joint_names)}); give one row per joint"
            )

    def _velocity(self, name: str, label: str) -> str:
        std = dict(self.identified).get(name)
        value = getattr(self, name)
        return f"{label} {value:.4g} rad/s" + ("" if std is None else f" (identified, std {std:.2g})")

    def describe(self) -> str:
        parts = []
        if self.friction:
            smooth = self.coulomb_zone and ({"coulomb", "stribeck"} & set(self.friction))
            zone = f", {self._velocity('coulomb_zone', 'smooth zone')}" if smooth else ""
            if "stribeck" in self.friction:
                zone += f", {self._velocity('stribeck_velocity', 'Stribeck velocity')}"
            parts.append(("asymmetric " if self.asymmetric else "") + " + ".join(self.friction) + " friction" + zone)
        if self.armature:
            parts.append("armature")
        if self.torque_offset:
            parts.append("torque offsets")
        if self.coupling:
            parts.append(f"per motor ({', '.join(self.motors)}) through a coupled transmission")
        if self.offsets:
            parts.append("offsets removed by centring")
        return f"joint torques '{self.key}'" + (f" ({'; '.join(parts)})" if parts else "")

    @property
    def terms(self) -> tuple[str, ...]:
        """The actuation columns of each drive, in order (``"fv"``, ``"fc"``, ``"fs"``, ``"offset"``, ``"Ia"``)."""
        return actuation_terms(self.friction, self.asymmetric, self.torque_offset, self.armature)

    def coupling_matrix(self) -> np.ndarray | None:
        """``C`` (joints x motors), or None without a coupled transmission."""
        return np.asarray(self.coupling, dtype=np.float64) if self.coupling else None

    def drive_matrix(self) -> np.ndarray | None:
        """``C^-1``: the joints' velocities into the motors' (None: the drives are the joints)."""
        c = self.coupling_matrix()
        return None if c is None else np.linalg.inv(c)

    def with_actuation(
        self,
        friction=(),
        coulomb_zone: float = 0.0,
        asymmetric: bool = False,
        armature: bool = False,
        torque_offset: bool = False,
        stribeck_velocity: float = 0.0,
    ) -> JointTorque:
        """The same measurement identified with another actuation model."""
        from dataclasses import replace

        return replace(
            self,
            friction=tuple(friction),
            coulomb_zone=coulomb_zone,
            stribeck_velocity=stribeck_velocity,
            identified=(),
            asymmetric=asymmetric,
            armature=armature,
            torque_offset=torque_offset,
        )

    # -- the model ------------------------------------------------------------------------
    def entries_function(self, model):
        return model.jax_joint_torque_entries

    def casadi_function(self, model):
        return model.casadi_joint_torque_regressor

    def nonzero(self, model) -> tuple[tuple[int, ...], ...]:
        return model.joint_torque_nonzero

    def phi_function(self, model):
        return model.jax_joint_torque_regressor

    def phi_theta_function(self, model):
        """The composed torques (inverse dynamics, O(n), never forming ``Y_tau``)."""
        return model.jax_joint_torques

    def transform(self) -> np.ndarray | None:
        """``C^T`` with a coupled transmission (joint torques into motor torques), else None (the identity)."""
        c = self.coupling_matrix()
        return None if c is None else c.T

    def rows(self, model, q, qd, qdd) -> np.ndarray:
        rows = model.joint_torque_regressor(q, qd, qdd)
        t = self.transform()
        return rows if t is None else t @ rows

    def predict(self, model, q, qd, qdd, theta) -> np.ndarray:
        tau = model.joint_torques(q, qd, qdd, theta)
        t = self.transform()
        return tau if t is None else tau @ t.T

    # -- the actuation model: extra kept columns --------------------------------------------
    def extra_names(self, model) -> tuple[str, ...]:
        return tuple(f"{drive}.{term}" for drive in self.axes(model) for term in self.terms)

    def extra_units(self, model) -> tuple[str, ...]:
        """The unit of each extra column's coefficient (:func:`extra_unit`)."""
        return tuple(extra_unit(term, t) for t in self._drive_types(model) for term in self.terms)

    def _extra_scale(self) -> np.ndarray | None:
        """Per axis, the factor the reading applies to a drive's torque (None: 1)."""
        return None

    def extra_rows_function(self, model):
        if not self.terms:
            return None
        drives = self.drive_matrix()
        return jax_extra(
            self.terms,
            self.coulomb_zone,
            self.stribeck_velocity,
            model.n_dof,
            _tuple_or_none(self._extra_scale()),
            None if drives is None else tuple(map(tuple, drives.tolist())),
        )

    def numpy_extra_rows(self, model, qd, qdd) -> np.ndarray:
        """``E`` (..., n_a, n_e) in NumPy from the joints' ``qd``, ``qdd`` (no compilation: the friction search
        evaluates it at many velocities, :mod:`ineid.identify.friction_search`)."""
        if not self.terms:
            return np.zeros(np.shape(qd)[:-1] + (self.n_axes(model), 0))
        args = (self.terms, self.coulomb_zone, self.stribeck_velocity, self._extra_scale(), self.drive_matrix())
        return drive_columns(np, *args, np.asarray(qd, dtype=np.float64), np.asarray(qdd, dtype=np.float64))

    def casadi_extra_function(self, model):
        if not self.terms:
            return None
        import casadi as ca

        n, terms = model.n_dof, self.terms
        q, qd, qdd = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd"))
        drives = self.drive_matrix()
        vd, ad = (qd, qdd) if drives is None else (ca.DM(drives) @ qd, ca.DM(drives) @ qdd)
        e = ca.SX.zeros(n, n * len(terms))
        scale = self._extra_scale()
        for j in range(n):
            for k, term in enumerate(terms):
                col = actuation_column(ca, term, vd[j], ad[j], self.coulomb_zone, self.stribeck_velocity)
                e[j, j * len(terms) + k] = col if scale is None else scale[j] * col
        return ca.Function("actuation_rows", [q, qd, qdd], [e], ["q", "qd", "qdd"], ["E"])

    # -- record ---------------------------------------------------------------------------
    def _record(self) -> dict:
        """The record; the Stribeck velocity, the identified velocities and the coupling only when set."""
        return {
            "friction": list(self.friction),
            "coulomb_zone": self.coulomb_zone,
            "asymmetric": self.asymmetric,
            "armature": self.armature,
            "torque_offset": self.torque_offset,
            **({"stribeck_velocity": self.stribeck_velocity} if self.stribeck_velocity else {}),
            **({"identified": dict(self.identified)} if self.identified else {}),
            **({"coupling": [list(r) for r in self.coupling], "motors": list(self.motors)} if self.coupling else {}),
        }

    @classmethod
    def _parse_record(cls, d: Mapping, where: str) -> dict:
        out = {name: d[name] for name in cls.RECORD_FIELDS if name in d}
        for name in ("friction", "coupling", "motors"):
            if name in out:
                if not isinstance(out[name], list):
                    raise DatasetError(f"{where}: the joint-torque channel's {name} must be a list, got {out[name]!r}")
                out[name] = tuple(tuple(r) if isinstance(r, list) else r for r in out[name])
        if "identified" in out:
            if not isinstance(out["identified"], Mapping):
                raise DatasetError(
                    f"{where}: the joint-torque channel's identified must be a record, got {out['identified']!r}"
                )
            out["identified"] = tuple(out["identified"].items())
        return out


@register
@dataclass(frozen=True, kw_only=True)
class MotorCurrent(JointTorque):
    """Motor currents ``i_j = tau_j / (k_j G_j)`` (A), the joint torques read through the drives.

    Attributes:
        key: where its values are stored (default ``"current"``), (C, F, n_dof), A.
        torque_constant: ``k_j`` per joint, N*m/A at the motor (datasheet values).
        gear_ratio: ``G_j`` per joint (motor turns per joint turn; the sign gives the direction).
        identify_k: the torque constants are identified (``<joint>.k``, from ``torque_constant`` as the nominal
            ``k0``: ``k_j = k0_j (1 + d_j)``), in the second of two steps (:mod:`ineid.identify.two_step`).
    """

    key: str = "current"
    torque_constant: tuple[float, ...] = ()
    gear_ratio: tuple[float, ...] = ()
    identify_k: bool = False

    kind = "motor_current"
    RECORD_FIELDS = (*JointTorque.RECORD_FIELDS, "torque_constant", "gear_ratio", "identify_k")

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("torque_constant", "gear_ratio"):
            values = getattr(self, name)
            try:
                values = tuple(float(v) for v in values)
            except (TypeError, ValueError):
                raise DatasetError(
                    f"motor-current channel {self.key!r}: {name} must be one number per joint, "
                    f"got {getattr(self, name)!r}"
                ) from None
            if not values or not all(math.isfinite(v) and v != 0 for v in values):
                raise DatasetError(
                    f"motor-current channel {self.key!r}: {name} must be finite, non-zero numbers, "
                    f"one per joint, got {getattr(self, name)!r}"
                )
            object.__setattr__(self, name, values)
        if len(self.torque_constant) != len(self.gear_ratio):
            raise DatasetError(
                f"motor-current channel {self.key!r}: {len(self.torque_constant)} torque constants "
                f"but {len(self.gear_ratio)} gear ratios; give one of each per joint"
            )
        if not isinstance(self.identify_k, bool):
            raise DatasetError(
                f"motor-current channel {self.key!r}: identify_k must be true or false, got {self.identify_k!r}"
            )

    def units(self, model) -> tuple[str, ...]:
        self._check_joints(model)
        return ("A",) * model.n_dof

    def describe(self) -> str:
        k = ", torque constants identified" if self.identify_k else ""
        return (
            super()
            .describe()
            .replace(f"joint torques '{self.key}'", f"motor currents '{self.key}' (tau = k G i{k})", 1)
        )

    def k_names(self, model) -> tuple[str, ...]:
        """The names of the identified torque constants, ``<joint>.k`` (none without ``identify_k``)."""
        return tuple(f"{drive}.k" for drive in self.axes(model)) if self.identify_k else ()

    def _check_joints(self, model) -> None:
        if len(self.gear_ratio) != model.n_dof:
            raise DatasetError(
                f"motor-current channel {self.key!r} gives {len(self.gear_ratio)} gear ratios for "
                f"{model.n_dof} joints ({', '.join(model.joint_names)}); give one per joint"
            )

    def _extra_scale(self) -> np.ndarray:
        return 1.0 / (np.asarray(self.torque_constant) * np.asarray(self.gear_ratio))

    def transform(self) -> np.ndarray:
        """``diag(1 / (k G))``: joint torques into motor currents (``diag(1 / (k G)) C^T`` with a coupling)."""
        c = self.coupling_matrix()
        scale = np.diag(self._extra_scale())
        return scale if c is None else scale @ c.T

    def rows(self, model, q, qd, qdd) -> np.ndarray:
        self._check_joints(model)
        return super().rows(model, q, qd, qdd)

    def _record(self) -> dict:
        return {
            **super()._record(),
            "torque_constant": list(self.torque_constant),
            "gear_ratio": list(self.gear_ratio),
            **({"identify_k": True} if self.identify_k else {}),
        }  # written only when set (older records unchanged)


def _joint_types(model) -> tuple[str, ...]:
    types = getattr(model, "joint_types", None)
    return tuple(types) if types is not None else ("revolute",) * model.n_dof


def _tuple_or_none(x):
    return None if x is None else tuple(float(v) for v in x)
