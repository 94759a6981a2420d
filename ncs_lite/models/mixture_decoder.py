"""Auxiliary mixture decoder: each slot paints its own image, an alpha mask picks the pixels.

Not in the NCS paper (its weight is 0 in the `paper` preset); the `reduced` preset uses it
to give slot attention an object bias it cannot get fast enough from SLATE's decoder on a
CPU budget. The autoregressive decoder can rebuild a whole scene from any grouping of
the tokens, so nothing makes one slot hold one cube. Here, as in the original slot
attention autoencoder (Locatello et al., 2020) and DINOSAUR's MLP decoder (Seitzer et al.,
2023), every slot is decoded *independently* into an image patch per token position plus
an alpha logit; a softmax over slots mixes them. A slot can only explain pixels it paints
itself, so the cheapest way to reconstruct four cubes is one slot per cube.

It works at the token grid (one p x p x 3 pixel patch per token), so it costs a small
MLP over K x N positions. Shapes: slots (B, K, D) -> patches (B, N, p*p*3), alpha (B, K, N).
"""
from __future__ import annotations

import torch
from torch import nn

from .positional import sinusoid_2d

__all__ = ["MixtureDecoder"]


class MixtureDecoder(nn.Module):
    def __init__(self, slot_dim: int, grid: int, patch: int, hidden: int):
        super().__init__()
        self.pos = nn.Parameter(sinusoid_2d(grid, hidden))           # (1, N, hidden)
        self.inp = nn.Linear(slot_dim, hidden)
        out = patch * patch * 3 + 1                                   # pixels + alpha logit
        self.mlp = nn.Sequential(nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out))

    def forward(self, slots: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """slots (B, K, D) -> (mixed patches (B, N, p*p*3), alpha (B, K, N) summing to 1 over K)."""
        h = self.inp(slots)[:, :, None] + self.pos[:, None]          # (B, K, N, hidden)
        out = self.mlp(h)                                             # (B, K, N, p*p*3 + 1)
        alpha = torch.softmax(out[..., -1].float(), dim=1)            # over slots
        patches = (alpha[..., None] * out[..., :-1].float()).sum(1)   # (B, N, p*p*3)
        return patches, alpha
