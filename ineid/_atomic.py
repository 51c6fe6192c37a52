"""The output policy: refuse to replace without ``overwrite``, write atomically, clean up on signals.

Every file ineid writes goes through here: :func:`atomic_write` for data in memory,
:func:`atomic_output` for files written by a library (HDF5, matplotlib, CSV writers), and
:class:`ineid.data.write.DatasetWriter` (which uses :func:`temporary_path`) for streamed
datasets. A temporary file beside the target is renamed into place only when complete, so
an exception, Ctrl-C or (once :func:`terminate_on_sigterm` is installed) a scheduler's
SIGTERM leaves either the old file or nothing, never half a file.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from ineid.errors import OutputExistsError


def check_output(path: str | Path, overwrite: bool) -> Path:
    """Return ``path`` if ineid may write it; :class:`OutputExistsError` if it exists and ``overwrite`` is off.

    The one place that words the refusal, so every command says the same thing.
    """
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{path} exists; pass --overwrite to replace it")
    return path


def temporary_path(path: str | Path) -> Path:
    """The hidden temporary name a file is written under before it replaces ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on a normal exit it replaces ``path``, otherwise it is deleted.

    Writers that append their own suffix (``savefig`` with a format) are given the suffix
    of ``path``, so the temporary file keeps it: ``.name.<pid>.tmp.png``.
    """
    path = Path(path)
    tmp = temporary_path(path)
    if path.suffix:
        tmp = tmp.with_name(tmp.name + path.suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as e:
        # never let the cleanup raise (a read-only folder refuses even the unlink): the
        # first error is the one the user needs to see, naming the file (a failed write()
        # on a full disk does not)
        with suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(e, OSError) and e.filename is None:
            e.filename = str(path)
        raise


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text or bytes) to ``path`` atomically; on failure ``path`` is untouched."""
    with atomic_output(path) as tmp:
        if isinstance(data, str):
            tmp.write_text(data)
        else:
            tmp.write_bytes(data)
    return Path(path)


class Terminated(BaseException):  # noqa: N818 - named for the signal, like KeyboardInterrupt
    """Raised in the main thread by SIGTERM once :func:`terminate_on_sigterm` is installed.

    A ``BaseException``, like ``KeyboardInterrupt``, so it unwinds through every
    ``except Exception`` and the atomic writers' cleanup runs.
    """


def _raise_terminated(signum, frame) -> None:  # noqa: ARG001
    raise Terminated(f"terminated by signal {signum}")


def terminate_on_sigterm() -> None:
    """Turn SIGTERM into :class:`Terminated` in the main thread (a no-op elsewhere)."""
    try:
        signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread
        print("ineid: SIGTERM handler not installed (not the main thread)", file=sys.stderr)


def write_csv(path: str | Path, fieldnames: list[str], rows: list[dict] | list[list]) -> Path:
    """Write a CSV with a header atomically; ``rows`` are dicts (by field name) or sequences."""
    import csv  # noqa: PLC0415
    import io  # noqa: PLC0415

    buf = io.StringIO(newline="")
    if rows and isinstance(rows[0], dict):
        w = csv.DictWriter(buf, fieldnames=fieldnames)
        w.writeheader()
        w.writerows(rows)
    else:
        w = csv.writer(buf)
        w.writerow(fieldnames)
        w.writerows(rows)
    return atomic_write(path, buf.getvalue())


def save_figure(fig, path: str | Path, **savefig_kwargs) -> Path:
    """``fig.savefig(path)`` atomically, the format taken from the suffix (default PNG)."""
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **savefig_kwargs)
    return path
