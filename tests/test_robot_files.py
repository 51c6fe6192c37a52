"""Robot files read safely: kinds of file, sizes and counts bounded before parsing, MuJoCo's log kept out of
the user's folder, encodings (:mod:`ineid.robots.robot_files`, :mod:`ineid.robots.urdf_checks`,
:mod:`ineid.robots.mjcf`).

Each refusal is one ``Error:`` line (exit 1) naming the file, the problem and the fix. Large inputs are cheap:
a model over a count limit is refused while it is counted, before any parser builds it.
"""

from __future__ import annotations

import importlib.util
import os
import re
import time

import pytest

import ineid
from ineid.errors import InputFileError, RobotModelError
from ineid.robots import BUILTIN_ROBOTS, load_chain
from ineid.robots.robot_files import MAX_BODIES, URDF_MAX_BYTES
from ineid.robots.urdf import DEFAULT_QD_MAX, parse_chain

from .test_faults import one_line

ARM = BUILTIN_ROBOTS["sweaty-arm"].urdf_path
needs_mujoco = pytest.mark.skipif(importlib.util.find_spec("mujoco") is None, reason="MuJoCo is not installed")


def arm_with(inside_robot: str) -> str:
    """sweaty-arm's URDF with ``inside_robot`` just after its ``<robot ...>`` tag."""
    text = ARM.read_text()
    at = text.index(">", text.index("<robot")) + 1
    return text[:at] + inside_robot + text[at:]


# -- URDF --------------------------------------------------------------------------------------------


def test_urdf_with_a_huge_comment_is_one_line(run, tmp_path):
    """A comment over lxml's 10 MB text node (yourdfpy hid lxml's refusal as a TypeError): the size limit
    refuses it, naming the limit; a comment within the limit is read (a comment is harmless)."""
    path = tmp_path / "comment.urdf"
    path.write_text(arm_with("<!--" + "x" * 12_000_000 + "-->"))
    size = path.stat().st_size
    expected = (
        f"Error: the URDF {path} is {size:,} bytes, over the {URDF_MAX_BYTES:,} bytes ineid reads for it "
        "(URDF_MAX_BYTES); give a smaller file"
    )
    assert one_line(run("robot", "show", path)) == expected
    assert one_line(run("generate", path, "--out", tmp_path / "code")) == expected
    assert not (tmp_path / "code").exists()
    with pytest.raises(InputFileError, match="URDF_MAX_BYTES"):  # the URDF text a dataset carries
        parse_chain(path.read_bytes(), source="dataset")
    fits = arm_with("<!--" + "x" * (URDF_MAX_BYTES - ARM.stat().st_size - 100) + "-->")
    assert parse_chain(fits, source="fits").n_dof == 4


def test_urdf_that_lxml_refuses_is_one_line():
    """Elements nested deeper than lxml's default 256: lxml's reason in one line, not yourdfpy's TypeError."""
    text = arm_with("<a>" * 300 + "</a>" * 300)
    with pytest.raises(
        RobotModelError,
        match="^deep: lxml, yourdfpy's XML parser, cannot read the URDF "
        r"\(Excessive depth in document: 256",
    ):
        parse_chain(text, source="deep")


def test_urdf_over_the_link_limit_is_refused_before_yourdfpy():
    links = "".join(
        f'<link name="s{i}"/><joint name="f{i}" type="fixed"><parent link="base_link"/><child link="s{i}"/></joint>'
        for i in range(MAX_BODIES)
    )
    t0 = time.perf_counter()
    with pytest.raises(
        InputFileError,
        match=f"^many: the model has {MAX_BODIES + ARM.read_text().count('<link '):,} "
        "links, over the 10,000 ineid reads \\(MAX_BODIES\\); give the model",
    ):
        parse_chain(arm_with(links), source="many")
    assert time.perf_counter() - t0 < 5  # yourdfpy would take seconds more


def test_urdf_limits_absent_or_zero_keep_the_default():
    """``velocity="0"`` is URDF writers' "not given" (Kinova's URDF): the default, as for an absent attribute;
    a negative velocity is refused (tests/test_robots.py)."""
    text = ARM.read_text()
    assert text.count(" velocity=") == 4
    for value in ('velocity="0"', 'velocity="0.0"', ""):
        changed = re.sub(r'velocity="[^"]*"', value, text)
        assert [j.qd_max for j in parse_chain(changed).joints] == [DEFAULT_QD_MAX] * 4


