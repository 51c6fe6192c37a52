"""``benchmarks/gpu.py --quick`` runs on a machine without a GPU and prints its tables (nothing timed here)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_gpu_benchmark_quick_runs_on_the_cpu():
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "gpu.py"), "--quick"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = done.stdout
    assert "default backend" in out and "usable" in out  # the machine
    for row in ("base_wrench  public", "regressor    raw jit", "NumPy in/out", "Pinocchio/frame"):
        assert row in out
    assert "GPU floors are not measured" in out
    assert "ineid.learn.train" in out and "bare Optax loop" in out
    assert "estimate: ineid study networks --plan quick (8 trials)" in out
