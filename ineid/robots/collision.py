"""Bounding capsules of a chain's bodies from the URDF's ``<collision>`` geometry, and capsule distances.

Each ``<collision>`` element of a link becomes one capsule (a segment and a radius) that
contains it, fixed in the body it is merged into (the moving link, or the root body for
what is welded to the fixture): a sphere is a capsule of zero length; a cylinder the
capsule along its axis with its radius and length; a box, or a mesh's axis-aligned bounds
(read with trimesh, which yourdfpy installs), the capsule along the longest side whose
radius is the half-diagonal of the other two. A mesh that cannot be read is skipped and
said so (:attr:`BodyCapsules.notes`), as is a link with no collision geometry.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ineid.chain import Chain
from ineid.robots.kinematics import parse_floats, rpy_rotation, welded_poses


@dataclass(frozen=True)
class Capsule:
    """Points within ``radius`` (m) of the segment ``a``-``b`` (m) in body ``link``'s frame (-1: the root body)."""

    link: int
    a: np.ndarray
    b: np.ndarray
    radius: float
    name: str
    shape: str


@dataclass
class BodyCapsules:
    """The capsules of a chain, and what had none (one line each)."""

    capsules: list[Capsule] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _box_capsule(center: np.ndarray, rot: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The capsule along the longest side of a box (``size`` full lengths, axes ``rot``, centre ``center``)."""
    k = int(np.argmax(size))
    others = [i for i in range(3) if i != k]
    half = 0.5 * rot[:, k] * size[k]
    return center - half, center + half, 0.5 * float(np.hypot(size[others[0]], size[others[1]]))


def _mesh_bounds(filename: str, urdf_path: Path | None) -> np.ndarray | None:
    """(2, 3) axis-aligned bounds of a mesh file, or None when it cannot be found or read."""
    rel = filename
    if rel.startswith("file://"):
        rel = rel[len("file://") :]
    candidates = []
    if rel.startswith("package://"):
        pkg_path = rel[len("package://") :]
        package, _, rest = pkg_path.partition("/")
        if urdf_path is not None:
            for anc in urdf_path.resolve().parents:
                candidates += [anc / package / rest, anc / rest]
    elif Path(rel).is_absolute():
        candidates.append(Path(rel))
    elif urdf_path is not None:
        candidates.append(urdf_path.resolve().parent / rel)
    path = next((c for c in candidates if c.is_file()), None)
    if path is None:
        return None
    try:
        import trimesh

        mesh = trimesh.load(str(path), force="mesh")
        bounds = np.asarray(mesh.bounds, dtype=np.float64)
    except Exception:  # any unreadable mesh is skipped and reported
        return None
    return bounds if bounds.shape == (2, 3) and np.all(np.isfinite(bounds)) else None


def body_capsules(urdf_text: str, chain: Chain, urdf_path: Path | None = None, locked_joints=None) -> BodyCapsules:
    """The bounding capsules of every body of ``chain`` (module doc), in their body's frame."""
    poses = welded_poses(urdf_text, chain, locked_joints)
    out = BodyCapsules()
    for link in ET.fromstring(urdf_text).findall("link"):
        name = link.get("name")
        if name not in poses:
            continue
        k, body_r, body_p = poses[name]
        elements = link.findall("collision")
        if not elements:
            if k >= 0 and name == chain.joints[k].link:
                out.notes.append(f"link {name!r} has no collision geometry")
            continue
        for el in elements:
            origin = el.find("origin")
            r = body_r @ rpy_rotation(parse_floats(origin.get("rpy") if origin is not None else None, (0, 0, 0)))
            c = body_p + body_r @ parse_floats(origin.get("xyz") if origin is not None else None, (0, 0, 0))
            geom = el.find("geometry")
            shape = next(iter(geom), None) if geom is not None else None
            tag = shape.tag if shape is not None else ""
            if tag == "sphere":
                a, b, rad = c, c, float(shape.get("radius"))
            elif tag == "cylinder":
                half = 0.5 * float(shape.get("length")) * r[:, 2]
                a, b, rad = c - half, c + half, float(shape.get("radius"))
            elif tag == "box":
                a, b, rad = _box_capsule(c, r, parse_floats(shape.get("size"), (0, 0, 0)))
            elif tag == "mesh":
                bounds = _mesh_bounds(shape.get("filename", ""), urdf_path)
                if bounds is None:
                    out.notes.append(f"link {name!r}: mesh {shape.get('filename')!r} not readable, skipped")
                    continue
                bounds = bounds * parse_floats(shape.get("scale"), (1, 1, 1))
                lo, hi = bounds.min(axis=0), bounds.max(axis=0)
                a, b, rad = _box_capsule(c + r @ (0.5 * (lo + hi)), r, hi - lo)
            else:
                out.notes.append(f"link {name!r}: collision geometry {tag or 'missing'!r} not understood, skipped")
                continue
            out.capsules.append(Capsule(k, np.asarray(a, float), np.asarray(b, float), rad, name, tag))
    return out


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray):
    """Closest points of segments ``p1-q1`` and ``p2-q2`` (..., 3) each (degenerate ones allowed).

    Returns:
        ``(d, c1, c2)``: (...,) distances and (..., 3) the closest points on each segment
        (:func:`closest_on_segments`).
    """
    return closest_on_segments(p1, q1 - p1, p2, q2 - p2)


def closest_on_segments(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray):
    """Closest points of the segments ``p1 + s d1`` and ``p2 + t d2``, ``s, t`` in [0, 1] ((..., 3) each).

    Ericson (Real-Time Collision Detection, 5.1.9), vectorised: the minimiser of
    ``|p1 + s d1 - p2 - t d2|^2`` without bounds, ``s`` clamped to [0, 1], the best ``t`` for it clamped,
    then the best ``s`` for that ``t`` clamped (which leaves ``s`` as it is unless ``t`` was clamped). A
    degenerate segment (a point) takes parameter 0; parallel segments take ``s = 0`` first.

    Returns:
        ``(d, c1, c2)``: (...,) distances and (..., 3) the closest points on each segment.
    """
    r = p1 - p2
    a = np.einsum("...i,...i", d1, d1)
    e = np.einsum("...i,...i", d2, d2)
    b = np.einsum("...i,...i", d1, d2)
    c = np.einsum("...i,...i", d1, r)
    f = np.einsum("...i,...i", d2, r)
    tiny = 1e-18
    on_a, on_e = a > tiny, e > tiny  # not points
    denom = a * e - b * b
    crossing = denom > tiny * np.maximum(a * e, tiny)  # not parallel
    s = np.where(crossing, np.clip((b * f - c * e) / np.where(crossing, denom, 1.0), 0.0, 1.0), 0.0)
    t = np.where(on_e, np.clip((b * s + f) / np.where(on_e, e, 1.0), 0.0, 1.0), 0.0)
    s = np.where(on_a, np.clip((b * t - c) / np.where(on_a, a, 1.0), 0.0, 1.0), 0.0)
    c1 = p1 + d1 * s[..., None]
    c2 = p2 + d2 * t[..., None]
    diff = c1 - c2
    return np.sqrt(np.einsum("...i,...i", diff, diff)), c1, c2
