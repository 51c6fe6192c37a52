"""Excitation design: joint trajectories whose frames identify the base parameters best.

Data flow: a :class:`ineid.RobotModel` and :class:`ExcitationSettings` -> Fourier trajectories
within the joints' bounds (:mod:`.trajectory`) and the safety limits (floor, workspace,
self-collision: :mod:`.safety`, :mod:`.collision`), checked first on a sample of the joint space
(:mod:`.feasibility`) -> the information criterion of their frames (:mod:`.criterion`, CasADi rows and
their pull-back; with link IMUs, the joint states' errors: :mod:`.states`) -> random feasible candidates
and IPOPT from the best of them (:mod:`.search`, :mod:`.callbacks`) -> :func:`design_excitation` -> an
:class:`ExcitationResult` (the design against the best and a typical random candidate, each a
:class:`DesignEvaluation`). Never imports sympy.

A trajectory of one's own is judged the same way: :func:`design_base`, :func:`design_noise` and
:func:`evaluate_design` on its samples.
"""

from __future__ import annotations

from ineid.excite.criterion import (
    CRITERIA,
    DESIGN_NOISE,
    DesignBase,
    DesignEvaluation,
    design_base,
    design_noise,
    evaluate_design,
)
from ineid.excite.design import design_excitation
from ineid.excite.safety import SafetyLimits
from ineid.excite.settings import MAX_SAMPLES, MAX_STARTS, ExcitationResult, ExcitationSettings, StartRecord
from ineid.excite.trajectory import Bounds, design_bounds

__all__ = [
    "CRITERIA",
    "DESIGN_NOISE",
    "MAX_SAMPLES",
    "MAX_STARTS",
    "Bounds",
    "DesignBase",
    "DesignEvaluation",
    "ExcitationResult",
    "ExcitationSettings",
    "SafetyLimits",
    "StartRecord",
    "design_base",
    "design_bounds",
    "design_excitation",
    "design_noise",
    "evaluate_design",
]
