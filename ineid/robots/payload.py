"""Payloads: links welded to a moving link, identified on their own, in their own frame.

A link ``P`` welded (fixed or locked joints) to moving link ``B`` moves with ``B``: the
generated regressor has one 10-column block per moving body, for ``B`` with everything
welded to it folded in, ``theta_B = theta_rest + X_P theta_P`` (``X_P`` the 10 x 10 map of
``P``'s parameters about its origin, in its axes, to ``B``'s frame:
:func:`ineid.params.transform_matrix`). Naming ``P`` in ``unknown_links`` adds a parameter
block for it after ``B``'s: the model's parameters are then ``theta_ext`` with
``theta = M theta_ext`` (``M`` (10 n_dof, 10 n_ext), identity on the moving bodies, ``X_P``
from ``P``'s block into ``B``'s), the regressor is ``Psi M``, and ``B``'s block keeps its CAD
*without* ``P`` (``theta_rest``), known. Every evaluator of the model sees the extended
columns through :func:`payload_modules`, which wraps the generated modules, so solvers,
identifiability and datasets need no change.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ineid.errors import RobotModelError
from ineid.params import transform_matrix
from ineid.robots.chain import Chain


@dataclass(frozen=True, eq=False)
class Payload:
    """A welded link identified on its own: ``link`` welded to moving link ``body``;
    ``fold`` (10, 10) maps its parameters (about its origin, its axes) into ``body``'s."""

    link: str
    body: str
    fold: np.ndarray


def resolve_payloads(chain: Chain, unknown: Sequence[str], robot: str) -> tuple[Payload, ...]:
    """The payloads among ``unknown`` (names that are not moving links), checked.

    Raises:
        RobotModelError: a name is no link of a moving body (one line naming the choices), or a
            payload's body is unknown too, or another payload is welded to the same body (their
            parameters cannot be told apart).
    """
    moving = [j.link for j in chain.joints]
    payloads = []
    for name in unknown:
        if name in moving:
            continue
        link = chain.body_links.get(name)
        if link is None or not link.parent:
            welded = [b.name for b in chain.body_links.values() if b.parent]
            tared = name in chain.merged_links.get(chain.root_link, ())
            why = (f"link {name!r} is welded to the root link {chain.root_link!r}: its weight is tared with the "
                   "fixture" if tared else f"unknown link {name!r} is not a moving link of {robot}")
            payload_hint = f"; or a link welded to one, as a payload: {', '.join(welded)}" if welded else ""
            choices = ", ".join(moving) + payload_hint
            raise RobotModelError(f"{why}; choose from {choices}")
        if link.body in unknown:
            raise RobotModelError(
                f"payload link {name!r} is welded to {link.body!r}, which is unknown too: the data cannot tell their "
                f"parameters apart; name one of them in --unknown-links"
            )
        twin = next((p.link for p in payloads if p.body == link.body), None)
        if twin is not None:
            raise RobotModelError(
                f"payload links {twin!r} and {name!r} are both welded to {link.body!r}: the data cannot tell their "
                "parameters apart (they move as one body); name one of them in --unknown-links"
            )
        payloads.append(Payload(name, link.body, transform_matrix(link.body_R_link, link.body_p_link)))
    return tuple(payloads)


def extended_links(chain: Chain, payloads: Sequence[Payload]) -> tuple[str, ...]:
    """The model's links: the moving links in chain order, each followed by its payloads (URDF order)."""
    out = []
    for j in chain.joints:
        out.append(j.link)
        out.extend(p.link for p in payloads if p.body == j.link)
    return tuple(out)


def column_map(chain: Chain, payloads: Sequence[Payload]) -> np.ndarray:
    """``M`` (10 n_dof, 10 n_ext): ``theta = M theta_ext``, links as :func:`extended_links`."""
    moving = [j.link for j in chain.joints]
    links = extended_links(chain, payloads)
    by_link = {p.link: p for p in payloads}
    m = np.zeros((10 * len(moving), 10 * len(links)))
    for c, name in enumerate(links):
        body = moving.index(by_link[name].body if name in by_link else name)
        m[10 * body : 10 * body + 10, 10 * c : 10 * c + 10] = by_link[name].fold if name in by_link else np.eye(10)
    return m


