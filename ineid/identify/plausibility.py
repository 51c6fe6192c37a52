"""Plausibility checks of a solve: the fit against the URDF, before a user trusts garbage.

Adds to the data-only checks of :mod:`ineid.data.recordings.plausibility` those that need the
estimates of :func:`ineid.identify.solve_dataset`:

* total mass: the estimated mass of the moving links (the unknown links' masses from the
  linear least squares of the same frames, whatever the method, plus the known links' CAD
  masses; without offsets a base parameter, the force rows' gravity column) is negative
  (``total_mass_negative``: a flipped wrench, or a sensor turned over without
  ``--sensor-pose``), or more than :data:`MASS_FACTOR` times above or below the URDF's
  (``total_mass_scale``: the wrench's unit; the units that fix it are suggested);
* held-out error: the median over the configurations of the relative wrench error on the
  held-out frames (a ``--validate`` recording's, the held-out frames, or the fitted frames when none
  are held out; with offsets estimated, relative to the wrench less its mean over the frames the
  offsets were fitted on) above :data:`ineid.identify.held_out_checks.HELD_OUT_ERROR` on a residual above the noise
  (``held_out_error``: the model explains almost nothing);
* unmodelled offsets (:func:`ineid.identify.noise_figures.check_offsets`, ``unmodelled_offsets``): a mean of
  the fitted frames' residual far above the noise on axes whose offsets were not fitted;
* residual above the noise (:func:`check_residual_noise`, ``residual_above_noise``): the held-out (else fitted)
  residual RMS more than ``NOISE_FACTOR`` times the noise of
  :func:`ineid.identify.noise_figures.axis_noise` (stated by synthetic data, estimated at import for a
  recording, with the joint angles' noise through the prediction);
* the fitted static force (the mean of the fitted frames less the estimated offsets, in the
  base frame) against gravity, as :func:`ineid.data.recordings.plausibility.check_static_force`;
* units only a fit can tell (:mod:`ineid.identify.unit_fits`): where the solve's linear fit
  leaves more than :data:`FIT_GATE` of the measurements unexplained, a subsample is refitted
  with the joint angles in the other unit (``angles_in_degrees``, ``angles_in_radians``) and
  with the moments x 0.001 and x 1000, each with the known links' contribution scaled freely (the
  wrench's scale); one that leaves less than 1 / :data:`UNIT_GAIN` of the stored units' error, or
  the stored units with a scale a power of ten off 1 leaving less than 1 / :data:`UNIT_GAIN` of
  the solve's, warns (``wrench_unit``: the force unit from the scale, the moment unit from it and
  the moments' factor).

:func:`check_solve` runs them all, most basic cause first, and leaves out what would only
repeat a consequence: gravity in another unit, time stamps in another unit and angles in
degrees make every fit check meaningless, so do units a refit finds; a fit that explains
nothing makes its mass and fitted static force meaningless (without offsets the static force
is the data's own mean: pointing up, it is the cause, reported instead); a negative mass
already says what the static force would.
"""

from __future__ import annotations

import math

import numpy as np

from ineid.channels import BaseWrench
from ineid.data.recordings.plausibility import (
    Finding,
    check_angle_units,
    check_gravity,
    check_recording_time,
    check_static_force,
    mean_force_in_base,
    moving_mass,
    power_of_ten,
    times,
)
from ineid.data.recordings.streams import FORCE_UNITS, MOMENT_UNITS
from ineid.errors import IdentificationError
from ineid.identify.held_out_checks import check_held_out_error, check_residual_noise
from ineid.identify.noise_figures import check_offsets
from ineid.identify.physical_checks import check_iteration_cap, check_physical_estimates
from ineid.identify.unit_fits import fit_error, fitted_channels, refit_units

