"""Excitation for the joint-state errors of a lab's sensors (encoders and link IMUs).

``ineid excite --encoder-bits N --imu LINK[:pose]`` designs for the joint states a lab's import
will estimate, not for exact ones. To first order, an error ``dx_k`` in the states
``x_k = (q_k, qd_k, qdd_k)`` of sample ``k`` changes the channels' readings by ``J_k dx_k`` with

    J_k = d(Psi theta) / dx  at the CAD parameters ``theta`` (every link's; extras such as friction 0),

from the channels' CasADi rows differentiated along every state coordinate (:func:`prediction_jacobian`).
The state errors' per-joint RMS
``s_x`` (3 n_dof) comes from rehearsing the trajectory (:func:`ineid.data.synthesis.imu_rehearsal.rehearse`:
quantized encoders, the import's low-pass and cut-off rule, central differences, the fusion with the
IMUs' simulated readings) against its exact states, over one whole trajectory (it is periodic). Taking
the errors as independent across joints, coordinates and samples, the noise of axis ``a`` becomes

    sigma_eff_a^2 = sigma_a^2 + mean_k (J_k diag(s_x^2) J_k^T)_aa

The optimizer's weights use ``sigma_eff`` of the first random start (evaluated once: IPOPT's
objective stays that of the module :mod:`ineid.excite.design`); the reported expected standard
deviations use the designed trajectory's own ``sigma_eff`` and the random comparison's its own.

Not modelled: the errors' correlation in time and across joints (a filter's lag is systematic, not
white), the bias of a least-squares fit with errors in the regressor (errors-in-variables), and the
quadratic terms in ``dx``.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ineid.data.synthesis.imu_rehearsal import ImuRehearsal, rehearse
from ineid.errors import ExcitationError

STREAM = 22
"""The random stream of the rehearsal's IMU noise (``SeedSequence([seed, STREAM])``): the same draws for the
design and its random comparison."""
BLOCK = 1280
"""Samples per call of the prediction's Jacobian (its array is ``BLOCK x A x 3 n_dof``)."""
MIN_SAMPLES = 8
"""The fewest samples the rehearsal filters and differentiates
(:func:`ineid.data.synthesis.imu_rehearsal.rehearse`'s)."""
UNITS = {"gyro": "rad/s", "accel": "m/s^2", "alpha": "rad/s^2"}


@dataclass(frozen=True)
class StateErrors:
    """The state errors one trajectory's rehearsal gives, and the noise they add to first order.

    Attributes:
        rms: (3, n_dof) RMS over the samples of the estimated ``q``, ``qd``, ``qdd`` less the truth
            (rad, rad/s, rad/s^2; m, m/s, m/s^2 for prismatic joints).
        sigma: (A,) the inflated noise std per axis, ``sqrt(sigma^2 + mean_k (J_k diag(s^2) J_k^T)_aa)``.
    """

    rms: np.ndarray
    sigma: np.ndarray

    def to_dict(self) -> dict:
        return {
            "rms_q": self.rms[0].tolist(),
            "rms_qd": self.rms[1].tolist(),
            "rms_qdd": self.rms[2].tolist(),
            "noise_std": self.sigma.tolist(),
        }


def rehearsed_rms(model, sensors: ImuRehearsal, trajectory, rate: float, seed: int = 0) -> np.ndarray:
    """(3, n_dof) RMS of the states the import would estimate from ``sensors`` along ``trajectory`` at ``rate``."""
    t, q, qd, qdd = trajectory.sample(rate)
    t, q, qd, qdd = t[:-1], q[:-1], qd[:-1], qdd[:-1]  # whole periods, the end left out: periodic
    if len(t) < MIN_SAMPLES:
        raise ExcitationError(
            f"{len(t)} samples are too few to rehearse the import's filter and differences for "
            f"--encoder-bits and --imu; raise --rate or lengthen --duration (at least {MIN_SAMPLES})",
            reason="settings",
        )
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), STREAM]))
    est = rehearse(model, sensors, t, q, qd, qdd, {}, rng)[:3]
    return np.stack([np.sqrt(np.mean((e - x) ** 2, axis=0)) for e, x in zip(est, (q, qd, qdd), strict=True)])


