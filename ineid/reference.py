"""An independent reference: Pinocchio's base wrench and base regressor, frame by frame.

ineid's tests and benchmarks compare against this; it needs the ``pin`` package (the
``dev`` extra) and is not used by the rest of ineid. Conventions follow ineid's: states
in chain order, continuous joints as angles, the wrench the robot exerts on its fixture.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def pinocchio_model(
    urdf_path,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    locked_joints: Mapping[str, float] | None = None,
    free_flyer: bool = False,
):
    """Pinocchio model of a URDF (fixed joints merged), with ``locked_joints`` removed; with ``free_flyer`` its root
    on a free-flyer joint (the first 6 rows of ``computeJointTorqueRegressor`` are then the root's dynamics)."""
    import pinocchio as pin

    model = (
        pin.buildModelFromUrdf(str(urdf_path), pin.JointModelFreeFlyer())
        if free_flyer
        else pin.buildModelFromUrdf(str(urdf_path))
    )
    if locked_joints:
        q_ref = pin.neutral(model)
        ids = []
        for name, value in locked_joints.items():
            jid = model.getJointId(name)
            ids.append(jid)
            q_ref[model.joints[jid].idx_q] = value
        model = pin.buildReducedModel(model, ids, q_ref)
    model.gravity.linear = np.asarray(gravity, dtype=np.float64)
    return model


def pinocchio_q(model, angles: np.ndarray) -> np.ndarray:
    """Pinocchio configuration of joint angles/positions (maps continuous joints to cos/sin)."""
    import pinocchio as pin

    return pin.integrate(model, pin.neutral(model), np.asarray(angles, dtype=np.float64))


def pinocchio_theta(model) -> np.ndarray:
    """(10 * n_bodies,) Pinocchio's dynamic parameters of the moving bodies, stacked."""
    return np.concatenate([model.inertias[i].toDynamicParameters() for i in range(1, model.njoints)])


def pinocchio_base_wrench(model, q, qd, qdd, data=None) -> np.ndarray:
    """Wrench on the fixture for each frame; (n_frames, n_dof) x3 -> (n_frames, 6).

    After RNEA, ``data.f[i]`` is the spatial force the parent applies to the subtree of
    joint ``i`` (its frame); for joints on the root, ``liMi[i]`` carries it into the base
    frame. The fixture receives the opposite.
    """
    import pinocchio as pin

    data = data or model.createData()
    roots = [i for i in range(1, model.njoints) if model.parents[i] == 0]
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    out = np.empty((len(q), 6))
    for k in range(len(q)):
        pin.rnea(model, data, pinocchio_q(model, q[k]), qd[k], qdd[k])
        total = np.zeros(6)
        for i in roots:
            total += data.liMi[i].act(data.f[i]).vector
        out[k] = -total
    return out


def pinocchio_base_regressor(model, q, qd, qdd, data=None) -> np.ndarray:
    """Base-wrench regressor for each frame; -> (n_frames, 6, 10 * n_bodies).

    Blocks ``-oMi[i].toDualActionMatrix() @ jointBodyRegressor(model, data, i)`` after
    RNEA (which leaves the gravity-including accelerations ``jointBodyRegressor`` needs).
    """
    import pinocchio as pin

    data = data or model.createData()
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    nb = model.njoints - 1
    out = np.empty((len(q), 6, 10 * nb))
    for k in range(len(q)):
        pin.rnea(model, data, pinocchio_q(model, q[k]), qd[k], qdd[k])
        pin.updateGlobalPlacements(model, data)
        for i in range(1, model.njoints):
            block = pin.jointBodyRegressor(model, data, i)
            out[k, :, 10 * (i - 1) : 10 * i] = -data.oMi[i].toDualActionMatrix() @ block
    return out


def pinocchio_joint_torques(model, q, qd, qdd, data=None) -> np.ndarray:
    """Pinocchio's ``rnea`` for each frame; (n_frames, n_dof) x3 -> (n_frames, n_dof)."""
    import pinocchio as pin

    data = data or model.createData()
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    return np.stack([pin.rnea(model, data, pinocchio_q(model, q[k]), qd[k], qdd[k]).copy() for k in range(len(q))])


def pinocchio_joint_torque_regressor(model, q, qd, qdd, data=None) -> np.ndarray:
    """Pinocchio's ``computeJointTorqueRegressor`` for each frame; -> (n_frames, n_dof, 10 * n_bodies)."""
    import pinocchio as pin

    data = data or model.createData()
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    return np.stack(
        [
            pin.computeJointTorqueRegressor(model, data, pinocchio_q(model, q[k]), qd[k], qdd[k]).copy()
            for k in range(len(q))
        ]
    )


def pinocchio_link_wrench(model, q, qd, qdd, link_joint: int, data=None) -> np.ndarray:
    """The wrench the bodies beyond body ``link_joint`` (Pinocchio's joint index of the link, 1-based) exert
    on it, in its frame, moment about its origin, for each frame; -> (n_frames, 6).

    After RNEA, ``data.f[c]`` is the force body ``link_joint`` applies to the subtree of each child
    joint ``c`` (in ``c``'s frame); ``liMi[c]`` carries it into the link's frame; the link receives the opposite.
    """
    import pinocchio as pin

    data = data or model.createData()
    children = [c for c in range(1, model.njoints) if model.parents[c] == link_joint]
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (q, qd, qdd))
    out = np.zeros((len(q), 6))
    for k in range(len(q)):
        pin.rnea(model, data, pinocchio_q(model, q[k]), qd[k], qdd[k])
        for c in children:
            out[k] -= data.liMi[c].act(data.f[c]).vector
    return out
