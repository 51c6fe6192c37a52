"""The robots shipped with ineid: their URDFs in this package and the links each identifies."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

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