def extended_theta_cad(chain: Chain, payloads: Sequence[Payload]) -> np.ndarray:
    """(10 n_ext,) CAD parameters: each payload its own ``<inertial>`` (its frame), each moving body
    its folded total less its payloads' share; ``column_map @ result`` is the chain's CAD."""
    parts = []
    for j in chain.joints:
        mine = [p for p in payloads if p.body == j.link]
        parts.append(j.theta - sum((p.fold @ chain.body_links[p.link].theta for p in mine), np.zeros(10)))
        parts.extend(chain.body_links[p.link].theta for p in mine)
    return np.concatenate(parts)


def payload_modules(jax_module, casadi_module, m: np.ndarray):
    """The generated modules seen through ``M``: ``(jax, casadi)`` with the same interface
    (``_temporaries``/``_entries``, ``NONZERO``, ``base_wrench``, ``base_wrench_regressor``,
    ``OP_COUNT``, ``KINEMATIC_FINGERPRINT``) over the extended columns. One pair of objects per
    modules and map, so compiled kernels keyed by module are shared by every such model."""
    return _wrapped(jax_module, casadi_module, tuple(map(tuple, np.asarray(m, dtype=np.float64))))


class _ModuleView:
    """A generated module seen through ``M`` (hashable by identity, like a module: it keys compile caches)."""

    def __init__(self, **attributes) -> None:
        self.__dict__.update(attributes)


@functools.lru_cache(maxsize=None)
def _wrapped(jax_module, casadi_module, m_rows: tuple):
    m = np.array(m_rows)
    n, n_ext = m.shape
    # per extended column: the original columns it combines, with their weights
    combos = [[(int(k), float(m[k, c])) for k in np.flatnonzero(m[:, c])] for c in range(n_ext)]
    nonzero = tuple(
        tuple(c for c in range(n_ext) if any(k in set(cols) for k, _ in combos[c]))
        for cols in jax_module.NONZERO
    )

    def temporaries(q, qd, qdd, gravity):
        return {"entries": jax_module._entries(**jax_module._temporaries(q, qd, qdd, gravity))}

    def entries(entries):
        out = []
        for r in range(6):
            for c in range(n_ext):
                terms = [w * entries[r * n + k] if w != 1.0 else entries[r * n + k] for k, w in combos[c]]
                terms = [t for t in terms if not (isinstance(t, (int, float)) and t == 0)]
                out.append(sum(terms[1:], terms[0]) if terms else 0)
        return tuple(out)

    def base_wrench_regressor(q, qd, qdd, gravity):
        return jax_module.base_wrench_regressor(q, qd, qdd, gravity) @ m

    def base_wrench(q, qd, qdd, gravity, theta):
        return jax_module.base_wrench(q, qd, qdd, gravity, theta @ m.T)

    jax_view = _ModuleView(
        __name__=f"{jax_module.__name__} (payload columns)", KINEMATIC_FINGERPRINT=jax_module.KINEMATIC_FINGERPRINT,
        OP_COUNT=jax_module.OP_COUNT, NONZERO=nonzero, _temporaries=temporaries, _entries=entries,
        base_wrench_regressor=base_wrench_regressor, base_wrench=base_wrench,
    )

    def casadi_regressor(q, qd, qdd, gravity):
        import casadi as ca  # noqa: PLC0415

        return casadi_module.base_wrench_regressor(q, qd, qdd, gravity) @ ca.DM(m)

    casadi_view = _ModuleView(
        __name__=f"{casadi_module.__name__} (payload columns)",
        KINEMATIC_FINGERPRINT=casadi_module.KINEMATIC_FINGERPRINT, base_wrench_regressor=casadi_regressor,
    )
    return jax_view, casadi_view
