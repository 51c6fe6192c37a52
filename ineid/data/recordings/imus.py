"""Link IMUs in a recording: their streams onto the frames, their mounts, and the fused joint states.

An IMU on a link measures the link's kinematics, not a linear function of the inertial
parameters, so it is no measurement channel (``docs/architecture.md``): its streams are state
estimation before identification. :func:`prepare_imus` matches each stream (:class:`ImuStream`)
to its mount (:class:`ineid.data.imu.readings.ImuMount`: an ``--imu`` given, else the link or URDF frame
the stream's name names), shifts it by ``imu_delay`` and filters it on its own clock with the
low-pass the angles and the wrench get; :meth:`PreparedImus.fuse` puts it on the frames' time
base (the cubic spline the wrench goes through) and calls
:func:`ineid.data.imu.estimation.estimate_joint_states`: ``q`` stays the encoders', ``qd`` and
``qdd`` are fused. The mounts and the estimate's summary go to the dataset's ``origin`` under
``"imu"``, never to its channels.

``--imu`` text: ``LINK``, ``LINK:x,y,z,roll,pitch,yaw`` (m, rad, URDF rpy, in the link's frame),
a URDF frame welded to a moving link, each optionally preceded by ``NAME=`` (the name the
columns or the bag's ``frame_id`` use when it is neither the link's nor a URDF frame's).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ineid.data.recordings import signals
from ineid.data.recordings.streams import ImuStream
from ineid.data.recordings.timing import audit_stream
from ineid.errors import DatasetError

IMU_AXES = {"gyro": ("wx", "wy", "wz"), "accel": ("ax", "ay", "az"), "alpha": ("alx", "aly", "alz")}
"""The CSV column suffixes of each kind of reading: ``imu_<NAME>_wx`` ... (sensor frame)."""
IMU_UNITS = {"gyro": "rad/s", "accel": "m/s^2", "alpha": "rad/s^2"}
NOISE_BANDWIDTH = 3 * math.pi / (8 * math.sqrt(2))
"""``int_0^inf |H(f)|^2 df / fc`` of :class:`ineid.data.recordings.signals.LowPass` (``|H| = 1 / (1 + (f/fc)^4)``):
white noise of std ``s`` at rate ``r`` leaves it with std ``s sqrt(NOISE_BANDWIDTH fc / (r / 2))``."""


def imu_column_kinds(header: Sequence[str], path) -> dict[str, dict[str, list[str]]]:
    """``{name: {kind: [its three columns]}}`` of a CSV header's ``imu_<NAME>_<axis>`` columns, in header order.

    Raises:
        DatasetError: a column ``imu_...`` whose suffix is no axis, or a kind with some of its three axes.
    """
    suffix_kind = {a: k for k, axes in IMU_AXES.items() for a in axes}
    found: dict[str, dict[str, set[str]]] = {}
    for h in header:
        if not h.startswith("imu_"):
            continue
        name, _, axis = h[4:].rpartition("_")
        if not name or axis not in suffix_kind:
            raise DatasetError(
                f"{path}: column {h!r} is no IMU axis; IMU columns are imu_<NAME>_wx,_wy,_wz (gyro, "
                "rad/s), imu_<NAME>_ax,_ay,_az (accelerometer, m/s^2), imu_<NAME>_alx,_aly,_alz "
                "(angular acceleration, rad/s^2)"
            )
        found.setdefault(name, {}).setdefault(suffix_kind[axis], set()).add(axis)
    out: dict[str, dict[str, list[str]]] = {}
    for name, kinds in found.items():
        out[name] = {}
        for kind in IMU_AXES:
            if kind not in kinds:
                continue
            missing = [a for a in IMU_AXES[kind] if a not in kinds[kind]]
            if missing:
                have = ", ".join(f"imu_{name}_{a}" for a in IMU_AXES[kind] if a in kinds[kind])
                raise DatasetError(
                    f"{path}: IMU {name!r} has {have} but no {', '.join(f'imu_{name}_{a}' for a in missing)}; "
                    f"give all three axes of its {kind} ({IMU_UNITS[kind]}, sensor frame) or none"
                )
            out[name][kind] = [f"imu_{name}_{a}" for a in IMU_AXES[kind]]
    return out


def named_imus(texts: Sequence[str], model) -> set[str]:
    """The IMU names (the ``<NAME>`` of ``imu_<NAME>_wx`` columns) the ``--imu`` texts give.

    Raises:
        DatasetError: a text that does not parse (:func:`parse_imu_text`).
    """
    return {parse_imu_text(text, model).name for text in texts}


def unused_imu_lines(origin: Mapping | None) -> tuple[str, ...]:
    """The import's line on the IMUs a recording holds and the import did not use (``origin["imu_unused"]``:
    CSV columns no ``--imu`` names, bag ``Imu`` topics no ``--imu-topic`` names), with how to use them."""
    unused = (origin or {}).get("imu_unused") or {}
    if unused.get("columns"):
        found = ", ".join(f"imu_{name}_* ({', '.join(kinds)})" for name, kinds in unused["columns"].items())
        return (
            f"IMU columns not used: {found}; to fuse an IMU with the joints name it: --imu NAME (on the link or "
            "URDF frame NAME) or --imu NAME=LINK[:x,y,z,roll,pitch,yaw]",
        )
    if unused.get("topics"):
        return (
            f"Imu topics not used: {', '.join(unused['topics'])}; to fuse one with the joints name it: --imu-topic "
            "TOPIC (and --imu NAME=LINK[:x,y,z,roll,pitch,yaw] where its frame_id names no link)",
        )
    return ()


def parse_imu_text(text: str, model):
    """An ``--imu`` text (``[NAME=]LINK[:x,y,z,roll,pitch,yaw]`` or a URDF frame) -> an :class:`ImuMount`.

    Raises:
        DatasetError: a link or frame the model does not have, a pose that does not parse.
    """
    from ineid.data.imu.readings import parse_imu

    name, eq, rest = text.partition("=")
    if eq:
        name = name.strip()
        if not name or any(c in name for c in ",: "):
            raise DatasetError(
                f"--imu {text!r}: the name before '=' must be a word (the <NAME> of imu_<NAME>_wx, or "
                "the bag's frame_id); write NAME=LINK[:x,y,z,roll,pitch,yaw]"
            )
    try:
        return parse_imu(rest.strip(), model, name=name) if eq else parse_imu(text.strip(), model)
    except DatasetError as e:
        if str(e).startswith("IMU "):
            raise
        raise DatasetError(f"--imu {text!r}: {e}") from None


def resolve_mounts(imus: Sequence[ImuStream], texts: Sequence[str], model, src: str) -> list:
    """The mount of each IMU stream (by name), its kinds those the streams hold.

    Raises:
        DatasetError: an ``--imu`` that does not parse or names no link of the model; a stream whose name is
            neither an ``--imu`` nor a link or URDF frame on a moving link; an ``--imu`` with no stream.
    """
    from ineid.data.imu.readings import parse_imu

    given = {}
    for text in texts:
        mount = parse_imu_text(text, model)
        if mount.name in given:
            raise DatasetError(
                f"--imu {text!r}: IMU {mount.name!r} is given twice; give each IMU once (NAME=LINK:pose "
                "names a second IMU on one link)"
            )
        given[mount.name] = mount
    kinds: dict[str, list[str]] = {}
    for s in imus:
        kinds.setdefault(s.name, [])
        kinds[s.name] += [k for k in s.readings if k not in kinds[s.name]]
    unused = [n for n in given if n not in kinds]
    if unused:
        raise DatasetError(
            f"{src}: --imu {unused[0]!r} has no readings in the recording (its IMUs: "
            f"{', '.join(kinds) or 'none'}); name its columns imu_{unused[0]}_wx... or its bag topic's "
            "frame_id after it, or drop the --imu"
        )
    mounts = []
    for name, ks in kinds.items():
        mount = given.get(name)
        if mount is None:
            try:
                mount = parse_imu(name, model)
            except DatasetError as e:
                moving = ", ".join(j.link for j in model.chain.joints)
                raise DatasetError(
                    f"{src}: IMU {name!r} names no moving link of {model.name} ({moving}) nor a URDF "
                    f"frame on one; give its mount: --imu {name}=LINK[:x,y,z,roll,pitch,yaw]"
                ) from e
        mounts.append(replace(mount, kinds=tuple(k for k in IMU_AXES if k in ks)))
    return mounts


@dataclass
class PreparedImus:
    """The IMU streams matched to mounts, delayed and filtered on their own clocks (:func:`prepare_imus`)."""

    mounts: list
    streams: list[tuple[str, np.ndarray, dict[str, np.ndarray]]]  # (name, uniform time, {kind: filtered})
    rates: dict[str, float]
    start: float  # the frames must lie within [start, stop]: every IMU covers it
    stop: float
    delay: float
    cutoff: float | None = None
    priors_cutoff: float | None = None  # Hz: the priors' cut-off (:func:`encoder_priors`), below ``cutoff``
    timing: tuple = ()  # each stream's :class:`ineid.data.recordings.timing.StreamTiming`, named ``IMU 'NAME'``

    def fuse(
        self,
        model,
        grid: np.ndarray,
        q: np.ndarray,
        qd: np.ndarray,
        qdd: np.ndarray,
        settings=None,
        imu_noise: dict | None = None,
    ):
        """``(qd, qdd, summary, record)``: the joint states fused with the IMUs at the frames ``grid``.

        ``settings.noise`` is the sensors' white noise at their own rates; the low-pass leaves
        ``sqrt(NOISE_BANDWIDTH cutoff / (rate / 2))`` of it (:func:`filtered_noise`, the
        slowest IMU's rate), which is what the estimate weighs and checks the residuals against.
        """
        from ineid.data.imu.estimation import estimate_joint_states
        from ineid.data.imu.settings import EstimationSettings, ImuNoise

        if settings is None:
            settings = EstimationSettings(noise=ImuNoise(**(imu_noise or {})), qdd_prior=qdd_prior(self.mounts))
        if self.cutoff is not None:
            noise = {k: getattr(settings.noise, k) for k in ("gyro", "accel", "alpha")}
            noise = filtered_noise(noise, self.cutoff, min(self.rates.values()))
            h = float(np.median(np.diff(grid))) if len(grid) > 1 else 1.0
            if self.cutoff < 0.45 / h:  # the frames hold the filter: its model error on them
                low = signals.LowPass(self.cutoff, 1.0 / h)
                noise = with_model_error(noise, filter_model_error(model, self.mounts, q, h, low.apply))
            settings = replace(settings, noise=noise, cutoff=self.cutoff if self.priors_cutoff else None)

        readings: dict[str, dict[str, np.ndarray]] = {}
        for name, t, parts in self.streams:
            x = signals.interpolate(t, np.concatenate(list(parts.values()), axis=1), grid)
            readings.setdefault(name, {}).update({k: x[:, 3 * i : 3 * i + 3] for i, k in enumerate(parts)})
        qd_f, qdd_f, summary = estimate_joint_states(model, q, qd, qdd, self.mounts, readings, settings, time=grid)
        record = {
            "mounts": [_mount_dict(m) for m in self.mounts],
            "rates": self.rates,
            "delay": self.delay,
            "estimation": summary.to_dict(),
        }
        return qd_f, qdd_f, summary, record


def qdd_prior(mounts) -> str:
    """The prior on ``qdd``: the derivative of the fused ``qd`` (``"gyros"``) when a gyro measures, else the
    encoders' second derivative (``"encoders"``)."""
    return "gyros" if any("gyro" in m.kinds for m in mounts) else "encoders"


DERIVATIVE_BANDWIDTH = math.pi / (8 * math.sqrt(2))
"""``int_0^inf x^2 |H(x fc)|^2 dx`` of :class:`ineid.data.recordings.signals.LowPass`: white noise of std ``s`` at
rate ``r``, filtered at ``fc`` and differentiated once, has std ``2 pi s sqrt(DERIVATIVE_BANDWIDTH fc^3 / (r / 2))``."""


def imu_cutoff(q: np.ndarray, rate: float, angles_cutoff: float, mounts_kinds, gyro_noise: float) -> tuple[float, str]:
    """The cut-off when gyros measure ``qd`` (no ``--cutoff``): ``(Hz, why)``, never below the angles' rule's.

    The angles' rule (:func:`ineid.data.recordings.signals.choose_cutoff`) bounds the noise of twice-differentiated
    encoders; with gyros ``qd`` is measured and ``qdd`` is the fused ``qd`` differentiated once, or measured too:

    * with angular-acceleration sensors, the rule's upper bound, 0.1 x the rate (nothing is differentiated);
    * with gyros alone, the highest cut-off at which the differentiated gyro noise (``gyro_noise`` rad/s white,
      :data:`DERIVATIVE_BANDWIDTH`) stays within 1 % of the accelerations' RMS (the angles' rule's target; the
      RMS of ``q``'s second derivative at the angles' cut-off), between 1 Hz and 0.1 x the rate.

    The encoders' derivatives, the fusion's priors, stay at the angles' cut-off (:func:`encoder_priors`):
    where the gyros leave a direction unseen (IMUs on some links only, or near an alignment of two joint axes)
    the fused rates are theirs, at their best (at the raised cut-off the fused ``qd`` was worse than the encoders
    alone there: 0.023 against 0.007 rad/s, 10-bit).

    Measured (``docs/recordings.md``, the sensor study): with 10-bit encoders the angles' rule filters a fast
    motion itself away; at 500 Hz the upper bound leaves a slow motion's differentiated gyros too noisy.

    Args:
        q: (N, n_dof) the encoders' angles on a uniform grid at ``rate`` Hz.
        angles_cutoff: Hz, the angles' rule's choice.
        mounts_kinds: each IMU's kinds.
        gyro_noise: rad/s, the gyros' white-noise std at ``rate``.
    """
    upper = 0.1 * rate
    if any("alpha" in kinds for kinds in mounts_kinds):
        return max(upper, angles_cutoff), "the upper bound, 0.1 x the rate: angular-acceleration sensors measure qdd"
    from ineid.data.recordings import signals

    h = 1.0 / rate
    _, qdd = signals.derivatives(signals.LowPass(angles_cutoff, rate).apply(q), h)
    rms = float(np.sqrt(np.mean(qdd[len(qdd) // 10 : -len(qdd) // 10 or None] ** 2)))
    fc = ((0.01 * rms / (2 * math.pi * gyro_noise)) ** 2 * (rate / 2) / DERIVATIVE_BANDWIDTH) ** (1 / 3)
    fc = float(min(max(fc, 1.0, angles_cutoff), max(upper, angles_cutoff)))
    return fc, (
        f"from the gyros' noise ({gyro_noise:g} rad/s): their fused qd differentiated once keeps 1 % of the "
        "accelerations' RMS"
    )


def encoder_priors(q: np.ndarray, rate: float, angles_cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """The fusion's priors when gyros raised the cut-off: the encoders' ``(qd, qdd)`` at the angles' own cut-off.

    The readings, the angles and the wrench go through the raised cut-off (the gyros measure the rates); the
    priors give the rates where the gyros do not see them, and there the encoders are best filtered by their own
    rule. Measured on the tests' fast motion (10-bit encoders, 200 Hz): with IMUs on the upper arm and forearm
    only, the fused ``qd`` 0.0045 against 0.012 (relative) from the encoders alone, ``qdd`` 0.013 against 0.019,
    the base error 0.013 against 0.049; with priors at the raised cut-off the fused ``qdd`` was 0.052.

    Args:
        q: (N, n_dof) the encoders' angles, uniform at ``rate`` Hz, unfiltered.
    """
    return signals.derivatives(signals.LowPass(angles_cutoff, rate).apply(q), 1.0 / rate)


def filter_model_error(model, mounts, q: np.ndarray, h: float, low) -> dict[str, float]:
    """Per kind the RMS of what the low-pass does to the readings that it does not do to the model: filtered
    readings ``LP(y(q, qd, qdd))`` against the maps at the filtered angles ``y(LP q, d/dt LP q, d2/dt2 LP q)``
    (the product of maps and rates does not commute with the filter). Estimated on the encoders' filtered angles
    as a stand-in for the true ones (within 2 % of the true mismatch at the angles' cut-off on the tests' fast
    motion, half of it at three times that cut-off, where it is small): at the angles' rule's cut-off it is ten
    times the filtered gyro noise, and the fusion must weigh it.

    Args:
        q: (F, n_dof) the filtered encoders' angles on a uniform grid of step ``h`` s.
        low: the filter (``x -> filtered x``, along axis 0).
    """
    from ineid.data.imu.readings import imu_readings

    q = np.asarray(q, dtype=np.float64)
    if len(q) < 8:
        return {}
    qd, qdd = signals.derivatives(q, h)
    q2 = low(q)
    qd2, qdd2 = signals.derivatives(q2, h)
    y1, y2 = imu_readings(model, mounts, q, qd, qdd), imu_readings(model, mounts, q2, qd2, qdd2)
    keep = slice(len(q) // 10, len(q) - len(q) // 10 or None)
    out: dict[str, list[float]] = {}
    for m in mounts:
        for k in m.kinds:
            d = low(y1[m.name][k]) - y2[m.name][k]
            out.setdefault(k, []).append(float(np.mean(d[keep] ** 2)))
    return {k: math.sqrt(float(np.mean(v))) for k, v in out.items()}


def with_model_error(noise, model_error: Mapping[str, float]):
    """``noise`` (an :class:`ImuNoise`) with the filter's model error added in quadrature per kind."""
    return replace(noise, **{k: math.hypot(getattr(noise, k), v) for k, v in model_error.items()})


def filtered_noise(noise: Mapping[str, float], cutoff: float | None, rate: float):
    """The :class:`ineid.data.imu.estimation.ImuNoise` of white noise ``noise`` at ``rate`` Hz after the
    low-pass at ``cutoff`` (None: unfiltered); a kind without noise gets a floor of 1 % of the default's (its
    readings are trusted, not infinitely)."""
    from ineid.data.imu.settings import ImuNoise

    factor = 1.0 if cutoff is None else math.sqrt(min(1.0, NOISE_BANDWIDTH * cutoff / (rate / 2)))
    default = ImuNoise()
    return ImuNoise(
        **{k: max(float(noise.get(k, 0.0)) * factor, 1e-2 * getattr(default, k)) for k in ("gyro", "accel", "alpha")}
    )


def _mount_dict(mount) -> dict:
    if hasattr(mount, "to_dict"):
        return mount.to_dict()
    return {"link": mount.link, "name": mount.name, "kinds": list(mount.kinds), "sensor": mount.sensor.to_dict()}


def prepare_imus(
    imus: Sequence[ImuStream],
    texts: Sequence[str],
    model,
    cutoff: float | None,
    delay: float,
    joint_span: tuple[float, float],
    src: str,
    keep_repeats: bool = False,
) -> PreparedImus:
    """Match, check, delay and filter the IMU streams (see the module docstring).

    Each stream's time stamps are audited as the joints' and the wrench's are
    (:func:`ineid.data.recordings.timing.audit_stream`): it is resampled at its nominal rate, its rows that
    hold the previous sample dropped (kept with ``keep_repeats``); the audits are :attr:`PreparedImus.timing`,
    for the import's summary, origin and warnings (:func:`ineid.data.recordings.timing.check_gaps`).

    Args:
        imus: the streams read from the file.
        texts: the ``--imu`` texts.
        model: the :class:`ineid.RobotModel`.
        cutoff: Hz, the low-pass the angles get (None: no filter, the joints' derivatives are measured).
        delay: s, how late the IMU time stamps are against the joints' (an IMU stamped ``t`` measured at
            ``t - delay``).
        joint_span: the joint stream's first and last time stamps.
        src: the file, for messages.
        keep_repeats: use rows that repeat the previous sample as data (``--keep-repeats``).

    Raises:
        DatasetError: see :func:`resolve_mounts`; NaN, infinite or non-increasing samples; a stream that does
            not overlap the joints in time.
    """
    mounts = resolve_mounts(imus, texts, model, src)
    edge = signals.edge_seconds(cutoff) if cutoff is not None else 0.0
    start, stop = -np.inf, np.inf
    out, rates, timings = [], {}, []
    for s in imus:
        t = np.asarray(s.time, dtype=np.float64)
        parts = {k: np.asarray(v, dtype=np.float64) for k, v in s.readings.items()}
        label = f"IMU {s.name!r}" + (f" ({s.where})" if s.where else "")
        for k, v in parts.items():
            if v.shape != (len(t), 3):
                raise DatasetError(
                    f"{src}: {label}'s {k} readings have shape {v.shape} for {len(t)} time stamps; expected 3 axes"
                )
        if len(t) < 4:
            raise DatasetError(
                f"{src}: {label} has {len(t)} sample{'s' if len(t) != 1 else ''}; a recording needs many more"
            )
        bad = ~np.isfinite(np.concatenate([t[:, None], *parts.values()], axis=1)).all(axis=1)
        if bad.any():
            raise DatasetError(
                f"{src}: {label} holds NaN or an infinite value at sample {int(np.flatnonzero(bad)[0])} "
                f"({int(bad.sum())} in all); values must be finite: drop or repair those samples"
            )
        signals.median_interval(t, f"{src}: {label}")
        timing, kept = audit_stream(f"IMU {s.name!r}", t, np.concatenate(list(parts.values()), axis=1), keep_repeats)
        t, parts, h = t[kept] - delay, {k: v[kept] for k, v in parts.items()}, timing.step
        timings.append(timing)
        lo, hi = max(t[0], joint_span[0]), min(t[-1], joint_span[1])
        if not hi - lo > 2 * edge + h:
            raise DatasetError(
                f"{src}: {label} ({t[0]:.6g}..{t[-1]:.6g} s"
                + (f", IMU delay {delay:g} s applied" if delay else "")
                + f") does not overlap the joints ({joint_span[0]:.6g}..{joint_span[1]:.6g} s)"
                + (f" beyond the filter's edges ({edge:.3g} s at each end)" if edge else "")
                + "; check its time stamps (the same clock origin as the joints') and --imu-delay"
            )
        if cutoff is not None:
            if cutoff >= 0.45 / h:
                raise DatasetError(
                    f"{src}: {label} at {1 / h:g} Hz cannot hold the cut-off {cutoff:g} Hz; log it "
                    "faster or lower --cutoff"
                )
            tu, x = signals.to_uniform(t, np.concatenate(list(parts.values()), axis=1), h)
            x = signals.LowPass(cutoff, 1.0 / h).apply(x)
            parts = {k: x[:, 3 * i : 3 * i + 3] for i, k in enumerate(parts)}
            t = tu
        start, stop = max(start, t[0] + edge), min(stop, t[-1] - edge)
        out.append((s.name, t, parts))
        rates[f"{s.name}.{'+'.join(parts)}"] = float(1.0 / h)
    return PreparedImus(mounts, out, rates, float(start), float(stop), float(delay), cutoff, timing=tuple(timings))


def imu_summary_lines(prepared: PreparedImus, summary) -> list[str]:
    """The import summary's IMU lines: each IMU's streams and rates, then the estimate's own lines."""
    rates = "; ".join(f"IMU {k.split('.', 1)[0]!r} {k.split('.', 1)[1]} at {r:g} Hz" for k, r in prepared.rates.items())
    out = [
        f"{rates}: resampled onto the frames"
        + (f", stamps {prepared.delay:g} s late" if prepared.delay else "")
        + "; qd, qdd fused from the encoders and the IMUs"
    ]
    return out + list(summary.lines())
