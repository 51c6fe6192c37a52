"""Synthetic ground truth: sample parameters and frames, compute what the sensors read, add noise.

The values of every measurement channel come from the channel's prediction (for the base
wrench, the generated JAX function ``base_wrench`` of the model, ``[F; M] = Psi(q, qd,
qdd) @ theta`` contracted inside one fused loop), evaluated a chunk of configurations at a
time. Generation streams: only one chunk of frames is in
memory, so the size of a dataset is bounded by the disk, not the RAM.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ineid.channels import ChannelSet, LinkWrench
from ineid.channels.link_wrench import refuse_nothing_beyond
from ineid.data.dataset.schema import Dataset, DatasetMeta
from ineid.data.dataset.write import DatasetWriter, chunk_rows, row_width
from ineid.data.synthesis.imu_rehearsal import ImuRehearsal
from ineid.data.synthesis.noise import NoiseModel
from ineid.data.synthesis.sampling import (
    RNG_BLOCK_CONFIGS,
    STREAM_FRAMES,
    STREAM_NOISE,
    Combination,
    FrameSampling,
    ParameterSampling,
    block_rng,
    sample_configurations,
    sample_frames,
)
from ineid.errors import DatasetError
from ineid.params import all_links_physical
from ineid.progress import Progress

if TYPE_CHECKING:
    from ineid.robots import RobotModel


@dataclass(frozen=True)
class DatasetSpec:
    """What to generate. The defaults are the paper's dataset: 100 x 100 configurations
    (full factorial of 100 sets per unknown link), 100 uniform frames each, no noise.

    Attributes:
        combination: how per-link parameter sets form configurations.
        n_frames: frames per configuration.
        seed: the one seed every random stream derives from.
        parameters: bands of the parameter sampling.
        frames: frame sampling mode and settings.
        noise: measurement noise, or ``None`` for clean data. Its wrench noise goes to the
            channel keyed ``wrench``, its ``channels`` noise to the channel of each key; other
            channels are noise-free.
        channels: the measurement channels to simulate (an :class:`ineid.channels.ChannelSet`);
            ``None``: the base wrench in the base frame, under ``wrench``. They are stored as
            given: their actuation settings (a joint-torque channel's ``friction``, ...) say
            how to identify, not what is simulated.
        extra_truth: the simulated actuation ``{name: value}``: joint friction, armature and
            torque offsets by the joint-torque channel's extra-parameter names
            (``"<joint>.fv"``, ``"<joint>.fc"``, ``"<joint>.offset"``, ``"<joint>.Ia"``, or
            the asymmetric ``"<joint>.fv+"``, ...; :func:`actuation_names`), and with ``"stribeck_velocity"``
            (``vs``, rad/s, :data:`STRIBECK_TRUTH`) the Stribeck terms ``"<joint>.fs"``. Each channel that
            takes them reads ``Phi theta + E x`` (``E`` its extra rows with every term on,
            ``x`` these values, 0 where not named). Stored as the dataset's ``extra_truth``.
        imu: link IMUs and encoders to rehearse (:class:`ineid.data.synthesis.imu_rehearsal.ImuRehearsal`, the
            fourier and trajectory frame modes): the states and values are then what the import would
            estimate from them, the truth in the ``*_clean`` arrays.
    """

    combination: Combination = field(default_factory=Combination)
    n_frames: int = 100
    seed: int = 0
    parameters: ParameterSampling = field(default_factory=ParameterSampling)
    frames: FrameSampling = field(default_factory=FrameSampling)
    noise: NoiseModel | None = None
    channels: ChannelSet | None = None
    extra_truth: Mapping[str, float] | None = None
    imu: ImuRehearsal | None = None

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {self.n_frames}")
        if self.imu is not None and self.frames.mode not in ("fourier", "trajectory"):
            raise ValueError(
                "a rehearsal (IMUs, encoder bits) filters and fuses time series: use --frame-mode fourier or "
                "trajectory, not "
                f"{self.frames.mode} (independent frames)"
            )
        if (
            self.imu is not None
            and self.noise is not None
            and any(np.any(np.asarray(getattr(self.noise, k)) > 0) for k in ("q", "qd", "qdd"))
        ):
            raise ValueError(
                "with IMUs the states are estimated from the encoders (--encoder-bits) and the IMUs: "
                "drop the q, qd, qdd noise"
            )
        if not 0 <= int(self.seed) < 2**63:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed}")

    def sampling_dict(self) -> dict:
        return {
            "combination": self.combination.to_dict(),
            "n_frames": self.n_frames,
            "parameters": self.parameters.to_dict(),
            "frames": self.frames.to_dict(),
            **({"imu": self.imu.to_dict()} if self.imu is not None else {}),
        }


MAX_CHUNK_BYTES = 1 << 30
"""The largest chunk of one array a dataset is generated and stored in (HDF5 allows < 4 GiB; memory
holds about ten): :data:`ineid.data.synthesis.sampling.RNG_BLOCK_CONFIGS` configurations of all their frames."""


class GenerationPlan:
    """The parts of a generation run shared by the in-memory and the streaming paths."""

    def __init__(self, model, spec: DatasetSpec) -> None:
        if not model.unknown_links:
            raise DatasetError("the model has no unknown links; choose the links to identify (--unknown-links)")
        cad_masses = model.theta_cad[model.unknown_index][0::10]
        massless = [link for link, m in zip(model.unknown_links, cad_masses, strict=True) if m <= 0]
        if massless:  # the sampler draws around the CAD: around nothing, there is nothing to draw
            raise DatasetError(
                f"unknown link {massless[0]!r} has no mass in the URDF, and synthetic configurations are sampled "
                "around the CAD values: give it an <inertial> with your best guess (a recording is identified "
                "without one)"
            )
        self.model, self.spec = model, spec
        self._check_memory()
        self.theta_known = np.asarray(model.theta_cad[model.known_index], dtype=np.float64)
        self.theta_unknown, self.link_set_index = sample_configurations(
            model.theta_cad[model.unknown_index], spec.combination, spec.seed, spec.parameters
        )
        bad = ~all_links_physical(self.theta_unknown)
        if bad.any():  # cannot happen by construction; a guard against a broken sampler
            raise DatasetError(f"sampler produced {int(bad.sum())} non-physical parameter sets")
        self.n_configs = len(self.theta_unknown)
        self.noise = spec.noise if spec.noise is not None and spec.noise.noisy_keys() else None
        self.meta = DatasetMeta.for_model(
            model,
            source="synthetic",
            seed=int(spec.seed),
            sampling=spec.sampling_dict(),
            noise=None if self.noise is None else self.noise.to_dict(),
            channels=spec.channels,
            extra_truth=dict(spec.extra_truth) if spec.extra_truth else None,
        )
        self.channels = self.meta.channels
        for channel in self.channels:  # a sensor with nothing beyond it would read zeros
            if isinstance(channel, LinkWrench):
                refuse_nothing_beyond(model, channel.link)
        if self.noise is not None:
            self._check_noise()
        self.actuation = actuation_plan(model, self.channels, self.meta.extra_truth)
        names = ["q", "qd", "qdd", *self.channels.keys, "theta_unknown", "link_set_index"]
        if spec.frames.mode in ("fourier", "trajectory"):
            names.append("time")
        if self.noise is not None:
            names += [f"{k}_clean" for k in self.noise.noisy_keys()]
        if spec.imu is not None:  # the estimates differ from the truth: every measured array keeps its truth
            names += [f"{k}_clean" for k in ("q", "qd", "qdd", *self.channels.keys) if f"{k}_clean" not in names]
        self.array_names = names
        # Chunks are whole random-number blocks, about 1 MiB of the widest array.
        rows = chunk_rows(spec.n_frames, row_width(self.meta), self.n_configs)
        if rows >= RNG_BLOCK_CONFIGS:
            rows -= rows % RNG_BLOCK_CONFIGS
        elif rows < self.n_configs:
            rows = min(RNG_BLOCK_CONFIGS, self.n_configs)
        self.rows = rows
        self._values_fn = None

    def _check_noise(self) -> None:
        """Noise only for channels there are, with one number or one per axis."""
        keys = self.channels.keys
        if "wrench" not in keys and np.any(self.noise.wrench > 0):
            raise DatasetError(
                f"wrench noise is for the channel keyed wrench, and the channels are "
                f"{', '.join(keys)}; give no force or moment noise, or add that channel"
            )
        for key, std in self.noise.channels.items():
            channel = self.channels.get(key)
            if channel is None and np.any(std > 0):
                raise DatasetError(
                    f"noise for {key!r}, and the channels are {', '.join(keys)}; give no {key} noise, "
                    f"or simulate that channel"
                )
            if channel is not None and std.size not in (1, channel.n_axes(self.model)):
                n_axes = channel.n_axes(self.model)
                raise DatasetError(
                    f"{key} noise has {std.size} standard deviations for the {n_axes} axes of "
                    f"{channel.describe()}; give one number or one per axis"
                )

    def _check_memory(self) -> None:
        """Refuse sizes whose parameters (all configurations) or one chunk of frames cannot be held.

        The parameters of every configuration are sampled up front, ``11 n_unknown`` numbers
        each; the frames are made a chunk at a time (at least :data:`RNG_BLOCK_CONFIGS`
        configurations), about ten arrays of ``rows x n_frames x max(6, n_dof)`` alive at once.
        """
        from ineid._faults import format_bytes, require_memory

        m, spec = self.model, self.spec
        n_u = len(m.unknown_links)
        n_configs = spec.combination.count(n_u)
        c = spec.combination
        pool = f" ({c.pool_size():,} parameter sets per link)" if c.mode == "random" and c.per_link else ""
        nbytes = (c.pool_size() * n_u * 10 + n_configs * 11 * n_u) * 8 * 2  # sets, parameters, indices; temporaries
        require_memory(nbytes, f"{n_configs:,} configurations{pool}", "make fewer (--n-configs, --factorial, --pool)")
        rows = min(RNG_BLOCK_CONFIGS, n_configs)
        chunk = rows * spec.n_frames * max(6, m.n_dof) * 8
        if chunk >= MAX_CHUNK_BYTES:
            raise DatasetError(
                f"{spec.n_frames:,} frames per configuration make chunks of {format_bytes(chunk)} per array ({rows} "
                f"configurations each), above the {format_bytes(MAX_CHUNK_BYTES)} ineid stores in one piece; "
                "use fewer frames (--n-frames)"
            )
        require_memory(10 * chunk, f"{spec.n_frames:,} frames per configuration", "use fewer frames (--n-frames)")

    def _values(self, q, qd, qdd, theta) -> np.ndarray:
        """What the channels read, stacked: (n, F, n_axes) (the base wrench alone: the composed ``base_wrench``);
        through CasADi for a dataset of at most :data:`ineid.robots.model.SMALL_JOB_FRAMES` frames."""
        from ineid.robots.model import SMALL_JOB_FRAMES

        if self.n_configs * self.spec.n_frames <= SMALL_JOB_FRAMES:  # a small dataset: CasADi, no compilation
            return self._values_casadi(q, qd, qdd, theta)
        import jax

        if self._values_fn is None:
            from ineid.cache import enable_compilation_cache

            enable_compilation_cache()
            self._values_fn = jax.jit(self.channels.jax_predict_function(self.model))
        n = len(q)
        if n < self.rows:  # pad the last chunk: one compiled shape for the whole run
            pad = self.rows - n
            q, qd, qdd = (np.concatenate([a, np.zeros((pad,) + a.shape[1:])]) for a in (q, qd, qdd))
            theta = np.concatenate([theta, np.repeat(theta[-1:], pad, axis=0)])
        full = self.model.full_theta(theta, self.theta_known)[:, None, :]
        return np.asarray(self._values_fn(q, qd, qdd, self.model.gravity, full))[:n]

    def _values_casadi(self, q, qd, qdd, theta) -> np.ndarray:
        """:meth:`_values` through the channels' CasADi rows ``T Phi`` (the same values to round-off)."""
        n, f = q.shape[:2]
        rows_fn = self.channels.casadi_rows(self.model)
        flat = [a.reshape(n * f, -1).T for a in (q, qd, qdd)]
        n_axes = self.channels.n_axes(self.model)
        rows = np.array(rows_fn.map(n * f)(*flat)).reshape(n_axes, n * f, -1).transpose(1, 0, 2)
        full = self.model.full_theta(theta, self.theta_known)
        return np.einsum("nfap,np->nfa", rows.reshape(n, f, n_axes, -1), full)

    def chunks(self) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        """Yield ``(first configuration, arrays)`` chunk by chunk."""
        m, spec = self.model, self.spec
        for start in range(0, self.n_configs, self.rows):
            stop = min(start + self.rows, self.n_configs)
            parts = []
            for b0 in range(start, stop, RNG_BLOCK_CONFIGS):
                b1 = min(b0 + RNG_BLOCK_CONFIGS, stop)
                rng = block_rng(spec.seed, STREAM_FRAMES, b0 // RNG_BLOCK_CONFIGS)
                parts.append(
                    sample_frames(b1 - b0, spec.n_frames, m.q_lower, m.q_upper, m.qd_max, m.qdd_max, rng, spec.frames)
                )
            q, qd, qdd = (np.concatenate([p[k] for p in parts]) for k in range(3))
            out = {"q": q, "qd": qd, "qdd": qdd}
            if spec.frames.mode in ("fourier", "trajectory"):
                out["time"] = np.concatenate([p[3] for p in parts])
            values = self._values(q, qd, qdd, self.theta_unknown[start:stop])
            one = len(self.channels) == 1
            out.update({self.channels.keys[0]: values} if one else self.channels.split(values, self.meta))
            for key, channel, x in self.actuation:  # E x: friction, armature, offsets with their true values
                out[key] = out[key] + channel.extra_rows(m, q, qd, qdd) @ x
            if self.noise is not None:
                # the noise streams draw six wrench numbers a frame whatever the channels (files stay identical)
                wrench = out.get("wrench", np.zeros(q.shape[:-1] + (6,)))
                noisy = []
                for b0 in range(start, stop, RNG_BLOCK_CONFIGS):
                    sl = slice(b0 - start, min(b0 + RNG_BLOCK_CONFIGS, stop) - start)
                    rng = block_rng(spec.seed, STREAM_NOISE, b0 // RNG_BLOCK_CONFIGS)
                    keys = ("q", "qd", "qdd", *(k for k in self.noise.channels if k in out))
                    noisy.append(self.noise.apply({**{k: out[k][sl] for k in keys}, "wrench": wrench[sl]}, rng))
                for k in self.noise.noisy_keys():
                    out[f"{k}_clean"] = out[k]
                    out[k] = np.concatenate([n[k] for n in noisy])
            if spec.imu is not None:
                self._rehearse(start, out)
            out["theta_unknown"] = self.theta_unknown[start:stop]
            out["link_set_index"] = self.link_set_index[start:stop]
            yield start, out

    def _rehearse(self, start: int, out: dict[str, np.ndarray]) -> None:
        """Replace the chunk's states and values by what the import would estimate
        (:mod:`ineid.data.synthesis.imu_rehearsal`)."""
        from ineid.data.synthesis.imu_rehearsal import STREAM_IMU, rehearse

        keys = self.channels.keys
        for k in ("q", "qd", "qdd", *keys):
            out.setdefault(f"{k}_clean", out[k])
            out[k] = np.array(out[k])
        for c in range(len(out["q"])):
            rng = block_rng(self.spec.seed, STREAM_IMU, start + c)
            truth = [out[f"{k}_clean"][c] for k in ("q", "qd", "qdd")]
            q, qd, qdd, values, _ = rehearse(
                self.model, self.spec.imu, out["time"][c], *truth, {k: out[k][c] for k in keys}, rng
            )
            out["q"][c], out["qd"][c], out["qdd"][c] = q, qd, qdd
            for k in keys:
                out[k][c] = values[k]


ACTUATION_FIELDS = ("friction", "armature", "torque_offset", "asymmetric")
"""The fields of a channel with actuation terms (the joint-torque channel): what :func:`actuation_plan` turns on."""
STRIBECK_TRUTH = "stribeck_velocity"
"""The ``extra_truth`` entry of the simulated Stribeck velocity ``vs`` (rad/s, shared by every joint): with it the
channels take the Stribeck terms ``<joint>.fs`` (``fs exp(-(qd / vs)^2) sign(qd)``)."""


def actuated(channel, asymmetric: bool = False, stribeck_velocity: float = 0.0):
    """``channel`` with every actuation term as an extra column (viscous and Coulomb friction, torque
    offset, armature; per direction with ``asymmetric``; the Stribeck term with a ``stribeck_velocity``), or None
    for a channel without them."""
    if not {f.name for f in dataclasses.fields(channel)} >= set(ACTUATION_FIELDS):
        return None
    stribeck = {"stribeck_velocity": float(stribeck_velocity)} if stribeck_velocity > 0 else {}
    return dataclasses.replace(
        channel,
        friction=("viscous", "coulomb", *(("stribeck",) if stribeck else ())),
        armature=True,
        torque_offset=True,
        asymmetric=asymmetric,
        **stribeck,
    )


def actuation_names(
    model, channels: ChannelSet, asymmetric: bool = False, stribeck_velocity: float = 0.0
) -> tuple[str, ...]:
    """The names ``extra_truth`` may give for ``channels`` (``"<joint>.fv"``, ...), in the channels' order."""
    full = [actuated(c, asymmetric, stribeck_velocity) for c in channels]
    return tuple(n for c in full if c is not None for n in c.extra_names(model))


def actuation_plan(
    model, channels: ChannelSet, truth: Mapping[str, float] | None
) -> list[tuple[str, object, np.ndarray]]:
    """``[(key, channel with every actuation term, x)]``: what adds ``E x`` to each channel's values
    (``truth[STRIBECK_TRUTH]``, when given, the Stribeck velocity of the simulated law, :data:`STRIBECK_TRUTH`).

    Raises:
        DatasetError: a name no channel takes (listing those it may take), or actuation truth
            with no channel that has actuation.
    """
    truth = dict(truth or {})
    vs = float(truth.pop(STRIBECK_TRUTH, 0.0))
    if vs < 0:
        raise DatasetError(f"the simulated Stribeck velocity must be positive (rad/s), got {vs:g}")
    if not truth:
        return []
    asymmetric = any(name.endswith(("+", "-")) for name in truth)
    names = actuation_names(model, channels, asymmetric, vs)
    if not names:
        raise DatasetError(
            f"actuation values ({', '.join(truth)}) are for joint torques, and the channels are "
            f"{', '.join(channels.keys)}; simulate joint torques (--channels wrench,torque)"
        )
    unknown = [n for n in truth if n not in names]
    if unknown:
        raise DatasetError(
            f"no simulated extra parameter {unknown[0]!r}; the channels take {', '.join(names[:8])}"
            + (", ..." if len(names) > 8 else "")
            + (" (one model per direction: fv+, fv-, fc+, fc- instead of fv, fc)" if asymmetric else "")
            + (" (the Stribeck terms fs need the Stribeck velocity: vs=...)" if unknown[0].endswith(".fs") else "")
        )
    plan = []
    for c in channels:
        full = actuated(c, asymmetric, vs)
        if full is not None:
            x = np.array([truth.get(n, 0.0) for n in full.extra_names(model)], dtype=np.float64)
            if np.any(x != 0):
                plan.append((c.key, full, x))
    return plan


def generate_dataset(model: RobotModel, spec: DatasetSpec = DatasetSpec(), progress: Progress | None = None) -> Dataset:
    """Generate a synthetic dataset in memory (for files, use :func:`write_dataset`).

    Args:
        model: the :class:`ineid.RobotModel`; its unknown links are sampled, the others
            keep their CAD values; its gravity is used.
        spec: sizes, sampling, seed, noise.
        progress: called after each chunk.

    Returns:
        The :class:`Dataset`; the same ``spec`` gives bit-identical arrays.
    """
    plan = GenerationPlan(model, spec)
    from ineid._faults import require_memory

    per_frame = (3 * model.n_dof + plan.channels.n_axes(plan.meta)) * (2 if plan.noise is not None else 1) + 1
    # states, the channels' values, clean copies, time
    require_memory(
        2 * plan.n_configs * spec.n_frames * per_frame * 8,  # the chunks, then their concatenation
        f"{plan.n_configs:,} configurations x {spec.n_frames:,} frames in memory",
        "make fewer configurations or frames",
    )
    collected: dict[str, list[np.ndarray]] = {}
    for start, arrays in plan.chunks():
        for k, v in arrays.items():
            collected.setdefault(k, []).append(v)
        if progress is not None:
            progress(start + len(arrays["q"]), plan.n_configs)
    arrays = {k: np.concatenate(v) for k, v in collected.items()}
    clean = {k[: -len("_clean")]: arrays.pop(k) for k in list(arrays) if k.endswith("_clean")}
    return Dataset(
        meta=plan.meta,
        q=arrays["q"],
        qd=arrays["qd"],
        qdd=arrays["qdd"],
        wrench=arrays.get("wrench"),
        channel_values={k: arrays[k] for k in plan.channels.keys if k != "wrench"},
        theta_known=plan.theta_known,
        theta_unknown=arrays["theta_unknown"],
        clean=clean,
        time=arrays.get("time"),
        link_set_index=arrays["link_set_index"],
    )


def write_dataset(
    model: RobotModel,
    spec: DatasetSpec,
    path: str | Path,
    overwrite: bool = False,
    progress: Progress | None = None,
    workers: int | None = None,
) -> Path:
    """Generate a synthetic dataset straight into an HDF5 file, chunk by chunk.

    Memory holds one chunk (about a megabyte per array); compression runs in a thread
    pool beside the computation. The file is complete or absent: an error or Ctrl-C
    removes the partial file.

    Args:
        model, spec, progress: as for :func:`generate_dataset`; the arrays are identical.
        path: the ``.h5`` file to write.
        overwrite: replace an existing file.
        workers: compression threads (default: the CPU count).
    """
    plan = GenerationPlan(model, spec)
    with DatasetWriter(
        path, plan.meta, plan.n_configs, spec.n_frames, plan.array_names, plan.rows, overwrite, workers
    ) as writer:
        writer.write_constant("theta_known", plan.theta_known)
        for start, arrays in plan.chunks():
            for name, arr in arrays.items():
                writer.write(name, start, arr)
            if progress is not None:
                progress(start + len(arrays["q"]), plan.n_configs)
    return Path(path)
