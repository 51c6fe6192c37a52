"""Write a model's URDF with identified ``<inertial>`` elements.

An identified link's parameters describe everything rigidly attached to it (the URDF
links welded to it by fixed joints are folded in, as when the model was built). So the
link's ``<inertial>`` gets the identified body: mass, centre of mass (``origin xyz``, link
frame) and the inertia about the centre of mass *in link-frame axes* (``rpy="0 0 0"``,
whatever rotation the original had), and the ``<inertial>`` of each link welded to it is
removed, with a comment, so nothing is counted twice. A payload (a welded link identified on
its own, :mod:`ineid.robots.payload`) gets its own ``<inertial>`` back, in its own frame, and
nothing else changes. Floats are written with ``repr``,
which reads back bit for bit.

Names (robots, links, joints) stay where ElementTree escapes them, in attributes; the
comments ineid adds hold none (an XML comment cannot escape ``--``), and the text
written is parsed back before it is returned.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ineid._atomic import atomic_write, check_output
from ineid.errors import IdentificationError, RobotModelError
from ineid.params import inertial_from_theta, physical_violations


def urdf_with_inertials(urdf_text: str, theta_by_link: dict[str, np.ndarray], locked_joints=None) -> str:
    """The URDF text with the given links' inertials replaced.

    Args:
        urdf_text: the model's URDF.
        theta_by_link: ``{link: (10,) parameters}`` about the link origin, link frame (a moving
            link with what is welded to it, or a payload link alone).
        locked_joints: as when the model was loaded (for the welded-link bookkeeping).

    Raises:
        IdentificationError: a link's parameters are not a rigid body (a URDF cannot hold
            them; identify with the consistent method).
        RobotModelError: a link is not a moving link of the URDF.
    """
    from ineid.robots.urdf import parse_chain

    chain = parse_chain(urdf_text, locked_joints=locked_joints or None)
    moving = {j.link for j in chain.joints}
    payloads = {b.name for b in chain.body_links.values() if b.parent}
    bad = []
    for link, theta in theta_by_link.items():
        if link not in moving | payloads:
            raise RobotModelError(
                f"{link!r} is not a moving link of the URDF ({', '.join(sorted(moving))}) nor a link welded to one"
            )
        problems = physical_violations(np.asarray(theta, dtype=np.float64), rtol=0.0)
        if problems:
            bad.append(f"link {link!r} ({'; '.join(problems)})")
    if bad:
        raise IdentificationError(
            f"the estimate is not a rigid body for {len(bad)} of {len(theta_by_link)} links, {', '.join(bad)}; "
            "a URDF cannot hold it: identify with --method consistent (physically consistent by construction)",
            status="non_physical",
        )
    root = ET.fromstring(urdf_text)
    links = {el.get("name"): el for el in root.findall("link")}
    for link, theta in theta_by_link.items():
        m, c, ic = inertial_from_theta(np.asarray(theta, dtype=np.float64))
        el = links[link]
        old = el.find("inertial")
        index = list(el).index(old) if old is not None else 0
        if old is not None:
            el.remove(old)
        inertial = ET.Element("inertial")
        ET.SubElement(inertial, "origin", xyz=" ".join(repr(float(v)) for v in c), rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=repr(float(m)))
        ET.SubElement(
            inertial,
            "inertia",
            ixx=repr(float(ic[0, 0])),
            ixy=repr(float(ic[0, 1])),
            ixz=repr(float(ic[0, 2])),
            iyy=repr(float(ic[1, 1])),
            iyz=repr(float(ic[1, 2])),
            izz=repr(float(ic[2, 2])),
        )
        el.insert(index, ET.Comment(" identified by ineid (mass, centre of mass, inertia about it in link axes) "))
        el.insert(index + 1, inertial)
        if link in payloads:  # a payload's own inertial, in its frame: its body and the rest stay as they are
            continue
        for welded in chain.merged_links.get(link, (link,))[1:]:
            w_el = links.get(welded)
            w_old = w_el.find("inertial") if w_el is not None else None
            if w_old is not None:
                w_el.remove(w_old)
                w_el.insert(0, ET.Comment(" inertial folded by ineid into the identified link this one is welded to "))
    ET.indent(root, space="  ")
    text = '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    _check_same_names(urdf_text, text)
    return text


def _check_same_names(before: str, after: str) -> None:
    """The written URDF parses and names the same links and joints as the original (defence in depth)."""

    def names(text: str) -> list[tuple[str, str | None]]:
        root = ET.fromstring(text)
        return [(el.tag, el.get("name")) for el in root if el.tag in ("link", "joint")]

    try:
        same = names(after) == names(before)
    except ET.ParseError:
        same = False
    if not same:
        raise RobotModelError(
            "the exported URDF would not read back with the original's links and joints; "
            "nothing was written (please report this)"
        )


def export_urdf(results, config: int, out: str | Path, overwrite: bool = False) -> Path:
    """Write ``results``' model with configuration ``config``'s estimates to ``out``.

    Args:
        results: a :class:`ineid.identify.solve.SolveResults` (or its file's contents).
        config: the configuration's index in the dataset (``config_index``).
        out: the ``.urdf`` file to write (atomically).
    """
    out = Path(out)
    check_output(out, overwrite)
    text = urdf_with_inertials(results.meta["urdf"], estimate_of(results, config), results.meta.get("locked_joints"))
    return atomic_write(out, text)


def estimate_of(results, config: int) -> dict[str, np.ndarray]:
    """``{link: (10,) parameters}`` of configuration ``config``'s identified links (what an export writes).

    Raises:
        IdentificationError: the configuration is not in the results, or was not identified.
    """
    rows = np.flatnonzero(np.asarray(results.config_index) == config)
    if rows.size == 0:
        shown = ", ".join(str(i) for i in results.config_index[:8]) + (", ..." if results.n > 8 else "")
        raise IdentificationError(f"configuration {config} is not in the results (solved: {shown})", status="missing")
    i = int(rows[0])
    if not results.success[i]:
        raise IdentificationError(
            f"configuration {config} was not identified ({results.status[i]}); nothing to export",
            status=str(results.status[i]),
        )
    theta = results.theta_links[i].reshape(-1, 10)  # the links only: extra parameters (friction...) are no URDF
    return dict(zip(results.meta["unknown_links"], theta, strict=True))
