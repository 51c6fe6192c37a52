"""How to solve: :class:`SolveSettings`, the options of ``ineid solve``, and the choices it is checked against.

Every solver step reads its options from here (the method, the weights, IPOPT's start, the backend, the
offsets, the frames fitted, the joint torques' actuation models), so the modules of ``identify`` take a
typed ``SolveSettings``. This module imports no other module of ``identify``: the choices it checks
(:data:`WEIGHT_MODES`, :data:`CLASSICAL_METHODS`, :data:`FRICTION_MODELS`, ...) live here, and the
modules that implement them import them from here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

LINEAR_METHODS = ("linear",)
"""The base least-squares fit and the null-space rule (:mod:`ineid.identify.linear`)."""
NLP_METHODS = ("nonlinear", "consistent")
"""IPOPT's methods (:mod:`ineid.identify.nlp`): the paper's mass / centre of mass / inertia form, log-Cholesky."""
CLASSICAL_METHODS = ("lsqlin", "lsqnonlin")
"""The paper's two MATLAB solvers, over every standard parameter of the unknown links
(:mod:`ineid.identify.classical`)."""
BUILTIN_METHODS = (*LINEAR_METHODS, *NLP_METHODS, *CLASSICAL_METHODS)
"""The methods identify implements itself; ``lsqlin``, ``lsqnonlin``: the paper's (:mod:`ineid.identify.classical`)."""
METHODS = (*BUILTIN_METHODS, "network")
"""Every method; ``network`` (a trained run) is implemented by :mod:`ineid.learn.amortized` and passed to
:func:`ineid.identify.solve.solve_dataset` in ``methods`` (:func:`ineid.workflow.solve_dataset` does): identify
never imports learn."""
WEIGHT_MODES = ("estimate", "noise", "none")
"""Row weights per measured axis: estimated from the residuals (the default), ``1/sigma`` of given noise
levels, or none (equal noise on every axis assumed)."""
STARTS = ("prior", "linear")
"""IPOPT's start: the CAD values, or the linear estimate made physical."""
BACKENDS = ("jax", "casadi", "casadi-c")
"""The least-squares engine: fused JAX kernels; CasADi per configuration (QR, an independent
route; linear method only); or the fused blocks through CasADi's C code, compiled (needs a C compiler)."""
BIAS_MODES = ("none", "estimate")
"""The sensors' constant offsets (six for the base wrench): absent (a tared sensor), or identified with the
parameters (every channel's, :meth:`ineid.channels.ChannelSet.with_offsets`)."""
FRICTION_MODELS = ("viscous", "coulomb", "stribeck")
"""The friction terms of a joint-torque channel, in the order its extra columns take them."""
IDENTIFY = "identify"
"""The value of ``coulomb_zone`` or ``stribeck_velocity`` that has it identified
(:mod:`ineid.identify.friction_search`)."""
FRICTION_VELOCITIES = ("coulomb_zone", "stribeck_velocity")
"""The friction laws' nonlinear parameters (rad/s), given or identified."""
HOLDOUT_FRACTION = 0.2
"""Without ``frames``, this share of each configuration's frames is held out for validation."""
DEFAULT_PULL = 1e-2
"""The quadratic pull of IPOPT's null-space part towards the prior (:class:`ineid.identify.nlp.NlpSolver`)."""
DEFAULT_ENTROPIC = 1e-3
"""The weight of ``consistent``'s log-det divergence from the prior (:class:`ineid.identify.nlp.NlpSolver`)."""


