"""Cross-cutting: names are data, never code; hostile robot, link and joint names in every input ineid reads.

Each name is planted as the robot's, a link's and a joint's name of one small 2-DOF URDF
(written with ElementTree, so the XML itself is well-formed). Nothing may run (a canary
file is never created), every command succeeds or fails with one line, and every output
parses: the generated modules compute the regressor of the clean-named twin, the exported
URDF reads back with the same names and parameters.
"""

from __future__ import annotations

import dataclasses
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ineid._trust import MANIFEST
from ineid.cli import main
from ineid.generated import file_names, load_from_directory, module_slug
from ineid.robots.program import casadi_functions, jax_functions
from ineid.robots.urdf import parse_chain

CANARY = Path(tempfile.gettempdir()) / f"ineid-hostile-canary-{os.getpid()}"
CODE = f"import pathlib;pathlib.Path({str(CANARY)!r}).write_text('ran')"

HOSTILE = {
    "newline-code": f"x\n{CODE}\n#",
    "cr-tab": f"a\r\tb\r\n{CODE}",
    "quotes": 'it\'s a "quoted" name',
    "triple-quotes": f'a"""\n{CODE}\n"""b\'\'\'c',
    "backslashes": "back\\slash\\n\\",
    "xml-comment": "x --> <link name='evil'/> <!-- y",
    "double-dash": "a--b",
    "mathtext": "$\\badcmd{$",
    "markup": "[bold]x[/bold] [/] [red",
    "path": "../../etc/x/..",
    "non-ascii": "ärm-λ-日本\u2028",
    "long": "n" * 300,
}
# All of them at once: what the command-line test plants.
NASTY = "".join(HOSTILE[k] for k in HOSTILE if k != "long") + "n" * 200


def hostile_urdf(name: str | None) -> str:
    """A 2-DOF arm named ``name`` whose root link, links and joints carry ``name`` too (None: clean names)."""
    n = {"robot": "clean", "root": "base", "l1": "l1", "l2": "l2", "tool": "tool", "j1": "j1", "j2": "j2", "jt": "jt"}
    if name is not None:
        n = {
            "robot": name,
            "root": name + " 0",
            "l1": name,
            "l2": name + " 2",
            "tool": name + " tool",
            "j1": name,
            "j2": name + " 2",
            "jt": name + " tool",
        }
    robot = ET.Element("robot", name=n["robot"])
    ET.SubElement(robot, "link", name=n["root"])
    for link, com in ((n["l1"], "0.1 0.02 0.05"), (n["l2"], "0.15 -0.01 0.02"), (n["tool"], "0 0 0.03")):
        el = ET.SubElement(ET.SubElement(robot, "link", name=link), "inertial")
        ET.SubElement(el, "origin", xyz=com, rpy="0 0 0")
        ET.SubElement(el, "mass", value="1.5")
        ET.SubElement(el, "inertia", ixx="0.02", ixy="0.001", ixz="0", iyy="0.03", iyz="0", izz="0.025")
    for joint, parent, child, xyz, axis in (
        (n["j1"], n["root"], n["l1"], "0 0 0.1", "0 0 1"),
        (n["j2"], n["l1"], n["l2"], "0.3 0 0", "0 1 0"),
    ):
        el = ET.SubElement(robot, "joint", name=joint, type="revolute")
        ET.SubElement(el, "parent", link=parent)
        ET.SubElement(el, "child", link=child)
        ET.SubElement(el, "origin", xyz=xyz, rpy="0 0 0")
        ET.SubElement(el, "axis", xyz=axis)
        ET.SubElement(el, "limit", lower="-2", upper="2", velocity="2", effort="10")
    el = ET.SubElement(robot, "joint", name=n["jt"], type="fixed")  # a tool welded to the last link
    ET.SubElement(el, "parent", link=n["l2"])
    ET.SubElement(el, "child", link=n["tool"])
    ET.SubElement(el, "origin", xyz="0.2 0 0", rpy="0 0 0")
    return ET.tostring(robot, encoding="unicode")


@pytest.fixture(autouse=True)
def _no_canary():
    CANARY.unlink(missing_ok=True)
    yield
    assert not CANARY.exists(), "a name from the URDF ran as code"


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """The clean twin: its chain, its derivation (names do not enter it) and its loaded modules."""
    from ineid.symbolic import derive_base_wrench_regressor
    from ineid.symbolic.emit import emit_modules, write_files

    chain = parse_chain(hostile_urdf(None))
    sym = derive_base_wrench_regressor(chain)
    folder = tmp_path_factory.mktemp("clean")
    write_files(emit_modules(sym, chain.name).files, folder)
    jax_mod, ca_mod = load_from_directory(folder, chain.name)
    rng = np.random.default_rng(7)
    q, qd, qdd = (rng.uniform(-1, 1, (5, 2)) for _ in range(3))
    g = np.array([0.0, 0.3, -9.81])
    return dataclasses.make_dataclass("Clean", ["chain", "sym", "states", "Y"])(
        chain, sym, (q, qd, qdd, g), np.asarray(jax_functions(jax_mod).regressor(q, qd, qdd, g))
    )


