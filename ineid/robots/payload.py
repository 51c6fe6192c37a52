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

from ineid.chain import Chain
from ineid.errors import RobotModelError
from ineid.params import transform_matrix


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
            why = (
                f"link {name!r} is welded to the root link {chain.root_link!r}: its weight is tared with the fixture"
                if tared
                else f"unknown link {name!r} is not a moving link of {robot}"
            )
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


def payload_modules(jax_module, casadi_module, chain: Chain, payloads: Sequence[Payload]):
    """The generated modules seen with the payloads as links of their own: ``(jax, casadi)``
    with the same interface (``program``, ``LINK_NAMES``, ``NONZERO``, ``OP_COUNT``,
    ``KINEMATIC_FINGERPRINT``, ``N_DOF``) over the extended links (:func:`extended_links`).

    The views' ``program`` inserts after each body ``B`` the outputs of a frame ``P`` welded to
    it at ``B_R_P, B_p_P = t``: ``base_R_P = base_R_B B_R_P``, ``base_p_P = base_p_B + base_R_B t``,
    ``w_P = B_R_P^T w_B``, ``wd_P = B_R_P^T wd_B``, ``a_P = B_R_P^T (a_B + wd_B x t + w_B x (w_B x t))``
    and ``Yn_P = Yn_B X_P`` (the columns of ``Psi M``). Every composition of
    :mod:`ineid.robots.program` (``Psi``, ``Psi theta``, link poses) then holds for the extended
    parameters. One pair of objects per modules and payloads, so compiled kernels keyed by
    module are shared by every such model.
    """
    moving = [j.link for j in chain.joints]
    spec = tuple(
        (
            moving.index(p.body),
            tuple(map(tuple, chain.body_links[p.link].body_R_link)),
            tuple(chain.body_links[p.link].body_p_link),
            tuple(map(tuple, p.fold)),
        )
        for p in payloads
    )
    m = column_map(chain, payloads)
    return _wrapped(jax_module, casadi_module, spec, extended_links(chain, payloads), tuple(map(tuple, m)))


class _ModuleView:
    """A generated module seen with its payloads (hashable by identity, like a module: it keys compile caches)."""

    def __init__(self, **attributes) -> None:
        self.__dict__.update(attributes)


_PER_LINK = ("R", "p", "w", "wd", "a", "Yn")


def _welded_outputs(out: dict, body: int, rotation, t, fold) -> dict:
    """The program outputs of a frame welded to link ``body`` (see :func:`payload_modules`)."""
    from ineid.robots.program import add, cross, matvec, mul

    r_b, w, wd, a = (out[k][body] for k in ("R", "w", "wd", "a"))
    rt = tuple(tuple(rotation[r][c] for r in range(3)) for c in range(3))  # B_R_P^T
    r_p = tuple(tuple(add(*(mul(r_b[r][k], rotation[k][c]) for k in range(3))) for c in range(3)) for r in range(3))
    p_p = tuple(add(x, y) for x, y in zip(out["p"][body], matvec(r_b, t), strict=True))
    a_origin = tuple(add(x, y, z) for x, y, z in zip(a, cross(wd, t), cross(w, cross(w, t)), strict=True))
    yn = tuple(tuple(add(*(mul(row[k], fold[k][c]) for k in range(10))) for c in range(10)) for row in out["Yn"][body])
    return {"R": r_p, "p": p_p, "w": matvec(rt, w), "wd": matvec(rt, wd), "a": matvec(rt, a_origin), "Yn": yn}


@functools.cache
def _wrapped(jax_module, casadi_module, spec: tuple, links: tuple[str, ...], m_rows: tuple):
    from ineid.robots.program import parents_of

    m = np.array(m_rows)
    n, n_ext = m.shape
    after = {}
    for body, rotation, t, fold in spec:
        after.setdefault(body, []).append((rotation, t, fold))

    def extended(program):
        def view(q, qd, qdd, gravity):
            out = program(q, qd, qdd, gravity)
            ext = {k: v for k, v in out.items() if k not in _PER_LINK}
            lists = {k: [] for k in _PER_LINK}
            for i in range(len(out["Yn"])):
                for k in _PER_LINK:
                    lists[k].append(out[k][i])
                for rotation, t, fold in after.get(i, ()):
                    welded = _welded_outputs(out, i, rotation, t, fold)
                    for k in _PER_LINK:
                        lists[k].append(welded[k])
            ext.update({k: tuple(v) for k, v in lists.items()})
            return ext

        return view

    body_of = tuple(
        int(np.flatnonzero(np.abs(m[:, 10 * c : 10 * c + 10]).sum(axis=1))[0]) // 10 for c in range(n_ext // 10)
    )  # each block's moving body
    # per extended column, the original columns it combines (the structural nonzeros of Psi M)
    sources = [set(np.flatnonzero(m[:, c]).tolist()) for c in range(n_ext)]
    nonzero = tuple(tuple(c for c in range(n_ext) if sources[c] & set(cols)) for cols in jax_module.NONZERO)

    def view_of(module, suffix):
        return _ModuleView(
            __name__=f"{module.__name__} ({suffix})",
            KINEMATIC_FINGERPRINT=module.KINEMATIC_FINGERPRINT,
            N_DOF=module.N_DOF,
            LINK_NAMES=links,
            OP_COUNT=getattr(module, "OP_COUNT", 0),
            NONZERO=nonzero,
            JOINT_TYPES=module.JOINT_TYPES,
            BODY_OF=body_of,
            PARENTS=parents_of(module),
            program=extended(module.program),
        )

    return view_of(jax_module, "payload links"), view_of(casadi_module, "payload links")
