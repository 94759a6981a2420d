"""State-mask decoder (not in the paper): where a slot is, read from its state s alone.

In the `reduced` recipe slot attention's masks say where each object is, and nothing made
the slot *vector* say it too: a linear probe read no position from s (R^2 about 0, issue
12). This head draws each slot's mask from its state half only, at every position of slot
attention's grid, and learns to predict slot attention's own (detached) masks. To draw its
object's mask, s has to hold where the object is; the type half z, which the head never
reads, is left to say what it is. The head also makes the slots decodable on their own
(`DSlate.render`), predicted slots included.

Positions enter as raw coordinates in [-1, 1], not sinusoids: a ReLU network draws a blob
at (x0, y0) most simply from |x - x0| and |y - y0|, i.e. from an s in which (x0, y0) is a
linear read-out, which is what the kit's position probe measures.

Shapes: states (B, K, Ds) -> mask logits (B, K, N), N = grid * grid.
"""
from __future__ import annotations

import torch
from torch import nn

__all__ = ["StateMaskDecoder", "coordinate_grid"]


def coordinate_grid(grid: int) -> torch.Tensor:
    """(grid * grid, 2) (row, col) cell centres in [-1, 1], row-major like the token grid."""
    c = (torch.arange(grid, dtype=torch.float32) + 0.5) / grid * 2 - 1
    r, q = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([r.flatten(), q.flatten()], dim=1)


class StateMaskDecoder(nn.Module):
    def __init__(self, state_dim: int, grid: int, hidden: int):
        super().__init__()
        self.grid = grid
        self.register_buffer("coords", coordinate_grid(grid), persistent=False)
        self.state_in = nn.Linear(state_dim, hidden)
        self.coord_in = nn.Linear(2, hidden, bias=False)
        self.mlp = nn.Sequential(nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))

    def forward(self, states: torch.Tensor) -> torch.Tensor:
        """states (B, K, Ds) -> mask logits (B, K, N); softmax over K gives masks."""
        h = self.state_in(states)[:, :, None] + self.coord_in(self.coords.to(states.dtype))  # (B, K, N, h)
        return self.mlp(h)[..., 0]
