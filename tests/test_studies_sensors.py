"""``ineid study sensors`` (:mod:`ineid.studies.sensors`): encoders alone or with link IMUs, on its quick scale."""

from __future__ import annotations


def test_study_sensors_quick(run, tmp_path):
    png, csv = tmp_path / "s.png", tmp_path / "s.csv"
    r = run("-q", "study", "sensors", "--quick", "--sensors", "12-bit,12-bit+gyro", "--plot", png, "--csv", csv)
    assert r.exit_code == 0, r.output
    assert png.stat().st_size > 0 and "12-bit+gyro" in csv.read_text()
    assert "base err" in r.output
