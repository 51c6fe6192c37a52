"""A lab's recording -> a one-configuration dataset: two clocks, angles only, the sensor frame.

What a lab records (:class:`Streams`): joint angles with their time stamps (velocities and
accelerations only when a sensor measures them, like the paper's gyroscopes), with joint
torques (or motor currents) on the same clock when the drives report them, and the F/T
sensor's wrench with its own time stamps, in the sensor's frame (a recording may have
torques and no wrench). :func:`recording_dataset` turns that into frames ``(q, qd, qdd,``
each channel's values ``)`` on one uniform time base:

1. checks: finite values, increasing time stamps, each stream with enough samples;
2. the wrench clock is shifted by ``delay`` (a wrench stamped ``t`` was measured at
   ``t - delay``), given or estimated from the model (:mod:`ineid.identify.delay`);
3. when ``qd``/``qdd`` are missing, joint angles, joint torques *and* wrench go through the
   same zero-phase low-pass (:mod:`ineid.data.recordings.signals`), at a cut-off chosen from the angles'
   spectrum or given, and the angles are differentiated; samples within the filter's edge
   are dropped. Measured ``qd``/``qdd`` are used as they are (no filter unless a cut-off is
   given, which then applies to every channel);
4. both streams are put on one time base: the slower stream's rate, or ``rate``, over the
   time both cover (cubic-spline interpolation; rows already on the grid are taken as they
   are, so one CSV with one time column and measured derivatives passes through unchanged).

The wrench stays in the sensor frame: the dataset records the sensor pose (the channel's
record) and identification transforms the regressor (:mod:`ineid.channels.pose`); a sensor
on a link is a wrench at that link (:mod:`ineid.data.recordings.channels`). Joint torques are
the ``joint_torque`` channel under ``tau`` (format version 4).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ineid.channels import BaseWrench, ChannelSet
from ineid.data.dataset.schema import Dataset, DatasetMeta
from ineid.data.recordings import signals
from ineid.data.recordings.channels import (  # noqa: F401  (resolve_sensor re-exported)
    RIDER_NAMES,
    joint_channels,
    resolve_sensor,
    resolve_wrench_channel,
    rider_channels,
)
from ineid.data.recordings.limits import (
    MAX_UPSAMPLING,
    check_cutoff,
    check_delay,
    check_rate,
    check_stream,
)
from ineid.data.recordings.settings import DelayEstimator, ImportSettings
from ineid.data.recordings.streams import (
    SI_UNITS,
    Streams,
    in_si_units,
    units_note,
)
from ineid.data.recordings.summary import DelayEstimate, ImportSummary
from ineid.errors import DatasetError
from ineid.progress import Progress


def recording_dataset(
    streams: Streams,
    model,
    settings: ImportSettings = ImportSettings(),
    delay_estimator: DelayEstimator | None = None,
) -> tuple[Dataset, ImportSummary]:
    """Frames on one time base from a recording's streams (see the module docstring).

    Args:
        streams: what was read from the file.
        model: the :class:`ineid.RobotModel` of the arm (joint count, URDF frames, CAD values).
        settings: cut-off, rate, delay, sensor pose, wrench sign.
        delay_estimator: what ``settings.estimate_delay`` calls (it fits the model, so it lives with the
            solvers: :func:`ineid.identify.delay.estimate_delay`; :func:`ineid.workflow.import_recording`
            passes it).

    Returns:
        ``(dataset, summary)``: one configuration, ``time`` the frames' time stamps on the
        joints' clock, ``wrench`` in the sensor frame (None without a wrench), ``meta.sensor``
        the pose, joint torques under ``tau`` (``channel_values``) when recorded.

    Raises:
        DatasetError: NaN or infinite samples, time that does not increase, too few
            samples, streams that do not overlap, a cut-off or rate that does not fit the
            sampling, a sensor pose that does not parse, torques for another number of
            joints, a recording with neither a wrench nor joint torques.
    """
    from dataclasses import replace

    if streams.wrench is None:  # the wrench's settings on a recording without one: a mistake, said once
        given = [
            flag
            for flag, on in (
                ("--sensor-pose", settings.sensor_pose is not None),
                ("--flip-wrench", settings.flip_wrench),
                ("--wrench-scale", settings.wrench_scale != 1.0),
                ("--force-unit", settings.force_unit != "N"),
                ("--moment-unit", settings.moment_unit != "Nm"),
            )
            if on
        ]
        if given:
            raise DatasetError(
                f"{streams.source}: {', '.join(given)} set{'s' if len(given) == 1 else ''} up the "
                "F/T sensor, and the recording has no wrench; drop it"
            )
    units = {k: getattr(settings, k) for k in SI_UNITS}
    if units != SI_UNITS:
        streams = in_si_units(streams, model, **units)
        settings = replace(settings, **SI_UNITS)
    has_wrench = streams.wrench is not None
    if settings.estimate_delay:
        if not has_wrench:
            raise DatasetError(
                f"{streams.source}: the recording has no wrench, so there is no wrench delay to "
                "estimate; drop --delay auto"
            )
        if delay_estimator is None:
            raise DatasetError(
                "estimating the wrench delay fits the model: pass delay_estimator=ineid.identify.estimate_delay "
                "(ineid.workflow.import_recording does), or give the delay (ImportSettings(delay=...), --delay S)"
            )
        # the wrench's own fit: the joints' other channels (torques) are on the joints' clock, not delayed
        estimate = delay_estimator(
            replace(streams, tau=None, current=None, imus=()),
            model,
            replace(settings, imus=(), imu_delay=0.0),
            settings.max_delay,
        )
        ds, summary = recording_dataset(streams, model, replace(settings, delay=estimate.delay, estimate_delay=False))
        summary.delay_estimate = estimate
        ds.meta.origin["import"] = summary.to_dict()
        return ds, summary
    src = streams.source
    n = model.n_dof
    tq = np.asarray(streams.joint_time, dtype=np.float64)
    q = np.asarray(streams.q, dtype=np.float64)
    if q.ndim != 2 or q.shape != (len(tq), n):
        raise DatasetError(f"{src}: joint angles of shape {q.shape} for {len(tq)} time stamps and {n} joints")
    measured = streams.qd is not None and streams.qdd is not None
    joint_arrays = {"q": q}
    if measured:
        joint_arrays.update(qd=np.asarray(streams.qd, dtype=np.float64), qdd=np.asarray(streams.qdd, dtype=np.float64))
    riders = joint_channels(streams, model, len(tq), settings)  # {key: (Nq, n_a)}: measured on the joints' clock
    if not has_wrench and not riders:
        raise DatasetError(
            f"{src}: the recording has neither a wrench nor joint torques; give the F/T sensor's "
            "columns fx..mz (or its WrenchStamped topic) or the joint torques tau1..tauN (or "
            "JointState.effort)"
        )
    if has_wrench:
        tw = np.asarray(streams.wrench_time, dtype=np.float64) - settings.delay
        w = np.asarray(streams.wrench, dtype=np.float64) * (-1.0 if settings.flip_wrench else 1.0)
        if w.ndim != 2 or w.shape != (len(tw), 6):
            raise DatasetError(f"{src}: wrench of shape {w.shape} for {len(tw)} time stamps; expected 6 columns")
        check_delay(settings.delay, tq, np.asarray(streams.wrench_time, dtype=np.float64), src)
    elif settings.delay:
        raise DatasetError(f"{src}: --delay is how late the wrench is, and the recording has no wrench; drop it")
    hq = check_stream("joint", tq, {**joint_arrays, **riders}, src)
    if has_wrench:
        hw = check_stream("wrench", tw, {"wrench": w}, src)
        wrench_channel, where = resolve_wrench_channel(settings.sensor_pose, streams.frame_id, model)
    else:
        tw, w, hw, wrench_channel, where = tq, None, hq, None, "the base frame"
    rate = settings.rate or min(1.0 / hq, 1.0 / hw)
    check_rate(
        settings.rate,
        1.0 / hq,
        1.0 / hw,
        min(tq[-1], tw[-1]) - max(tq[0], tw[0]),
        n + sum(a.shape[1] for a in riders.values()),
    )
    same_clock = not has_wrench or (len(tq) == len(tw) and np.array_equal(tq, tw))

    # 1. filter (and differentiate) each stream on a uniform grid at its own rate: the joints' other
    #    channels (torques) with the angles, through the same filter as the wrench
    choice, cutoff_note, priors_cutoff = None, None, None
    cutoff = settings.cutoff
    if not measured and cutoff is None:
        q_u = signals.to_uniform(tq, q, hq)[1]  # the angles on a uniform grid: the cut-off rules and the priors
        choice = signals.choose_cutoff(q_u, 1.0 / hq)
        cutoff = min(choice.cutoff, 0.4 * rate)
        if any("gyro" in s.readings for s in streams.imus):  # the gyros measure qd: recording_imu's rule
            from ineid.data.recordings.imus import imu_cutoff

            gyro = (settings.imu_noise or {}).get("gyro", 0.005)
            angles_cutoff = cutoff
            cutoff, cutoff_note = imu_cutoff(q_u, 1.0 / hq, cutoff, [tuple(s.readings) for s in streams.imus], gyro)
            cutoff = min(cutoff, 0.4 * rate)
            priors_cutoff = angles_cutoff if angles_cutoff < cutoff else None
    if cutoff is not None and cutoff >= 0.45 * rate:
        raise DatasetError(
            f"cut-off {cutoff:g} Hz is above what frames at {rate:g} Hz can hold (Nyquist {rate / 2:g} Hz); "
            f"use --cutoff below {0.45 * rate:g} Hz or a higher --rate"
        )
    if settings.cutoff is not None:
        check_cutoff(settings.cutoff, min(tq[-1], tw[-1]) - max(tq[0], tw[0]), rate)
    prepared = _prepare_imus(streams, model, settings, cutoff, tq, priors_cutoff)
    joint_parts = {**joint_arrays, **riders}
    if cutoff is not None:
        tq_u, jq = signals.to_uniform(tq, np.concatenate(list(joint_parts.values()), axis=1), hq)
        jq = signals.LowPass(cutoff, 1.0 / hq).apply(jq)
        parts = _columns(jq, joint_parts)
        if measured:
            q_s, qd_s, qdd_s = parts["q"], parts["qd"], parts["qdd"]
        else:
            q_s = parts["q"]
            qd_s, qdd_s = signals.derivatives(q_s, hq)
        riders_s = {k: parts[k] for k in riders}
        if has_wrench:
            tw_u, w_s = signals.to_uniform(tw, w, hw)
            w_s = signals.LowPass(cutoff, 1.0 / hw).apply(w_s)
        else:
            tw_u, w_s = tq_u, None
        edge = signals.edge_seconds(min(cutoff, priors_cutoff or cutoff))
    else:
        tq_u, q_s, qd_s, qdd_s = tq, q, joint_arrays["qd"], joint_arrays["qdd"]
        riders_s = riders
        tw_u, w_s = tw, w
        edge = 0.0

    # 2. one time base over what both streams cover, edges dropped
    start = max(tq_u[0], tw_u[0]) + edge
    stop = min(tq_u[-1], tw_u[-1]) - edge
    if prepared is not None and prepared.stop - prepared.start < stop - start:  # every IMU covers the frames
        start, stop = max(start, prepared.start), min(stop, prepared.stop)
        if not stop > start:
            raise DatasetError(
                f"{src}: the IMUs, the joints and the wrench cover no common time beyond the filter's "
                "edges; record longer, or check the time stamps, --delay and --imu-delay"
            )
    if not stop > start:
        if not has_wrench:
            raise DatasetError(
                f"{src}: the joint stream ({tq[0]:.6g}..{tq[-1]:.6g} s) is shorter than the filter's "
                f"edges ({edge:.3g} s at each end); record longer"
            )
        raise DatasetError(
            f"{src}: the joint stream ({tq[0]:.6g}..{tq[-1]:.6g} s) and the wrench stream ({tw[0]:.6g}..{tw[-1]:.6g} s"
            + (f", delay {settings.delay:g} s applied" if settings.delay else "")
            + f") overlap in {max(0.0, min(tq_u[-1], tw_u[-1]) - max(tq_u[0], tw_u[0])):.3g} s"
            + (f", less than the filter's edges ({edge:.3g} s at each end)" if edge else "")
            + "; record longer, or check the time stamps and --delay"
        )
    passthrough = same_clock and settings.rate is None and cutoff is None
    slower_t = tq_u if hq >= hw else tw_u
    if passthrough:  # one clock, measured derivatives: the rows are the frames
        grid = tq[(tq >= start) & (tq <= stop)]
        rate = 1.0 / hq
    elif settings.rate is None and signals.is_uniform(slower_t):  # the slower stream's own time base
        grid = slower_t[(slower_t >= start - 1e-9 * max(hq, hw)) & (slower_t <= stop + 1e-9 * max(hq, hw))]
    else:
        h = 1.0 / rate
        grid = start + h * np.arange(int(math.floor((stop - start) / h * (1 + 1e-12))) + 1)
    if len(grid) < 2:
        raise DatasetError(
            f"{src}: {len(grid)} frame{'s' if len(grid) != 1 else ''} left on the common time base; "
            "record longer or raise --rate"
        )
    joints = np.concatenate([q_s, qd_s, qdd_s, *riders_s.values()], axis=1)
    joints, moved_q = signals.on_grid(tq_u, joints, grid)
    wrench, moved_w = signals.on_grid(tw_u, w_s, grid) if has_wrench else (None, False)
    imu_lines, imu_record = (), None
    if prepared is not None:  # q the encoders', qd and qdd fused with the IMUs
        from ineid.data.recordings.imus import encoder_priors, imu_summary_lines

        priors = (
            joints[:, n : 3 * n]
            if priors_cutoff is None
            else signals.on_grid(tq_u, np.concatenate(encoder_priors(q_u, 1.0 / hq, priors_cutoff), axis=1), grid)[0]
        )
        qd_f, qdd_f, estimate, imu_record = prepared.fuse(
            model, grid, joints[:, :n], priors[:, :n], priors[:, n:], settings.estimation, settings.imu_noise
        )
        joints[:, n : 2 * n], joints[:, 2 * n : 3 * n] = qd_f, qdd_f
        imu_lines = tuple(imu_summary_lines(prepared, estimate))
    resampled = [name for name, moved in (("joints", moved_q), ("wrench", moved_w)) if moved]
    summary = ImportSummary(
        n_frames=len(grid),
        rate=float(rate),
        span=float(grid[-1] - grid[0]),
        joint_rate=1.0 / hq,
        wrench_rate=1.0 / hw if has_wrench else None,
        derived=not measured,
        cutoff=cutoff,
        cutoff_choice=choice if settings.cutoff is None else None,
        dropped_start=float(grid[0] - min(tq[0], tw[0])),
        dropped_end=float(max(tq[-1], tw[-1]) - grid[-1]),
        dropped_joint_samples=int(np.sum((tq < grid[0] - 1e-9 * hq) | (tq > grid[-1] + 1e-9 * hq))),
        dropped_wrench_samples=(
            int(np.sum((tw < grid[0] - 1e-9 * hw) | (tw > grid[-1] + 1e-9 * hw))) if has_wrench else 0
        ),
        cutoff_note=cutoff_note,
        resampled=tuple(resampled),
        sensor=None if wrench_channel is None else wrench_channel.sensor,
        delay=settings.delay,
        units=units_note(streams.origin),
        joint_channels=tuple(RIDER_NAMES[k] for k in riders),
        sensor_where=where,
        imu=imu_lines,
    )
    values = _columns(joints[:, 3 * n :], riders)
    origin = {**streams.origin, "import": summary.to_dict(), **({"imu": imu_record} if imu_record else {})}
    if riders or not isinstance(wrench_channel, BaseWrench):  # channels of version 4
        channels = ChannelSet(
            tuple(c for c in (wrench_channel, *rider_channels(riders, model, settings)) if c is not None)
        )
        meta = DatasetMeta.for_model(model, source="recording", origin=origin, channels=channels)
        key = None if wrench_channel is None else wrench_channel.key
        channel_values = {k: v[None] for k, v in values.items()}
        if key is not None and key != "wrench":
            channel_values[key] = wrench[None]
            wrench = None
    else:  # the base wrench alone, as before issue 21
        meta = DatasetMeta.for_model(model, source="recording", origin=origin, sensor=wrench_channel.sensor.to_dict())
        channel_values = {}
    ds = Dataset(
        meta=meta,
        q=joints[None, :, :n],
        qd=joints[None, :, n : 2 * n],
        qdd=joints[None, :, 2 * n : 3 * n],
        wrench=None if wrench is None else wrench[None],
        channel_values=channel_values,
        theta_known=np.asarray(model.theta_cad[model.known_index], dtype=np.float64),
        time=grid[None],
    )
    return ds, summary


def _prepare_imus(
    streams: Streams,
    model,
    settings: ImportSettings,
    cutoff: float | None,
    tq: np.ndarray,
    priors_cutoff: float | None = None,
):
    """The recording's IMU streams matched, delayed and filtered (:func:`ineid.data.recordings.imus.prepare_imus`),
    or None without IMUs; ``--imu`` or ``--imu-delay`` without IMU readings is one line."""
    if not streams.imus:
        if settings.imus or settings.imu_delay:
            flag = "--imu" if settings.imus else "--imu-delay"
            raise DatasetError(
                f"{streams.source}: {flag} is for the recording's link IMUs, and it has no IMU readings "
                "(CSV columns imu_<NAME>_wx..., or bag topics named by --imu-topic); drop it"
            )
        return None
    from ineid.data.recordings.imus import prepare_imus

    return replace(
        prepare_imus(
            streams.imus,
            settings.imus,
            model,
            cutoff,
            settings.imu_delay,
            (float(tq[0]), float(tq[-1])),
            streams.source,
        ),
        priors_cutoff=priors_cutoff,
    )


def _columns(x: np.ndarray, like: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``x`` (N, sum of widths) cut into ``{key: (N, width of like[key])}``, in ``like``'s order."""
    out, start = {}, 0
    for key, a in like.items():
        out[key] = x[:, start : start + a.shape[1]]
        start += a.shape[1]
    return out


