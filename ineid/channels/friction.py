"""The actuation columns of a joint-torque channel: friction laws, armature, offsets, one drive at a time.

Per drive (a joint, or a motor of a coupled transmission, :mod:`ineid.channels.transmission`) with velocity
``v`` and acceleration ``a``, the columns and their coefficients are::

    fv   v                                   viscous, N*m*s/rad
    fc   c(v)                                Coulomb, N*m
    fs   exp(-(v / vs)^2) c(v)               Stribeck, N*m: the static friction's excess over fc
    offset  1                                a constant torque, N*m
    Ia   a                                   armature (rotor inertia through the gear), kg*m^2

with ``c(v) = sign(v)``, or ``tanh(v / zone)`` with a smooth zone (rad/s: the sigmoid models published
for real arms, ``2 / (1 + exp(-v / s)) - 1 = tanh(v / 2s)``, are this with ``zone = 2 s``). The Stribeck term
is the Gaussian form of Armstrong-Helouvry: with ``fc + fs`` the breakaway torque, the friction at rest is
``fc + fs`` and falls to ``fc`` above ``vs`` (rad/s, the Stribeck velocity). Each column is linear in its
coefficient at a given ``zone`` and ``vs``; :mod:`ineid.identify.friction_search` identifies either of them by a
1-D search. Asymmetric friction splits ``fv``, ``fc`` and ``fs`` into ``+`` and ``-`` columns: the positive and
the negative parts of the column.

References:
    Armstrong-Helouvry, Dupont, Canudas de Wit (1994), A survey of models, analysis tools and compensation
    methods for the control of machines with friction.
"""

from __future__ import annotations

import functools

FRICTION_TERMS = ("viscous", "coulomb", "stribeck")
"""The friction models a joint-torque channel knows, in the order of their columns."""
SHORT_NAMES = {"viscous": "fv", "coulomb": "fc", "stribeck": "fs"}
"""The coefficient name of each friction model (``<joint>.fv``, ...)."""
EXTRA_UNITS = {"fv": "N*m*s/rad", "fc": "N*m", "fs": "N*m", "offset": "N*m", "Ia": "kg*m^2", "k": "N*m/A"}
"""The units of each actuation coefficient of a revolute joint (:func:`extra_unit`)."""
PRISMATIC_UNITS = {"fv": "N*s/m", "fc": "N", "fs": "N", "offset": "N", "Ia": "kg", "k": "N/A"}


def extra_unit(name: str, joint_type: str = "revolute") -> str:
    """The unit of an actuation coefficient named ``<joint>.<term>`` (``fv``, ``fv+``, ``fc-``, ``fs``, ``Ia``, ...)."""
    term = name.rsplit(".", 1)[-1].rstrip("+-")
    return (PRISMATIC_UNITS if joint_type == "prismatic" else EXTRA_UNITS)[term]


def actuation_terms(
    friction: tuple[str, ...], asymmetric: bool, torque_offset: bool, armature: bool
) -> tuple[str, ...]:
    """The column terms of one drive, in order."""
    out: list[str] = []
    for kind in FRICTION_TERMS:
        if kind in friction:
            short = SHORT_NAMES[kind]
            out += [f"{short}+", f"{short}-"] if asymmetric else [short]
    if torque_offset:
        out.append("offset")
    if armature:
        out.append("Ia")
    return tuple(out)


def actuation_column(xp, term: str, qd, qdd, zone: float, stribeck: float = 0.0):
    """One actuation column of one drive from its velocity and acceleration (NumPy, jax.numpy or CasADi)."""
    if term == "fv":
        return qd
    if term == "offset":
        return xp.ones_like(qd) if hasattr(xp, "ones_like") else 1
    if term == "Ia":
        return qdd
    coulomb = xp.tanh(qd / zone) if zone > 0 else xp.sign(qd)
    if term.startswith("fs"):
        coulomb = xp.exp(-((qd / stribeck) ** 2)) * coulomb
    base = qd if term.startswith("fv") else coulomb
    if term in ("fc", "fs"):
        return coulomb
    positive = term.endswith("+")
    if hasattr(xp, "maximum"):
        return xp.maximum(base, 0) if positive else xp.minimum(base, 0)
    return xp.fmax(base, 0) if positive else xp.fmin(base, 0)


def drive_columns(xp, terms: tuple[str, ...], zone: float, stribeck: float, scale, to_drives, qd, qdd):
    """``E`` (..., n_a, n_a * len(terms)) from the joints' ``qd``, ``qdd`` (..., n_dof) with NumPy or jax.numpy:
    row ``j`` holds drive ``j``'s columns, each multiplied by ``scale[j]`` (None: 1). ``to_drives`` (n_a, n_dof)
    takes the joints' velocities and accelerations to the drives' (a coupled transmission's motors); None: the
    drives are the joints."""
    if to_drives is not None:
        m = xp.asarray(to_drives, dtype=qd.dtype)
        qd, qdd = qd @ m.T, qdd @ m.T
    batch, n_a = qd.shape[:-1], qd.shape[-1]
    cols = xp.stack(
        [xp.broadcast_to(actuation_column(xp, t, qd, qdd, zone, stribeck), batch + (n_a,)) for t in terms], -1
    )  # (..., n_a, n_terms)
    if scale is not None:
        cols = cols * xp.asarray(scale, dtype=cols.dtype)[:, None]
    eye = xp.eye(n_a, dtype=cols.dtype)
    return (eye[:, :, None] * cols[..., :, None, :]).reshape(batch + (n_a, n_a * len(terms)))


@functools.cache
def jax_extra(
    terms: tuple[str, ...],
    zone: float,
    stribeck: float,
    n_dof: int,
    scale: tuple | None,
    to_drives: tuple | None = None,
):
    """``E(q, qd, qdd)`` (..., n_a, n_a * len(terms)), jit-safe (:func:`drive_columns`; ``to_drives`` as nested
    tuples)."""
    import jax.numpy as jnp

    def extra(q, qd, qdd):
        batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
        qd, qdd = jnp.broadcast_to(qd, batch + (n_dof,)), jnp.broadcast_to(qdd, batch + (n_dof,))
        return drive_columns(jnp, terms, zone, stribeck, scale, to_drives, qd, qdd)

    return extra