__all__ = [
    "Finding",
    "check_fitted_units",
    "check_held_out_error",
    "check_residual_noise",
    "check_solve",
    "check_total_mass",
    "estimated_total_mass",
    "fitted_channels",
    "fit_checks",
    "fitted_static_force",
    "linear_counterpart",
]

MASS_FACTOR = 3.0
"""An estimated total mass more than this factor above or below the URDF's warns."""
FIT_GATE = 0.005
"""The units are refitted only where the solve's linear fit leaves more than this of the measurements unexplained
(:func:`ineid.identify.unit_fits.fit_error`): noise-free data leave 1e-4 at most (nothing to refit), the least a
unit mistake left on the recordings measured was 0.057 (radians imported as degrees, +-4 degrees of motion, no
offsets), and a recording's noise alone leaves more than this."""
UNIT_GAIN = 10.0
"""Another unit warns where its refit leaves less than 1 / this of the stored units' error: on the mistakes
measured the right units left 1e-4 to 1e-7 of the wrong ones' error; noise alone leaves the two alike."""
_FORCE_NAMES = {f: (u, u) for u, f in FORCE_UNITS.items()}
_MOMENT_NAMES = {f: (u, {"Nm": "N*m", "Nmm": "N*mm (mN*m)", "kNm": "kN*m"}[u]) for u, f in MOMENT_UNITS.items()}


def estimated_total_mass(res, model) -> np.ndarray:
    """Per solved configuration, the estimated mass of the moving links (kg, NaN where the solve failed).

    The unknown links' estimated masses (``theta_hat``, 10 parameters per link, the mass first)
    plus the known links' CAD masses.
    """
    known = float(np.sum(np.asarray(model.theta_cad, dtype=np.float64)[model.known_index][0::10]))
    theta = np.asarray(res.theta_links, dtype=np.float64)  # without the extra parameters (friction, ...)
    total = theta[:, 0::10].sum(axis=1) + known
    return np.where(np.asarray(res.success, dtype=bool), total, np.nan)


def _wrench_fix(force: float, moment: float) -> tuple[str, str]:
    """``(the units in words, the import options)`` of forces and moments that want these factors to become
    N and N*m; ``--wrench-scale`` where no unit gives them."""
    if force in _FORCE_NAMES and moment in _MOMENT_NAMES:
        (fu, fw), (mu, mw) = _FORCE_NAMES[force], _MOMENT_NAMES[moment]
        options = [f"--force-unit {fu}"] * (fu != "N") + [f"--moment-unit {mu}"] * (mu != "Nm")
        return f"forces in {fw} and moments in {mw}", "data import " + " ".join(options)
    if force == moment:
        return "units other than N and N*m", f"data import --wrench-scale {force:g}"
    return (
        f"forces x {force:g} and moments x {moment:g} off N and N*m",
        f"data import --force-unit, --moment-unit and --wrench-scale to make the forces x {force:g} and the "
        f"moments x {moment:g}",
    )


def linear_counterpart(ds, res, model):
    """``res`` itself for the linear method, else the linear least squares of the same frames and settings.

    The total mass is read from the linear fit: a physically consistent fit cannot follow a
    flipped wrench to a negative mass (it bends elsewhere: 374 kg for the flipped MuJoCo
    recording with offsets, against the linear fit's -0.42 kg), and a trained run's estimates
    are what it learnt, not what these frames say.
    """
    if res.settings.method == "linear":
        return res
    from dataclasses import replace

    from ineid.identify.solve import solve_dataset

    network = res.settings.method == "network"
    backend = "casadi" if res.settings.backend == "casadi" else "jax"  # the route chosen: no compilation
    settings = replace(
        res.settings,
        method="linear",
        frames=res.n_frames_fit,
        backend=backend,
        run=None,
        bounds=None,
        weights="none" if network else res.settings.weights,
        axis_sigma=None if network else res.settings.axis_sigma,
    )
    return solve_dataset(ds, settings, model=model)