@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_robot_file_that_is_not_a_regular_file(run, tmp_path, kind):
    """A FIFO would block the first read forever: refused from its ``stat``, by every reader."""
    path = tmp_path / "arm.urdf"
    if kind == "fifo":
        os.mkfifo(path)
        what = "a FIFO (named pipe)"
    else:
        path.mkdir()
        what = "a folder"
    line = f"Error: the URDF {path} is {what}, not a regular file; give a file"
    assert one_line(run("robot", "show", path)) == line
    assert one_line(run("generate", path, "--out", tmp_path / "code")) == line
    with pytest.raises(InputFileError, match=re.escape(what)):
        ineid.load_robot(path)
    with pytest.raises(InputFileError, match=re.escape(what)):
        load_chain(path)


# -- MJCF --------------------------------------------------------------------------------------------

ARM_BODY = (
    '<body name="b0"><joint name="j0" axis="0 0 1"/>'
    '<inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body>'
)


def mjcf(inside_worldbody: str = "", head: str = "", after: str = "") -> str:
    return f'{head}<mujoco model="t">{after}<worldbody>{ARM_BODY}{inside_worldbody}</worldbody></mujoco>'


OVER = {
    "flat bodies": (mjcf("<body/>" * 1_000_000), "more bodies than the 10,000 ineid reads (MAX_BODIES)"),
    "replicate": (
        mjcf(
            '<replicate count="1000" offset="0 0 1"><replicate count="1000" offset="1 0 0"><body>'
            '<geom size=".1"/></body></replicate></replicate>'
        ),
        "(MAX_BODIES)",
    ),
    "flexcomp": (
        mjcf('<flexcomp name="f" type="grid" count="100 100 2" spacing=".1 .1 .1" radius=".01" dim="3"/>'),
        "(MAX_BODIES)",
    ),
    "joints": (
        mjcf('<body name="m"><geom size=".1"/>' + "<joint/>" * 10_001 + "</body>"),
        "more joints than the 10,000 ineid reads (MAX_JOINTS)",
    ),
    "geoms": (
        mjcf('<body name="g">' + '<geom size=".1"/>' * 50_001 + "</body>"),
        "more elements than the 50,000 ineid reads (MJCF_MAX_ELEMENTS)",
    ),
    "included bodies": (mjcf('<include file="parts/many.xml"/>'), "(MAX_BODIES)"),
}


@needs_mujoco
@pytest.mark.parametrize("case", sorted(OVER))
def test_mjcf_over_a_limit_is_refused_before_mujoco(run, tmp_path, monkeypatch, case):
    """MuJoCo's parser takes time with the square of the bodies (10^6 flat bodies: hours); the count refuses
    them first, in a fraction of a second, and MuJoCo never sees the file."""
    import ineid.robots.mjcf as mjcf_module

    def never(*args, **kwargs):
        raise AssertionError("MuJoCo was asked to compile a model over the limits")

    monkeypatch.setattr(mjcf_module, "compile_mjcf", never)
    text, words = OVER[case]
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "many.xml").write_text("<mujoco>" + "<body/>" * (MAX_BODIES + 1) + "</mujoco>")
    path = tmp_path / "model.xml"
    path.write_text(text)
    t0 = time.perf_counter()
    line = one_line(run("robot", "show", path))
    assert time.perf_counter() - t0 < 5
    assert line.startswith(f"Error: {path}: the model has ") and words in line, line
    assert line.endswith("; give the model of the robot alone (the arm ineid identifies, without scenery or copies)")


@needs_mujoco
@pytest.mark.parametrize("where", ["include", "mesh"])
def test_mjcf_naming_a_fifo_is_one_line(run, tmp_path, where):
    """MuJoCo blocks forever reading a FIFO (a mesh named ``part.stl``, say): every file an MJCF names is checked."""
    fifo = tmp_path / ("part.xml" if where == "include" else "part.stl")
    os.mkfifo(fifo)
    path = tmp_path / "model.xml"
    if where == "include":
        path.write_text(mjcf('<include file="part.xml"/>'))
    else:
        path.write_text(mjcf(after='<asset><mesh name="m" file="part.stl"/></asset>'))
    verb = "includes" if where == "include" else "names"
    assert one_line(run("robot", "show", path)) == (
        f"Error: {path}: the MJCF {verb} {fifo}, which is a FIFO (named pipe), not a regular file; give a file"
    )


