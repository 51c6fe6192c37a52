"""Inertial sensors on the links: what an IMU is, where it sits, and what it reads.

An IMU is fixed to a moving link ``L`` of the arm at a pose ``(R, r)`` in ``L``'s frame
(``R = link_R_sensor``, ``r = link_p_sensor``; :class:`ineid.channels.SensorPose`, URDF's xyz and
rpy). It reads, in its own frame (the sensor axes),

    gyro   (rad/s):    y_w = R^T w
    alpha  (rad/s^2):  y_al = R^T wd                          (angular acceleration: the paper's sensor)
    accel  (m/s^2):    y_a = R^T (a + wd x r + w x (w x r))  (specific force: acceleration minus gravity)

with ``w``, ``wd`` the link's angular velocity and acceleration and ``a`` its origin's
acceleration minus gravity, all in ``L``'s frame: the generated Newton-Euler program's outputs
(``model.jax_program(q, qd, qdd, gravity)``, :mod:`ineid.robots.program`), which fold the model's
gravity into ``a`` as the base acceleration ``-g``. An accelerometer at rest reads ``-R^T g_L``
(9.81 m/s^2 up). The program is exactly linear in the rates, so

    w   = J_w(q) qd
    wd  = J_w(q) qdd + c_wd(q, qd)
    a_r = (J_o(q) - S(r) J_w(q)) qdd + c_a(q, qd) + c_wd(q, qd) x r + w x (w x r)

(``a_r`` the specific force at ``r``, ``S(r) v = r x v``): ``J_w``, ``J_o`` are the program's
``wd`` and ``a`` at ``qdd`` a unit vector with ``qd = 0`` and no gravity, ``c_wd``, ``c_a`` its
``wd`` and ``a`` at ``qdd = 0`` (:func:`imu_jacobians`; what :mod:`ineid.data.imu.estimation`
inverts). IMUs are state estimation, not a measurement channel (``docs/architecture.md``).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ineid.channels.link_wrench import link_frame
from ineid.channels.pose import SensorPose
from ineid.errors import DatasetError
from ineid.robots.chunked import host_array, run_chunked

KINDS = ("gyro", "accel", "alpha")
"""What an IMU may measure: angular velocity, specific force, angular acceleration (sensor frame)."""
UNITS = {"gyro": "rad/s", "accel": "m/s^2", "alpha": "rad/s^2"}
AXES = {"gyro": ("wx", "wy", "wz"), "accel": ("ax", "ay", "az"), "alpha": ("alx", "aly", "alz")}
"""Column suffixes of each kind: a recording's ``imu_<name>_wx`` ... (``docs/recordings.md``)."""
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class ImuMount:
    """An IMU fixed to a moving link.

    Attributes:
        link: the moving link of the model it is fixed to (the child link of a moving joint).
        sensor: its pose in the link's frame (xyz m, rpy rad, URDF convention); default the link frame.
        name: the prefix of its columns and topics (``imu_<name>_wx`` ...); default the link's name.
        kinds: what it measures, any of :data:`KINDS`; default all three.
    """

    link: str
    sensor: SensorPose = field(default_factory=SensorPose)
    name: str = ""
    kinds: tuple[str, ...] = KINDS

    def __post_init__(self) -> None:
        if not isinstance(self.link, str) or not self.link:
            raise DatasetError("IMU: name the moving link it is fixed to")
        if not isinstance(self.sensor, SensorPose):
            raise TypeError(f"IMU {self.link!r}: sensor must be a SensorPose, got {type(self.sensor).__name__}")
        if not self.name:
            object.__setattr__(self, "name", self.link)
        if not _NAME.match(self.name):
            raise DatasetError(
                f"IMU name {self.name!r}: use letters, digits and _ (it prefixes the columns imu_<name>_wx ...)"
            )
        kinds = (self.kinds,) if isinstance(self.kinds, str) else tuple(self.kinds)
        bad = [k for k in kinds if k not in KINDS]
        if bad or not kinds or len(set(kinds)) != len(kinds):
            raise DatasetError(f"IMU {self.name!r}: kinds must be distinct ones of {', '.join(KINDS)}, got {kinds!r}")
        object.__setattr__(self, "kinds", kinds)

    @property
    def link_R_sensor(self) -> np.ndarray:
        return self.sensor.base_R_sensor  # SensorPose names the frame it is given in "base": here the link

    @property
    def link_p_sensor(self) -> np.ndarray:
        return self.sensor.base_p_sensor

    def columns(self, kind: str) -> tuple[str, str, str]:
        """The three column names of ``kind``: ``imu_<name>_wx, _wy, _wz`` (gyro), ``_ax ..``, ``_alx ..``."""
        return tuple(f"imu_{self.name}_{a}" for a in AXES[kind])  # type: ignore[return-value]

    def describe(self) -> str:
        where = "at the link origin" if self.sensor.is_identity else self.sensor.describe()
        return f"IMU {self.name!r} on {self.link!r} ({', '.join(self.kinds)}), {where}"

    def to_dict(self) -> dict:
        return {"link": self.link, "sensor": self.sensor.to_dict(), "name": self.name, "kinds": list(self.kinds)}

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "imu") -> ImuMount:
        if not isinstance(d, Mapping) or not isinstance(d.get("link"), str):
            raise DatasetError(f"{where}: an IMU record needs link, sensor, name and kinds, got {d!r}")
        sensor = SensorPose.from_dict(d.get("sensor") or {"xyz": [0, 0, 0], "rpy": [0, 0, 0]}, f"{where}: sensor")
        return cls(d["link"], sensor, str(d.get("name") or ""), tuple(d.get("kinds") or KINDS))


