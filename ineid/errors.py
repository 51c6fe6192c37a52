"""The exceptions ineid raises for user-facing problems.

Every message names the problem and, where there is one, the fix. The CLI turns any
:class:`IneidError` into a one-line message and a non-zero exit status.
"""

from __future__ import annotations


class IneidError(Exception):
    """Base class of every error ineid raises on purpose."""


class RobotModelError(IneidError):
    """A robot description (URDF or built-in name) cannot be used as a model (a tree of moving joints on a fixed
    base)."""


class PhysicalConsistencyError(IneidError):
    """Inertial parameters that no rigid body can have (e.g. negative mass)."""


class CodegenError(IneidError):
    """Generated code is missing, stale, or cannot be produced."""


class DatasetError(IneidError):
    """A dataset file or array is malformed."""


class IdentificationError(IneidError):
    """An identification problem cannot be solved as posed; carries the solver status."""

    def __init__(self, message: str, status: str | None = None) -> None:
        super().__init__(message)
        self.status = status


class TrainingError(IneidError):
    """A network cannot be trained or evaluated as asked (no truth in the data, a bad run folder)."""


class OutputExistsError(IneidError):
    """An output file or folder exists and the caller did not ask to replace it."""


class ExcitationError(IneidError):
    """An excitation trajectory cannot be designed as asked; ``reason`` says which check failed
    (``infeasible_bounds``, ``duration``, ``harmonics``, ``rank_deficient``, ``noise``, ``settings``, ``workers``)."""

    def __init__(self, message: str, reason: str | None = None) -> None:
        super().__init__(message)
        self.reason = reason


class OptionalDependencyError(IneidError):
    """A feature needs an optional package that is not installed (the message says how to install it)."""


class UntrustedCodeError(CodegenError):
    """Code on disk that ineid will not run: it does not match the manifest ineid wrote beside it,
    or (in the cache) a file or folder is owned by another user or writable by others.
    ``reason`` is the phrase that says which check failed."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


class CacheError(IneidError):
    """The cache folder cannot be used or cleared as asked (a folder ineid did not create, for instance)."""


class OutputIsInputError(IneidError):
    """An output would replace one of the command's own inputs (the same file, or a file of an input folder)."""


class OutputBusyError(IneidError):
    """Another process holds the output's lock (:func:`ineid._atomic.output_lock`): it is writing the same output."""


class StorageError(IneidError):
    """A file cannot be written where asked: not enough free space, a read-only or forbidden folder.

    (The file system's own faults, ``OSError`` with ``ENOSPC``, ``EROFS``, ``EACCES``..., are
    worded by :func:`ineid._faults.describe_fault`; this is raised before a write that
    cannot fit.)
    """


class InputFileError(IneidError):
    """An input cannot be read safely: not a regular file (a FIFO, a device), too large for its format,
    or a file that reaches outside itself (an HDF5 external link). The message names the file and the fix."""


class ResourceError(IneidError):
    """A request needs more memory (or another machine resource) than there is, or than ineid allows."""
