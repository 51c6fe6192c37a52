"""Sweeps on a Ray cluster: one Ray task per population (``ineid sweep --engine ray``).

The driver puts the dataset in Ray's object store once and submits one task per population
of trials (:func:`ineid.learn.trials.populations`: the trials that share a network's shapes
train together), each reserving ``cpus_per_trial`` CPUs and ``gpus_per_trial`` GPUs. A task
trains and evaluates its trials into temporary folders on its node and returns each run
folder's files with its row; the driver writes them into ``OUT/<name>`` (a new folder swapped
in whole), so the nodes need no shared file system. Without an address, a local cluster is started for the
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
from ineid.learn.trials import SweepRow, populations, run_name, run_population, run_trial

INSTALL_HINT = "the ray engine needs Ray: pip install 'ineid[ray]' (or pip install 'ray[default]')"


def import_ray():
    """The ``ray`` module, or :class:`OptionalDependencyError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise OptionalDependencyError(INSTALL_HINT) from None
    return ray


def _population(
    ds, cfgs: list[TrainConfig], dataset_path: str | None, physics_mode: str, started: list[dict[str, bytes] | None]
) -> list[tuple[SweepRow, dict[str, bytes]]]:
    """One population on a worker: its trials trained together and evaluated in a temporary folder each; per trial
    its row and its folder's files (none for a failed trial).

    ``started``: per trial, the files of an interrupted run of it (continued from its checkpoint), or None.
    """
    # float64 JAX: the worker imported this module, ineid.learn.ray_engine, so ineid/__init__ ran first
    with tempfile.TemporaryDirectory(prefix="ineid-population-") as tmp:
        jobs = []
        for i, (cfg, files) in enumerate(zip(cfgs, started, strict=True)):
            run_dir = Path(tmp) / str(i) / run_name(cfg)
            run_dir.mkdir(parents=True)
            for name, data in (files or {}).items():
                (run_dir / name).write_bytes(data)
            jobs.append((cfg, run_dir, "checkpoint" if files else "new"))
        rows = run_population(ds, jobs, dataset_path, None, physics_mode, failed_text=_named)
        return [
            (row, {n: (d / n).read_bytes() for n in RUN_FILES if (d / n).is_file()} if row.status == "ok" else {})
            for row, (_, d, _) in zip(rows, jobs, strict=True)
        ]


def _named(err: BaseException) -> str:
    """A trial's error as a failed row says it: its class and first line."""
    first = next((line for line in str(err).splitlines() if line.strip()), "")
    return f"{type(err).__name__}: {first.strip()}"


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
    """Run every trial of ``cfgs`` into ``out_dir/<name>``, one Ray task per population; rows in the order of
    ``cfgs`` (see :func:`ray_populations`; ``states``: a resumed sweep's
    :func:`ineid.learn.trials.trial_state` per trial name)."""
    states = states or {}
    jobs = [(cfg, Path(out_dir) / run_name(cfg), states.get(run_name(cfg), "new")) for cfg in cfgs]
    return ray_populations(
        ds,
        jobs,
        populations(cfgs),
        dataset_path=dataset_path,
        physics_mode=physics_mode,
        progress=progress,
        address=address,
        cpus_per_trial=cpus_per_trial,
        gpus_per_trial=gpus_per_trial,
        ray_init=ray_init,
    )


def ray_populations(
    ds,
    jobs: list[tuple[TrainConfig, Path, str]],
    groups: list[list[int]],
    *,
    dataset_path: str | None = None,
    physics_mode: str = "cached",
    progress: Callable | None = None,
    address: str | None = None,
    cpus_per_trial: float = 1.0,
    gpus_per_trial: float = 0.0,
    ray_init: dict | None = None,
) -> list[SweepRow]:
    """Run the trials ``(cfg, run folder, state)`` as Ray tasks, one per population of ``groups`` (indices into
    ``jobs``); rows in the order of ``jobs`` (see the module doc).

    Args:
        ds: the dataset (with the truth); sent to the object store once.
        jobs: per trial its settings, its run folder, and its :func:`ineid.learn.trials.trial_state`: finished
            trials (and those only to evaluate) are done here without Ray; an interrupted one is sent with its
            files and continued from its checkpoint.
        groups: the populations.
        dataset_path, physics_mode: as for :func:`ineid.learn.sweep.sweep`.
        progress: ``progress(done, total, row)`` after each trial.
        address: a Ray cluster's address (``ray://host:10001``, ``host:6379`` or ``auto``);
            None starts a local cluster and stops it afterwards.
        cpus_per_trial, gpus_per_trial: resources each task (a population) reserves.
        ray_init: extra ``ray.init`` arguments for the local cluster (e.g. ``num_cpus=2``).

    Raises:
        OptionalDependencyError: Ray is not installed.
        ValueError: negative resources, or ``cpus_per_trial`` more than a local cluster has.
    """
    ray = import_ray()
    if cpus_per_trial < 0 or gpus_per_trial < 0:
        raise ValueError(f"resources per trial must be >= 0, got {cpus_per_trial} CPUs and {gpus_per_trial} GPUs")
    rows: list[SweepRow | None] = [None] * len(jobs)
    done = [0]

    def report(i: int, row: SweepRow) -> None:
        rows[i] = row
        done[0] += 1
        if progress is not None:
            progress(done[0], len(jobs), row)

    remote = []
    for group in groups:
        sent = []
        for i in group:
            cfg, run_dir, state = jobs[i]
            if state in ("finished", "evaluate"):
                try:
                    report(i, run_trial(ds, cfg, run_dir, dataset_path, None, physics_mode, state))
                except IneidError as e:
                    report(i, SweepRow.failed(cfg, str(e)))
            else:
                sent.append(i)
        if sent:
            remote.append(sent)
    if remote:
        _run_remote(
            ray,
            ds,
            jobs,
            remote,
            (dataset_path, physics_mode),
            (address, cpus_per_trial, gpus_per_trial, ray_init),
            report,
        )
    return rows


def _run_remote(ray, ds, jobs, remote: list[list[int]], settings: tuple, cluster: tuple, report: Callable) -> None:
    """Submit one task per population of ``remote`` and report its trials' rows as each completes."""
    address, cpus_per_trial, gpus_per_trial, ray_init = cluster
    started = _start_cluster(ray, address, cpus_per_trial, ray_init)
    try:
        task = ray.remote(_population).options(num_cpus=cpus_per_trial, num_gpus=gpus_per_trial, max_retries=0)
        ds_ref = ray.put(ds)
        pending = {}
        for group in remote:
            cfgs = [jobs[i][0] for i in group]
            files = [_run_files(jobs[i][1]) if jobs[i][2] == "checkpoint" else None for i in group]
            pending[task.remote(ds_ref, cfgs, *settings, files)] = group
        _gather(ray, pending, jobs, report)
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


def _gather(ray, pending: dict, jobs: list, report: Callable) -> None:
    """Wait for the ``pending`` tasks (``{object ref: its trials' indices into jobs}``), reporting each trial's row as
    its population completes and writing its run folder from the files sent back (a population that raised or whose
    worker died: every trial a failed row; a trial that sent back anything but its run files: a failed row,
    nothing written)."""
    while pending:
        (ref,), _ = ray.wait(list(pending), num_returns=1)
        group = pending.pop(ref)
        try:
            results = ray.get(ref)
        except ray.exceptions.RayError as e:  # the population raised, or its worker died
            for i in group:
                report(i, SweepRow.failed(jobs[i][0], _message(e)))
            continue
        for i, (row, files) in zip(group, results, strict=True):
            if row.status == "ok":
                problem = files_problem(files)
                if problem is None:
                    _write_run(jobs[i][1], files)
                else:  # a worker that is not ours, or a broken one: write nothing of it
                    row = SweepRow.failed(
                        jobs[i][0], f"the worker sent back {problem}; nothing of this trial was written"
                    )
            report(i, row)


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
