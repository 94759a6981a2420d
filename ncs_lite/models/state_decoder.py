"""State-mask decoder (not in the paper): where a slot is, drawn from its state s alone.

It draws each slot's mask from its state half only and learns to predict slot attention's
own (detached) masks, from detached states: a read-out that shapes nothing upstream. It
makes the slots decodable on their own (`DSlate.render`), predicted slots included, and it
shows whether s says where the object is (the masks it draws are only as good as that).

Each slot is drawn as an axis-aligned 2-D Gaussian bump: a linear map of s gives its centre
(mu_row, mu_col), its spread (log sigma per axis) and its height a, and the mask logit at
grid position p is a - sum_i (p_i - mu_i)^2 / (2 sigma_i^2); a softmax over slots makes the
masks. A small object is a high narrow bump; the floor a low flat one that wins wherever no
bump is. With `slots.position_state`, s holds where its slot attends and the bump only has to
read it. Its gradient stops at s: sent into slot attention, an MLP head did not learn where
and a bump head collapsed the masks into one slot (docs/HISTORY.md, "The type/state split").

`SlotRenderer` draws the same kind of bump for `DSlate.render`, fitted to the frames instead
(the render phase: a pixel loss through the frozen mixture decoder). Fitted to slot
attention's soft masks, the linear bump's cubes stay low and wide and the floor paints over
them: the image is nearly empty floor, and a pixel loss through the linear map does not fix
it (why: docs/recipe.md, `train.render_steps`; the runs: docs/HISTORY.md, "Rendering before
the render phase" and "Moved from the docstrings"). The renderer's centre comes from s
alone, through an MLP; its spread and height also from the whole slot, since what the object
is (the floor or a cube) sets how big and how dominant its mask is.

Shapes: states (B, K, Ds) -> mask logits (B, K, N), N = grid * grid, positions in [-1, 1].
"""
from __future__ import annotations

import torch
from torch import nn

from .split import split

__all__ = ["SlotRenderer", "StateMaskDecoder", "coordinate_grid"]


def coordinate_grid(grid: int) -> torch.Tensor:
    """(grid * grid, 2) (row, col) cell centres in [-1, 1], row-major like the token grid."""
    c = (torch.arange(grid, dtype=torch.float32) + 0.5) / grid * 2 - 1
    r, q = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([r.flatten(), q.flatten()], dim=1)


class StateMaskDecoder(nn.Module):
    def __init__(self, state_dim: int, grid: int):
        super().__init__()
        self.grid = grid
        self.register_buffer("coords", coordinate_grid(grid), persistent=False)
        self.bump = nn.Linear(state_dim, 5)                          # mu (2), log sigma (2), height
        nn.init.normal_(self.bump.weight, std=state_dim ** -0.5)
        nn.init.zeros_(self.bump.bias)
        with torch.no_grad():
            self.bump.bias[2:4] = -1.0                                # sigma e^-1: about a third of the image

    def bumps(self, states: torch.Tensor) -> dict:
        """states (B, K, Ds) -> {"centre" (B, K, 2) (row, col) in grid units of [-1, 1],
        "sigma" (B, K, 2), "height" (B, K)}."""
        out = self.bump(states)
        return {"centre": out[..., :2], "sigma": out[..., 2:4].clamp(-6, 3).exp(),
                "height": out[..., 4]}

    def forward(self, states: torch.Tensor) -> torch.Tensor:
        """states (B, K, Ds) -> mask logits (B, K, N); softmax over K gives masks."""
        b = self.bumps(states)
        d = (self.coords.to(states.dtype) - b["centre"][:, :, None]) / b["sigma"][:, :, None]  # (B, K, N, 2)
        return b["height"][..., None] - 0.5 * d.pow(2).sum(-1)


class SlotRenderer(nn.Module):
    """The masks `DSlate.render` paints with: a bump per slot, its centre from s, its spread
    and height from [z; s] (module docstring); trained by the render phase alone."""

    def __init__(self, type_dim: int, state_dim: int, grid: int, hidden: int):
        super().__init__()
        self.type_dim = type_dim
        self.register_buffer("coords", coordinate_grid(grid), persistent=False)
        self.where = nn.Sequential(nn.Linear(state_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                   nn.ReLU(), nn.Linear(hidden, 5))      # from s: mu, log sigma, height
        self.what = nn.Sequential(nn.Linear(type_dim + state_dim, hidden), nn.ReLU(),
                                  nn.Linear(hidden, 3))                  # from [z; s]: log sigma, height
        with torch.no_grad():
            self.where[-1].bias[2:4] = -1.0

    def forward(self, slots: torch.Tensor) -> torch.Tensor:
        """slots (B, K, Dz + Ds) -> mask logits (B, K, N); softmax over K gives masks."""
        out = self.where(split(slots, self.type_dim)[1])
        rest = out[..., 2:] + self.what(slots)
        sigma = rest[..., :2].clamp(-6, 3).exp()
        d = (self.coords.to(slots.dtype) - out[..., None, :2]) / sigma[:, :, None]   # (B, K, N, 2)
        return rest[..., 2:] - 0.5 * d.pow(2).sum(-1)
