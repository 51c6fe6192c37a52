"""``ineid study paper`` (:mod:`ineid.studies.paper`): the paper's classical experiments on a quick
scale, its claims checked, and the network section it runs after them."""

from __future__ import annotations

import csv
from pathlib import Path

import ineid

from .test_cli import one_line_error


def test_study_paper_quick(run, tmp_path):
    out = tmp_path / "paper.csv"
    r = run("study", "paper", "--quick", "--frames", "4,10", "--csv", out, "--plot", tmp_path / "paper.png")
    assert r.exit_code == 0 and (tmp_path / "paper.png").stat().st_size > 10_000, r.output
    for text in (
        "The paper's classical experiments, sweaty-arm: 20 configurations",
        "forearm.Icxx",
        "The paper's claims (section 4), checked",
        "holds, for another reason",
        "does not hold",
    ):
        assert text in r.output, text
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 2 * 4 * 20 and {r["method"] for r in rows} == {"lsqlin", "lsqnonlin", "linear", "consistent"}
    masses = [r for r in rows if r["parameter"] == "upper_arm.m"]
    assert all(r["identifiable"] == "False" and "upper_arm.m + forearm.m" in r["reason"] for r in masses)
    assert all(0 <= float(r["within_5"]) <= 1 for r in rows)
    line = one_line_error(run("study", "paper", "--quick", "--frames", "3"))
    assert "use at least 4 frames" in line and "3 generic frames give rank 15 of 17" in line
    r = run("study", "paper", "--quick", "--frames", "4", "--methods", "lsqlin", "--parameters", "standard")
    assert r.exit_code == 0 and "forearm.mx" in r.output and "identifiable" in r.output, r.output


def test_study_paper_networks_section(run, tmp_path, monkeypatch):
    """``--networks DIR`` runs ``ineid study networks`` after the classical sections (its quick size with
    ``--quick``; the network study itself is tests/test_studies_paper_networks.py's), and refuses a full folder or
    another robot before the classical part runs."""
    from ineid.cli import study_networks

    calls = []
    monkeypatch.setattr(
        study_networks.study_networks, "callback", lambda **kw: calls.append(kw) or print("networks section ran")
    )
    out = tmp_path / "nets"
    r = run("study", "paper", "--quick", "--frames", "4", "--methods", "lsqlin", "--networks", out)
    assert r.exit_code == 0 and r.output.index("The paper's claims") < r.output.index("networks section ran"), r.output
    assert len(calls) == 1 and calls[0]["quick"] and calls[0]["plan_name"] == "decisive" and calls[0]["out_dir"] == out
    out.mkdir()
    (out / "x").write_text("")
    line = one_line_error(
        run("study", "paper", "--quick", "--frames", "4", "--methods", "lsqlin", "--networks", out), 2
    )
    assert "holds files" in line and len(calls) == 1
    line = one_line_error(
        run(
            "study",
            "paper",
            str(Path(ineid.__file__).parent / "robots" / "sweaty_arm.urdf"),
            "--quick",
            "--networks",
            tmp_path / "n2",
        ),
        2,
    )
    assert "sweaty-arm" in line and len(calls) == 1
