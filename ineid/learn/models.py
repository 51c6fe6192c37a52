"""The networks: the paper's simple network, Table 1's Networks 1-7, the funnel, any MLP;
single- or multi-frame input; Siamese networks with one shared frame encoder.

Every model maps a batch of samples ``x`` (B, K, 18), K frames of one configuration with
18 scaled features each (``q, qd, qdd, wrench``), to (B, N_out) scaled parameters:

* ``MLP``: the K frames concatenated (K * 18 inputs), hidden layers, a linear output;
* ``Siamese``: one encoder (the hidden layers) applied to every frame with the same
  weights, the K embeddings averaged (so the output does not depend on the frames' order
  and K may differ between training and use), then a head (one hidden layer of the last
  width, then the linear output). Shared weights hold by construction: the encoder is one
  module called K times.
* ``wls`` (:class:`ineid.learn.wls.WLS`): a weighted least-squares solve built from the
  robot's regressor, with learned per-frame weights and a learned prior; it also takes
  each frame's regressor and wrench (``uses_regressor``) and the constants fitted on the
  training split (``context``).

Table 1 of the paper (N_out = 20 for two unknown links):

==========  ======  ======================
network     depth   width
==========  ======  ======================
simple      1       20 (Fig. 1)
net1        8       N_out
net2        8       2 N_out
net3        12      N_out
net4        16      N_out
net5        8       4 N_out
net6        8       8 N_out
net7        8       16 N_out
funnel      6       64, 32, 16, 8, 4, 2
==========  ======  ======================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax.numpy as jnp

from ineid.learn.layers import ACTIVATIONS, Encoder

TABLE1 = {  # name: (depth, width factor of N_out)
    "net1": (8, 1),
    "net2": (8, 2),
    "net3": (12, 1),
    "net4": (16, 1),
    "net5": (8, 4),
    "net6": (8, 8),
    "net7": (8, 16),
}
ARCHITECTURES = ("simple", *TABLE1, "funnel", "mlp", "wls")
SIZED = ("mlp", "wls")
"""Architectures whose sizes ``--depth`` and ``--width`` set (wls: its frame encoder, default 2 x 32)."""


MAX_DEPTH = 64
"""The deepest ``mlp``/``wls`` encoder (compilation time grows with the layers: 100,000 never finished)."""
MAX_WEIGHTS = 10_000_000
"""At most this many hidden-to-hidden weights, ``(depth - 1) * width^2 + width``: 80 MB in float64,
about four times that with the optimizer's state and the best parameters kept."""


def _check_size(arch: str, depth: int, width: int) -> None:
    weights = (depth - 1) * width * width + width
    if depth > MAX_DEPTH or weights > MAX_WEIGHTS:
        raise ValueError(
            f"the {arch} network of depth {depth} and width {width} is too large ({weights:,} weights; at most depth "
            f"{MAX_DEPTH} and {MAX_WEIGHTS:,} weights, (depth - 1) x width^2 + width); lower --depth or --width"
        )


def hidden_widths(arch: str, n_out: int, depth: int | None = None, width: int | None = None) -> tuple[int, ...]:
    """Hidden-layer widths of a named architecture (``mlp`` takes ``depth`` and ``width``).

    Raises:
        ValueError: an unknown name, or sizes below 1 or above :data:`MAX_DEPTH` / :data:`MAX_WEIGHTS`.
    """
    if arch == "simple":
        return (20,)
    if arch in TABLE1:
        d, k = TABLE1[arch]
        return (k * n_out,) * d
    if arch == "funnel":
        return (64, 32, 16, 8, 4, 2)
    if arch == "mlp":
        if not depth or not width or depth < 1 or width < 1:
            raise ValueError("the mlp architecture needs depth >= 1 and width >= 1")
        _check_size(arch, int(depth), int(width))
        return (int(width),) * int(depth)
    if arch == "wls":
        from ineid.learn.wls import WLS_DEPTH, WLS_WIDTH

        depth, width = depth or WLS_DEPTH, width or WLS_WIDTH
        if depth < 1 or width < 1:
            raise ValueError("the wls encoder needs depth >= 1 and width >= 1")
        _check_size(arch, int(depth), int(width))
        return (int(width),) * int(depth)
    raise ValueError(f"architecture must be one of {', '.join(ARCHITECTURES)}, got {arch!r}")


