"""The zoo: every serial arm example-robot-data ships, through a new user's command sequence.

``ZOO`` names each arm's URDF (under example-robot-data's ``robots`` folder, found through its
installed distribution: :func:`tests.conftest.example_robot_data_dir`) and the joints locked
to make it a serial chain. :func:`user_sequence` runs ``robot show``, ``identifiability``, a
short ``excite``, ``data generate``, ``solve --method linear`` and ``consistent`` and
``export-urdf`` through click's CliRunner in one folder, then reloads the exported URDF with
Pinocchio and compares its RNEA base wrench with ineid's on the original URDF with the
identified parameters (:func:`check_export`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .conftest import example_robot_data_dir


@dataclass(frozen=True)
class ZooArm:
    """One arm: ``urdf`` relative to example-robot-data's ``robots`` folder, ``locked`` joints at their values."""

    urdf: str
    locked: dict[str, float] = field(default_factory=dict)

    @property
    def path(self) -> Path:
        return example_robot_data_dir() / self.urdf

    def robot_args(self) -> list[str]:
        """ROBOT and its ``--lock`` options, as a user types them."""
        args = [str(self.path)]
        for joint, value in self.locked.items():
            args += ["--lock", f"{joint}={value:g}"]
        return args


# TALOS is a humanoid: its left arm is the chain base_link -> torso -> arm_left_1..7 once every
# other branch (legs, right arm, head, grippers) and the torso joints are locked.
_TALOS_OTHERS = (
    ["torso_1_joint", "torso_2_joint", "head_1_joint", "head_2_joint", "gripper_left_joint", "gripper_right_joint"]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
    + [f"leg_left_{i}_joint" for i in range(1, 7)]
    + [f"leg_right_{i}_joint" for i in range(1, 7)]
)

ZOO: dict[str, ZooArm] = {
    "double-pendulum": ZooArm("double_pendulum_description/urdf/double_pendulum.urdf"),
    "ur3": ZooArm("ur_description/urdf/ur3_robot.urdf"),
    "ur5": ZooArm("ur_description/urdf/ur5_robot.urdf"),
    "ur10": ZooArm("ur_description/urdf/ur10_robot.urdf"),
    "panda": ZooArm("panda_description/urdf/panda.urdf", {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}),
    "kinova": ZooArm("kinova_description/robots/kinova.urdf"),
    "z1": ZooArm("z1_description/urdf/z1.urdf"),
    "xarm7": ZooArm("xarm_description/urdf/xarm7.urdf"),
    "so101": ZooArm("so_arm_description/urdf/so101.urdf"),
    "talos-left-arm": ZooArm("talos_data/robots/talos_reduced.urdf", dict.fromkeys(_TALOS_OTHERS, 0.0)),
}

EXCITE = ("--duration", "4", "--harmonics", "3", "--starts", "1")
"""A short design: one start, 3 harmonics over 4 s (what the zoo study ran)."""
GENERATE = ("--n-configs", "5", "--n-frames", "60")
"""Five configurations of 60 frames: enough for every arm's base parameters, noise-free."""


def ok(result, step: str) -> str:
    """The command's output; an AssertionError naming the step and its last line when it failed."""
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 0, f"{step}: exit {result.exit_code}: {lines[-1] if lines else ''}"
    return result.output


def user_sequence(run, arm: ZooArm, folder: Path, steps: tuple[str, ...] | None = None) -> dict[str, str]:
    """Run the user's commands on ``arm`` in ``folder``; return each step's output.

    ``steps`` (default all, in order): ``show``, ``identifiability``, ``excite``, ``generate``,
    ``linear``, ``consistent``, ``export``. Each must exit 0 (:func:`ok`). The files:
    ``traj.csv``, ``d.h5``, ``lin.h5``, ``con.h5``, ``exp.urdf`` (configuration 0 of ``con.h5``).
    """
    robot = arm.robot_args()
    commands = {
        "show": ("robot", "show", *robot),
        "identifiability": ("identifiability", *robot),
        "excite": ("excite", *robot, *EXCITE, "--out", folder / "traj.csv"),
        "generate": ("data", "generate", *robot, *GENERATE, "--seed", "1", "--out", folder / "d.h5"),
        "linear": ("solve", folder / "d.h5", "--method", "linear", "--out", folder / "lin.h5"),
        "consistent": ("solve", folder / "d.h5", "--method", "consistent", "--out", folder / "con.h5"),
        "export": ("export-urdf", folder / "con.h5", "--config", "0", "--out", folder / "exp.urdf"),
    }
    return {step: ok(run(*commands[step]), step) for step in (steps or tuple(commands))}


def check_export(arm: ZooArm, folder: Path, n_states: int = 50, tol: float = 1e-9) -> dict[str, float]:
    """The exported URDF, reloaded by Pinocchio, gives the identified model's base wrench.

    Pinocchio's RNEA base wrench on ``exp.urdf`` against ineid's regressor of the original
    URDF times the identified parameters (``con.h5``'s configuration 0 for the unknown links,
    CAD for the known), on ``n_states`` random states and on the dataset's own frames: both
    below ``tol``. And the fits to the (noise-free) measured wrench of configuration 0: the
    linear estimate's below 1e-8, the consistent one's below 1e-3 (an interior-point
    solution: its tolerance, not round-off; Panda's is 1.1e-4). Returns the relative errors.
    """
    import ineid
    from ineid.data import load_dataset
    from ineid.data.synthesis.sampling import model_uniform_states
    from ineid.identify.results import load_results
    from ineid.reference import pinocchio_base_wrench, pinocchio_model

    def identified(results: str) -> tuple[object, np.ndarray]:
        res = load_results(folder / results)
        row = int(np.flatnonzero(np.asarray(res.config_index) == 0)[0])
        model = ineid.load_robot(
            arm.path, locked_joints=arm.locked or None, unknown_links=list(res.meta["unknown_links"])
        )
        theta = model.theta_cad.copy()
        theta[model.unknown_index] = res.theta_hat[row]
        return model, theta

    model, theta = identified("con.h5")
    _, theta_linear = identified("lin.h5")
    pin = pinocchio_model(folder / "exp.urdf", locked_joints=arm.locked or None)
    assert pin.nv == model.n_dof, f"Pinocchio reloads {pin.nv} joints, ineid has {model.n_dof}"
    ds = load_dataset(folder / "d.h5", configs=[0])
    q, qd, qdd = model_uniform_states(model, n_states, np.random.default_rng(0))

    def rel(a, b) -> float:
        return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))

    errors = {
        "random states": rel(pinocchio_base_wrench(pin, q, qd, qdd), np.asarray(model.regressor(q, qd, qdd)) @ theta),
        "dataset frames": rel(
            pinocchio_base_wrench(pin, ds.q[0], ds.qd[0], ds.qdd[0]),
            np.asarray(model.regressor(ds.q[0], ds.qd[0], ds.qdd[0])) @ theta,
        ),
        "measured, consistent": rel(np.asarray(model.regressor(ds.q[0], ds.qd[0], ds.qdd[0])) @ theta, ds.wrench[0]),
        "measured, linear": rel(np.asarray(model.regressor(ds.q[0], ds.qd[0], ds.qdd[0])) @ theta_linear, ds.wrench[0]),
    }
    assert errors["random states"] < tol and errors["dataset frames"] < tol, errors
    assert errors["measured, linear"] < 1e-8 and errors["measured, consistent"] < 1e-3, errors
    return errors
