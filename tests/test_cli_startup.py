"""What a fresh ``ineid`` process loads and sets before it solves (each test runs its own interpreter)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest


def _python(code: str, **env: str | None) -> str:
    """stdout of ``python -c code`` in a fresh interpreter, ``env`` changed (None: unset)."""
    environ = dict(os.environ)
    for key, value in env.items():
        if value is None:
            environ.pop(key, None)
        else:
            environ[key] = value
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=environ).stdout


@pytest.mark.parametrize(
    ("code", "given", "expected"),
    [
        ("import ineid", None, "1"),  # ineid's threads run the batches; OpenBLAS's own would oversubscribe
        ("import ineid", "3", "3"),  # the user's choice wins
        ("import numpy, ineid", None, "None"),  # OpenBLAS already loaded: nothing to change
    ],
)
def test_openblas_threads(code, given, expected):
    out = _python(f"{code}; import os; print(os.environ.get('OPENBLAS_NUM_THREADS'))", OPENBLAS_NUM_THREADS=given)
    assert out.strip() == expected


def test_solve_imports_only_what_it_uses(tmp_path):
    """A linear solve of a synthetic dataset imports neither SymPy nor Matplotlib, nor anything for plots or
    other formats."""
    import ineid
    from ineid.data import Combination, DatasetSpec, write_dataset

    data = tmp_path / "d.h5"
    write_dataset(ineid.load_robot("sweaty-arm"), DatasetSpec(Combination("random", n_configs=3), n_frames=20), data)
    code = (
        "import sys; from click.testing import CliRunner; from ineid.cli import main; "
        f"r = CliRunner().invoke(main, ['-q', 'solve', {str(data)!r}, '--method', 'linear', "
        f"'--out', {str(tmp_path / 'r.h5')!r}]); assert r.exit_code == 0, r.output; "
        "print(sorted(m for m in ('sympy', 'matplotlib', 'pandas', 'yourdfpy', 'trimesh', 'flax', 'optax') "
        "if m in sys.modules))"
    )
    assert _python(code).strip() == "[]"