@needs_mujoco
def test_mjcf_with_nan_inertia_writes_no_mujoco_log(run, tmp_path, monkeypatch, capfd):
    """MuJoCo's default warning handler writes MUJOCO_LOG.TXT into the working folder (and stderr); ineid
    catches the warning and says it in its one line."""
    import mujoco

    monkeypatch.chdir(tmp_path)
    (tmp_path / "nan.xml").write_text(mjcf().replace('diaginertia="0.01 0.01 0.01"', 'diaginertia="nan 0.01 0.01"'))
    line = one_line(run("robot", "show", "nan.xml"))
    assert line == (
        "Error: nan.xml: MuJoCo reads a NaN in the model (XML contains a 'NaN'. Please check it "
        "carefully.); give finite numbers"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.xml"]
    assert "WARNING" not in capfd.readouterr().err
    assert mujoco.get_mju_user_warning() is None  # MuJoCo's own handler is back


MJCF_BAD = {
    "inf pos": (
        mjcf().replace('<body name="b0">', '<body name="b0" pos="inf 0 0">'),
        "body 'b0': pos inf 0.0 0.0 is not finite; give finite numbers",
    ),
    "inf ref": (
        mjcf().replace('axis="0 0 1"', 'axis="0 0 1" ref="inf"'),
        "joint 'j0': ref inf is not finite; give a finite number",
    ),
    "latin-1 name": (
        mjcf(head='<?xml version="1.0" encoding="ISO-8859-1"?>').replace('"b0"', '"b\xe9"'),
        "the name of body #1 is not UTF-8 (MuJoCo reads a file's bytes as UTF-8, whatever its XML "
        "declaration says); save the MJCF as UTF-8",
    ),
    "not its encoding": (
        mjcf("<!-- caf\xe9 -->"),
        "(0xe9) of the MJCF is not valid UTF-8, the encoding of "
        "XML without a declaration; save the file in that encoding, or declare the one it is in",
    ),
    "utf-16": (
        mjcf(head='<?xml version="1.0" encoding="UTF-16"?>'),
        "the MJCF is UTF-16 or UTF-32 (a byte-order "
        "mark), which MuJoCo does not read; save the file as UTF-8 (MuJoCo reads a file's bytes as UTF-8)",
    ),
    "unknown encoding": (
        mjcf(head='<?xml version="1.0" encoding="klingon"?>'),
        "the MJCF declares encoding 'klingon', which ineid does not know; save the file as UTF-8",
    ),
    "ebcdic": (
        mjcf(head='<?xml version="1.0" encoding="cp500"?>'),
        "the MJCF declares encoding 'cp500', which is not a superset of ASCII and which MuJoCo does not read",
    ),
}


@needs_mujoco
@pytest.mark.parametrize("case", sorted(MJCF_BAD))
def test_mjcf_numbers_and_encodings_are_one_line(run, tmp_path, case):
    text, words = MJCF_BAD[case]
    path = tmp_path / "bad.xml"
    path.write_bytes(text.encode("utf-16" if case == "utf-16" else "latin-1"))
    line = one_line(run("robot", "show", path))
    assert line.startswith(f"Error: {path}: ") and words in line, line


@needs_mujoco
def test_mujoco_warnings_while_stepping_stay_out_of_the_working_folder(tmp_path, monkeypatch):
    """An unstable step warns through the same handler (``ineid.studies.mujoco_sim`` steps inside it)."""
    import mujoco

    from ineid.robots.mjcf import mujoco_warnings

    monkeypatch.chdir(tmp_path)
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint/><geom size="0.1"/></body></worldbody></mujoco>'
    )
    d = mujoco.MjData(m)
    d.qvel[:] = 1e300
    with mujoco_warnings(mujoco) as warnings:
        mujoco.mj_step(m, d)
    assert len(warnings) == 1 and "QVEL" in warnings[0] and not list(tmp_path.iterdir())
