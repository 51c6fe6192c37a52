"""The exceptions ineid raises for user-facing problems.

Every message names the problem and, where there is one, the fix. The CLI turns any
:class:`IneidError` into a one-line message and a non-zero exit status.
"""

from __future__ import annotations


class IneidError(Exception):
    """Base class of every error ineid raises on purpose."""


class RobotModelError(IneidError):
    """A robot description (URDF or built-in name) cannot be used as a serial-chain model."""


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
    (``infeasible_bounds``, ``duration``, ``harmonics``, ``rank_deficient``, ``noise``, ``settings``)."""

    def __init__(self, message: str, reason: str | None = None) -> None:
        super().__init__(message)
        self.reason = reason


class OptionalDependencyError(IneidError):
    """A feature needs an optional package that is not installed (the message says how to install it)."""


class StorageError(IneidError):
    """A file cannot be written where asked: not enough free space, a read-only or forbidden folder.

    (The file system's own faults, ``OSError`` with ``ENOSPC``, ``EROFS``, ``EACCES``..., are
    worded by :func:`ineid._faults.describe_fault`; this is raised before a write that
    cannot fit.)
    """


class ResourceError(IneidError):
    """A request needs more memory (or another machine resource) than there is, or than ineid allows."""
