"""Fixed 2-D sine/cosine position features for a square token grid."""
from __future__ import annotations

import math

import torch

__all__ = ["sinusoid_2d"]


def sinusoid_2d(grid: int, dim: int) -> torch.Tensor:
    """(1, grid*grid, dim) 2-D sine/cosine features of (row, col) with small amplitude."""
    q = dim // 4
    freqs = torch.exp(torch.linspace(0, -math.log(grid * 2.0), max(q, 1)))[:q] * math.pi   # (q,)
    pos = torch.arange(grid, dtype=torch.float32) / grid
    r, c = torch.meshgrid(pos, pos, indexing="ij")
    feats = [f(x.flatten()[:, None] * freqs) for x in (r, c) for f in (torch.sin, torch.cos)]
    out = torch.cat(feats, dim=1)                                   # (N, 4q)
    out = torch.cat([out, torch.zeros(grid * grid, dim - out.shape[1])], dim=1)
    return 0.5 * out[None]