def _negative_cause(res) -> str:
    """The likely cause of a negative total mass, by the channels ``res`` fitted (``meta["channels"]``): the
    wrench's sign or the sensor's pose where a base wrench was fitted, else the fitted channels' sign."""
    records = res.meta.get("channels") or [{"kind": "wrench", "key": "wrench"}]  # a file of ineid 0.1: the wrench
    if any(r.get("kind") == "wrench" for r in records):
        return (
            "the wrench's sign looks flipped (data import --flip-wrench), or the sensor is turned over and its pose "
            "not given (data import --sensor-pose)"
        )
    names = ", ".join(
        f"{r.get('kind', '?').removeprefix('joint_').replace('_', ' ')} ({r.get('key', '?')})" for r in records
    )
    return (
        f"only {names} fitted, and their sign looks opposite to the URDF's joint axes (the drive's sign "
        "convention: negate the columns before data import), or gravity points the wrong way (data import "
        "--gravity)"
    )


def check_total_mass(res, model) -> Finding | None:
    """A total mass (median over configurations) that is negative or more than :data:`MASS_FACTOR` off the URDF's.

    The units suggested (``--force-unit``, ``--moment-unit``; ``--wrench-scale`` where none fits) are those
    of the power of ten within 2x of ``URDF mass / estimate`` (a unit mistake); none is suggested otherwise.
    """
    m = estimated_total_mass(res, model)
    m = m[np.isfinite(m)]
    urdf = moving_mass(model)
    if not len(m) or urdf <= 0:
        return None
    est = float(np.median(m))
    ratio = est / urdf
    what = f"the estimated total mass of the moving links {est:.4g} kg" + (
        f" (median over {len(m)} configurations)" if len(m) > 1 else ""
    )
    if est < 0:
        # with offsets estimated the static part is absorbed and a flipped wrench leaves a small
        # negative mass: only a large one also says something about the unit
        scale = power_of_ten(-1 / ratio) if -ratio > MASS_FACTOR else None
        unit = f"; its size is {times(-ratio)} the URDF's: also {_wrench_fix(scale, scale)[1]}" if scale else ""
        return Finding(
            "total_mass_negative", f"{what} is negative (the URDF's: {urdf:.4g} kg): {_negative_cause(res)}{unit}"
        )
    if 1 / MASS_FACTOR <= ratio <= MASS_FACTOR:
        return None
    scale = power_of_ten(1 / ratio) if ratio > 0 else None
    if scale is not None:
        words, options = _wrench_fix(scale, scale)
        hint = f"the wrench looks like {words} ({options})"
    else:
        hint = (
            "check the sensor pose (data import --sensor-pose), the wrench's unit (data import --wrench-scale) "
            "and the URDF's masses"
        )
    return Finding("total_mass_scale", f"{what} is {times(ratio)} the URDF's {urdf:.4g} kg: {hint}")


def fitted_static_force(res, ds) -> np.ndarray | None:
    """The fitted model's static force (3,), N, base frame: the mean over the solved configurations
    of the fitted frames' mean force less the estimated force offsets (none without ``--bias estimate``),
    from the first base-wrench channel fitted; None when none was."""
    block = next((b for b in fitted_channels(res, ds).blocks(ds.meta) if isinstance(b.channel, BaseWrench)), None)
    if block is None:
        return None
    ok = np.asarray(res.success, dtype=bool)
    f = np.asarray(ds.measurements[block.channel.key][ok, : res.n_frames_fit, :3], dtype=np.float64).mean(axis=1)
    if res.bias_hat is not None:
        f = f - np.asarray(res.bias_hat, dtype=np.float64)[ok, block.start : block.start + 3]
    mean = np.concatenate([f.mean(axis=0), np.zeros(3)]) if len(f) else np.zeros(6)
    return mean_force_in_base(mean, block.channel.sensor)


