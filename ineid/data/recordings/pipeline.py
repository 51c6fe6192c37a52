"""A lab's recording -> a one-configuration dataset: two clocks, angles only, the sensor frame.

What a lab records (:class:`Streams`): joint angles with their time stamps (velocities and
accelerations only when a sensor measures them, like the paper's gyroscopes), with joint
torques (or motor currents) on the same clock when the drives report them, and the F/T
sensor's wrench with its own time stamps, in the sensor's frame (a recording may have
torques and no wrench). :func:`recording_dataset` turns that into frames ``(q, qd, qdd,``
each channel's values ``)`` on one uniform time base:

1. checks: finite values, increasing time stamps, each stream with enough samples; each stream's time
   stamps audited (its nominal rate, jitter, gaps, and the rows that hold the previous sample dropped:
   :mod:`ineid.data.recordings.timing`);
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

The checks, the cut-off, the filter and the time base are steps of :mod:`ineid.data.recordings.frames`;
this module reads the file, estimates the delay, fuses the IMUs, and builds the dataset and its summary.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ineid.channels import BaseWrench, ChannelSet
from ineid.data.dataset.schema import Dataset, DatasetMeta
from ineid.data.recordings import signals
from ineid.data.recordings.channels import (  # noqa: F401  (resolve_sensor re-exported)
    RIDER_NAMES,
    resolve_sensor,
    rider_channels,
)
from ineid.data.recordings.frames import (
    Cutoff,
    RecordingArrays,
    checked_arrays,
    choose_cutoff,
    smoothed,
    split_columns,
    time_base,
)
from ineid.data.recordings.imus import unused_imu_lines
from ineid.data.recordings.limits import MAX_UPSAMPLING
from ineid.data.recordings.noise_estimate import import_noise
from ineid.data.recordings.settings import DelayEstimator, ImportSettings
from ineid.data.recordings.streams import SI_UNITS, Streams, in_si_units, units_note
from ineid.data.recordings.summary import DelayEstimate, ImportSummary
from ineid.data.recordings.timing import check_gaps
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
            joints, a recording with neither a wrench nor joint torques, a gap in a stream longer than
            the filter's support without ``settings.allow_gaps`` (:mod:`ineid.data.recordings.timing`).
    """
    _refuse_wrench_settings(streams, settings)
    units = {k: getattr(settings, k) for k in SI_UNITS}
    if units != SI_UNITS:
        streams = in_si_units(streams, model, **units)
        settings = replace(settings, **SI_UNITS)
    if settings.estimate_delay:
        return _at_estimated_delay(streams, model, settings, delay_estimator)
    arrays = checked_arrays(streams, model, settings)
    cut = choose_cutoff(arrays, streams, settings)
    check_gaps(arrays.timing, cut.hz or signals.CUTOFF_RANGE[1] * arrays.rate, arrays.source)
    prepared = _prepare_imus(streams, model, settings, cut.hz, arrays.tq, cut.priors_hz)
    if prepared is not None:  # the IMU streams audited like the joints and the wrench
        arrays.timing.streams = (*arrays.timing.streams, *prepared.timing)
        check_gaps(arrays.timing, cut.hz or signals.CUTOFF_RANGE[1] * arrays.rate, arrays.source)
    smooth = smoothed(arrays, cut)
    imu_span = None if prepared is None else (prepared.start, prepared.stop)
    grid, rate = time_base(arrays, smooth, imu_span, settings, cut.hz)
    n = arrays.n_dof
    joints = np.concatenate([smooth.q, smooth.qd, smooth.qdd, *smooth.riders.values()], axis=1)
    joints, moved_q = signals.on_grid(smooth.tq, joints, grid)
    wrench, moved_w = signals.on_grid(smooth.tw, smooth.wrench, grid) if arrays.has_wrench else (None, False)
    imu_lines, imu_record = (), None
    if prepared is not None:  # q the encoders', qd and qdd fused with the IMUs
        priors = joints[:, n : 3 * n] if cut.priors_hz is None else _encoder_priors(cut, arrays.hq, smooth.tq, grid)
        imu_lines, imu_record = _fuse_imus(prepared, model, settings, grid, joints, priors)
    resampled = tuple(name for name, moved in (("joints", moved_q), ("wrench", moved_w)) if moved)
    imu_lines = (*imu_lines, *unused_imu_lines(streams.origin))
    summary = _summary(arrays, cut, settings, grid, rate, resampled, units_note(streams.origin), imu_lines)
    origin = {**streams.origin, "import": summary.to_dict(), **({"imu": imu_record} if imu_record else {})}
    origin["noise"] = import_noise(arrays, cut.hz)
    return _dataset(model, settings, arrays, origin, joints, wrench, grid), summary


