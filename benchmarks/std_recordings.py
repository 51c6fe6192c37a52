"""Is the std of a fit on a filtered recording honest? The calibration table, before and after.

MuJoCo simulates ``sweaty-arm`` on a 6-axis F/T sensor turned nearly upside down, with offsets, for 10 s at 1 kHz
(:mod:`ineid.studies.std_recordings`); the recording is the untared wrench and the joint angles only, and in the
``torque`` scenario the joint torques too, with viscous (0.05 N*m*s/rad) and Coulomb (0.3 N*m) friction in the
joints: by default the law ``fv qd + fc tanh(qd / 0.05)`` that ineid's smooth Coulomb model represents, solved at its
zone (``--friction law``) or with the zone identified (``law-identify``); or MuJoCo's own dry friction (a soft
constraint no ``fc c(qd)`` represents exactly), solved with ``sign(qd)`` (``mujoco-sign``) or at the zone that fits
it best (``mujoco-zone``). Each noise draw (white, per sample: angles 2e-5 rad, wrench 0.3 N and 0.02 N*m, torques
0.02 N*m) is taken every ``step``-th sample (1 kHz, 500 Hz, 200 Hz), imported with the low-pass at the cut-off, and
solved by the linear method with ``bias="estimate"`` (and ``friction=("viscous", "coulomb")`` with torques).

Per rate and cut-off: the RMS over draws and parameters of ``z = (estimate - truth) / std`` per group (``links``:
the base parameters of the links; ``friction``: ``fv`` and ``fc`` per joint; ``offsets``: the sensor's six),
``before`` with the std of independent frames, ``after`` with the std of :mod:`ineid.identify.time_correlation`
(the residuals' band density and the filter's own error). ``noise-free`` rows: no noise at all, what is left is the
filter's and the differentiation's error. An honest std gives an RMS z near 1 (0.8 to 1.25); with ``N`` draws of
``p`` parameters each the RMS itself scatters by about ``1 / sqrt(2 N p)`` (more: a draw's parameters are
correlated).

``--method consistent`` (or ``nonlinear``) solves each draw by that method instead: the linear fit's covariance through
the active constraints (:mod:`ineid.identify.constrained_std`); ``--rod`` makes the forearm a thin rod (two zero
principal moments: on the physical set's boundary, constraints active) and ``--noise 10`` scales the noise.
``--friction`` chooses the torque scenario's friction and the model it is solved with (:data:`FRICTION`).

Usage: ``python benchmarks/std_recordings.py [--draws 6] [--scenario wrench|torque|both] [--friction law]
[--method consistent] [--rod] [--noise 1]``. The load average is printed before and after (timings are not the
point here).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from ineid.studies.std_recordings import LAW_ZONE, friction_zone, rms_z, scenario, solve_draw, with_friction_law

GRID = ((1, 10.0), (1, 5.0), (1, 20.0), (2, 10.0), (5, 10.0), (5, 20.0))
"""``(step, cut-off Hz)``: 1 kHz at 5, 10 and 20 Hz, 500 Hz at 10 Hz, 200 Hz at 10 and 20 Hz."""


def _row(label: str, before: dict, after: dict, seconds: float) -> str:
    groups = ("links", "friction", "offsets")
    cells = [f"{before[g]:7.2f} {after[g]:6.2f}" if g in after else f"{'-':>7} {'-':>6}" for g in groups]
    return f"| {label:<24} | " + " | ".join(cells) + f" | {seconds:6.0f} |"


def thin_rod(mass: float = 1.2, length: float = 0.3) -> np.ndarray:
    """A thin rod along the link's -z axis (1e-7 kg m^2 about it: MuJoCo needs a positive inertia)."""
    i = mass * length**2 / 3
    return np.array([mass, 0.0, 0.0, -mass * length / 2, i, 0.0, i, 0.0, 0.0, 1e-7])


FRICTION = {
    "law": "the law fv qd + fc tanh(qd / 0.05), solved at its zone",
    "law-identify": "the law fv qd + fc tanh(qd / 0.05), its zone identified",
    "mujoco-sign": "MuJoCo's friction, solved with fc sign(qd)",
    "mujoco-zone": "MuJoCo's friction, solved at the zone that fits it best",
}
"""The joints' friction of the torque scenario and the model it is solved with (``--friction``)."""


def _friction_case(sc, friction: str):
    """``(scenario, zone)`` of a ``--friction`` case."""
    if friction.startswith("law"):
        return with_friction_law(sc), ("identify" if friction == "law-identify" else LAW_ZONE)
    return sc, (friction_zone(sc.sim) if friction == "mujoco-zone" else 0.0)


def table(
    torque: bool, draws: int, duration: float, method: str = "linear", rod: bool = False, noise=1.0, friction="law"
) -> None:
    sc = scenario(torque=torque, duration=duration, links={"forearm": thin_rod()} if rod else None)
    sc, zone = _friction_case(sc, friction)
    what = f"wrench and joint torques, {FRICTION[friction]}" if torque else "wrench"
    print(f"\nscenario: {what}, {method}{', forearm a rod' if rod else ''}, noise x{noise:g} ({draws} draws per row)")
    print("| rate, cut-off            | links before after | friction before after | offsets before after |      s |")
    print("|---|---|---|---|---|")
    for step, cutoff in GRID:
        t0 = time.perf_counter()
        rng = np.random.default_rng(100 + step)
        out = [solve_draw(sc, step, cutoff, rng, noise, method=method, zone=zone) for _ in range(draws)]
        before, after = rms_z([o[0] for o in out]), rms_z([o[1] for o in out])
        print(_row(f"{1000 / step:g} Hz, {cutoff:g} Hz", before, after, time.perf_counter() - t0), flush=True)
    for step, cutoff in ((1, 10.0), (5, 10.0)):
        t0 = time.perf_counter()
        before, after = solve_draw(sc, step, cutoff, None, method=method, zone=zone)
        label = f"{1000 / step:g} Hz, {cutoff:g} Hz, noise-free"
        print(_row(label, rms_z([before]), rms_z([after]), time.perf_counter() - t0), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=6, help="noise draws per row (default 6)")
    parser.add_argument("--scenario", choices=("wrench", "torque", "both"), default="both")
    parser.add_argument("--duration", type=float, default=10.0, help="seconds simulated (default 10)")
    parser.add_argument("--method", choices=("linear", "consistent", "nonlinear"), default="linear")
    parser.add_argument("--rod", action="store_true", help="the forearm a thin rod (constraints active)")
    parser.add_argument("--noise", type=float, default=1.0, help="times the default noise (default 1)")
    parser.add_argument(
        "--friction", choices=tuple(FRICTION), default="law", help="the torque scenario's friction (default law)"
    )
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f}")
    for torque in {"wrench": (False,), "torque": (True,), "both": (False, True)}[args.scenario]:
        table(torque, args.draws, args.duration, args.method, args.rod, args.noise, args.friction)
    print(f"\nload average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