_JACOBIANS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def prediction_jacobian(model, channels=None):
    """``casadi.Function`` ``(q, qd, qdd) -> J`` (A x 3 n_dof): ``d(T Phi theta_cad)/d(q, qd, qdd)``, the channels'
    rows (default: the base wrench) at the CAD parameters of every link (extra columns at their prior, 0);
    built once per model and channels."""
    import casadi as ca

    from ineid.channels import BASE_WRENCH

    channels = BASE_WRENCH if channels is None else channels
    per_model = _JACOBIANS.setdefault(model, {})
    key = channels.key_tuple()
    if key not in per_model:
        q, qd, qdd = (ca.SX.sym(s, model.n_dof) for s in ("q", "qd", "qdd"))
        w = ca.mtimes(channels.casadi_rows(model)(q, qd, qdd), ca.DM(np.asarray(model.theta_cad, dtype=np.float64)))
        per_model[key] = ca.Function("prediction_jacobian", [q, qd, qdd], [ca.jacobian(w, ca.vertcat(q, qd, qdd))])
    return per_model[key]


def inflated_noise(model, q, qd, qdd, sigma: np.ndarray, rms: np.ndarray, channels=None) -> np.ndarray:
    """(A,) ``sigma_eff`` (module doc) over samples ``q, qd, qdd`` (F, n_dof) for state errors of RMS ``rms``."""
    q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (q, qd, qdd))
    s2 = np.asarray(rms, dtype=np.float64).reshape(-1) ** 2  # q_1..q_n, qd_1..qd_n, qdd_1..qdd_n: J's columns
    jac_fn = prediction_jacobian(model, channels)
    n_a = jac_fn.size1_out(0)
    added = np.zeros(len(sigma))
    for start in range(0, len(q), BLOCK):
        part = slice(start, start + BLOCK)
        m = len(q[part])
        jac = np.asarray(jac_fn.map(m)(q[part].T, qd[part].T, qdd[part].T)).reshape(n_a, m, -1)  # (A, m, 3 n_dof)
        added += np.einsum("akd,d->a", jac**2, s2)
    return np.sqrt(np.asarray(sigma, dtype=np.float64) ** 2 + added / len(q))


def state_errors(
    model, sensors: ImuRehearsal, trajectory, rate: float, sigma: np.ndarray, channels=None, seed: int = 0
) -> StateErrors:
    """The rehearsed state errors of ``trajectory`` and the noise they add (module doc)."""
    rms = rehearsed_rms(model, sensors, trajectory, rate, seed)
    _, q, qd, qdd = trajectory.sample(rate)
    return StateErrors(rms, inflated_noise(model, q, qd, qdd, sigma, rms, channels))


def describe_sensors(sensors: ImuRehearsal) -> str:
    """``12-bit encoders and IMUs upper_arm, forearm (gyro 0.005 rad/s, ...)``: the sensors assumed, in words."""
    bits = sensors.encoder_bits
    text = "exact encoder angles" if bits is None else f"{bits}-bit encoders"
    if sensors.mounts:
        kinds = [k for k in UNITS if any(k in m.kinds for m in sensors.mounts)]
        noise = ", ".join(f"{k} {sensors.noise.get(k, 0.0):g} {UNITS[k]}" for k in kinds)
        text += (
            f" and IMU{'s' if len(sensors.mounts) > 1 else ''} {', '.join(m.name for m in sensors.mounts)} ({noise})"
        )
    return text + ", filtered, differentiated" + (" and fused" if sensors.mounts else "") + " as the import does"


def states_record(sensors: ImuRehearsal, weights: StateErrors, designed: StateErrors, random: StateErrors) -> dict:
    """The design record's ``joint_state_errors``: the sensors, and each trajectory's errors and noise."""
    return {
        "sensors": sensors.to_dict(),
        "described": describe_sensors(sensors),
        "weights_noise_std": weights.sigma.tolist(),
        "optimized": designed.to_dict(),
        "random_fourier": random.to_dict(),
    }
