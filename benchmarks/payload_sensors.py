"""A payload identified from each sensor a lab may have.

The built-in arm carries its hand as a payload (``--unknown-links hand``: the hand's 10
parameters in its own frame, the arm's links known from CAD). The same motions (random
configurations of the hand's parameters, uniform frames) are measured by

* a wrist F/T sensor on the forearm (``--sensor-pose forearm``: what the hand exerts on the forearm),
* the F/T sensor under the base (the paper's),
* joint torque sensors (every joint),

each with realistic noise: F/T 0.5 N / 0.05 N*m per axis (both F/T sensors), joint torques
0.05 N*m (BIRDy's TX40 default). Every channel is identified by ``solve_dataset`` (linear,
per-axis noise estimated), and the payload's mass, centre of mass and inertia about it are
compared with the truth: median absolute error over configurations and the median reported
std. The wrist sensor sees the payload alone, so its errors do not grow with the arm.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from regressor import header  # benchmarks/regressor.py

import ineid
from ineid.channels import BaseWrench, ChannelSet, JointTorque, sensor_channel
from ineid.data import Combination, DatasetSpec, generate_dataset
from ineid.identify.payload import physical_quantities
from ineid.identify.solve import SolveSettings, solve_dataset

NOISE = {"wrench": (0.5, 0.05), "tau": 0.05}


def noisy(ds, channel, rng):
    """The dataset with white noise added to ``channel``'s values (in place of its clean values)."""
    values = ds.measurements[channel.key]
    if channel.key == "tau":
        sigma = np.full(values.shape[-1], NOISE["tau"])
    else:
        sigma = np.repeat(NOISE["wrench"], 3)
    noise = rng.normal(size=values.shape) * sigma
    if channel.key == "wrench" and ds.wrench is not None:
        ds.wrench = ds.wrench + noise
    else:
        ds.channel_values[channel.key] = values + noise
    return ds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", type=int, default=200)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    model = ineid.load_robot("sweaty-arm", unknown_links=["hand"])
    sensors = (
        ("wrist F/T (forearm)", sensor_channel("forearm", model)),
        ("base F/T", BaseWrench()),
        ("joint torques", JointTorque()),
    )
    print(header())
    print(
        f"sweaty-arm, payload 'hand' unknown, {args.configs} configurations x {args.frames} frames "
        f"(half fitted, half held out), linear, noise F/T {NOISE['wrench'][0]} N / {NOISE['wrench'][1]} N*m, "
        f"torques {NOISE['tau']} N*m"
    )
    head = (
        f"{'sensor':22s} {'mass err':>10s} {'mass std':>10s} {'com err mm':>11s} {'com std mm':>11s} "
        f"{'I_C err':>10s} {'I_C std':>10s} {'seconds':>8s}"
    )
    print(head)
    print("-" * len(head))
    for label, channel in sensors:
        rng = np.random.default_rng(args.seed)
        spec = DatasetSpec(
            Combination("random", n_configs=args.configs),
            n_frames=args.frames,
            seed=args.seed,
            channels=ChannelSet.of(channel),
        )
        ds = noisy(generate_dataset(model, spec), channel, rng)
        t0 = time.perf_counter()
        res = solve_dataset(ds, SolveSettings(method="linear", frames=args.frames // 2), model=model)
        seconds = time.perf_counter() - t0
        block = slice(10 * model.link_names.index("hand"), 10 * model.link_names.index("hand") + 10)
        col = [i for i, n in enumerate(res.param_names) if n.startswith("hand.")]
        truth = np.stack([physical_quantities(t[block])[0] for t in ds.theta()[res.config_index]])
        est = np.stack([physical_quantities(t)[0] for t in res.theta_hat[:, col]])
        pay = res.payload["hand"]
        err = np.abs(est - truth)
        print(
            f"{label:22s} {np.median(err[:, 0]):10.2e} {np.median(pay['mass_std']):10.2e} "
            f"{1e3 * np.median(err[:, 1:4]):11.3f} {1e3 * np.median(pay['com_std']):11.3f} "
            f"{np.median(err[:, 4:]):10.2e} {np.median(pay['inertia_std']):10.2e} {seconds:8.2f}"
        )


if __name__ == "__main__":
    main()
