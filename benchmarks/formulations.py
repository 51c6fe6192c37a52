"""Where the formulations study's time goes: MuJoCo's simulation, then each formulation's solves.

``ineid study formulations`` (``ineid.studies.formulations``) simulates every configuration
in MuJoCo (RK4 at 1 ms, the computed-torque law and the Stribeck term in a Python control callback
called at every RK4 stage), then identifies the recordings by each formulation twice (with friction,
then with ideal drives). Printed: the simulation's seconds and its rate (simulated seconds per wall
second), each formulation's solve with friction (its first solve of a channel set compiles the JAX
kernels), and the whole identification; run twice in one process, so the second pass shows the
solves without compilation.
"""

from __future__ import annotations

import argparse
import time

from regressor import header  # benchmarks/regressor.py

import ineid
from ineid.studies.formulations import SIZES, identify_formulations, simulate_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("robot", nargs="?", default="sweaty-arm")
    ap.add_argument("--quick", action="store_true", help="2 configurations of 6 s at 50 Hz (default: 10 of 30 s)")
    args = ap.parse_args()
    model = ineid.load_robot(args.robot)
    size = SIZES["quick" if args.quick else "full"]
    print(header())
    t0 = time.perf_counter()
    data = simulate_study(model, size)
    sim = time.perf_counter() - t0
    simulated = size.n_configs * size.duration
    print(f"{model.name}: {size.n_configs} configurations x {size.duration:g} s at {size.rate:g} Hz")
    print(f"simulation: {sim:.1f} s ({simulated / sim:.2f} simulated s per s)")
    for attempt in ("first (compiles)", "second"):
        t0 = time.perf_counter()
        rows, _ = identify_formulations(model, data)
        total = time.perf_counter() - t0
        solves = ", ".join(f"{r.formulation} {r.seconds:.1f}" for r in rows)
        print(f"identification, {attempt}: {total:.1f} s in all; one solve with friction each: {solves}")


if __name__ == "__main__":
    main()
