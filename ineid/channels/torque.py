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
and negative parts of ``tanh``), all four positive for a passive drive.

:class:`MotorCurrent` is the same model read through the drive: ``i_j = tau_j / (k_j G_j)``
with the torque constant ``k_j`` (N*m/A, motor side) and gear ratio ``G_j`` given, so its
``T = diag(1 / (k G))`` and the actuation coefficients keep their joint-side units. With
``identify_k`` the torque constants are identified as well (``<joint>.k``, N*m/A, around the given
ones), in the second of two steps (:mod:`ineid.identify.two_step`).

References:
    Atkeson, An, Hollerbach (1986): linearity in the parameters.
    Khalil, Dombre (2002), Modeling, Identification and Control of Robots, ch. 12 (friction, offsets, armature).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ineid.channels.base import Channel, register
from ineid.errors import DatasetError

FRICTION_TERMS = ("viscous", "coulomb")
"""The friction models a joint-torque channel knows, in the order of their columns."""
EXTRA_UNITS = {"fv": "N*m*s/rad", "fc": "N*m", "offset": "N*m", "Ia": "kg*m^2", "k": "N*m/A"}
"""The units of each actuation coefficient of a revolute joint (:func:`extra_unit`)."""
_PRISMATIC_UNITS = {"fv": "N*s/m", "fc": "N", "offset": "N", "Ia": "kg", "k": "N/A"}


def extra_unit(name: str, joint_type: str = "revolute") -> str:
    """The unit of an actuation coefficient named ``<joint>.<term>`` (``fv``, ``fv+``, ``fc-``, ``Ia``, ...)."""
    term = name.rsplit(".", 1)[-1].rstrip("+-")
    return (_PRISMATIC_UNITS if joint_type == "prismatic" else EXTRA_UNITS)[term]


def _terms(friction: tuple[str, ...], asymmetric: bool, torque_offset: bool, armature: bool) -> tuple[str, ...]:
    """The column terms of one joint, in order."""
    out: list[str] = []
    for kind, short in (("viscous", "fv"), ("coulomb", "fc")):
        if kind in friction:
            out += [f"{short}+", f"{short}-"] if asymmetric else [short]
    if torque_offset:
        out.append("offset")
    if armature:
        out.append("Ia")
    return tuple(out)


def _column(xp, term: str, qd, qdd, zone: float):
    """One actuation column of one joint from its velocity and acceleration (NumPy, jax.numpy or CasADi)."""
    if term == "fv":
        return qd
    if term == "offset":
        return xp.ones_like(qd) if hasattr(xp, "ones_like") else 1
    if term == "Ia":
        return qdd
    coulomb = xp.tanh(qd / zone) if zone > 0 else xp.sign(qd)
    base = qd if term.startswith("fv") else coulomb
    if term == "fc":
        return coulomb
    positive = term.endswith("+")
    if hasattr(xp, "maximum"):
        return xp.maximum(base, 0) if positive else xp.minimum(base, 0)
    return xp.fmax(base, 0) if positive else xp.fmin(base, 0)