def import_recording(
    path: str | Path,
    model,
    settings: ImportSettings = ImportSettings(),
    joint_topic: str = "/joint_states",
    wrench_topic: str | None = None,
    progress: Progress | None = None,
    imu_topics: tuple[str, ...] = (),
    delay_estimator: DelayEstimator | None = None,
) -> tuple[Dataset, ImportSummary]:
    """Read a recording file (CSV, ROS 1 ``.bag``, ROS 2 bag folder or ``.mcap``) into a dataset.

    Args:
        path: the file or (ROS 2) folder.
        model: the :class:`ineid.RobotModel` of the arm.
        settings: see :class:`ImportSettings`.
        joint_topic, wrench_topic: bag topics (``sensor_msgs/JointState``,
            ``geometry_msgs/WrenchStamped``; the wrench topic may be left out when the bag
            has one such topic).
        imu_topics: bag topics of link IMUs (``sensor_msgs/Imu``, :mod:`ineid.data.recordings.bags`).
        progress: ``progress(done, total)`` over rows or messages read.
        delay_estimator: see :func:`recording_dataset`.

    Raises:
        DatasetError: see :func:`recording_dataset`, :func:`ineid.data.recordings.csv_import.read_csv_streams`
            and :func:`ineid.data.recordings.bags.read_bag_streams`.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    if path.is_dir() or path.suffix.lower() in (".bag", ".mcap", ".db3"):
        from ineid.data.recordings.bags import read_bag_streams

        streams = read_bag_streams(path, model.joint_names, joint_topic, wrench_topic, progress, imu_topics)
    else:
        if imu_topics:
            raise DatasetError(
                f"{path}: --imu-topic names a bag's IMU topics; a CSV gives its IMUs as columns "
                "imu_<NAME>_wx...: drop it"
            )
        from ineid.data.recordings.csv_import import read_csv_streams

        streams = read_csv_streams(path, model, progress)
    try:
        return recording_dataset(streams, model, settings, delay_estimator)
    except DatasetError as e:  # a time column in ms fails the cut-off rules first, whose fix is not the cause's
        from ineid.data.recordings.plausibility import with_time_unit_hint

        raise with_time_unit_hint(e, streams, model, settings) from None


def read_recording_csv(path: str | Path, model, flip_wrench: bool = False, settings=None) -> Dataset:
    """Read a recording CSV into a :class:`Dataset` of one configuration.

    Args:
        path: the CSV file (comma-separated; ``#`` lines are comments).
        model: the :class:`ineid.RobotModel` the arm is.
        flip_wrench: the sensor reports the wrench on the robot; negate it.
        settings: an :class:`ImportSettings` (sensor pose, cut-off,
            rate, delay); its ``flip_wrench`` is overridden by the argument.

    Raises:
        DatasetError: see :func:`ineid.data.recordings.csv_import.read_csv_streams` and
            :func:`recording_dataset`.
    """
    from dataclasses import replace

    from ineid.data.recordings.csv_import import read_csv_streams

    settings = replace(settings or ImportSettings(), flip_wrench=flip_wrench)
    return recording_dataset(read_csv_streams(path, model), model, settings)[0]


__all__ = [
    "MAX_UPSAMPLING",
    "DelayEstimate",
    "DelayEstimator",
    "ImportSettings",
    "ImportSummary",
    "import_recording",
    "read_recording_csv",
    "recording_dataset",
]
