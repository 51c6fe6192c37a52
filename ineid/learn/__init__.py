"""Learning: Flax networks that map measured frames to the unknown links' parameters.

Data flow: a :class:`ineid.data.Dataset` -> :func:`split_configs` and scalers ->
:class:`ModelSpec` (the paper's networks, multi-frame, Siamese) -> :func:`train` with the
MSE or the physics-informed loss (:mod:`.losses`, the generated JAX regressor inside the
jitted loss) -> :func:`evaluate` against the null-space floor and the linear least
squares -> :func:`sweep` over grids; a trained run identifies datasets as
``solve_dataset``'s ``method="network"`` (:func:`solve_with_run`, passed in by :mod:`ineid.workflow`).
Never imports sympy.
"""

from __future__ import annotations

from ineid.errors import TrainingError
from ineid.learn.amortized import solve_with_run
from ineid.learn.data import Split, epoch_groups, fixed_groups, frame_features, split_configs
from ineid.learn.evaluate import Evaluation, evaluate, floor_estimator, predict
from ineid.learn.losses import LOSSES, PHYSICS_MODES, Physics, make_loss
from ineid.learn.models import ACTIVATIONS, ARCHITECTURES, MLP, TABLE1, ModelSpec, Siamese, hidden_widths
from ineid.learn.runs import Run, load_run
from ineid.learn.scalers import SCALERS, Scaler
from ineid.learn.sweep import Grid, SweepRow, sweep
from ineid.learn.train import OPTIMIZERS, SCHEDULES, TrainConfig, TrainResult, train

__all__ = [
    "ACTIVATIONS",
    "ARCHITECTURES",
    "LOSSES",
    "MLP",
    "OPTIMIZERS",
    "PHYSICS_MODES",
    "SCALERS",
    "SCHEDULES",
    "TABLE1",
    "Evaluation",
    "Grid",
    "ModelSpec",
    "Physics",
    "Run",
    "Scaler",
    "Siamese",
    "Split",
    "SweepRow",
    "TrainConfig",
    "TrainResult",
    "TrainingError",
    "epoch_groups",
    "evaluate",
    "fixed_groups",
    "floor_estimator",
    "frame_features",
    "hidden_widths",
    "load_run",
    "make_loss",
    "predict",
    "split_configs",
    "solve_with_run",
    "sweep",
    "train",
]