def _force_factor(fit, model) -> float:
    """The factor that makes the forces of a :class:`ineid.identify.unit_fits.UnitFit` N: the power of ten within
    2x of ``1 / scale`` (without known links: of ``URDF mass / fitted mass`` of the unknown links) where that is
    more than :data:`MASS_FACTOR` off 1, else 1."""
    urdf = float(np.sum(np.asarray(model.theta_cad, dtype=np.float64)[model.unknown_index][0::10]))
    scale = fit.scale if math.isfinite(fit.scale) else (fit.mass / urdf if urdf > 0 else 1.0)
    off = scale > 0 and not 1 / MASS_FACTOR <= scale <= MASS_FACTOR
    return (power_of_ten(1 / scale) or 1.0) if off else 1.0


def check_fitted_units(ds, res, linear, model) -> Finding | None:
    """Joint angles in the other unit, or a wrench in other units than N and N*m, told by refits (module docstring).

    Args:
        ds: the solved :class:`ineid.data.Dataset`.
        res: its :class:`ineid.identify.SolveResults` (the channels fitted, the offsets).
        linear: the solve's linear least squares (:func:`linear_counterpart`; None: ``res``'s own error gates).
        model: its :class:`ineid.RobotModel`.

    Returns:
        A :class:`Finding` (``angles_in_degrees``, ``angles_in_radians`` or ``wrench_unit``) naming the
        likely unit and the import option, or None.
    """
    solved = fit_error(res if linear is None else linear, ds)  # inf where it failed everywhere
    if not solved > FIT_GATE:
        return None
    imported_deg = (ds.meta.origin or {}).get("angle_unit") == "deg"
    angle = 180 / math.pi if imported_deg else math.pi / 180
    channels = fitted_channels(res, ds)
    wrench = any(isinstance(c, BaseWrench) for c in channels)
    hypotheses = [(1.0, 1.0), (angle, 1.0)] + ([(1.0, 1e-3), (1.0, 1e3)] if wrench else [])
    fits = refit_units(ds, channels, res.settings.bias == "estimate", model, hypotheses)
    best = min(fits, key=lambda f: f.error)
    force = _force_factor(best, model) if wrench else 1.0
    # against the stored units refitted (another unit won), or against the solve (the wrench's scale alone)
    before = fits[0].error if best is not fits[0] else solved
    if (best is fits[0] and force == 1.0) or not best.error * UNIT_GAIN < before:
        return None
    what = "wrench" if wrench else "measurements"
    ratio = before / best.error if 0 < best.error and math.isfinite(before) else math.inf
    gain = " over 1000x better" if ratio > 1000 else f" {times(ratio)} better"
    evidence = (
        f"the model explains the {what}{gain} (error {best.error:.2g} against {before:.2g}, a linear fit of "
        f"{best.n_frames} frames)"
    )
    if best.angle != 1.0:
        if imported_deg:
            return Finding(
                "angles_in_radians",
                "the joint angles look like radians that --angle-unit deg converted "
                f"again: read as radians {evidence}: import the recording without --angle-unit deg",
            )
        return Finding(
            "angles_in_degrees",
            f"the joint angles look like degrees: read as degrees {evidence}: "
            "import the recording with data import --angle-unit deg",
        )
    moment = force * best.moment
    words, options = _wrench_fix(force, moment)
    change = (
        f"the wrench x {force:g}"
        if force == moment
        else " and ".join(f"the {name} x {k:g}" for name, k in (("forces", force), ("moments", moment)) if k != 1.0)
    )
    return Finding("wrench_unit", f"the wrench looks like {words}: with {change} {evidence}: {options}")


