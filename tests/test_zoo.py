"""Cross-cutting: the zoo, the arms of example-robot-data through a new user's commands (``tests/zoo.py``).

Default suite: the double pendulum's whole sequence (2 joints: a few seconds of code generation
and compilation). ``make test-slow``: every arm of the zoo, each through ``robot show``,
``identifiability``, a short ``excite``, ``data generate``, ``solve --method linear`` and
``consistent``, ``export-urdf``, and the export reloaded by Pinocchio to the identified
model's base wrench. None is skipped or expected to fail: an arm that stops is a bug.
"""

from __future__ import annotations

import pytest

from .zoo import ZOO, check_export, user_sequence


def _whole_sequence(run, name, tmp_path):
    arm = ZOO[name]
    out = user_sequence(run, arm, tmp_path)
    assert "base parameters" in out["identifiability"].lower()
    assert (tmp_path / "traj.csv").is_file() and (tmp_path / "exp.urdf").is_file()
    for step in ("linear", "consistent"):
        assert "5/5 configurations identified" in out[step], out[step]
    check_export(arm, tmp_path)


def test_double_pendulum_whole_sequence(run, tmp_path):
    _whole_sequence(run, "double-pendulum", tmp_path)


@pytest.mark.slow  # a 6-7 joint arm's code generation and compilations: minutes each on a 2-core machine
@pytest.mark.parametrize("name", [n for n in ZOO if n != "double-pendulum"])
def test_zoo_arm_whole_sequence(run, tmp_path, name):
    _whole_sequence(run, name, tmp_path)
