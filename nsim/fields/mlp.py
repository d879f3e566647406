"""Small fully connected networks, initialised from an explicit generator."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


def init_linear_(layer: nn.Linear, generator: torch.Generator | None) -> nn.Linear:
    """PyTorch's default ``nn.Linear`` init (uniform +-1/sqrt(fan_in)), drawn from ``generator``."""
    bound = 1.0 / math.sqrt(layer.in_features)
    with torch.no_grad():
        layer.weight.uniform_(-bound, bound, generator=generator)
        if layer.bias is not None:
            layer.bias.uniform_(-bound, bound, generator=generator)
    return layer


class MLP(nn.Module):
    """``in_dim -> [hidden_dim] * hidden_layers -> out_dim`` with ReLU between layers, none at the end.

    ``hidden_layers = 0`` is a single linear layer.
    """

    def __init__(self, in_dim: int, hidden_dim: int, hidden_layers: int, out_dim: int,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        dims = [in_dim] + [hidden_dim] * hidden_layers + [out_dim]
        self.layers = nn.ModuleList(init_linear_(nn.Linear(a, b), generator) for a, b in zip(dims[:-1], dims[1:], strict=True))

    def forward(self, x: Tensor) -> Tensor:
        for k, layer in enumerate(self.layers):
            x = layer(x)
            if k < len(self.layers) - 1:
                x = torch.relu(x)
        return x
