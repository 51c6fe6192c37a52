"""Sweeps on a Ray cluster: one Ray task per trial (``ineid sweep --engine ray``).

The driver puts the dataset in Ray's object store once and submits one task per grid
point, each reserving ``cpus_per_trial`` CPUs and ``gpus_per_trial`` GPUs. A task trains
and evaluates into a temporary folder on its node and returns the run folder's files with
its row; the driver writes them into ``OUT/<name>`` (a new folder swapped in whole), so
the nodes need no shared file system. Without an address, a local cluster is started for the
sweep and stopped after it (a Ray instance this process already started is used and left
running). A trial that raises, or whose worker dies, is reported as a failed row; the
others go on.

The nodes need ineid (with its generated code) importable: on a local cluster the workers
inherit the driver's environment; on a remote one install ineid on every node.
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

from ineid._atomic import output_lock, replace_folder, staging_folder
from ineid.errors import IneidError, OptionalDependencyError, TrainingError
from ineid.learn.runs import RUN_FILES
from ineid.learn.train import TrainConfig
from ineid.learn.trials import SweepRow, run_name, run_trial

INSTALL_HINT = "the ray engine needs Ray: pip install 'ineid[ray]' (or pip install 'ray[default]')"


def import_ray():
    """The ``ray`` module, or :class:`OptionalDependencyError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise OptionalDependencyError(INSTALL_HINT) from None
    return ray


def _trial(
    ds, cfg: TrainConfig, dataset_path: str | None, physics_mode: str, started: dict[str, bytes] | None = None
) -> tuple[SweepRow, dict[str, bytes]]:
    """One trial on a worker: train and evaluate in a temporary folder; the row and the folder's files.

    ``started``: the files of an interrupted run of this trial, continued from its checkpoint.
    """
    # float64 JAX: the worker imported this module, ineid.learn.ray_engine, so ineid/__init__ ran first
    with tempfile.TemporaryDirectory(prefix="ineid-trial-") as tmp:
        run_dir = Path(tmp) / run_name(cfg)
        run_dir.mkdir()
        for name, data in (started or {}).items():
            (run_dir / name).write_bytes(data)
        row = run_trial(ds, cfg, run_dir, dataset_path, None, physics_mode, "checkpoint" if started else "new")
        files = {name: (run_dir / name).read_bytes() for name in RUN_FILES if (run_dir / name).is_file()}
    return row, files


def _message(err: BaseException) -> str:
    """The first line of what went wrong in a trial (the trial's own exception when Ray wrapped it)."""
    cause = getattr(err, "cause", None)
    text = str(cause) if cause is not None else str(err)
    first = next((line for line in text.splitlines() if line.strip()), type(err).__name__)
    return f"{type(cause or err).__name__}: {first.strip()}"


def ray_trials(
    ds,
    cfgs: list[TrainConfig],
    out_dir: Path,
    *,
    dataset_path: str | None = None,
    physics_mode: str = "cached",
    progress: Callable | None = None,
    address: str | None = None,
    cpus_per_trial: float = 1.0,
    gpus_per_trial: float = 0.0,
    ray_init: dict | None = None,
    states: dict[str, str] | None = None,
) -> list[SweepRow]:
    """Run every trial of ``cfgs`` as a Ray task; rows in completion order (see the module doc).

    Args:
        ds: the dataset (with the truth); sent to the object store once.
        cfgs: one training configuration per trial.
        out_dir: where the run folders ``<name>`` are written.
        dataset_path, physics_mode: as for :func:`ineid.learn.sweep.sweep`.
        progress: ``progress(done, total, row)`` after each trial.
        address: a Ray cluster's address (``ray://host:10001``, ``host:6379`` or ``auto``);
            None starts a local cluster and stops it afterwards.
        cpus_per_trial, gpus_per_trial: resources each task reserves.
        ray_init: extra ``ray.init`` arguments for the local cluster (e.g. ``num_cpus=2``).
        states: a resumed sweep's :func:`ineid.learn.trials.trial_state` per trial name:
            finished trials (and those only to evaluate) are done here without Ray; an
            interrupted one is sent with its files and continued from its checkpoint.

    Raises:
        OptionalDependencyError: Ray is not installed.
        ValueError: negative resources, or ``cpus_per_trial`` more than a local cluster has.
    """
    ray = import_ray()
    if cpus_per_trial < 0 or gpus_per_trial < 0:
        raise ValueError(f"resources per trial must be >= 0, got {cpus_per_trial} CPUs and {gpus_per_trial} GPUs")
    states = states or {}
    rows: list[SweepRow] = []
    remote = []
    for cfg in cfgs:
        state = states.get(run_name(cfg), "new")
        if state in ("finished", "evaluate"):
            try:
                rows.append(run_trial(ds, cfg, out_dir / run_name(cfg), dataset_path, None, physics_mode, state))
            except IneidError as e:
                rows.append(SweepRow.failed(cfg, str(e)))
            if progress is not None:
                progress(len(rows), len(cfgs), rows[-1])
        else:
            remote.append((cfg, _run_files(out_dir / run_name(cfg)) if state == "checkpoint" else None))
    if not remote:
        return rows
    started = _start_cluster(ray, address, cpus_per_trial, ray_init)
    try:
        task = ray.remote(_trial).options(num_cpus=cpus_per_trial, num_gpus=gpus_per_trial, max_retries=0)
        ds_ref = ray.put(ds)
        pending = {task.remote(ds_ref, cfg, dataset_path, physics_mode, files): cfg for cfg, files in remote}
        _gather(ray, pending, out_dir, rows, len(cfgs), progress)
        return rows
    finally:
        if started:
            ray.shutdown()


def _start_cluster(ray, address: str | None, cpus_per_trial: float, ray_init: dict | None) -> bool:
    """Join the cluster at ``address``, or start a local one (None), unless Ray is already initialized.

    Returns:
        Whether this call initialized Ray (and the caller shuts it down).

    Raises:
        ValueError: ``cpus_per_trial`` more than the local cluster has.
    """
    if ray.is_initialized():
        return False
    sigterm = signal.getsignal(signal.SIGTERM)
    if address is None:
        options = {"include_dashboard": False, "log_to_driver": False, **(ray_init or {})}
        cpus = options.get("num_cpus") or os.cpu_count() or 1
        if cpus_per_trial > cpus:
            raise ValueError(
                f"{cpus_per_trial} CPUs per trial but the local cluster has {cpus}; lower --cpus-per-trial"
            )
        ray.init(**options)
    else:
        ray.init(address=address, log_to_driver=False)
    if sigterm is not None and threading.current_thread() is threading.main_thread():
        # a local cluster's head installs its own SIGTERM handler in this process (stop Ray's processes, exit 1,
        # no line); ineid's stays, and the shutdown below stops those processes
        signal.signal(signal.SIGTERM, sigterm)
    return True


def _gather(ray, pending: dict, out_dir: Path, rows: list[SweepRow], total: int, progress: Callable | None) -> None:
    """Wait for the ``pending`` tasks (``{object ref: its configuration}``), appending each trial's row to ``rows`` as
    it completes and writing its run folder from the files it sent back (a trial that raised, died or sent back
    anything but its run files: a failed row, nothing written)."""
    while pending:
        (ref,), _ = ray.wait(list(pending), num_returns=1)
        cfg = pending.pop(ref)
        try:
            row, files = ray.get(ref)
        except ray.exceptions.RayError as e:  # the trial raised, or its worker died
            row = SweepRow.failed(cfg, _message(e))
        else:
            problem = files_problem(files)
            if problem is None:
                _write_run(out_dir / run_name(cfg), files)
            else:  # a worker that is not ours, or a broken one: write nothing of it
                row = SweepRow.failed(cfg, f"the worker sent back {problem}; nothing of this trial was written")
        rows.append(row)
        if progress is not None:
            progress(len(rows), total, row)


def _run_files(run_dir: Path) -> dict[str, bytes]:
    return {name: (run_dir / name).read_bytes() for name in RUN_FILES if (run_dir / name).is_file()}


def files_problem(files: object) -> str | None:
    """Why a worker's ``{file name: bytes}`` may not be written into a run folder, or None if it may.

    Only the plain names of :data:`~ineid.learn.runs.RUN_FILES` are accepted: a name is
    joined onto the run folder, so one with a path separator or ``..`` could write anywhere.
    """
    if not isinstance(files, dict):
        return f"{type(files).__name__} instead of the run's files"
    for name, content in files.items():
        if not isinstance(name, str) or name not in RUN_FILES:
            return f"a file named {name!r}, not one of the run files ({', '.join(RUN_FILES)})"
        if not isinstance(content, bytes):
            return f"{type(content).__name__} instead of the bytes of {name}"
    return None


def _write_run(run_dir: Path, files: dict[str, bytes]) -> None:
    """Put a trial's run folder holding ``files`` at ``run_dir``: written beside it and swapped in whole
    (:func:`ineid._atomic.replace_folder`), so an interruption leaves the old folder, never a mix.

    Raises:
        TrainingError: ``files`` holds anything but run files (:func:`files_problem`).
    """
    problem = files_problem(files)
    if problem is not None:
        raise TrainingError(f"refusing to write {problem} into {run_dir}")
    with output_lock(run_dir):
        staging = staging_folder(run_dir)
        try:
            for name, data in files.items():
                (staging / name).write_bytes(data)
            replace_folder(staging, run_dir, keep=RUN_FILES)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