def parse_imu(text: str, model, name: str | None = None, kinds: Sequence[str] = KINDS) -> ImuMount:
    """The IMU ``--imu`` names: ``LINK``, ``LINK:x,y,z,roll,pitch,yaw`` (its pose in moving link
    ``LINK``'s frame, m and rad, URDF rpy), or a URDF frame welded to a moving link (its pose from the
    URDF; the frame's name is the IMU's), resolved as a wrist F/T sensor's is
    (:func:`ineid.channels.link_wrench.link_frame`).

    Raises:
        DatasetError: a link the model does not have, a link that does not move, or a pose that does
            not parse (one line naming the moving links).
    """
    text = (text or "").strip()
    moving = ", ".join(j.link for j in model.chain.joints)
    try:
        resolved = link_frame(text, model, what="IMU", otherwise="")
    except DatasetError as e:
        if "does not parse" not in str(e) and "six finite numbers" not in str(e):
            raise
        raise DatasetError(
            f"IMU {text!r}: the pose does not parse; give LINK:x,y,z,roll,pitch,yaw, six numbers "
            "(m, rad, URDF rpy) in the link's frame"
        ) from None
    if resolved is None:
        raise DatasetError(
            f"IMU {text!r}: not a moving link of {model.name}; give LINK or LINK:x,y,z,roll,pitch,yaw "
            f"(m, rad) with LINK one of {moving}, or a URDF frame welded to one"
        )
    link, sensor, from_frame = resolved
    return ImuMount(link, sensor, name or (sensor.frame if from_frame else link), tuple(kinds))


def moving_index(model, mount: ImuMount) -> int:
    """The index of ``mount``'s link among the moving links (joint order): its row in :func:`link_motion`.

    Raises:
        DatasetError: the link does not move (one line naming the moving links).
    """
    moving = [j.link for j in model.chain.joints]
    if mount.link not in moving:
        raise DatasetError(
            f"IMU {mount.name!r}: {mount.link!r} is not a moving link of {model.name} (choose from "
            f"{', '.join(moving)}, or a URDF frame welded to one)"
        )
    return moving.index(mount.link)


def _moving_blocks(model) -> tuple[int, ...]:
    """The parameter blocks of the moving links (payload blocks left out), joint order."""
    return tuple(model.link_names.index(j.link) for j in model.chain.joints)


def check_imu_names(mounts: Sequence[ImuMount]) -> None:
    """Refuse IMUs of which two share a name (:class:`ineid.errors.DatasetError` naming the first such name)."""
    names = [m.name for m in mounts]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DatasetError(f"IMUs: the name {dup[0]!r} is given twice; name each IMU apart (its column prefix)")


# -- the kernels: one compilation per robot (program) and set of links ----------------------------
def _vec(out, key, i, batch, dtype):
    import jax.numpy as jnp

    return jnp.stack([jnp.broadcast_to(jnp.asarray(v, dtype=dtype), batch) for v in out[key][i]], axis=-1)