class MLP(nn.Module):
    """Frames concatenated -> hidden layers -> linear output. (B, K, F) -> (B, n_out)."""

    hidden: Sequence[int]
    n_out: int
    activation: str = "tanh"
    param_dtype: Any = jnp.float64

    @nn.compact
    def __call__(self, x):
        h = Encoder(self.hidden, self.activation, self.param_dtype, name="encoder")(x.reshape(x.shape[0], -1))
        return nn.Dense(self.n_out, param_dtype=self.param_dtype, name="out")(h)


class Siamese(nn.Module):
    """Shared encoder on every frame, mean of the embeddings, head. (B, K, F) -> (B, n_out)."""

    hidden: Sequence[int]
    n_out: int
    activation: str = "tanh"
    param_dtype: Any = jnp.float64

    @nn.compact
    def __call__(self, x):
        act = ACTIVATIONS[self.activation]
        encoder = Encoder(self.hidden, self.activation, self.param_dtype, name="encoder")
        emb = encoder(x)  # Dense acts on the last axis: the same weights for every frame
        pooled = emb.mean(axis=1)
        h = act(nn.Dense(self.hidden[-1], param_dtype=self.param_dtype, name="head_hidden")(pooled))
        return nn.Dense(self.n_out, param_dtype=self.param_dtype, name="out")(h)


@dataclass(frozen=True)
class ModelSpec:
    """What to build: architecture, sizes, activation, Siamese or not, frames per sample."""

    arch: str = "simple"
    activation: str = "tanh"
    depth: int | None = None
    width: int | None = None
    siamese: bool = False
    frames: int = 1

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {self.activation!r}")
        if self.frames < 1:
            raise ValueError(f"frames per sample must be >= 1, got {self.frames}")
        hidden_widths(self.arch, 1, self.depth, self.width)  # validates the name and sizes
        if self.arch not in SIZED and (self.depth is not None or self.width is not None):
            raise ValueError(f"depth and width apply to the mlp and wls architectures; {self.arch} has fixed sizes")
        if self.arch == "wls" and self.siamese:
            raise ValueError("the wls network shares its frame encoder by construction; drop siamese")

    @property
    def uses_regressor(self) -> bool:
        """Whether the network also takes each frame's regressor and wrench (``wls``)."""
        return self.arch == "wls"

    def build(self, n_out: int, context=None, dtype: str = "float64") -> nn.Module:
        """The Flax module, its parameters of ``dtype``; ``context`` (a :class:`ineid.learn.wls.WlsContext`) is
        required by ``wls`` (float64 only: it solves least squares inside)."""
        hidden = hidden_widths(self.arch, n_out, self.depth, self.width)
        if self.uses_regressor:
            from ineid.learn.wls import WLS

            if context is None:
                raise ValueError("the wls network needs the constants fitted on its training split (context)")
            return WLS(hidden=hidden, context=context, activation=self.activation)
        cls = Siamese if self.siamese else MLP
        return cls(hidden=hidden, n_out=n_out, activation=self.activation, param_dtype=jnp.dtype(dtype))

    @property
    def name(self) -> str:
        if self.arch == "wls":
            sizes = "" if self.depth is None and self.width is None else f"{self.depth or ''}x{self.width or ''}"
            return f"wls{sizes}-{self.activation}-k{self.frames}"
        base = self.arch if self.arch != "mlp" else f"mlp{self.depth}x{self.width}"
        kind = "siamese" if self.siamese else ("multi" if self.frames > 1 else "single")
        return f"{base}-{self.activation}-{kind}{self.frames if self.frames > 1 else ''}"