def fit_checks(ds, res, model=None, validate=None) -> list[Finding]:
    """The plausibility checks of a solve's fit to its data, most basic cause first (see the module docstring).

    Args:
        ds: the solved :class:`ineid.data.Dataset` (the selected configurations, in order).
        res: its :class:`ineid.identify.SolveResults`.
        model: its :class:`ineid.RobotModel` (default: rebuilt from ``ds``).
        validate: the separate validation recording of ``solve --validate`` (None: none, or not at hand).

    Returns:
        The findings, at most one per likely mistake; empty when all is plausible.
    """
    model = model or ds.model()
    first = (
        check_gravity(model.gravity, "the dataset's gravity", "data import or data generate --gravity")
        or check_recording_time(ds)
        or check_angle_units(model, ds.q)
    )
    if first is not None:  # every fit of these frames is garbage: nothing more to learn
        return [first]
    try:
        linear = linear_counterpart(ds, res, model)
    except IdentificationError:  # too few frames for the linear fit (a trained run's short samples)
        linear = None
    units = check_fitted_units(ds, res, linear, model)
    if units is not None:  # the fits under the stored units are garbage too
        return [units]
    fit = res if np.asarray(res.success, dtype=bool).any() else linear  # a method that failed everywhere
    if fit is None or not np.asarray(fit.success, dtype=bool).any():
        return []
    force = fitted_static_force(fit, ds)
    static = (
        None
        if force is None
        else check_static_force(
            model,
            force,
            "the fitted model's static force" if fit.bias_hat is not None else "the mean force over the fitted frames",
        )
    )
    held = check_held_out_error(fit, ds, validate, model)
    mass = None if linear is None else check_total_mass(linear, model)
    if held is not None:
        # the fit explains nothing, so its own mass and fitted static force mean nothing; without
        # offsets the static force is the data's own mean, and pointing up it is the cause (a
        # flipped wrench that a physically consistent fit cannot follow); with offsets the linear
        # fit's negative mass says the same
        if static is not None and fit.bias_hat is None:
            return [static]
        return [mass] if mass is not None and mass.code == "total_mass_negative" else [held]
    if mass is not None and mass.code == "total_mass_negative":
        return [mass]  # the static force would say the same
    offsets = check_offsets(fit, ds, model, fitted_channels(fit, ds))
    # a mass, static force or offsets the fit gets wrong leave a residual above the noise: said once, by them
    explained = any(f is not None for f in (mass, static, offsets))
    residual = None if explained else check_residual_noise(fit, ds, validate, model)
    return [f for f in (mass, static, offsets, residual) if f is not None]


CAUSES = frozenset(
    {
        "gravity_unit",
        "time_unit",
        "angles_in_degrees",
        "angles_in_radians",
        "wrench_unit",
        "static_wrench_against_gravity",
        "total_mass_negative",
        "total_mass_scale",
        "held_out_error",
    }
)
"""Findings of a mistake in the data or its settings (units, sign, a model that explains nothing): an estimate
fitted through one is no rigid body as a consequence, so :func:`check_solve` does not repeat it."""


def check_solve(ds, res, model=None, validate=None) -> list[Finding]:
    """Every plausibility check of a solve: :func:`fit_checks`, and unless they found a mistake in the data
    (:data:`CAUSES`: wrong units or sign leave no rigid body either, that would only repeat a consequence) the
    estimates' physical validity (:func:`ineid.identify.physical_checks.check_physical_estimates`); and the
    configurations where IPOPT stopped at its iteration cap
    (:func:`ineid.identify.physical_checks.check_iteration_cap`).

    Args:
        ds: the solved :class:`ineid.data.Dataset` (the selected configurations, in order).
        res: its :class:`ineid.identify.SolveResults`.
        model: its :class:`ineid.RobotModel` (default: rebuilt from ``ds``).
        validate: the ``--validate`` recording (a :class:`ineid.data.Dataset`), or None.

    Returns:
        The findings, at most one per likely mistake; empty when all is plausible.
    """
    found = fit_checks(ds, res, model, validate)
    physical = None if any(f.code in CAUSES for f in found) else check_physical_estimates(res)
    return [f for f in (*found, physical, check_iteration_cap(res)) if f is not None]
