"""The backward pass's cost: joint-torque regressor and torques beside Pinocchio's.

For ``sweaty-arm`` (4 joints) and example-robot-data's Panda (7 joints, fingers locked), N
random frames (q uniform within the joint limits, qd and qdd within +-bounds, float64,
seed 0), NumPy in and out, one call per row (the chunk kernels compiled, or loaded from the
persistent cache, on a small warm-up call first; best of ``--repeats``):

* ``model.joint_torque_regressor(q, qd, qdd)`` -> (N, n_dof, 10 n) and ``model.joint_torques``
  (inverse dynamics composed link by link, never forming the regressor);
* ``model.link_wrench_regressor(q, qd, qdd, link)`` at the second link (a wrist-style cut);
* the peer, Pinocchio from Python frame by frame: ``computeJointTorqueRegressor`` and ``rnea``.

Every row's first frames are checked against Pinocchio (1e-10 relative).
"""

from __future__ import annotations

import argparse

import numpy as np
from public_api import best  # benchmarks/public_api.py
from regressor import header, sample  # benchmarks/regressor.py

import ineid
from ineid.reference import (
    pinocchio_joint_torque_regressor,
    pinocchio_joint_torques,
    pinocchio_model,
    pinocchio_q,
)


def robots():
    yield "sweaty-arm", ineid.load_robot("sweaty-arm"), pinocchio_model(ineid.load_robot("sweaty-arm").urdf_path)
    import importlib.metadata as md

    root = md.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
    path = root / "panda_description/urdf/panda.urdf"
    locked = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    yield "panda (7 joints)", ineid.load_robot(path, locked_joints=locked), pinocchio_model(path, locked_joints=locked)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--peer-frames", type=int, default=20_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(header())
    head = f"{'robot':18s} {'call':52s} {'frames':>9s} {'seconds':>8s} {'M frames/s':>11s} {'vs Pinocchio':>13s}"
    print(head)
    print("-" * len(head))
    import pinocchio as pin

    for name, model, pm in robots():
        n, m = args.frames, min(args.peer_frames, args.frames)
        q, qd, qdd = sample(model, n)
        y_ref = pinocchio_joint_torque_regressor(pm, q[:50], qd[:50], qdd[:50])
        tau_ref = pinocchio_joint_torques(pm, q[:50], qd[:50], qdd[:50])
        for label, got, ref in (
            ("regressor", model.joint_torque_regressor(q[:50], qd[:50], qdd[:50]), y_ref),
            ("torques", model.joint_torques(q[:50], qd[:50], qdd[:50]), tau_ref),
        ):
            err = float(np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
            if not err <= 1e-10:
                raise AssertionError(f"{name}: joint {label} differ from Pinocchio by {err:.3g}")
        link = model.link_names[1]
        w = min(n, 4096)  # warm: compile (or load) the full-chunk kernels, not only the small shape
        model.joint_torque_regressor(q[:w], qd[:w], qdd[:w])
        model.joint_torques(q[:w], qd[:w], qdd[:w])
        model.link_wrench_regressor(q[:w], qd[:w], qdd[:w], link)
        data = pm.createData()
        pq = np.stack([pinocchio_q(pm, x) for x in q[:m]])

        def pin_regressor():
            for k in range(m):
                pin.computeJointTorqueRegressor(pm, data, pq[k], qd[k], qdd[k])

        def pin_rnea():
            for k in range(m):
                pin.rnea(pm, data, pq[k], qd[k], qdd[k])

        peer_y = m / best(pin_regressor, args.repeats)
        peer_tau = m / best(pin_rnea, args.repeats)
        rows = [
            (
                "model.joint_torque_regressor(q, qd, qdd)",
                n,
                best(lambda: model.joint_torque_regressor(q, qd, qdd), args.repeats),
                peer_y,
            ),
            (
                "model.joint_torques(q, qd, qdd) (CAD theta)",
                n,
                best(lambda: model.joint_torques(q, qd, qdd), args.repeats),
                peer_tau,
            ),
            (
                f"model.link_wrench_regressor(..., {link!r})"[:52],
                n,
                best(lambda: model.link_wrench_regressor(q, qd, qdd, link), args.repeats),
                peer_y,
            ),
            ("peer: Pinocchio computeJointTorqueRegressor/frame", m, m / peer_y, peer_y),
            ("peer: Pinocchio rnea per frame", m, m / peer_tau, peer_tau),
        ]
        for label, k, sec, peer in rows:
            print(f"{name:18s} {label:52s} {k:9,d} {sec:8.3f} {k / sec / 1e6:11.3f} {k / sec / peer:12.1f}x")


if __name__ == "__main__":
    main()
