"""``benchmarks/trees.py`` times what it claims: its Pinocchio peer (a free-flyer root held at identity, the
tree's joints mapped by name, the locks applied) is ineid's base regressor, the CasADi route it times equals
it, and its reading of a command's log finds the derivation and the XLA compile seconds."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import ineid

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCH))  # its ``machine`` module
    saved = os.environ.get("INEID_XLA_CACHE")
    try:
        spec = importlib.util.spec_from_file_location("bench_trees", BENCH / "trees.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCH))
        if saved is None:  # the benchmark turns JAX's persistent cache off for its own process only
            os.environ.pop("INEID_XLA_CACHE", None)
        else:
            os.environ["INEID_XLA_CACHE"] = saved
    return module


def test_pinocchio_peer_and_casadi_route_equal_ineid_on_baxter(bench, tmp_path):
    path, locked = bench.robot_path("baxter")
    model = ineid.load_robot(path, locked_joints=locked, codegen_dir=tmp_path / "gen")
    assert model.n_dof == 15 and not model.chain.is_serial
    data = bench.sample(model, bench.CHUNK)
    step, ref = bench.pinocchio_free_flyer(model, path, locked, data)
    y = np.asarray(model.casadi_regressor.map(20)(*(x[:20].T for x in data))).reshape(6, 20, -1).transpose(1, 0, 2)
    bench.check("ineid", y, ref)
    bench.check("CasADi route", bench.casadi_method(model, data, "serial")(0, bench.CHUNK), ref)
    swapped = np.arange(ref.shape[2])
    swapped[:10], swapped[10:20] = np.arange(10, 20), np.arange(10)  # two links' columns exchanged
    with pytest.raises(AssertionError, match="differs from Pinocchio's"):
        bench.check("swapped", y, ref[:, :, swapped])


def test_log_reading_finds_derivation_and_compile_seconds(bench):
    log = (
        "ineid: regressor derivation, step 35 of 35: finished for 'talos' after 1.5 s\n"
        "Finished XLA compilation of jit(<lambda>) in 9.25 sec\n"
        "Persistent compilation cache hit for 'jit__lambda' with key 'k'\n"
        "Finished XLA compilation of jit(f) in 1.5e-01 sec\n"
    )
    assert bench.read_log(log) == {"derive": 1.5, "xla": 9.4, "kernels": 2, "hits": 1}
