"""The networks' building blocks: the activations by name and the hidden layers (the frame encoder).

Shared by the paper's networks (:mod:`ineid.learn.models`) and the weighted least-squares
network (:mod:`ineid.learn.wls`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax.numpy as jnp

ACTIVATIONS = {
    "tanh": nn.tanh,
    "relu": nn.relu,
    "gelu": nn.gelu,
    "sigmoid": nn.sigmoid,
    "elu": nn.elu,
    "silu": nn.silu,
}


class Encoder(nn.Module):
    """The hidden layers of an architecture: (..., F) -> (..., last width)."""

    hidden: Sequence[int]
    activation: str = "tanh"
    param_dtype: Any = jnp.float64

    @nn.compact
    def __call__(self, x):
        act = ACTIVATIONS[self.activation]
        for i, w in enumerate(self.hidden):
            x = act(nn.Dense(w, param_dtype=self.param_dtype, name=f"hidden_{i}")(x))
        return x