@dataclass(frozen=True)
class SolveSettings:
    """How to identify.

    Attributes:
        method: ``"linear"``, ``"nonlinear"`` (the paper's mass / centre of mass / inertia
            form) or ``"consistent"`` (log-Cholesky, always physical); ``"lsqlin"``, ``"lsqnonlin"``: the
            paper's MATLAB solvers over every standard parameter, its reference (:mod:`ineid.identify.classical`).
        frames: frames fitted per configuration (the first ``frames``); the rest are held
            out for validation. ``None``: all but the last 20 % (all, when too few).
        weights: ``"estimate"`` (the default: the noise of each measured axis estimated from the
            residuals, :mod:`ineid.identify.least_squares`), ``"noise"`` (``1/sigma`` per measured axis
            from ``axis_sigma``, or from the dataset's recorded noise) or ``"none"`` (equal noise on
            every axis assumed: the standard deviations are wrong where it differs).
        axis_sigma: (A,) noise standard deviations per measured axis (the base wrench: fx..mz)
            for ``weights="noise"``.
        start: IPOPT's (and ``lsqnonlin``'s) start, ``"prior"`` (the CAD values) or ``"linear"`` (the linear
            estimate, made physical for ``consistent`` if needed).
        bounds: ``lsqlin``'s box, ``theta_cad -/+ bounds * max(|theta_cad|, scale)``
            (:func:`ineid.identify.classical.cad_bounds`); None: unbounded (minimum norm).
        pull, entropic: prior weights of the IPOPT solvers (see :mod:`ineid.identify.nlp`).
        backend: ``"jax"`` (fused normal-equation blocks, batched), ``"casadi"`` (per
            configuration, the generated CasADi function and CasADi's QR; no compilation)
            or ``"casadi-c"`` (the same blocks as ``"jax"`` from the CasADi function printed
            as C and compiled, see :mod:`ineid.identify.casadi_c`, and for ``nonlinear`` /
            ``consistent`` the IPOPT problem compiled too; needs a C compiler).
        workers: processes for the IPOPT solvers (default 1); used from
            :data:`ineid.identify.nlp_runs.PARALLEL_MIN_CONFIGS` configurations on. More than one uses spawned
            processes (multiprocessing): call from under ``if __name__ == "__main__":``.
        bias: ``"none"`` (the wrench holds no offset) or ``"estimate"``: constant offsets,
            one per sensor axis (six for the base wrench), identified jointly with the parameters (every method;
            :class:`ineid.identify.systems.Offsets`). They also take the weight of whatever
            sits between the sensor and the first joint.
        run: the trained run folder of ``method="network"`` (:mod:`ineid.learn.amortized`).
        known_uncertainty: ``(link, fraction)`` pairs, the known links' CAD uncertainty
            (:mod:`ineid.identify.known`: std ``fraction * max(|theta_cad|, scale)`` per
            parameter) added to the reported covariance; link ``"*"`` for every known link.
            Empty: the CAD values are taken as exact.
        use: the dataset's channels fitted, by key or kind (``("wrench",)``, ``("torque",)``,
            ``("wrench", "torque")``; :mod:`ineid.identify.choose`); None: every channel it has.
        friction: the joint torques' friction model, any of ``"viscous"``, ``"coulomb"``;
            ``coulomb_zone`` (rad/s) smooths ``sign(qd)`` into ``tanh(qd / zone)``;
            ``"stribeck"`` adds ``fs exp(-(qd / vs)^2) c(qd)`` at ``stribeck_velocity`` (rad/s);
            either velocity ``"identify"``: found by a 1-D search (:mod:`ineid.identify.friction_search`);
            ``asymmetric_friction``: one coefficient per direction. ``armature``: rotor inertia
            ``Ia qdd``; ``torque_offset``: a constant torque per joint. Each adds extra kept
            columns to the joint-torque channels (``<joint>.fv``, ...), identified with the links'
            parameters and recorded after them (:mod:`ineid.identify.extras`); refused without a
            joint-torque channel among those fitted.
        two_step: FloBaRoID's two steps (:mod:`ineid.identify.two_step`): the links from the
            wrench alone, then the joint torques' extra parameters from their residual with the
            links fixed; needs both channels.
        torque_constant_unknown: the motor-current channels' torque constants are identified too
            (``<joint>.k``, relative to their nominal values), in step 2 of ``two_step`` (needs it).
        coupling: a coupling file (JSON, CSV or URDF, :mod:`ineid.channels.transmission`): the joint-torque
            channels read per motor through it.
    """

    method: str = "linear"
    frames: int | None = None
    weights: str = "estimate"
    axis_sigma: tuple[float, ...] | None = None
    start: str = "prior"
    pull: float = DEFAULT_PULL
    entropic: float = DEFAULT_ENTROPIC
    backend: str = "jax"
    workers: int | None = None
    bias: str = "none"
    run: str | None = None
    known_uncertainty: tuple[tuple[str, float], ...] = ()
    use: tuple[str, ...] | None = None
    friction: tuple[str, ...] = ()
    coulomb_zone: float | str = 0.0
    stribeck_velocity: float | str = 0.0
    asymmetric_friction: bool = False
    armature: bool = False
    torque_offset: bool = False
    two_step: bool = False
    torque_constant_unknown: bool = False
    bounds: float | None = None
    coupling: str | None = None

    def __post_init__(self) -> None:
        self._check_choices()
        self._check_options()
        pairs = tuple((str(link), float(f)) for link, f in self.known_uncertainty)
        object.__setattr__(self, "known_uncertainty", pairs)  # lists from a results file: hashable pairs
        for link, f in pairs:
            if not (np.isfinite(f) and f >= 0):
                raise ValueError(f"known_uncertainty of {link!r} must be a fraction >= 0, got {f}")
        if pairs and self.method == "network":
            raise ValueError("method='network' does not propagate the known links' uncertainty")
        if self.use is not None:  # lists from a results file: hashable tuples
            object.__setattr__(self, "use", tuple(str(u) for u in self.use))
        object.__setattr__(self, "friction", tuple(str(f) for f in self.friction))
        self._check_actuation()
        if self.method == "network" and (self.actuation_requested or self.two_step):
            raise ValueError(
                "method='network' predicts the links from the channels it was trained on; "
                "leave the friction, armature, torque-offset and two-step options out"
            )

    def _check_choices(self) -> None:
        """Refuse a name that is not among its choices (``ValueError`` naming them)."""
        for name, choices in (
            ("method", METHODS),
            ("weights", WEIGHT_MODES),
            ("start", STARTS),
            ("backend", BACKENDS),
            ("bias", BIAS_MODES),
        ):
            value = getattr(self, name)
            if value not in choices:
                raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")

    def _check_options(self) -> None:
        """Refuse options that do not go together (``ValueError``, one line each)."""
        if self.backend == "casadi-c" and self.estimates_offsets:
            raise ValueError("backend='casadi-c' does not estimate sensor offsets; use backend 'jax' or 'casadi'")
        if self.backend == "casadi" and self.method not in BUILTIN_METHODS:  # casadi-c serves every method
            raise ValueError("backend='casadi' applies to identify's own methods, not a trained network")
        if self.bounds is not None and (self.method != "lsqlin" or not (np.isfinite(self.bounds) and self.bounds > 0)):
            raise ValueError(f"bounds (a fraction > 0 of the CAD values) go with method='lsqlin', got {self.bounds}")
        if self.frames is not None and self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if self.method == "network" and self.bias != "none":
            raise ValueError("method='network' estimates no sensor offsets; use bias='none'")
        if (self.method == "network") != (self.run is not None):
            raise ValueError("method='network' needs run (a trained run folder), and run goes with method='network'")

    def _check_actuation(self) -> None:
        """Refuse inconsistent actuation settings (``ValueError``, one line each)."""
        bad = [f for f in self.friction if f not in FRICTION_MODELS]
        if bad or len(set(self.friction)) != len(self.friction):
            raise ValueError(
                f"friction must be none or any of {', '.join(FRICTION_MODELS)} (each once), "
                f"got {','.join(self.friction)}"
            )
        for name in FRICTION_VELOCITIES:
            v = getattr(self, name)
            if v != IDENTIFY and not (isinstance(v, (int, float)) and v >= 0 and np.isfinite(v)):
                raise ValueError(f"{name} must be >= 0 rad/s or {IDENTIFY!r}, got {v!r}")
        if self.coulomb_zone and not {"coulomb", "stribeck"} & set(self.friction):
            raise ValueError("coulomb_zone smooths Coulomb friction: add friction 'coulomb' (--friction coulomb)")
        if ("stribeck" in self.friction) != bool(self.stribeck_velocity):
            raise ValueError(
                "Stribeck friction needs its velocity, and the velocity goes with it: "
                "--friction ...,stribeck with --stribeck-velocity RAD_PER_S (or identify)"
            )
        if self.torque_constant_unknown and not self.two_step:
            raise ValueError(
                "torque constants are identified in the second of two steps (the links from the wrench "
                "first): add --two-step"
            )
        if self.asymmetric_friction and not self.friction:
            raise ValueError(
                "asymmetric_friction splits the friction coefficients per direction: "
                "add a friction model (--friction viscous,coulomb)"
            )

    @property
    def estimates_offsets(self) -> bool:
        """Whether the sensors' constant offsets are identified (``bias == "estimate"``)."""
        return self.bias == "estimate"

    @property
    def actuation_requested(self) -> bool:
        """Whether any actuation model of the joint torques is asked for (friction, armature, torque offsets,
        torque constants)."""
        return bool(
            self.friction
            or self.armature
            or self.torque_offset
            or self.asymmetric_friction
            or self.coulomb_zone
            or self.torque_constant_unknown
            or self.coupling
        )

    @property
    def searched_velocities(self) -> tuple[str, ...]:
        """The friction velocities to identify (:data:`FRICTION_VELOCITIES` set to ``"identify"``)."""
        return tuple(n for n in FRICTION_VELOCITIES if getattr(self, n) == IDENTIFY)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["axis_sigma"] = None if self.axis_sigma is None else list(self.axis_sigma)
        d["known_uncertainty"] = [list(p) for p in self.known_uncertainty]
        d["use"] = None if self.use is None else list(self.use)
        d["friction"] = list(self.friction)
        return d
