"""Parsed URDFs remembered in the cache folder: one JSON file per URDF text and choice of locked joints.

A parse with yourdfpy costs about half a second (its trimesh import); a chain read back from
here costs milliseconds. Entries are data, not code, under the same ownership and permission
rule as the generated code (:mod:`ineid._trust`); a damaged or unsound entry is parsed again.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path

import numpy as np

from ineid.chain import BodyLink, Chain, JointSpec

CHAIN_SUBDIR = "chains"
"""Parsed URDFs live in ``cache_dir() / CHAIN_SUBDIR`` as JSON, one file per URDF text."""

_PARSER_FILES = (
    "urdf.py",
    "urdf_checks.py",
    "robot_files.py",
    "inertial.py",
    "cad_rounding.py",
    "../chain.py",
    "urdf_cache.py",
)
"""The modules a parse depends on (paths from this folder): a change to any of them parses every URDF again."""


def chain_key(data: bytes, source: str, locked_joints: Mapping[str, float] | None) -> str:
    """Hash of what a parse depends on: the parser's code, the URDF bytes, the source
    name (a nameless ``<robot>`` is named after it) and the locked joints; the key of
    :func:`cached_chain`, :func:`chain_file` and :func:`store_chain`."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha256(b"".join((here / name).read_bytes() for name in _PARSER_FILES))
    h.update(json.dumps([source, sorted((str(k), float(v)) for k, v in (locked_joints or {}).items())]).encode())
    h.update(data)
    return h.hexdigest()[:32]


def chain_file(key: str) -> Path:
    """The cache file of the chain parsed under ``key`` (:func:`chain_key`), in the private cache folder."""
    from ineid.cache import private_folder

    return private_folder(CHAIN_SUBDIR) / f"{key}.json"


_ARRAY_FIELDS = ("parent_R_joint", "parent_p_joint", "axis", "theta")
_ARRAY_SHAPES = {"parent_R_joint": (3, 3), "parent_p_joint": (3,), "axis": (3,), "theta": (10,)}
_LINK_ARRAYS = {"body_R_link": (3, 3), "body_p_link": (3,), "theta": (10,)}


def cached_chain(key: str) -> Chain | None:
    """The chain parsed earlier under ``key``, or None (not parsed yet, or an unreadable file).

    Like code, it is read only from a private cache folder (:mod:`ineid._trust`), and only
    when the file is owned by you and not writable by others.
    """
    import logging

    from ineid._inputs import parse_json
    from ineid._trust import Untrusted, read_checked

    path = chain_file(key)
    try:
        doc = parse_json(read_checked(path, private=True))  # nested too deep: a ValueError, parsed again
        joints = tuple(
            JointSpec(**{**j, **{k: np.asarray(j[k], dtype=np.float64) for k in _ARRAY_FIELDS}}) for j in doc["joints"]
        )
        links = {
            name: BodyLink(**{**b, **{k: np.asarray(b[k], dtype=np.float64) for k in _LINK_ARRAYS}})
            for name, b in doc["body_links"].items()
        }
        chain = Chain(
            doc["name"],
            doc["root_link"],
            joints,
            {k: tuple(v) for k, v in doc["merged_links"].items()},
            links,
            tuple(doc["notes"]),
            tuple(doc["parents"]),
        )
    except Untrusted as e:  # e.reason: "has a file that is writable by group or others (<file>)"
        # logged under the parser's name: the warning is what a URDF's parse meets
        logging.getLogger("ineid.robots.urdf").warning(
            "the cache of parsed URDFs in %s %s; parsing the URDF again", path.parent, e.reason
        )
        return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not _sound(chain):  # a damaged entry (disk, hand edit): parse the URDF again, which rewrites it
        return None
    return chain


def _sound(chain: Chain) -> bool:
    """Whether a chain read back from the cache has the types, shapes and finite values a parse gives."""
    if not chain.joints or not all(isinstance(v, str) for v in (chain.name, chain.root_link)):
        return False
    for j in chain.joints:
        if not all(isinstance(v, str) for v in (j.name, j.type, j.link)) or not isinstance(j.continuous, bool):
            return False
        if any(
            getattr(j, k).shape != shape or not np.all(np.isfinite(getattr(j, k))) for k, shape in _ARRAY_SHAPES.items()
        ):
            return False
        bounds = (j.q_lower, j.q_upper, j.qd_max, j.qdd_max)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and not np.isnan(v) for v in bounds):
            return False
    for name, b in chain.body_links.items():
        if not all(isinstance(v, str) for v in (b.name, b.body, b.parent)) or b.name != name:
            return False
        if any(
            getattr(b, k).shape != shape or not np.all(np.isfinite(getattr(b, k))) for k, shape in _LINK_ARRAYS.items()
        ):
            return False
    return all(isinstance(n, str) for n in chain.notes)


def store_chain(key: str, chain: Chain) -> None:
    """Remember a parsed chain (JSON: floats round-trip exactly); a read-only cache is skipped."""
    from ineid._atomic import atomic_write

    joints = [
        {
            f.name: (getattr(j, f.name).tolist() if f.name in _ARRAY_FIELDS else getattr(j, f.name))
            for f in fields(JointSpec)
        }
        for j in chain.joints
    ]
    links = {
        name: {
            f.name: (getattr(b, f.name).tolist() if f.name in _LINK_ARRAYS else getattr(b, f.name))
            for f in fields(BodyLink)
        }
        for name, b in chain.body_links.items()
    }
    doc = {
        "name": chain.name,
        "root_link": chain.root_link,
        "joints": joints,
        "merged_links": {k: list(v) for k, v in chain.merged_links.items()},
        "body_links": links,
        "notes": list(chain.notes),
        "parents": list(chain.parents),
    }
    path = chain_file(key)
    try:
        atomic_write(path, json.dumps(doc))
    except OSError:
        pass