def _refuse_wrench_settings(streams: Streams, settings: ImportSettings) -> None:
    """Refuse the F/T sensor's settings (pose, sign, scale, units) on a recording without a wrench: a mistake,
    said once, naming every such flag given."""
    if streams.wrench is not None:
        return
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


def _at_estimated_delay(
    streams: Streams, model, settings: ImportSettings, delay_estimator: DelayEstimator | None
) -> tuple[Dataset, ImportSummary]:
    """:func:`recording_dataset` at the wrench delay ``delay_estimator`` fits (the estimate in the summary and
    in the dataset's import record); ``streams`` and ``settings`` in SI units."""
    if streams.wrench is None:
        raise DatasetError(
            f"{streams.source}: the recording has no wrench, so there is no wrench delay to estimate; drop --delay auto"
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


def _encoder_priors(cut: Cutoff, hq: float, t_joints: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(N, 2 n_dof) the encoders' ``qd``, ``qdd`` at the frames' times ``grid``, from the angles filtered at
    their own cut-off ``cut.priors_hz`` (below the filters' ``cut.hz``); ``t_joints`` the filtered joints' times."""
    from ineid.data.recordings.imus import encoder_priors

    return signals.on_grid(
        t_joints, np.concatenate(encoder_priors(cut.q_uniform, 1.0 / hq, cut.priors_hz), axis=1), grid
    )[0]


def _fuse_imus(prepared, model, settings: ImportSettings, grid, joints, priors) -> tuple[tuple[str, ...], dict]:
    """``qd`` and ``qdd`` of the frames fused with the IMUs, written into ``joints`` (N, 3 n_dof + riders): its
    ``q`` stays the encoders'; ``priors`` (N, 2 n_dof) the encoders' ``qd``, ``qdd``.

    Returns:
        ``(lines, record)``: the summary's lines and the dataset's ``imu`` record.
    """
    from ineid.data.recordings.imus import imu_summary_lines

    n = model.n_dof
    qd_f, qdd_f, estimate, imu_record = prepared.fuse(
        model, grid, joints[:, :n], priors[:, :n], priors[:, n:], settings.estimation, settings.imu_noise
    )
    joints[:, n : 2 * n], joints[:, 2 * n : 3 * n] = qd_f, qdd_f
    return tuple(imu_summary_lines(prepared, estimate)), imu_record


def _summary(
    arrays: RecordingArrays,
    cut: Cutoff,
    settings: ImportSettings,
    grid: np.ndarray,
    rate: float,
    resampled: tuple[str, ...],
    units: str | None,
    imu_lines: tuple[str, ...],
) -> ImportSummary:
    """What the import did: frames, rates, filter, the samples dropped at the edges, the sensor, the IMUs."""
    tq, tw, hq, hw = arrays.tq, arrays.tw, arrays.hq, arrays.hw
    return ImportSummary(
        n_frames=len(grid),
        rate=float(rate),
        span=float(grid[-1] - grid[0]),
        joint_rate=1.0 / hq,
        wrench_rate=1.0 / hw if arrays.has_wrench else None,
        derived=not arrays.measured,
        cutoff=cut.hz,
        cutoff_choice=cut.choice if settings.cutoff is None else None,
        dropped_start=float(grid[0] - min(tq[0], tw[0])),
        dropped_end=float(max(tq[-1], tw[-1]) - grid[-1]),
        dropped_joint_samples=int(np.sum((tq < grid[0] - 1e-9 * hq) | (tq > grid[-1] + 1e-9 * hq))),
        dropped_wrench_samples=(
            int(np.sum((tw < grid[0] - 1e-9 * hw) | (tw > grid[-1] + 1e-9 * hw))) if arrays.has_wrench else 0
        ),
        cutoff_note=cut.note,
        resampled=resampled,
        sensor=None if arrays.wrench_channel is None else arrays.wrench_channel.sensor,
        delay=settings.delay,
        units=units,
        joint_channels=tuple(RIDER_NAMES[k] for k in arrays.riders),
        sensor_where=arrays.where,
        imu=imu_lines,
        timing=arrays.timing,
    )


def _dataset(
    model,
    settings: ImportSettings,
    arrays: RecordingArrays,
    origin: dict,
    joints: np.ndarray,
    wrench: np.ndarray | None,
    grid: np.ndarray,
) -> Dataset:
    """The dataset of one configuration: ``joints`` (N, 3 n_dof + riders) cut into ``q``, ``qd``, ``qdd`` and
    the joints' channels, the wrench under its channel's key, the frames' times ``grid``."""
    n, riders, wrench_channel = arrays.n_dof, arrays.riders, arrays.wrench_channel
    values = split_columns(joints[:, 3 * n :], riders)
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
    else:  # the base wrench alone: its pose kept as the meta's sensor record, numbers as given
        meta = DatasetMeta.for_model(model, source="recording", origin=origin, sensor=wrench_channel.sensor.to_dict())
        channel_values = {}
    return Dataset(
        meta=meta,
        q=joints[None, :, :n],
        qd=joints[None, :, n : 2 * n],
        qdd=joints[None, :, 2 * n : 3 * n],
        wrench=None if wrench is None else wrench[None],
        channel_values=channel_values,
        theta_known=np.asarray(model.theta_cad[model.known_index], dtype=np.float64),
        time=grid[None],
    )


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
            settings.keep_repeats,
        ),
        priors_cutoff=priors_cutoff,
    )


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
    streams = read_streams(
        path, model, joint_topic, wrench_topic, progress, imu_topics, settings.imus, settings.coupling
    )
    return hinted_recording_dataset(streams, model, settings, delay_estimator)


def read_streams(
    path: str | Path,
    model,
    joint_topic: str = "/joint_states",
    wrench_topic: str | None = None,
    progress: Progress | None = None,
    imu_topics: tuple[str, ...] = (),
    imus: tuple[str, ...] = (),
    coupling: str | None = None,
) -> Streams:
    """The :class:`Streams` of a recording file (CSV, ROS 1 ``.bag``, ROS 2 bag folder or ``.mcap``); the
    arguments as :func:`import_recording`'s, ``imus`` its settings' ``--imu`` texts (a CSV's IMU columns
    are read only where one names them), ``coupling`` its coupling file (a CSV's torque and current columns
    may then be named after its motors).

    Raises:
        DatasetError: a file that does not exist, ``imu_topics`` for a CSV, and see
            :func:`ineid.data.recordings.csv_import.read_csv_streams` and
            :func:`ineid.data.recordings.bags.read_bag_streams`.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    if path.is_dir() or path.suffix.lower() in (".bag", ".mcap", ".db3"):
        from ineid.data.recordings.bags import read_bag_streams

        return read_bag_streams(path, model.joint_names, joint_topic, wrench_topic, progress, imu_topics)
    if imu_topics:
        raise DatasetError(
            f"{path}: --imu-topic names a bag's IMU topics; a CSV gives its IMUs as columns imu_<NAME>_wx...: drop it"
        )
    from ineid.data.recordings.csv_import import read_csv_streams

    return read_csv_streams(path, model, progress, imus, coupling_motors(coupling, model))


def coupling_motors(coupling: str | None, model) -> tuple[str, ...]:
    """The motors of the coupling file ``coupling`` (:func:`ineid.channels.transmission.read_coupling`), () without."""
    if not coupling:
        return ()
    from ineid.channels.transmission import read_coupling

    return read_coupling(coupling, model.joint_names)[1]


def own_cutoff(streams: Streams, model, settings: ImportSettings) -> tuple[Cutoff, RecordingArrays]:
    """The cut-off :func:`recording_dataset` would choose for ``streams`` (``settings.cutoff`` when given;
    ``hz`` None: no filter, measured ``qd``, ``qdd``), and the checked arrays it was chosen from; nothing filtered.

    Raises:
        DatasetError: as :func:`recording_dataset`'s checks of the streams and the cut-off.
    """
    try:
        _refuse_wrench_settings(streams, settings)
        units = {k: getattr(settings, k) for k in SI_UNITS}
        si_streams = in_si_units(streams, model, **units) if units != SI_UNITS else streams
        si = replace(settings, **SI_UNITS, delay=0.0, estimate_delay=False)
        arrays = checked_arrays(si_streams, model, si)
        return choose_cutoff(arrays, si_streams, si), arrays
    except DatasetError as e:
        from ineid.data.recordings.plausibility import with_time_unit_hint

        raise with_time_unit_hint(e, streams, model, settings) from None


def hinted_recording_dataset(
    streams: Streams, model, settings: ImportSettings, delay_estimator: DelayEstimator | None = None
) -> tuple[Dataset, ImportSummary]:
    """:func:`recording_dataset`, its errors led by the time stamps' unit where another unit would mend them."""
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
    streams = read_csv_streams(path, model, imus=settings.imus, motors=coupling_motors(settings.coupling, model))
    return recording_dataset(streams, model, settings)[0]


__all__ = [
    "MAX_UPSAMPLING",
    "DelayEstimate",
    "DelayEstimator",
    "ImportSettings",
    "ImportSummary",
    "hinted_recording_dataset",
    "import_recording",
    "own_cutoff",
    "read_recording_csv",
    "read_streams",
    "recording_dataset",
]
