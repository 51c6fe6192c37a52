"""A URDF's elements checked before yourdfpy reads them: names, counts, and every number ineid reads.

yourdfpy turns ``nan`` and ``inf`` into floats without a word, reports a missing name as a bare
``KeyError``, keeps the last of two elements with one name, and hides its XML parser's refusals
(lxml's limits: a text node over 10 MB, elements nested over 256 deep) behind a ``TypeError``.
So ineid reads the tree ElementTree built first, and asks lxml itself, and each refusal is one
:class:`~ineid.errors.RobotModelError` line naming the joint or link, the attribute, its value
and the fix (the counts: :class:`~ineid.errors.InputFileError`, :mod:`ineid.robots.robot_files`).

The numbers: a joint's ``<origin xyz rpy>``, ``<axis xyz>``, ``<limit lower upper velocity effort>``,
``<mimic multiplier offset>`` and ``<ineid acceleration>``; a link's ``<inertial>`` (``origin``,
``mass``, ``inertia``) and ``<collision>`` (``origin``, the geometry's sizes). Each must be a
finite number; ``velocity``, ``effort`` and ``acceleration`` must not be negative. An absent
attribute keeps its default (a missing velocity: :data:`ineid.robots.urdf.DEFAULT_QD_MAX`), and so
does ``velocity="0"`` or ``effort="0"``, which URDF writers put for "not given" (34 joints of
example-robot-data, Kinova's among them).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from ineid.errors import RobotModelError
from ineid.robots.robot_files import check_counts

_ORIGIN = {"xyz": 3, "rpy": 3}
_JOINT_NUMBERS = {
    "origin": _ORIGIN,
    "axis": {"xyz": 3},
    "limit": {"lower": 1, "upper": 1, "velocity": 1, "effort": 1},
    "mimic": {"multiplier": 1, "offset": 1},
    "ineid": {"acceleration": 1},
}
"""Per child element of a ``<joint>``: its numeric attributes and how many numbers each holds."""
_LINK_NUMBERS = {
    "inertial/origin": _ORIGIN,
    "inertial/mass": {"value": 1},
    "inertial/inertia": dict.fromkeys(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), 1),
    "collision/origin": _ORIGIN,
    "collision/geometry/box": {"size": 3},
    "collision/geometry/cylinder": {"radius": 1, "length": 1},
    "collision/geometry/sphere": {"radius": 1},
    "collision/geometry/mesh": {"scale": None},
}
"""Per element path under a ``<link>``: its numeric attributes (None: any count)."""
_NOT_NEGATIVE = {
    ("limit", "velocity"): "the joint's speed limit",
    ("limit", "effort"): "the joint's force or torque limit",
    ("ineid", "acceleration"): "the joint's acceleration limit",
}
"""The attributes that are limits: a negative value is a mistake (0 is "not given", as URDF writers use it)."""


def check_urdf_tree(root: ET.Element, source: str) -> None:
    """Names, counts and numbers of a URDF (module doc), before yourdfpy reads it.

    Raises:
        RobotModelError: a nameless or twice-named link or joint, a joint without parent or child, a
            number that is not one, not finite, or negative where a limit is.
        InputFileError: more links or joints than :mod:`ineid.robots.robot_files` allows.
    """
    links, joints = root.findall("link"), root.findall("joint")
    check_counts(source, "links", len(links), len(joints))
    for tag, elements in (("link", links), ("joint", joints)):
        seen: set[str] = set()
        for el in elements:
            name = el.get("name")
            if name is None:
                raise RobotModelError(f"{source}: a <{tag}> element has no name attribute")
            if name in seen:
                raise RobotModelError(
                    f"{source}: two <{tag}> elements are named {name!r}; give every {tag} its own name"
                )
            seen.add(name)
    for j in joints:
        for sub, attrs in _JOINT_NUMBERS.items():
            for el in j.findall(sub):
                _check_numbers(el, sub, attrs, f"joint {j.get('name')!r}", source)
        for sub in ("parent", "child"):
            s = j.find(sub)
            if s is None or s.get("link") is None:
                raise RobotModelError(f"{source}: joint {j.get('name')!r} has no <{sub} link=...>")
    for link in links:
        for sub, attrs in _LINK_NUMBERS.items():
            for el in link.findall(sub):
                _check_numbers(el, sub, attrs, f"link {link.get('name')!r}", source)


def _check_numbers(el: ET.Element, path: str, attrs: dict[str, int | None], owner: str, source: str) -> None:
    """Each attribute of ``attrs`` present on ``el`` holds that many finite numbers (non-negative where a limit)."""
    tag = path.rsplit("/", 1)[-1]
    shown = "><".join(path.split("/"))
    for attr, count in attrs.items():
        text = el.get(attr)
        if text is None:
            continue
        where = f"{source}: {owner}: <{shown} {attr}={text!r}>"
        want = "a number" if count == 1 else f"{count} numbers" if count else "numbers"
        try:
            values = [float(v) for v in text.split()]
        except ValueError:
            raise RobotModelError(f"{where} is not {want}; give {want}") from None
        if not values or (count is not None and len(values) != count):
            raise RobotModelError(f"{where} holds {len(values)} numbers; give {count}")
        if not all(math.isfinite(v) for v in values):
            raise RobotModelError(f"{where} holds a non-finite value (nan or inf); give finite numbers")
        meaning = _NOT_NEGATIVE.get((tag, attr))
        if meaning and values[0] < 0:
            raise RobotModelError(
                f"{where} is negative; give {meaning} (a positive number), or leave the attribute "
                "out for ineid's default"
            )


def check_lxml(data: bytes, source: str) -> None:
    """lxml, with the parser yourdfpy uses (default limits), reads ``data``; else one line with lxml's reason.

    Raises:
        RobotModelError: lxml refuses the XML (a text node over 10 MB, elements nested over 256 deep...).
    """
    from lxml import etree

    try:
        etree.fromstring(data, parser=etree.XMLParser(remove_blank_text=True))
    except etree.XMLSyntaxError as e:
        raise RobotModelError(
            f"{source}: lxml, yourdfpy's XML parser, cannot read the URDF ({e}); remove what no "
            "URDF reader needs (huge comments or text, deep nesting)"
        ) from None