@functools.cache
def _motion_kernel(program, blocks: tuple[int, ...]):
    """Jitted ``(q, qd, qdd, gravity) -> (N, len(blocks), 3, 3)``: per block ``[w, wd, a]`` (link frame)."""
    import jax
    import jax.numpy as jnp

    def kernel(q, qd, qdd, gravity):
        out = program(q, qd, qdd, gravity)
        batch = q.shape[:-1]
        return jnp.stack(
            [jnp.stack([_vec(out, k, i, batch, q.dtype) for k in ("w", "wd", "a")], axis=-2) for i in blocks], axis=-3
        )

    return jax.jit(kernel)


@functools.cache
def _jacobian_kernel(program, blocks: tuple[int, ...], n_dof: int):
    """Jitted ``q -> (N, len(blocks), 2, 3, n_dof)``: per block ``[J_w, J_o]``, the program's ``wd`` and
    ``a`` at ``qdd = e_j`` (``qd = 0``, no gravity): exact columns, the program being linear in ``qdd``."""
    import jax
    import jax.numpy as jnp

    def kernel(q):
        n = q.shape[0]
        qb = jnp.broadcast_to(q[:, None, :], (n, n_dof, n_dof))
        eye = jnp.broadcast_to(jnp.eye(n_dof, dtype=q.dtype), (n, n_dof, n_dof))
        out = program(qb, jnp.zeros_like(qb), eye, jnp.zeros(3, q.dtype))
        cols = [jnp.stack([_vec(out, k, i, (n, n_dof), q.dtype) for k in ("wd", "a")], axis=-3) for i in blocks]
        return jnp.swapaxes(jnp.stack(cols, axis=1), -1, -2)  # (N, blocks, 2, n_dof, 3) -> (..., 3, n_dof)

    return jax.jit(kernel)


def _flat(model, q, qd=None, qdd=None):
    arrays = []
    for label, x in (("q", q), ("qd", qd), ("qdd", qdd)):
        if x is None:
            continue
        x = host_array(label, x)
        if x.ndim == 0 or x.shape[-1] != model.n_dof:
            raise ValueError(f"{label} must have shape (..., {model.n_dof}), got {tuple(x.shape)}")
        arrays.append(x)
    batch = arrays[0].shape[:-1]
    if any(x.shape[:-1] != batch for x in arrays):
        raise ValueError(f"q, qd, qdd must have one leading shape, got {', '.join(str(x.shape) for x in arrays)}")
    return [x.reshape(-1, model.n_dof) for x in arrays], batch


def link_motion(model, q, qd, qdd, gravity=None) -> np.ndarray:
    """``(N, n_dof, 3, 3)``: per frame and moving link (joint order) ``[w, wd, a]`` in the link's frame
    (rad/s, rad/s^2, m/s^2; ``a`` minus ``gravity``, default the model's), from the generated program,
    compiled once per robot and run over chunks of frames (:func:`ineid.robots.chunked.run_chunked`)."""
    flat, _ = _flat(model, q, qd, qdd)
    blocks = _moving_blocks(model)
    out = np.empty((len(flat[0]), len(blocks), 3, 3))

    def write(start, stop, rows):
        out[start:stop] = rows[: stop - start]

    g = np.asarray(model.gravity if gravity is None else gravity, dtype=np.float64)
    run_chunked(_motion_kernel(model.jax_program, blocks), flat, (g,), write)
    return out


def link_jacobians(model, q) -> np.ndarray:
    """``(N, n_dof, 2, 3, n_dof)``: per frame and moving link ``[J_w, J_o]`` (link frame): ``w = J_w qd``,
    ``wd = J_w qdd + c_wd``, ``a = J_o qdd + c_a`` (see the module docstring); compiled once per robot."""
    flat, _ = _flat(model, q)
    blocks = _moving_blocks(model)
    out = np.empty((len(flat[0]), len(blocks), 2, 3, model.n_dof))

    def write(start, stop, rows):
        out[start:stop] = rows[: stop - start]

    run_chunked(_jacobian_kernel(model.jax_program, blocks, model.n_dof), flat, (), write)
    return out


def readings_from_motion(mount: ImuMount, w: np.ndarray, wd: np.ndarray, a: np.ndarray) -> dict[str, np.ndarray]:
    """The mount's readings (sensor frame) from its link's ``w``, ``wd``, ``a`` (N, 3), link frame."""
    rt = mount.link_R_sensor.T
    r = mount.link_p_sensor
    out = {}
    for kind in mount.kinds:
        if kind == "gyro":
            v = w
        elif kind == "alpha":
            v = wd
        else:
            v = a + np.cross(wd, r) + np.cross(w, np.cross(w, r))
        out[kind] = v @ rt.T
    return out


