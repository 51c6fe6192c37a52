"""Excitation design: joint trajectories whose frames identify the base parameters best.

Data flow: a :class:`ineid.RobotModel` and :class:`ExcitationSettings` -> Fourier trajectories
within the joints' bounds (:mod:`.trajectory`) and the safety limits (floor, workspace,
self-collision: :mod:`.safety`, :mod:`.collision`) -> the information criterion of their frames
(:mod:`.criterion`; with link IMUs, the joint states' errors: :mod:`.states`) optimised by IPOPT
-> :func:`design_excitation` -> an :class:`ExcitationResult` (the design against the random
trajectories it was compared with). Never imports sympy.
"""

from __future__ import annotations

from ineid.excite.design import design_excitation
from ineid.excite.safety import SafetyLimits
from ineid.excite.settings import ExcitationResult, ExcitationSettings, StartRecord
from ineid.excite.trajectory import Bounds, design_bounds

__all__ = [
    "Bounds",
    "ExcitationResult",
    "ExcitationSettings",
    "SafetyLimits",
    "StartRecord",
    "design_bounds",
    "design_excitation",
]
