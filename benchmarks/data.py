"""Seconds to generate the paper's dataset end to end, and to load it back.

``sweaty-arm`` (2 unknown links), ``DatasetSpec()`` defaults: factorial 100 sets per
unknown link -> 10,000 configurations x 100 uniform frames, seed 0, no noise, written by
``ineid.data.write_dataset`` to an HDF5 file in a temporary folder (parameter sampling,
frame sampling, the JAX base wrench, compression in a thread pool, the atomic rename: all
of it). The first run of the process is reported as its own row: it includes JAX's compile
of the chunk shape. Then one warm-up of a tiny dataset with the same chunk shape (so no
timed run compiles), and every other row is the best of ``--repeats`` runs:

* the same file with noise (force 0.5 N, moment 0.05 N*m, qd 0.01 rad/s, qdd 0.1 rad/s^2;
  the clean wrench, qd and qdd are stored too);
* the same file with Fourier-trajectory frames (``FrameSampling("fourier")``);
* ``generate_dataset``: the same arrays in memory, no file;
* ``load_dataset`` of the clean file: every array read, decompressed and checked.

``--configs-per-link`` and ``--frames`` shrink the dataset for a quick run.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import math
import platform
import tempfile
import time
from pathlib import Path

from machine import cpu_description  # benchmarks/machine.py

import ineid  # turns on JAX's float64 mode before jax is used
from ineid.data import (
    Combination,
    DatasetSpec,
    FrameSampling,
    NoiseModel,
    generate_dataset,
    load_dataset,
    write_dataset,
)
from ineid.data.dataset.write import chunk_rows

FLOOR_S = 30.0


def header() -> str:
    """CPU model, core count, library versions."""
    versions = ", ".join(f"{p} {md.version(p)}" for p in ("jax", "h5py", "numpy"))
    return f"CPU: {cpu_description()}; {versions}; Python {platform.python_version()}"


def warmup_spec(model, spec: DatasetSpec) -> DatasetSpec:
    """The smallest factorial dataset whose chunks have ``spec``'s shape (one JAX compile serves both).

    Generation evaluates the wrench one chunk of configurations at a time, padded to the chunk
    size, so the compiled shape depends only on the chunk rows; those are ``chunk_rows`` (about
    1 MiB of the widest array) once the dataset has at least that many configurations.
    """
    n_unknown = len(model.unknown_links)
    target = spec.combination.count(n_unknown)
    need = min(target, chunk_rows(spec.n_frames, max(6, model.n_dof), target))
    per_link = math.ceil(need ** (1 / n_unknown))
    while per_link**n_unknown < need:  # guard against the float root rounding down
        per_link += 1
    return DatasetSpec(
        combination=Combination("factorial", per_link=per_link),
        n_frames=spec.n_frames,
        seed=spec.seed + 1,
        parameters=spec.parameters,
        frames=spec.frames,
        noise=spec.noise,
    )


def timed(fn) -> float:
    """Seconds of one call."""
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv=None) -> None:
    """Parse options, time each case, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--configs-per-link",
        type=int,
        default=100,
        metavar="N",
        help="parameter sets per unknown link, full factorial (default 100: the paper's 10,000 configs)",
    )
    ap.add_argument("--frames", type=int, default=100, metavar="F", help="frames per configuration (default 100)")
    ap.add_argument("--repeats", type=int, default=3, metavar="R", help="timed runs; the best is reported (default 3)")
    args = ap.parse_args(argv)

    print(header())
    model = ineid.load_robot("sweaty-arm")
    clean = DatasetSpec(combination=Combination("factorial", per_link=args.configs_per_link), n_frames=args.frames)
    noise = NoiseModel.create(model.n_dof, force=0.5, moment=0.05, qd=0.01, qdd=0.1)
    variants = {
        "clean": clean,
        "noise": DatasetSpec(combination=clean.combination, n_frames=args.frames, noise=noise),
        "fourier": DatasetSpec(combination=clean.combination, n_frames=args.frames, frames=FrameSampling("fourier")),
    }
    n_configs = clean.combination.count(len(model.unknown_links))
    n_frames = n_configs * args.frames
    is_paper = (args.configs_per_link, args.frames) == (100, 100)
    print(
        f"\nsweaty-arm ({', '.join(model.unknown_links)} unknown): factorial {args.configs_per_link} -> "
        f"{n_configs:,} configurations x {args.frames} frames = {n_frames:,} frames"
        f"{' (the paper dataset)' if is_paper else ''}; best of {args.repeats} after a warm-up"
    )

    rows = []  # (case, seconds, file MB or None)
    with tempfile.TemporaryDirectory(prefix="ineid-bench-") as tmp:
        path, scratch = Path(tmp) / "data.h5", Path(tmp) / "warmup.h5"

        def write(spec: DatasetSpec) -> float:
            path.unlink(missing_ok=True)
            return timed(lambda: write_dataset(model, spec, path))

        def size_mb() -> float:
            return path.stat().st_size / 1e6

        cold = write(clean)
        rows.append(("write_dataset, first run in the process (JAX compile incl.)", cold, size_mb()))
        write_dataset(model, warmup_spec(model, clean), scratch)  # noise and Fourier frames: same shapes

        for key, label in (
            ("clean", "write_dataset, clean (the paper's settings)"),
            ("noise", "write_dataset + noise (clean arrays kept too)"),
            ("fourier", "write_dataset, Fourier-trajectory frames"),
        ):
            best = min(write(variants[key]) for _ in range(args.repeats))
            rows.append((label, best, size_mb()))
        best_write = rows[1][1]
        best = min(timed(lambda: generate_dataset(model, clean)) for _ in range(args.repeats))
        rows.append(("generate_dataset (in memory, no file)", best, None))
        write(clean)  # the file to load: the clean one
        best = min(timed(lambda: load_dataset(path)) for _ in range(args.repeats))
        rows.append(("load_dataset of the clean file (all arrays, checked)", best, None))

    print(f"{'case':<60} {'seconds':>8} {'frames/s':>12} {'file MB':>8}")
    for label, seconds, mb in rows:
        print(f"{label:<60} {seconds:>8.2f} {n_frames / seconds:>12,.0f} {'' if mb is None else f'{mb:.1f}':>8}")
    verdict = "MET" if best_write < FLOOR_S else "MISSED"
    what = "" if is_paper else f" (this run: {n_frames:,} frames, not the paper's 1,000,000)"
    print(f"floor < {FLOOR_S:.0f} s for the paper's dataset: {best_write:.2f} s -> {verdict}{what}")


if __name__ == "__main__":
    main()
