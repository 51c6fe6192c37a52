"""Robots from files: the reader picked by the file (URDF or MJCF), and :func:`load_robot`.

A built-in robot loads its checked-in generated modules; any other robot file is read by its
format's reader into a :class:`ineid.chain.Chain` (:func:`robot_file_chain`), and its generated
modules are found in the cache or derived (:mod:`ineid.robots.codegen`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from ineid._inputs import regular_file
from ineid.chain import Chain
from ineid.errors import RobotModelError
from ineid.robots.builtin import BUILTIN_ROBOTS
from ineid.robots.codegen import generated_modules_for
from ineid.robots.mjcf import is_mjcf, load_mjcf_chain
from ineid.robots.model import DEFAULT_GRAVITY, RobotModel
from ineid.robots.robot_files import MJCF_MAX_BYTES, URDF_MAX_BYTES
from ineid.robots.urdf import load_chain


def robot_file_chain(path: str | Path, locked_joints: Mapping[str, float] | None = None) -> tuple[Chain, str | None]:
    """``(chain, urdf_text)`` of a robot file: an MJCF (:func:`is_mjcf`) through its URDF, else a URDF (text None).

    Raises:
        InputFileError: the file is not a regular file (checked before it is opened), or is over its
            format's limits (:mod:`ineid.robots.robot_files`).
    """
    if Path(path).suffix.lower() == ".urdf":
        path = regular_file(path, "the URDF", max_bytes=URDF_MAX_BYTES, limit_name="URDF_MAX_BYTES")
    else:  # bounded before is_mjcf reads up to its first element
        path = regular_file(path, "the robot file", max_bytes=MJCF_MAX_BYTES, limit_name="MJCF_MAX_BYTES")
    if is_mjcf(path):
        return load_mjcf_chain(path, locked_joints)
    return load_chain(path, locked_joints=locked_joints), None


def load_robot(
    robot: str | Path,
    *,
    unknown_links: Sequence[str] | None = None,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
    locked_joints: Mapping[str, float] | None = None,
    codegen_dir: str | Path | None = None,
) -> RobotModel:
    """Load a built-in robot by name or any URDF or MJCF by path (a serial arm or a kinematic tree on a fixed base).

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
