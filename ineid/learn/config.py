"""A training run's settings (:class:`TrainConfig`), as ``config.json`` records them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ineid.learn.losses import LOSSES
from ineid.learn.models import ModelSpec
from ineid.learn.scalers import SCALERS

OPTIMIZERS = ("sgd", "adam", "adamw")
DTYPES = ("float64", "float32")
"""What a network can train in (``--dtype``)."""
SCHEDULES = ("constant", "cosine")


@dataclass(frozen=True)
class TrainConfig:
    """Settings of a training run (see ``docs/learning.md``).

    Attributes:
        model: architecture, activation, Siamese, frames per sample.
        scaler: feature and target scaler kind.
        loss: ``"mse"`` or ``"physics"`` (``alpha * MSE + beta * wrench residual``).
        alpha, beta: loss weights (``beta`` used by the physics loss only).
        optimizer: ``"sgd"`` (with ``momentum``), ``"adam"``, ``"adamw"`` (``weight_decay``).
        lr, schedule: learning rate and its schedule (``constant`` or ``cosine`` decay to 0).
        epochs, batch: epochs and samples per step.
        patience: stop after this many epochs without a better validation MSE (0: never).
        seed: the one seed of the run.
        n_train, n_val, n_test: configurations per split (defaults 70 / 15 / 15 %).
        dtype: what the network trains in, ``"float64"`` or ``"float32"`` (the data are scaled in it on the
            device; evaluation and identification stay float64).
    """

    model: ModelSpec = field(default_factory=ModelSpec)
    scaler: str = "standard"
    loss: str = "mse"
    alpha: float = 1.0
    beta: float = 1.0
    optimizer: str = "adam"
    lr: float = 1e-3
    momentum: float = 0.9
    weight_decay: float = 1e-4
    schedule: str = "constant"
    epochs: int = 100
    batch: int = 256
    patience: int = 20
    seed: int = 0
    n_train: int | None = None
    n_val: int | None = None
    n_test: int | None = None
    dtype: str = "float64"

    def __post_init__(self) -> None:
        checks = [
            (self.scaler in SCALERS, f"scaler must be one of {', '.join(SCALERS)}"),
            (self.loss in LOSSES, f"loss must be one of {', '.join(LOSSES)}"),
            (self.optimizer in OPTIMIZERS, f"optimizer must be one of {', '.join(OPTIMIZERS)}"),
            (self.schedule in SCHEDULES, f"schedule must be one of {', '.join(SCHEDULES)}"),
            (
                self.lr > 0 and self.epochs >= 1 and self.batch >= 1 and self.patience >= 0,
                "lr, epochs and batch must be positive and patience >= 0",
            ),
            (self.dtype in DTYPES, f"dtype must be one of {', '.join(DTYPES)}"),
            (
                self.dtype == "float64" or not self.model.uses_regressor,
                "the wls network solves least squares inside and trains in float64; drop --dtype float32",
            ),
            (
                self.alpha >= 0 and self.beta >= 0 and (self.alpha > 0 or (self.loss == "physics" and self.beta > 0)),
                "alpha and beta must be >= 0 and the loss not identically zero",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    @property
    def effective_beta(self) -> float:
        return self.beta if self.loss == "physics" else 0.0

    def to_dict(self) -> dict:
        """The settings as ``config.json`` records them (``dtype`` only when not float64, so the runs written
        before it existed still match their settings on ``--resume``)."""
        d = dataclasses.asdict(self)
        d["model"] = dataclasses.asdict(self.model)
        if self.dtype == "float64":
            del d["dtype"]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = dict(d)
        d["model"] = ModelSpec(**d["model"])
        return cls(**d)
