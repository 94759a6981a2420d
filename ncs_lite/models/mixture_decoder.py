"""Auxiliary mixture decoder: each slot paints its own image, an alpha mask picks the pixels.

Not in the NCS paper (its weight is 0 in the `paper` preset); the `reduced` preset uses it
to give slot attention an object bias it cannot get fast enough from SLATE's decoder on a
CPU budget. The autoregressive decoder can rebuild a whole scene from any grouping of
the tokens, so nothing makes one slot hold one cube. Here, as in the original slot
attention autoencoder (Locatello et al., 2020) and DINOSAUR's MLP decoder (Seitzer et al.,
2023), every slot is decoded *independently* into an image patch per grid position; the
slots' patches are mixed with weights that sum to one over slots. A slot can only explain
pixels it paints itself, so the cheapest way to reconstruct four cubes is one slot per cube.

Where the mixing weights (alpha) come from:
* "decoder": each slot also paints an alpha logit, softmax over slots (Locatello et al.);
* "attention": alpha is slot attention's own mask. The reconstruction error then reaches
  the attention logits directly: a pixel that a slot cannot paint pushes the pixel toward
  another slot, soft k-means with learned colours, which breaks the "every slot paints the
  floor" plateau sooner than "decoder" (why: docs/recipe.md, `mixture.alpha`).
  The decoder must then work on slot attention's grid (patch = image size / grid).

What a slot paints (appearance):
* "slot": the whole slot and the position, an MLP at every grid position (Locatello et al.);
* "type": the type half z alone, one patch repeated at every position: a slot paints one
  look wherever it is (not in any paper; `reduced`). A decoder that knows where it paints
  can give the floor's slot a cube of the floor's colour at the cube's place, and the
  floor's slot then keeps that cube at no cost (the absorbed cubes of notebook 03); one
  that does not know pays for every pixel of another colour, so the attention gradient
  moves the cube to a slot of its own. It also leaves position out of z: z only has to say
  what the object looks like (why: docs/recipe.md, `mixture.appearance`). Needs alpha
  "attention" (nothing else says where).

It costs a small MLP over K x N positions ("slot") or K ("type"). Shapes: slots (B, K, D)
[, attention (B, K, N)] -> patches (B, N, p*p*3), alpha (B, K, N) summing to 1 over K.
"""
from __future__ import annotations

import torch
from torch import nn

from ..config import MIXTURE_ALPHAS, MIXTURE_APPEARANCES
from .positional import sinusoid_2d
from .split import split

__all__ = ["MixtureDecoder"]


class MixtureDecoder(nn.Module):
    def __init__(self, slot_dim: int, grid: int, patch: int, hidden: int, alpha: str = "decoder",
                 appearance: str = "slot", type_dim: int | None = None):
        super().__init__()
        if alpha not in MIXTURE_ALPHAS:
            raise ValueError(f"alpha must be one of {MIXTURE_ALPHAS}, got {alpha!r}")
        if appearance not in MIXTURE_APPEARANCES:
            raise ValueError(f"appearance must be one of {MIXTURE_APPEARANCES}, got {appearance!r}")
        if appearance == "type" and (alpha != "attention" or not type_dim):
            raise ValueError("appearance 'type' paints without a position: it needs alpha "
                             f"'attention' and a type_dim, got {alpha!r} and {type_dim!r}")
        self.alpha, self.grid, self.appearance, self.type_dim = alpha, grid, appearance, type_dim
        self.pos = nn.Parameter(sinusoid_2d(grid, hidden)) if appearance == "slot" else None
        self.inp = nn.Linear(type_dim if appearance == "type" else slot_dim, hidden)
        out = patch * patch * 3 + (alpha == "decoder")                # pixels [+ alpha logit]
        # one hidden layer: it runs at K x N positions, the largest activations of the step
        self.mlp = nn.Sequential(nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out))

    def paint(self, slots: torch.Tensor, attention: torch.Tensor | None = None
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """What each slot paints, before mixing: slots (B, K, D) [, attention (B, K, N) for
        alpha "attention"] -> (patches (B, K, N, p*p*3), or (B, K, 1, p*p*3) for "type": one
        look everywhere; alpha (B, K, N) summing to 1 over K)."""
        K, N = slots.shape[1], self.grid ** 2
        if self.alpha == "attention" and (attention is None or attention.shape[1:] != (K, N)):
            got = None if attention is None else tuple(attention.shape)
            raise ValueError(f"alpha 'attention' needs attention of shape (B, {K}, {N}), got {got}")
        if self.appearance == "type":                                 # one look per slot
            look = self.mlp(self.inp(split(slots, self.type_dim)[0])).float()   # (B, K, p*p*3)
            return look[:, :, None], attention.float()
        h = self.inp(slots)[:, :, None] + self.pos[:, None]          # (B, K, N, hidden)
        out = self.mlp(h).float()                                     # (B, K, N, p*p*3 [+ 1])
        if self.alpha == "decoder":
            return out[..., :-1], torch.softmax(out[..., -1], dim=1)
        return out, attention.float()

    def forward(self, slots: torch.Tensor, attention: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """slots (B, K, D) [, attention (B, K, N) for alpha "attention"] -> (mixed patches
        (B, N, p*p*3), alpha (B, K, N) summing to 1 over K)."""
        patches, alpha = self.paint(slots, attention)
        if self.appearance == "type":
            return torch.einsum("bkn,bkc->bnc", alpha, patches[:, :, 0]), alpha
        return (alpha[..., None] * patches).sum(1), alpha
