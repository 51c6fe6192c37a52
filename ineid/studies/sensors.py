"""Sensor study: encoders alone, or with link gyroscopes and angular-acceleration sensors?

The paper measures angular velocities and accelerations directly so that no numerical
differentiation is needed; ineid differentiates filtered encoder angles. This study runs one
experiment of the arm (Fourier excitation, one period, the base wrench with noise) through the
rehearsal of a lab's import (:mod:`ineid.data.synthesis.imu_rehearsal`: encoders quantized, the import's
filter and cut-off rule, the IMUs fused by :func:`ineid.data.imu.estimation.estimate_joint_states`)
for each sensor set

* ``fine``: 20-bit encoders, filtered and differentiated;
* ``12-bit``, ``10-bit``: coarse encoders, filtered and differentiated;
* ``+gyro``: the coarse encoders and a gyroscope on every moving link;
* ``+gyro+alpha``: and an angular-acceleration sensor (the paper's) on every moving link;
* ``+gyro2``: gyroscopes on the last two moving links only (the unknown ones: a lab's cheapest retrofit),
  which leave joint directions unseen;

over the logging rate and the motion's bandwidth (its highest harmonic), and identifies the
unknown links by linear least squares on the first ``fit_share`` of each period. Errors:

* base: per base parameter ``|beta_hat - beta| / max(|beta|, scale)``, the largest, median over
  the configurations (the recordings benchmark's measure);
* held-out: on the frames not fitted, ``||Psi(true states) theta_hat - w_true|| / ||w_true||``,
  the true wrench predicted from the true states by the identified model, median over the
  configurations.

The IMU readings come from ineid's own forward model (:func:`ineid.data.imu.readings.imu_readings`, checked
against MuJoCo's gyro, accelerometer and body accelerations in the tests).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ineid._atomic import save_figure, write_csv

SENSOR_SETS = (
    "fine",
    "12-bit",
    "12-bit+gyro",
    "12-bit+gyro+alpha",
    "10-bit",
    "10-bit+gyro",
    "10-bit+gyro+alpha",
    "10-bit+gyro2",
)
"""The sensor sets, in table order (:func:`sensor_set`)."""
FINE_BITS = 20
IMU_NOISE = {"gyro": 0.005, "alpha": 0.17}
"""White-noise std at the frames' rate: a MEMS gyroscope (rad/s), the group's angular-acceleration sensor
(0.17 rad/s^2, as reported)."""
GYRO_BIAS = 0.01
"""rad/s, the std of each gyro axis's constant bias (estimated by the fusion)."""
WRENCH_NOISE = {"force": 0.05, "moment": 0.005}
"""N, N*m: the F/T sensor's white noise."""


@dataclass(frozen=True)
class SensorStudyRow:
    """One cell of the study: a sensor set at one rate and bandwidth, medians over the configurations."""

    rate: float
    bandwidth: float
    sensors: str
    base_error: float
    held_out_error: float
    qd_error: float
    qdd_error: float
    seconds: float


@dataclass(frozen=True)
class SensorStudySize:
    """The sweep: logging rates (Hz), motion bandwidths (Hz: the highest harmonic), configurations."""

    rates: tuple[float, ...] = (100.0, 500.0)
    bandwidths: tuple[float, ...] = (0.5, 2.0)
    n_configs: int = 5
    period: float = 10.0
    fit_share: float = 0.7

    @classmethod
    def quick(cls) -> SensorStudySize:
        """The test suite's size: one rate, one bandwidth, one configuration, a short period."""
        return cls(rates=(100.0,), bandwidths=(1.0,), n_configs=1, period=4.0)


def sensor_set(name: str, model) -> tuple[int, tuple]:
    """``(encoder bits, IMU mounts)`` of a :data:`SENSOR_SETS` name: IMUs at every moving link's origin (``gyro2``:
    the last two's)."""
    from ineid.data.imu.readings import ImuMount

    if name not in SENSOR_SETS:
        raise ValueError(f"sensor set must be one of {', '.join(SENSOR_SETS)}, got {name!r}")
    bits = FINE_BITS if name == "fine" else int(name.split("-")[0])
    kinds = tuple(k for k in ("gyro", "alpha") if f"+{k}" in name)
    links = [j.link for j in model.chain.joints][-2 if name.endswith("gyro2") else 0 :]
    return bits, tuple(ImuMount(link, kinds=kinds) for link in links) if kinds else ()


