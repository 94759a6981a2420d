"""CNN pixel encoder for slot attention (STEVE's choice; SLATE reads the dVAE tokens).

SLATE feeds slot attention the embeddings of the dVAE tokens (one per 4x4 patch).
On block-rearrange a cube is ~9 pixels wide, so most of its tokens are edge tokens that
mix cube and floor, and a mask at 16x16 cannot follow its outline. STEVE (Singh et al.,
2022), SLATE's video successor, gives slot attention a CNN over the pixels instead and
keeps the dVAE tokens as the decoder's targets. With `stride` 2 the features (and so the
attention masks) are 32x32 (why: docs/recipe.md, `slots.encoder`).
Shapes: images (B, H, W, 3) in [0, 1] -> (B, (H/s)^2, dim).
"""
from __future__ import annotations

import torch
from torch import nn

from .positional import sinusoid_2d

__all__ = ["PixelEncoder"]


class PixelEncoder(nn.Module):
    def __init__(self, dim: int, stride: int, image_size: int):
        super().__init__()
        if image_size % stride:
            raise ValueError(f"image_size {image_size} must be divisible by the encoder stride {stride}")
        self.grid = image_size // stride
        self.net = nn.Sequential(
            nn.Conv2d(3, dim, 5, stride, 2), nn.ReLU(),
            nn.Conv2d(dim, dim, 3, 1, 1), nn.ReLU(),
            nn.Conv2d(dim, dim, 3, 1, 1))
        # normalise before adding positions: a fresh CNN's features vary far less across
        # pixels than the position code, so slot attention would start grouping by place
        self.norm = nn.LayerNorm(dim)
        self.pos = nn.Parameter(sinusoid_2d(self.grid, dim))          # learned, sinusoid start

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        h = self.net(images.permute(0, 3, 1, 2))                      # (B, dim, g, g)
        return self.norm(h.flatten(2).transpose(1, 2)) + self.pos.to(h.dtype)  # (B, g*g, dim)
