"""Find or derive the generated modules of a chain.

This module sits above :mod:`ineid.robots` (URDF parsing, :class:`RobotModel`) and
:mod:`ineid.symbolic` (SymPy derivation): a built-in robot loads its checked-in modules
from :mod:`ineid.generated`; any other URDF loads its modules from the cache folder keyed
by its kinematic fingerprint, and derives and writes them first when they are missing,
stale, or fail the checks of :mod:`ineid._trust` (ownership, permissions, content hash).
``robots`` never imports ``symbolic``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import ModuleType

from ineid.cache import private_folder
from ineid.chain import Chain
from ineid.errors import UntrustedCodeError

log = logging.getLogger(__name__)


def default_codegen_dir(chain: Chain) -> Path:
    """The cache folder of a chain's generated modules, ``<cache>/generated/<fingerprint>``, created 0700.

    When the cache cannot be trusted (see :func:`ineid.cache.private_folder`), a private
    temporary folder of this process instead.
    """
    return private_folder("generated", chain.kinematic_fingerprint())


def generated_modules_for(
    chain: Chain, robot_name: str, codegen_dir: str | Path | None = None
) -> tuple[ModuleType, ModuleType]:
    """``(jax module, casadi module)`` of a URDF chain, deriving and writing them first if needed.

    The modules are reused when their files match the manifest ineid wrote beside them
    (in the cache, also: owned by you, not writable by others; see :mod:`ineid._trust`)
    and their ``KINEMATIC_FINGERPRINT`` equals the chain's. Files that fail a check are
    never run: they are regenerated, with one warning line saying why.
    """
    from ineid.generated import file_names, load_from_directory, load_sources

    cached = codegen_dir is None
    directory = default_codegen_dir(chain) if cached else Path(codegen_dir)
    try:
        modules = load_from_directory(directory, robot_name, private=cached)
    except UntrustedCodeError as e:
        what = "the cached generated code" if cached else "the generated code"
        log.warning("%s of %s in %s %s; regenerating", what, robot_name, directory, e.reason)
        modules = None
    if modules is not None and modules[0].KINEMATIC_FINGERPRINT == chain.kinematic_fingerprint():
        log.info("generated code of %s found in %s", robot_name, directory)
        return modules
    log.info("deriving the regressor of %s with SymPy into %s", robot_name, directory)
    emitted = generate_code(chain, robot_name, directory)
    # the bytes just written and hashed, not a second read of the files
    return load_sources(directory, robot_name, {n: emitted.files[n].encode() for n in file_names(robot_name)})


def generate_code(chain: Chain, robot_name: str, directory: str | Path, regenerate: str | None = None):
    """Derive and emit a chain's modules into ``directory``; returns the :class:`~ineid.symbolic.emit.Emitted` record.

    ``regenerate`` is the command named in the files' header (default ``ineid generate ROBOT``).
    Each step is logged at INFO (see :func:`~ineid.symbolic.emit.derive_and_emit`).
    Outside the package's own ``ineid/generated`` (package code, not checked), the SHA-256
    of each file is recorded in the folder's manifest (:data:`ineid._trust.MANIFEST`),
    written after the files: what :func:`ineid.generated.load_from_directory` checks.

    Raises:
        CodegenError: a chain longer than ``MAX_DERIVED_JOINTS`` (lock joints), or emitted code that fails its check.
    """
    from ineid.generated import BUILTIN_DIR
    from ineid.symbolic.emit import derive_and_emit, write_files

    emitted = derive_and_emit(chain, robot_name, regenerate or "ineid generate ROBOT")
    write_files(emitted.files, directory, manifest=Path(directory).resolve() != BUILTIN_DIR)
    return emitted