def sensor_study(
    model, size: SensorStudySize = SensorStudySize(), sensors: Sequence[str] = SENSOR_SETS, seed: int = 0, progress=None
) -> list[SensorStudyRow]:
    """Run the sweep; one :class:`SensorStudyRow` per (rate, bandwidth, sensor set)."""
    import time

    from ineid.data import Combination, DatasetSpec, FrameSampling, NoiseModel, generate_dataset
    from ineid.data.synthesis.imu_rehearsal import ImuRehearsal
    from ineid.identify.solve import SolveSettings, solve_dataset

    rows: list[SensorStudyRow] = []
    total, done = len(size.rates) * len(size.bandwidths) * len(sensors), 0
    noise = NoiseModel.create(model.n_dof, force=WRENCH_NOISE["force"], moment=WRENCH_NOISE["moment"])
    for rate in size.rates:
        n_frames = int(round(rate * size.period))
        fit = int(size.fit_share * n_frames)
        for bandwidth in size.bandwidths:
            f0 = 1.0 / size.period
            frames = FrameSampling("fourier", harmonics=max(1, int(round(bandwidth / f0))), base_frequency=f0)
            for name in sensors:
                bits, mounts = sensor_set(name, model)
                rehearsal = ImuRehearsal(
                    mounts,
                    {k: v for k, v in IMU_NOISE.items() if any(k in m.kinds for m in mounts)},
                    GYRO_BIAS if mounts else 0.0,
                    bits,
                )
                t0 = time.perf_counter()
                spec = DatasetSpec(
                    Combination("random", n_configs=size.n_configs),
                    n_frames=n_frames,
                    seed=seed,
                    frames=frames,
                    noise=noise,
                    imu=rehearsal,
                )
                ds = generate_dataset(model, spec)
                res = solve_dataset(ds, SolveSettings(method="linear", weights="estimate", frames=fit), model=model)
                rows.append(
                    SensorStudyRow(
                        rate=float(rate),
                        bandwidth=float(bandwidth),
                        sensors=name,
                        base_error=float(np.median(_base_error(res, ds.theta_unknown))),
                        held_out_error=float(np.median(_held_out(model, ds, res.theta_hat, fit))),
                        qd_error=_rel(ds.qd, ds.clean["qd"]),
                        qdd_error=_rel(ds.qdd, ds.clean["qdd"]),
                        seconds=time.perf_counter() - t0,
                    )
                )
                done += 1
                if progress is not None:
                    progress(done, total)
    return rows


def _base_error(res, theta_unknown: np.ndarray) -> np.ndarray:
    """Per configuration, the largest ``|beta_hat - beta| / max(|beta|, scale)`` over the base parameters."""
    b = res.base
    truth = theta_unknown @ b.B.T
    return np.max(np.abs(res.base_hat - truth) / np.maximum(np.abs(truth), b.scales[b.base_index]), axis=1)


def _held_out(model, ds, theta_hat: np.ndarray, fit: int) -> np.ndarray:
    """Per configuration, the true wrench on the frames not fitted predicted from the true states."""
    out = []
    for c in range(ds.n_configs):
        q, qd, qdd = (ds.clean[k][c, fit:] for k in ("q", "qd", "qdd"))
        full = model.full_theta(theta_hat[c], ds.theta_known)
        w_true = ds.clean["wrench"][c, fit:] if "wrench" in ds.clean else ds.wrench[c, fit:]
        w_hat = model.base_wrench(q, qd, qdd, full)
        out.append(np.linalg.norm(w_hat - w_true) / np.linalg.norm(w_true))
    return np.asarray(out)


def _rel(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS of ``estimate - truth`` relative to the truth's RMS."""
    return float(np.sqrt(np.mean((estimate - truth) ** 2) / np.mean(truth**2)))


def write_rows(rows: list[SensorStudyRow], path: str | Path) -> Path:
    """The study's table as CSV (atomically)."""
    return write_csv(path, list(asdict(rows[0])), [asdict(r) for r in rows])


def plot(rows: list[SensorStudyRow], path: str | Path) -> Path:
    """Base and held-out errors of each sensor set, one group of bars per rate and bandwidth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = sorted({(r.rate, r.bandwidth) for r in rows})
    sets = [s for s in SENSOR_SETS if any(r.sensors == s for r in rows)]
    fig, axes = plt.subplots(1, 2, figsize=(14, 4.5), constrained_layout=True)
    width = 0.8 / max(len(sets), 1)
    for si, s in enumerate(sets):
        for ax, field in zip(axes, ("base_error", "held_out_error"), strict=True):
            values = [
                next((getattr(r, field) for r in rows if (r.rate, r.bandwidth) == c and r.sensors == s), np.nan)
                for c in cases
            ]
            ax.bar(np.arange(len(cases)) + si * width, values, width, label=s, color=f"C{si}")
    for ax, title in zip(
        axes, ("base parameters: largest relative error", "held-out wrench: relative error"), strict=True
    ):
        ax.set_yscale("log")
        ax.set_title(title)
        ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2)
        ax.set_xticklabels([f"{r:g} Hz frames\n{b:g} Hz motion" for r, b in cases], fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
    for text in axes[1].legend(fontsize=7).get_texts():
        text.set_parse_math(False)
    path = Path(path)
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
