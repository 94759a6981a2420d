"""Discrete VAE (Ramesh et al., 2021) as used by SLATE: image -> grid of discrete tokens.

The encoder maps each `downsample x downsample` patch to logits over a vocabulary of V
codes (like SLATE's 4x4-stride-4 conv followed by 1x1 convs); a relaxed one-hot sample
(gumbel-softmax with temperature tau) is decoded back to pixels. Everything but one 3x3
convolution in the decoder is a per-token linear map on a channels-last tensor, so the
work is a few large matmuls (fast on CPUs with AMX and on GPUs).

Shapes: images (B, H, W, 3) float in [0, 1]; tokens on a G x G grid, N = G^2;
logits (B, N, V); soft codes (B, N, V); token ids (B, N) int64.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["DVAE", "cosine_anneal", "tau_schedule"]


def cosine_anneal(step: int, start: float, end: float, steps: int) -> float:
    """Half-cosine from `start` (step 0) to `end` (step >= `steps`), as in SLATE."""
    if steps <= 0 or step >= steps:
        return float(end)
    if step <= 0:
        return float(start)
    return float(end + 0.5 * (start - end) * (1.0 + math.cos(math.pi * step / steps)))


def tau_schedule(step: int, cfg) -> float:
    """Gumbel-softmax temperature at optimizer step `step` for a `DVAEConfig`."""
    return cosine_anneal(step, cfg.tau_start, cfg.tau_end, cfg.tau_steps)


def patchify(x: torch.Tensor, p: int) -> torch.Tensor:
    """(B, H, W, C) -> (B, H/p * W/p, p*p*C): non-overlapping p x p patches, row-major."""
    B, H, W, C = x.shape
    x = x.reshape(B, H // p, p, W // p, p, C).permute(0, 1, 3, 2, 4, 5)
    return x.reshape(B, (H // p) * (W // p), p * p * C)


def unpatchify(x: torch.Tensor, p: int, g: int) -> torch.Tensor:
    """(B, g*g, p*p*C) -> (B, g*p, g*p, C); inverse of `patchify`."""
    B, N, PC = x.shape
    C = PC // (p * p)
    x = x.reshape(B, g, g, p, p, C).permute(0, 1, 3, 2, 4, 5)
    return x.reshape(B, g * p, g * p, C)


class DVAE(nn.Module):
    def __init__(self, vocab_size: int, hidden: int = 64, downsample: int = 4, image_size: int = 64):
        super().__init__()
        self.vocab_size, self.p, self.grid = vocab_size, downsample, image_size // downsample
        patch = downsample * downsample * 3
        # encoder: per-patch MLP (= 4x4/stride-4 conv + 1x1 convs)
        self.encoder = nn.Sequential(
            nn.Linear(patch, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, vocab_size),
        )
        # decoder: code embedding, one 3x3 conv for neighbourhood context, per-patch MLP to pixels
        self.dec_in = nn.Linear(vocab_size, hidden)
        self.dec_conv = nn.Conv2d(hidden, hidden, 3, padding=1)
        self.dec_out = nn.Sequential(
            nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, patch),
        )

    def encode(self, images: torch.Tensor) -> torch.Tensor:
        """images (B, H, W, 3) in [0, 1] -> log-probabilities over codes (B, N, V)."""
        return F.log_softmax(self.logits(images), dim=-1)

    def logits(self, images: torch.Tensor) -> torch.Tensor:
        """images (B, H, W, 3) in [0, 1] -> unnormalised code logits (B, N, V); training feeds
        these to `sample` directly (the log-softmax of `encode` would only shift each row)."""
        return self.encoder(patchify(images, self.p))

    def sample(self, logits: torch.Tensor, tau: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Gumbel-softmax: (soft codes (B, N, V), sampled token ids (B, N)).

        `logits` may be unnormalised (or the log-probabilities of `encode`): softmax ignores
        a per-row shift. The ids are the argmax of the same perturbed logits as the soft codes:
        a sampled (not argmax-of-logits) hard target, which SLATE feeds detached to the
        transformer. Gumbel noise is -log(E) with E ~ Exp(1): one random pass and one log
        over the (B, N, V) tensor, the largest in a paper-width step.
        """
        g = torch.empty_like(logits, dtype=torch.float32).exponential_().log_().neg_()
        y = (logits.float() + g).div_(tau)
        soft = torch.softmax(y, dim=-1)
        return soft, y.argmax(dim=-1).detach()

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """codes (B, N, V) soft or one-hot -> images (B, H, W, 3) (unclamped, ~[0, 1])."""
        B, N, _ = codes.shape
        h = self.dec_in(codes)                                      # (B, N, C)
        h = h.transpose(1, 2).reshape(B, -1, self.grid, self.grid)  # (B, C, G, G)
        h = self.dec_conv(h).flatten(2).transpose(1, 2)             # (B, N, C)
        return unpatchify(self.dec_out(h), self.p, self.grid)

    def decode_ids(self, ids: torch.Tensor) -> torch.Tensor:
        """token ids (B, N) -> images (B, H, W, 3)."""
        return self.decode(F.one_hot(ids, self.vocab_size).to(self.dec_in.weight.dtype))

    def tokenize(self, images: torch.Tensor) -> torch.Tensor:
        """Deterministic tokens for inference: argmax code per patch, (B, N) int64."""
        return self.logits(images).argmax(dim=-1)
