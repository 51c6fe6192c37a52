"""A 7-joint arm's joint-torque recordings: ``ineid solve`` against the pipeline a lab writes by hand.

The recordings stand in for public hardware logs of a lightweight arm: example-robot-data's Panda
(fingers locked, its seven links unknown), one smooth Fourier excitation (``ineid data generate
--frame-mode fourier``, 10 harmonics, one period) sampled at 200 Hz and cut in three: two
recordings of 4,876 frames fitted, the third validated. Joint torques carry viscous (0.5
N*m*s/rad), Coulomb (0.8 N*m) and offset (0.1 N*m) terms on every joint and 0.3 N*m of noise.
A second case is one 1 kHz log of 16,000 frames, its first 80 % fitted and the rest validated.

Rows, each a fresh process timed from outside (Python start, imports, reading, solving, writing):

* ``ineid solve A.h5 B.h5 --validate C.h5 --use torque --method linear --friction viscous,coulomb
  --torque-offset``: first with an empty cache folder (the robot's regressor derived by SymPy, the
  kernels compiled: what a user's first solve of a new arm costs), then warm (best of ``--repeats``);
* the same with ``--method consistent`` (warm);
* the hand pipeline, as its own Python process that never imports ineid: h5py reads the files,
  Pinocchio's ``computeJointTorqueRegressor`` frame by frame, the friction and offset columns
  (``qd``, ``sign(qd)``, 1 per joint), ``numpy.linalg.lstsq`` on the stacked rows, its
  validation error ``||tau - tau_hat|| / ||tau||`` (best of ``--repeats``).

Printed: seconds, the ratio to the hand pipeline's process and both validation errors (they agree:
the same least squares, ineid's weights estimated per joint).

Run: ``PYTHONPATH=. python benchmarks/real_arm.py`` (about three minutes on two busy cores;
``--quick``: short recordings, one repeat, a smoke test).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LOCKED = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
FRICTION_TRUTH = "fv=0.5,fc=0.8,offset=0.1"
TORQUE_NOISE = 0.3
SOLVE_ARGS = ["--use", "torque", "--friction", "viscous,coulomb", "--torque-offset"]
BLAS_THREADS = os.environ.get("OPENBLAS_NUM_THREADS")  # before ineid sets its default: the hand pipeline's own


# -- the hand pipeline (its own process: h5py, Pinocchio and NumPy only) ------------------------------------
def hand_read(path):
    """``(q, qd, qdd, tau, urdf text, locked joints)`` of a one-configuration dataset, read by h5py alone."""
    import h5py

    with h5py.File(path, "r") as f:
        arrays = [f[k][0] for k in ("q", "qd", "qdd", "tau")]
        return (*arrays, f.attrs["urdf"], json.loads(f.attrs["locked_joints"]))


def hand_rows(model, data, q, qd, qdd):
    """(F n_dof, 10 n + 3 n_dof) rows: Pinocchio's joint-torque regressor frame by frame, then per joint
    the viscous, Coulomb and offset columns."""
    import numpy as np
    import pinocchio as pin

    n, nv = q.shape
    y = np.empty((n, nv, 10 * (model.njoints - 1) + 3 * nv))
    for k in range(n):
        y[k, :, : -3 * nv] = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
    friction = np.zeros((n, nv, nv, 3))
    j = np.arange(nv)
    friction[:, j, j, 0] = qd
    friction[:, j, j, 1] = np.sign(qd)
    friction[:, j, j, 2] = 1.0
    y[:, :, -3 * nv :] = friction.reshape(n, nv, 3 * nv)
    return y.reshape(n * nv, -1)


def hand_pipeline(fit_paths, validate, fit_fraction: float | None) -> dict:
    """What a lab writes: read, regressor rows, ``lstsq``, the validation error. Validation on ``validate``,
    or (``fit_fraction``) on the frames after that share of the single fitted file."""
    import numpy as np
    import pinocchio as pin

    recordings = [hand_read(p) for p in fit_paths]
    urdf, locked = recordings[0][4], recordings[0][5]
    model = pin.buildModelFromXML(urdf)
    if locked:
        q_ref = pin.neutral(model)
        ids = [model.getJointId(name) for name in locked]
        for jid, value in zip(ids, locked.values(), strict=True):
            q_ref[model.joints[jid].idx_q] = value
        model = pin.buildReducedModel(model, ids, q_ref)
    data = model.createData()
    if validate is not None:
        fit = [r[:4] for r in recordings]
        val = hand_read(validate)[:4]
    else:
        n_fit = int(round(fit_fraction * len(recordings[0][0])))
        fit = [tuple(a[:n_fit] for a in recordings[0][:4])]
        val = tuple(a[n_fit:] for a in recordings[0][:4])
    a = np.concatenate([hand_rows(model, data, *r[:3]) for r in fit])
    b = np.concatenate([r[3].ravel() for r in fit])
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    resid = val[3].ravel() - hand_rows(model, data, *val[:3]) @ x
    return {"rel": float(np.linalg.norm(resid) / np.linalg.norm(val[3]))}


# -- the benchmark (imports ineid) ----------------------------------------------------------------------
def robot_path():
    import importlib.metadata as md

    root = md.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
    return root / "panda_description/urdf/panda.urdf"


def make_recordings(folder: Path, parts: list[int], rate: float, seed: int, env: dict) -> list[Path]:
    """One Fourier excitation of ``sum(parts)`` frames at ``rate`` Hz (``ineid data generate``), cut into
    datasets of ``parts`` frames each."""
    from ineid.data.dataset.read import load_dataset

    total = sum(parts)
    whole = folder / f"whole-{rate:g}hz.h5"
    cmd = [sys.executable, "-m", "ineid.cli", "-q", "data", "generate", str(robot_path())]
    for joint, value in LOCKED.items():
        cmd += ["--lock", f"{joint}={value}"]
    cmd += ["--n-configs", "1", "--n-frames", str(total), "--frame-mode", "fourier", "--harmonics", "10"]
    cmd += ["--base-frequency", f"{rate / total:.9g}", "--seed", str(seed), "--channels", "torque"]
    cmd += ["--friction-truth", FRICTION_TRUTH, "--noise", f"tau={TORQUE_NOISE}", "--out", str(whole)]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    ds = load_dataset(whole, clean=False)
    paths, start = [], 0
    for i, n in enumerate(parts):
        path = folder / f"rec{i}-{rate:g}hz.h5"
        ds.select(frames=slice(start, start + n)).save(path, overwrite=True)
        paths.append(path)
        start += n
    return paths


def timed(cmd: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def ineid_solve(inputs, validate, method: str, env: dict, out: Path) -> tuple[float, float]:
    """Wall seconds of ``ineid solve`` in a fresh process, and its validation error (median)."""
    from ineid.identify.results import load_results

    cmd = [sys.executable, "-m", "ineid.cli", "-q", "solve", *map(str, inputs)]
    cmd += [] if validate is None else ["--validate", str(validate)]
    cmd += ["--method", method, *SOLVE_ARGS, "--out", str(out), "--overwrite"]
    seconds = timed(cmd, env)
    return seconds, float(load_results(out).validation_rel[0])


def hand_solve(inputs, validate, env: dict, out: Path) -> tuple[float, float]:
    """Wall seconds of the hand pipeline in a fresh process, and its validation error."""
    cmd = [sys.executable, __file__, "--hand", str(out), *map(str, inputs)]
    cmd += ["--hand-validate", str(validate)] if validate is not None else ["--hand-fit-fraction", "0.8"]
    env = {k: v for k, v in env.items() if k != "OPENBLAS_NUM_THREADS"}  # NumPy's default threads, as a lab runs it
    if BLAS_THREADS is not None:
        env["OPENBLAS_NUM_THREADS"] = BLAS_THREADS
    seconds = timed(cmd, env)
    return seconds, json.loads(out.read_text())["rel"]


def case(name: str, inputs, validate, tmp: Path, env: dict, repeats: int, consistent: bool) -> None:
    """The rows of one case: ineid cold and warm (and consistent), the hand pipeline, the ratios."""
    cold_env = dict(env, INEID_CACHE_DIR=str(tmp / f"cold-{name}"))
    rows = [("ineid linear, empty cache", *ineid_solve(inputs, validate, "linear", cold_env, tmp / "r.h5"))]
    for method in ("linear", "consistent") if consistent else ("linear",):  # compiled into env's cache, untimed
        ineid_solve(inputs, validate, method, env, tmp / "r.h5")
    warm = [ineid_solve(inputs, validate, "linear", env, tmp / "r.h5") for _ in range(repeats)]
    rows.append(("ineid linear, warm", min(s for s, _ in warm), warm[0][1]))
    if consistent:
        runs = [ineid_solve(inputs, validate, "consistent", env, tmp / "r.h5") for _ in range(repeats)]
        rows.append(("ineid consistent, warm", min(s for s, _ in runs), runs[0][1]))
    hand = [hand_solve(inputs, validate, env, tmp / "hand.json") for _ in range(repeats)]
    hand_s = min(s for s, _ in hand)
    rows.append(("hand: Pinocchio per frame + lstsq", hand_s, hand[0][1]))
    print(f"\n{name}")
    print(f"{'process':38s} {'seconds':>8s} {'x hand':>7s} {'validation error':>17s}")
    for label, seconds, rel in rows:
        print(f"{label:38s} {seconds:8.2f} {seconds / hand_s:7.2f} {rel:17.4%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="short recordings, one repeat: a smoke test")
    ap.add_argument("--repeats", type=int, default=2, help="warm runs per row (best taken)")
    ap.add_argument("--no-consistent", dest="consistent", action="store_false")
    ap.add_argument("--hand", help=argparse.SUPPRESS)  # the hand pipeline's own process: where its answer goes
    ap.add_argument("--hand-validate", help=argparse.SUPPRESS)
    ap.add_argument("--hand-fit-fraction", type=float, help=argparse.SUPPRESS)
    args, rest = ap.parse_known_args()
    if args.hand:
        result = hand_pipeline(rest, args.hand_validate, args.hand_fit_fraction)
        Path(args.hand).write_text(json.dumps(result))
        return

    from machine import cpu_description  # benchmarks/machine.py

    import ineid

    frames, long_frames = (600, 2000) if args.quick else (4876, 16_000)
    repeats = 1 if args.quick else args.repeats
    print(f"machine: {cpu_description()}; load average {os.getloadavg()[0]:.2f}; ineid {ineid.__version__}")
    print(
        f"panda (7 joints, fingers locked, 7 links unknown); joint torques with viscous, Coulomb and offset "
        f"terms, noise {TORQUE_NOISE} N*m; fitted with --friction viscous,coulomb --torque-offset"
    )
    with tempfile.TemporaryDirectory(prefix="ineid-real-arm-") as name:
        tmp = Path(name)
        env = dict(os.environ, INEID_CACHE_DIR=str(tmp / "cache"))
        a, b, c = make_recordings(tmp, [frames] * 3, 200.0, 1, env)
        (long,) = make_recordings(tmp, [long_frames], 1000.0, 2, env)
        case(
            f"two recordings of {frames:,} frames at 200 Hz fitted, a third validated",
            [a, b],
            c,
            tmp,
            env,
            repeats,
            args.consistent,
        )
        case(f"one 1 kHz log of {long_frames:,} frames, 80 % fitted", [long], None, tmp, env, repeats, False)


if __name__ == "__main__":
    main()