@pytest.mark.parametrize("name", list(HOSTILE.values()), ids=list(HOSTILE))
def test_generated_code_holds_names_as_data(name, clean, tmp_path):
    from ineid.symbolic.emit import emit_modules, write_files

    chain = parse_chain(hostile_urdf(name), source="hostile.urdf")
    assert (chain.name, chain.root_link) == (name, name + " 0")
    assert [(j.name, j.link) for j in chain.joints] == [(name, name), (name + " 2", name + " 2")]
    emitted = emit_modules(dataclasses.replace(clean.sym, chain=chain), chain.name, regenerate=f"ineid generate {name}")
    for fname, text in emitted.files.items():
        assert re.fullmatch(r"[a-z0-9_]{1,60}_(jax|casadi)\.py", fname), fname
        assert text.isascii()
        lines = text.splitlines()
        assert all(line.startswith("# ") for line in lines[:6]) and lines[6].startswith('"""')  # the header
        if ascii(name)[1:-1] != name:  # a name that needs escaping is never written raw (comments, docstrings)
            assert name not in "\n".join(line for line in lines if "regenerate with" not in line)
    written = write_files(emitted.files, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, *(p.name for p in written)])  # nowhere else
    jax_mod, ca_mod = load_from_directory(tmp_path, chain.name)
    for mod in (jax_mod, ca_mod):
        assert mod.ROBOT == name
        assert mod.JOINT_NAMES == (name, name + " 2") and mod.LINK_NAMES == (name, name + " 2")
    q, qd, qdd, g = clean.states
    np.testing.assert_array_equal(np.asarray(jax_functions(jax_mod).regressor(q, qd, qdd, g)), clean.Y)
    y_ca = np.asarray(casadi_functions(ca_mod).regressor(q[0], qd[0], qdd[0], g))
    np.testing.assert_allclose(y_ca, clean.Y[0], rtol=0, atol=1e-14 * np.abs(clean.Y[0]).max())


@pytest.mark.parametrize("name", list(HOSTILE.values()), ids=list(HOSTILE))
def test_exported_urdf_reads_back(name):
    from ineid.params import theta_from_inertial
    from ineid.robots.urdf_write import urdf_with_inertials

    theta = {
        name: theta_from_inertial(2.0, np.array([0.1, 0.0, 0.03]), np.diag([0.02, 0.03, 0.04])),
        name + " 2": theta_from_inertial(0.7, np.array([0.05, 0.01, 0.0]), np.diag([0.01, 0.01, 0.015])),
    }
    text = urdf_with_inertials(hostile_urdf(name), theta)
    root = ET.fromstring(text)
    assert [el.get("name") for el in root.findall("link")] == [name + " 0", name, name + " 2", name + " tool"]
    assert not root.findall(".//link/link") and len(root.findall(".//link")) == 4  # nothing injected
    assert root.findall("link")[3].find("inertial") is None  # the welded tool's inertial went into the estimate
    chain = parse_chain(text, source="exported.urdf")
    assert chain.name == name
    for j in chain.joints:
        np.testing.assert_allclose(j.theta, theta[j.link], rtol=1e-12, atol=1e-15)


def test_module_slug_is_a_safe_file_name():
    for name in [*HOSTILE.values(), "", " ", "..", "/", "0abc", "CON", "a" * 5000]:
        slug = module_slug(name)
        assert re.fullmatch(r"[a-z_][a-z0-9_]{0,59}", slug), (name, slug)
        assert all("/" not in f and f not in (".", "..") for f in file_names(name))
    assert module_slug("sweaty-arm") == "sweaty_arm"  # unchanged for plain names
    assert module_slug("a" * 300) != module_slug("a" * 301)  # cut names stay apart
    assert module_slug("ärm") != module_slug("örm")