@register
@dataclass(frozen=True, kw_only=True)
class JointTorque(Channel):
    """The torque (force, prismatic) each joint's actuator applies, with its actuation model (module docstring).

    Attributes:
        key: where its values are stored (default ``"tau"``), (C, F, n_dof), N*m or N.
        friction: the friction terms identified, any of :data:`FRICTION_TERMS` (in that order).
        coulomb_zone: rad/s (m/s): 0 gives ``sign(qd)``; above 0, ``tanh(qd / zone)``.
        asymmetric: one viscous and one Coulomb coefficient per direction of motion.
        armature: the rotor inertia ``<joint>.Ia`` (times ``qdd``) is identified.
        torque_offset: a constant ``<joint>.offset`` per joint is identified (a column of ones; unlike
            ``offsets``, which removes constants by centring, it is reported with its std).
        offsets: per-axis constants removed by centring (as for a wrench), named ``<key>.<joint>.offset``.
    """

    key: str = "tau"
    friction: tuple[str, ...] = ()
    coulomb_zone: float = 0.0
    asymmetric: bool = False
    armature: bool = False
    torque_offset: bool = False

    kind = "joint_torque"
    RECORD_FIELDS = ("friction", "coulomb_zone", "asymmetric", "armature", "torque_offset")

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
        zone = self.coulomb_zone
        if isinstance(zone, bool) or not isinstance(zone, (int, float)) or not math.isfinite(zone) or zone < 0:
            raise DatasetError(
                f"joint-torque channel {self.key!r}: the Coulomb zone must be a finite number >= 0 "
                f"(rad/s; 0 for sign(qd)), got {zone!r}"
            )
        object.__setattr__(self, "coulomb_zone", float(zone))
        for name in ("asymmetric", "armature", "torque_offset"):
            if not isinstance(getattr(self, name), bool):
                raise DatasetError(
                    f"joint-torque channel {self.key!r}: {name} must be true or false, got {getattr(self, name)!r}"
                )

    # -- what it measures ------------------------------------------------------------------
    def axes(self, model) -> tuple[str, ...]:
        return tuple(model.joint_names)

    def units(self, model) -> tuple[str, ...]:
        return tuple("N" if t == "prismatic" else "N*m" for t in _joint_types(model))

    def describe(self) -> str:
        parts = []
        if self.friction:
            zone = (
                f", smooth zone {self.coulomb_zone:g} rad/s" if self.coulomb_zone and "coulomb" in self.friction else ""
            )
            parts.append(("asymmetric " if self.asymmetric else "") + " + ".join(self.friction) + " friction" + zone)
        if self.armature:
            parts.append("armature")
        if self.torque_offset:
            parts.append("torque offsets")
        if self.offsets:
            parts.append("offsets removed by centring")
        return f"joint torques '{self.key}'" + (f" ({'; '.join(parts)})" if parts else "")

    @property
    def terms(self) -> tuple[str, ...]:
        """The actuation columns of each joint, in order (``"fv"``, ``"fc"``, ``"offset"``, ``"Ia"``, ...)."""
        return _terms(self.friction, self.asymmetric, self.torque_offset, self.armature)

    def with_actuation(
        self,
        friction=(),
        coulomb_zone: float = 0.0,
        asymmetric: bool = False,
        armature: bool = False,
        torque_offset: bool = False,
    ) -> JointTorque:
        """The same measurement identified with another actuation model."""
        from dataclasses import replace

        return replace(
            self,
            friction=tuple(friction),
            coulomb_zone=coulomb_zone,
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
        return tuple(f"{joint}.{term}" for joint in model.joint_names for term in self.terms)

    def extra_units(self, model) -> tuple[str, ...]:
        """The unit of each extra column's coefficient (:func:`extra_unit`)."""
        return tuple(extra_unit(term, t) for t in _joint_types(model) for term in self.terms)

    def _extra_scale(self) -> np.ndarray | None:
        """Per axis, the factor the reading applies to a joint-side torque (None: 1)."""
        return None

    def extra_rows_function(self, model):
        if not self.terms:
            return None
        return _jax_extra(self.terms, self.coulomb_zone, model.n_dof, _tuple_or_none(self._extra_scale()))

    def casadi_extra_function(self, model):
        if not self.terms:
            return None
        import casadi as ca

        n, terms = model.n_dof, self.terms
        q, qd, qdd = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd"))
        e = ca.SX.zeros(n, n * len(terms))
        scale = self._extra_scale()
        for j in range(n):
            for k, term in enumerate(terms):
                col = _column(ca, term, qd[j], qdd[j], self.coulomb_zone)
                e[j, j * len(terms) + k] = col if scale is None else scale[j] * col
        return ca.Function("actuation_rows", [q, qd, qdd], [e], ["q", "qd", "qdd"], ["E"])

    # -- record ---------------------------------------------------------------------------
    def _record(self) -> dict:
        return {
            "friction": list(self.friction),
            "coulomb_zone": self.coulomb_zone,
            "asymmetric": self.asymmetric,
            "armature": self.armature,
            "torque_offset": self.torque_offset,
        }

    @classmethod
    def _parse_record(cls, d: Mapping, where: str) -> dict:
        out = {name: d[name] for name in cls.RECORD_FIELDS if name in d}
        if "friction" in out:
            if not isinstance(out["friction"], list):
                raise DatasetError(
                    f"{where}: the joint-torque channel's friction must be a list, got {out['friction']!r}"
                )
            out["friction"] = tuple(out["friction"])
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
        return tuple(f"{joint}.k" for joint in model.joint_names) if self.identify_k else ()

    def _check_joints(self, model) -> None:
        if len(self.gear_ratio) != model.n_dof:
            raise DatasetError(
                f"motor-current channel {self.key!r} gives {len(self.gear_ratio)} gear ratios for "
                f"{model.n_dof} joints ({', '.join(model.joint_names)}); give one per joint"
            )

    def _extra_scale(self) -> np.ndarray:
        return 1.0 / (np.asarray(self.torque_constant) * np.asarray(self.gear_ratio))

    def transform(self) -> np.ndarray:
        """``diag(1 / (k G))``: joint torques into motor currents."""
        return np.diag(self._extra_scale())

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


@functools.cache
def _jax_extra(terms: tuple[str, ...], zone: float, n_dof: int, scale: tuple | None):
    """``E(q, qd, qdd)`` (..., n_dof, n_dof * len(terms)), jit-safe: row ``j`` holds joint ``j``'s columns."""
    import jax.numpy as jnp

    def extra(q, qd, qdd):
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        qd, qdd = jnp.broadcast_to(qd, batch + (n_dof,)), jnp.broadcast_to(qdd, batch + (n_dof,))
        cols = jnp.stack(
            [jnp.broadcast_to(_column(jnp, t, qd, qdd, zone), batch + (n_dof,)) for t in terms], -1
        )  # (..., n_dof, n_terms)
        if scale is not None:
            cols = cols * jnp.asarray(scale, dtype=cols.dtype)[:, None]
        eye = jnp.eye(n_dof, dtype=cols.dtype)
        return (eye[:, :, None] * cols[..., :, None, :]).reshape(batch + (n_dof, n_dof * len(terms)))

    return extra
