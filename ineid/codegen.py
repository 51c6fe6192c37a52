"""Find or derive the generated modules of a chain, and load robot models on top of them.

This module sits above :mod:`ineid.robots` (URDF parsing, :class:`RobotModel`) and
:mod:`ineid.symbolic` (SymPy derivation): a built-in robot loads its checked-in modules
from :mod:`ineid.generated`; any other URDF loads its modules from the cache folder keyed
by its kinematic fingerprint, and derives and writes them first when they are missing,
stale, or fail the checks of :mod:`ineid._trust` (ownership, permissions, content hash).
``robots`` never imports ``symbolic``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType

from ineid.cache import private_folder
from ineid.errors import RobotModelError, UntrustedCodeError
from ineid.robots import BUILTIN_ROBOTS, Chain, RobotModel, load_chain
from ineid.robots.model import DEFAULT_GRAVITY

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


def load_robot(
    robot: str | Path,
    *,
    unknown_links: Sequence[str] | None = None,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
    locked_joints: Mapping[str, float] | None = None,
    codegen_dir: str | Path | None = None,
) -> RobotModel:
    """Load a built-in robot by name or any serial-chain URDF or MJCF by path.

    Args:
        robot: a built-in name (``"sweaty-arm"``), a path to a ``.urdf`` file, or to an MJCF
            (``.xml``; read by MuJoCo, :mod:`ineid.robots.mjcf`: needs ``ineid[mujoco]``).
        unknown_links: moving links whose parameters are to be identified; default: the
            built-in robot's choice, or every moving link of a URDF.
        gravity: (3,) m/s^2 in the base frame.
        locked_joints: ``{joint name: position}`` of joints to treat as fixed (a URDF's
            gripper fingers, for instance). Not for built-in robots.
        codegen_dir: folder with (or for) a URDF's generated code; default: a cache folder
            keyed by the kinematic fingerprint (see :mod:`ineid.cache`). A URDF without
            generated code is derived once with SymPy (seconds).

    Raises:
        RobotModelError: unknown name, unreadable or unusable URDF or MJCF, or bad link choice.
        OptionalDependencyError: an MJCF without MuJoCo installed.
    """
    from ineid.generated import load_builtin
    from ineid.robots.mjcf import robot_file_chain

    key = str(robot)
    if key in BUILTIN_ROBOTS and not Path(key).is_file():
        spec = BUILTIN_ROBOTS[key]
        if locked_joints:
            raise RobotModelError(f"{key} is a built-in serial arm; locked_joints applies to URDF files only")
        chain = load_chain(spec.urdf_path)
        jax_mod, ca_mod = load_builtin(key)
        links = spec.unknown_links if unknown_links is None else unknown_links
        return RobotModel(chain, spec.urdf_path, key, gravity, links, jax_mod, ca_mod)
    path = Path(key)
    if not path.exists():  # a FIFO or a folder is refused by robot_file_chain, naming what it is
        raise RobotModelError(
            f"{key!r} is neither a built-in robot ({', '.join(BUILTIN_ROBOTS)}) nor a URDF file (or MJCF) that exists"
        )
    chain, urdf_text = robot_file_chain(path, locked_joints)  # an MJCF comes with the URDF written from it
    jax_mod, ca_mod = generated_modules_for(chain, chain.name, codegen_dir)
    links = [j.link for j in chain.joints] if unknown_links is None else unknown_links
    urdf_path = path.resolve() if urdf_text is None else None
    return RobotModel(
        chain,
        urdf_path,
        chain.name,
        gravity,
        links,
        jax_mod,
        ca_mod,
        locked_joints,
        urdf_text=urdf_text,
        model_path=path.resolve(),
    )
