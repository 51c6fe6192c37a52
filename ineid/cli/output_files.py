"""The outputs of the ``ineid`` commands: checked before any work, never one of the command's inputs, locked
while written, and what an interruption leaves said in one line."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import click

from ineid.cli.options import RobotChoice

overwrite_option = click.option("--overwrite", is_flag=True, help="Replace the output if it exists.")


def prepare_output(
    path: Path,
    overwrite: bool,
    kind: str = "file",
    *,
    inputs: Iterable[tuple[str, Path | None]] = (),
    option: str = "--out",
    contents: Iterable[str] = (),
) -> Path:
    """Check an output before any work, and lock it for the rest of the command.

    A file (``kind="file"``) must be a file name in an existing folder, new unless
    ``overwrite``; a folder (``kind="folder"``, a run or sweep folder whose contents the
    library checks) gets its missing parent folders. Neither may be one of the command's
    ``inputs`` (the same file, or the same resolved path); a folder's ``contents`` (the
    names the command writes in it) are checked the same way. Then the output's lock
    (:func:`ineid._atomic.output_lock`) is taken and held until the command ends, so a
    second ineid process writing the same output stops at once with one line.

    Args:
        path: the output.
        overwrite: ``--overwrite`` was given.
        kind: ``"file"`` or ``"folder"``.
        inputs: ``(what, path)`` of each input the command reads (``("the input dataset",
            data.h5)``); None paths are skipped. The refusal reads ``--out PATH is WHAT``.
        option: the option that named the output, for the messages.
        contents: for a folder, the files the command writes in it.

    Raises:
        OutputIsInputError: the output is an input.
        OutputBusyError: another process is writing it.
        OutputExistsError: it exists and ``overwrite`` is off (:func:`ineid._atomic.check_output`).
        click.BadParameter: a folder where a file is expected, or a missing parent folder.
    """
    from ineid._atomic import check_output, output_lock

    path = Path(path)
    if kind == "file" and path.is_dir():
        raise click.BadParameter(f"{path} is a folder; give a file name", param_hint=option)
    if kind == "file" and not path.parent.is_dir():
        raise click.BadParameter(f"folder {path.parent} does not exist; create it first", param_hint=option)
    inputs = [(what, Path(p)) for what, p in inputs if p is not None]
    check_not_input(path, inputs, option, kind)
    for name in contents:
        check_not_input(path / name, inputs, option, kind, folder=path)
    if kind == "folder":
        path.parent.mkdir(parents=True, exist_ok=True)
    ctx = click.get_current_context(silent=True)
    if ctx is not None:
        ctx.with_resource(output_lock(path, option))
    return check_output(path, overwrite) if kind == "file" else path


def check_not_input(
    path: Path,
    inputs: Iterable[tuple[str, Path]],
    option: str = "--out",
    kind: str = "file",
    folder: Path | None = None,
) -> None:
    """:class:`OutputIsInputError` if ``path`` is one of ``inputs`` (:func:`ineid._atomic.same_path`).

    ``folder``: ``path`` is a file the command writes in this output folder (the message names the folder).
    """
    from ineid._atomic import same_path
    from ineid.errors import OutputIsInputError

    for what, inp in inputs:
        if same_path(path, inp):
            problem = (
                f"{option} {path} is {what}" if folder is None else f"{option} {folder} would replace {path}, {what}"
            )
            raise OutputIsInputError(f"{problem}; choose another {kind}")


def folder_inputs(path: Path | None, what: str) -> list[tuple[str, Path | None]]:
    """``path`` as an input, and when it is a folder (a ROS 2 bag) each file in it too."""
    if path is None:
        return []
    path = Path(path)
    files = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else []
    return [(what, path)] + [(f"a file of {what} {path}", p) for p in files]


def robot_inputs(robot: RobotChoice) -> list[tuple[str, Path | None]]:
    """The robot's URDF as an input (nothing for a built-in name)."""
    path = Path(robot.robot)
    return [("the robot's URDF", path)] if path.is_file() else []


def run_inputs(run_dir: Path | None, what: str = "the input run") -> list[tuple[str, Path | None]]:
    """The files of a run folder read as an input, for :func:`prepare_output` (its evaluation may be rewritten)."""
    if run_dir is None:
        return []
    from ineid.learn.runs import EVALUATION, RUN_FILES  # no JAX: runs imports it lazily

    return [(f"{what}'s {name}", Path(run_dir) / name) for name in RUN_FILES if name != EVALUATION]


def results_inputs(results_path: Path) -> list[tuple[str, Path | None]]:
    """The files a results file records as what it was solved on (the dataset, each recording, the
    validation recording), as inputs: a command that reads the results never replaces them. Nothing for
    a results file that does not read (the command's own read says why)."""
    from ineid.errors import DatasetError
    from ineid.identify.results import load_results

    try:
        meta = load_results(results_path).meta
    except (DatasetError, OSError):
        return []
    found = [("the dataset the results were solved on", meta.get("dataset_path"))]
    found += [("a recording the results were solved on", r.get("path")) for r in meta.get("recordings") or []]
    found.append(("the validation recording of the results", (meta.get("validation") or {}).get("path")))
    return [(what, Path(path)) for what, path in found if path]


@contextmanager
def on_interrupt(left_behind: Callable[[], str | None]) -> Iterator[None]:
    """On Ctrl-C or SIGTERM, let the CLI say what the command left on purpose (``left_behind()``, or
    None for nothing) instead of "no partial output file was left"; the exit status stays 130 / 143."""
    from ineid._interrupts import Terminated

    try:
        yield
    except (KeyboardInterrupt, Terminated) as e:
        note = left_behind()
        if note:
            e.ineid_left_behind = note
        raise
