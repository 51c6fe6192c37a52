"""Robot models: the built-in arm(s) and URDF loading."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ineid.errors import RobotModelError
from ineid.robots.model import DEFAULT_GRAVITY, RobotModel, generated_modules_for
from ineid.robots.urdf import Chain, JointSpec, load_chain

_HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class BuiltinRobot:
    """A robot shipped with ineid: its URDF in this package and the links it identifies."""

    name: str
    urdf: str
    unknown_links: tuple[str, ...]
    description: str

    @property
    def urdf_path(self) -> Path:
        return _HERE / self.urdf


BUILTIN_ROBOTS: dict[str, BuiltinRobot] = {
    "sweaty-arm": BuiltinRobot(
        name="sweaty-arm",
        urdf="sweaty_arm.urdf",
        unknown_links=("upper_arm", "forearm"),
        description="4-DOF humanoid arm (shoulder pitch, shoulder roll, upper-arm yaw, elbow); representative values",
    ),
}


def load_robot(
    robot: str | Path,
    *,
    unknown_links: Sequence[str] | None = None,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
    locked_joints: Mapping[str, float] | None = None,
    codegen_dir: str | Path | None = None,
) -> RobotModel:
    """Load a built-in robot by name or any serial-chain URDF by path.

    Args:
        robot: a built-in name (``"sweaty-arm"``) or a path to a ``.urdf`` file.
        unknown_links: moving links whose parameters are to be identified; default: the
            built-in robot's choice, or every moving link of a URDF.
        gravity: (3,) m/s^2 in the base frame.
        locked_joints: ``{joint name: position}`` of joints to treat as fixed (a URDF's
            gripper fingers, for instance). Not for built-in robots.
        codegen_dir: folder with (or for) a URDF's generated code; default: a cache folder
            keyed by the kinematic fingerprint (``$INEID_CACHE_DIR`` or ``~/.cache/ineid``).
            A URDF without generated code is derived once with SymPy (seconds).

    Raises:
        RobotModelError: unknown name, unreadable or unusable URDF, or bad link choice.
    """
    from ineid.generated import load_builtin  # noqa: PLC0415

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
    if not path.is_file():
        raise RobotModelError(
            f"{key!r} is neither a built-in robot ({', '.join(BUILTIN_ROBOTS)}) nor a URDF file that exists"
        )
    chain = load_chain(path, locked_joints=locked_joints)
    name = chain.name
    jax_mod, ca_mod = generated_modules_for(chain, name, codegen_dir)
    links = [j.link for j in chain.joints] if unknown_links is None else unknown_links
    return RobotModel(chain, path.resolve(), name, gravity, links, jax_mod, ca_mod, locked_joints)


__all__ = ["BUILTIN_ROBOTS", "BuiltinRobot", "Chain", "JointSpec", "RobotModel", "load_chain", "load_robot"]
