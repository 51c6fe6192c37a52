"""Classical identification: base parameters, linear, nonlinear and physically consistent.

Data flow: a :class:`ineid.data.Dataset` -> stacked systems (:mod:`.systems`) -> the base
least-squares fit (:func:`fit_base`) -> standard parameters by the null-space rule
(:func:`linear_estimate`), by IPOPT (:class:`NlpSolver`) or by the paper's MATLAB solvers
(:mod:`.classical`) -> :func:`solve_dataset`
results -> :func:`save_results` / :func:`export_urdf` / :func:`export_mjcf`. Never imports sympy.
"""

from __future__ import annotations

from ineid.identify.delay import estimate_delay
from ineid.identify.frame_minimum import FrameMinimum
from ineid.identify.frames import identify_frames
from ineid.identify.identifiability import (
    BaseParameters,
    BiasCost,
    FrameAnalysis,
    analyze_frames,
    base_parameters,
    base_parameters_from_regressor,
    bias_cost,
    frame_minimum,
    generic_frames,
)
from ineid.identify.linear import BaseFit, Estimate, fit_base, linear_estimate, standard_from_base
from ineid.identify.nlp import NlpSolver, nlp_estimate
from ineid.identify.results import error_summary, load_results, relative_error, save_results
from ineid.identify.solve import METHODS, SolveResults, SolveSettings, solve_dataset
from ineid.identify.systems import parameter_scales, stack, stack_casadi
from ineid.robots.mjcf_write import export_mjcf, mjcf_with_inertials
from ineid.robots.urdf_write import export_urdf, urdf_with_inertials

__all__ = [
    "METHODS",
    "BaseFit",
    "BaseParameters",
    "BiasCost",
    "Estimate",
    "FrameAnalysis",
    "FrameMinimum",
    "NlpSolver",
    "SolveResults",
    "SolveSettings",
    "analyze_frames",
    "base_parameters",
    "base_parameters_from_regressor",
    "bias_cost",
    "error_summary",
    "estimate_delay",
    "export_mjcf",
    "export_urdf",
    "fit_base",
    "frame_minimum",
    "generic_frames",
    "identify_frames",
    "linear_estimate",
    "load_results",
    "mjcf_with_inertials",
    "nlp_estimate",
    "parameter_scales",
    "relative_error",
    "save_results",
    "solve_dataset",
    "stack",
    "stack_casadi",
    "standard_from_base",
    "urdf_with_inertials",
]