def test_a_module_with_an_injected_statement_is_refused():
    """The second line of defence: the emitter's text is parsed and its top level checked."""
    from ineid.errors import CodegenError
    from ineid.generated import BUILTIN_DIR
    from ineid.generated._source import check_module_source

    jax_text = (BUILTIN_DIR / "sweaty_arm_jax.py").read_text()
    ca_text = (BUILTIN_DIR / "sweaty_arm_casadi.py").read_text()
    assert check_module_source(jax_text, "jax")["ROBOT"] == "sweaty-arm"
    assert check_module_source(ca_text, "casadi")["N_DOF"] == 4
    at_import = "\nimport jax.numpy as jnp\n"
    for evil in (
        f"\n{CODE}\n",
        "\nimport os\n",
        "\nX = __import__('os').getcwd()\n",
        "\ndef f(a=print('x')):\n    pass\n",
        "\n@print\ndef program(q, qd, qdd, gravity):\n    pass\n",
        "\nROBOT = open('/etc/passwd').read()\n",
        "\nclass A:\n    print('x')\n",
        "\nprint('x')\n",
    ):
        with pytest.raises(CodegenError, match="unexpected statement|defined twice"):
            check_module_source(jax_text.replace(at_import, at_import + evil, 1), "jax")
    with pytest.raises(CodegenError, match="unexpected statement"):  # no call runs on import, not even ours
        check_module_source(ca_text + "\nY = program([0.0] * 4, [0.0] * 4, [0.0] * 4, [0.0] * 3)\n", "casadi")
    with pytest.raises(CodegenError, match="lacks program"):
        check_module_source(ca_text[: ca_text.index("\ndef program(")], "casadi")
    with pytest.raises(CodegenError, match="not 4 names|joint type other than"):
        check_module_source(jax_text.replace("JOINT_TYPES = ('revolute',", "JOINT_TYPES = ('os.system',"), "jax")


def ok(result):
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    return result.output


@pytest.fixture(scope="module")
def nasty(tmp_path_factory):
    """The URDF with every hostile fragment in each name, and a small clean dataset of it."""
    folder = tmp_path_factory.mktemp("nasty")
    urdf = folder / "nasty.urdf"
    urdf.write_text(hostile_urdf(NASTY))
    data = folder / "d.h5"
    ok(
        CliRunner().invoke(
            main,
            ["data", "generate", str(urdf), "--n-configs", "2", "--n-frames", "40", "--seed", "3", "--out", str(data)],
            catch_exceptions=False,
        )
    )
    assert not CANARY.exists()
    return urdf, data


def test_commands_on_a_hostile_urdf(run, nasty, tmp_path):
    urdf, data = nasty
    out = ok(run("robot", "show", urdf))
    assert "[bold]x[/bold] [/]" in out and "$\\badcmd{$" in out  # shown, not interpreted
    ok(run("generate", urdf, "--out", tmp_path / "gen"))
    ((jax_file, _),) = [file_names(NASTY)]
    assert sorted(os.listdir(tmp_path / "gen")) == sorted(
        [jax_file, jax_file.replace("_jax.py", "_casadi.py"), MANIFEST]
    )
    assert load_from_directory(tmp_path / "gen", NASTY)[0].ROBOT == NASTY
    assert "d.h5" in ok(run("data", "info", data))


def test_solve_plot_and_export_a_hostile_dataset(run, nasty, tmp_path, monkeypatch):
    from ineid.identify import load_results

    urdf, data = nasty
    # A fresh cache: the dataset's URDF is derived again on solve.
    monkeypatch.setenv("INEID_CACHE_DIR", str(tmp_path / "fresh-cache"))
    results, png = tmp_path / "r.h5", tmp_path / "v.png"
    ok(run("solve", data, "--method", "linear", "--select", "0", "--plot", png, "--out", results))
    assert png.stat().st_size > 0
    ok(run("results", "info", results))
    exported = tmp_path / "x.urdf"
    ok(run("export-urdf", results, "--config", 0, "--out", exported))
    chain = parse_chain(exported.read_text(), source="exported")
    res = load_results(results)
    assert chain.name == NASTY and [j.link for j in chain.joints] == [NASTY, NASTY + " 2"]
    np.testing.assert_allclose(np.concatenate([j.theta for j in chain.joints]), res.theta_hat[0], rtol=1e-9, atol=1e-12)


def test_recordings_of_a_hostile_robot(run, nasty, tmp_path):
    """A CSV (with a byte-order mark) and a ROS bag whose joint names and frame_id are hostile."""
    from ineid.data import load_dataset, write_recording_csv

    from .bag_files import write_bag

    urdf, data = nasty
    ds = load_dataset(data, configs=[0])
    csv = write_recording_csv(tmp_path / "rec.csv", ds)
    csv.write_bytes(b"\xef\xbb\xbf" + csv.read_bytes())
    ok(run("data", "import", csv, "--robot", urdf, "--out", tmp_path / "csv.h5"))
    t = np.arange(800) * 0.01  # longer than the derivative filter's edges
    q = np.stack([0.3 * np.sin(t), 0.2 * np.cos(0.7 * t)], axis=1)
    wrench = np.tile([0.1, 0.0, 30.0, 0.5, -0.2, 0.0], (len(t), 1))
    bag = write_bag(
        tmp_path / "rec.bag", "ros1", [NASTY + " 2", NASTY], t, q[:, ::-1], t, wrench, frame_id=NASTY + " 0"
    )  # the root link: the sensor sits under the base
    ok(run("data", "import", bag, "--robot", urdf, "--delay", 0, "--out", tmp_path / "bag.h5"))
    out = ok(run("data", "info", tmp_path / "bag.h5"))
    assert "[bold]x[/bold]" in out
    assert load_dataset(tmp_path / "bag.h5").meta.sensor_pose().frame == NASTY + " 0"