def imu_readings(model, mounts: Sequence[ImuMount], q, qd, qdd) -> dict[str, dict[str, np.ndarray]]:
    """What each IMU reads, noise-free: ``{mount.name: {kind: (..., 3)}}``, sensor frame.

    ``gyro`` ``R^T w`` (rad/s), ``alpha`` ``R^T wd`` (rad/s^2), ``accel`` ``R^T (a + wd x r + w x (w x r))``
    (m/s^2, specific force with the model's gravity: ``+9.81`` up at rest), from the generated
    program (see the module docstring).

    Args:
        model: the :class:`ineid.RobotModel`.
        mounts: the IMUs (distinct names, each on a moving link).
        q, qd, qdd: (..., n_dof) joint states, one leading shape.

    Raises:
        DatasetError: an IMU on a link that does not move, or two IMUs with one name.
    """
    mounts = list(mounts)
    check_imu_names(mounts)
    index = [moving_index(model, m) for m in mounts]
    flat, batch = _flat(model, q, qd, qdd)
    motion = link_motion(model, *flat) if mounts else None
    result = {}
    for m, i in zip(mounts, index, strict=True):
        w, wd, a = (motion[:, i, k] for k in range(3))
        result[m.name] = {k: v.reshape(batch + (3,)) for k, v in readings_from_motion(m, w, wd, a).items()}
    return result


class ImuJacobians(NamedTuple):
    """The linear maps of one IMU's readings (sensor frame), per frame (N leading):

        gyro  = gyro_qd qd
        alpha = gyro_qd qdd + alpha_0
        accel = accel_qdd qdd + accel_0

    Attributes:
        gyro_qd: (N, 3, n_dof) ``R^T J_w`` (also the map of ``qdd`` into ``alpha``).
        accel_qdd: (N, 3, n_dof) ``R^T (J_o - S(r) J_w)``.
        alpha_0: (N, 3) ``R^T c_wd(q, qd)``, the angular acceleration at ``qdd = 0``.
        accel_0: (N, 3) ``R^T (c_a + c_wd x r + w x (w x r))``, the specific force at ``qdd = 0`` (gravity in it).
    """

    gyro_qd: np.ndarray
    accel_qdd: np.ndarray
    alpha_0: np.ndarray
    accel_0: np.ndarray


def jacobians_from(mount: ImuMount, jac: np.ndarray, motion0: np.ndarray) -> ImuJacobians:
    """:class:`ImuJacobians` from the link's ``[J_w, J_o]`` (N, 2, 3, n) and ``[w, wd, a]`` at ``qdd = 0`` (N, 3, 3)."""
    rt = mount.link_R_sensor.T
    r = mount.link_p_sensor
    skew_r = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    j_w, j_o = jac[:, 0], jac[:, 1]
    w, c_wd, c_a = motion0[:, 0], motion0[:, 1], motion0[:, 2]
    acc0 = c_a + np.cross(c_wd, r) + np.cross(w, np.cross(w, r))
    return ImuJacobians(rt @ j_w, rt @ (j_o - skew_r @ j_w), c_wd @ rt.T, acc0 @ rt.T)


def imu_jacobians(model, mount: ImuMount, q, qd) -> ImuJacobians:
    """The linear maps of ``mount``'s readings in the joint rates at ``(q, qd)`` (:class:`ImuJacobians`).

    ``J_w``, ``J_o`` are exact columns of the generated program at unit accelerations (it is linear in
    ``qd`` for ``w`` and in ``qdd`` for ``wd`` and ``a``); the offsets are the program at ``qdd = 0``
    with the model's gravity. ``imu_readings(model, [mount], q, qd, qdd)`` equals the maps applied to
    ``qd``, ``qdd`` to round-off.

    Args:
        q, qd: (N, n_dof) joint positions and velocities.
    """
    i = moving_index(model, mount)
    flat, _ = _flat(model, q, qd)
    jac = link_jacobians(model, flat[0])[:, i]
    motion0 = link_motion(model, flat[0], flat[1], np.zeros_like(flat[1]))[:, i]
    return jacobians_from(mount, jac, motion0)
