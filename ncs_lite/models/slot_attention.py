"""Slot attention (Locatello et al., 2020) with a learned Gaussian initialisation.

K slots compete for N input features: the softmax is over *slots*, so each input is
shared out among them, and each slot takes the attention-weighted mean of the values.
A GRU folds that update into the slot, then a residual MLP refines it. The returned
attention (B, K, N) sums to one over K at every input: it is the segmentation mask.

Initial slots are drawn as mu + exp(log_sigma) * eps with eps ~ N(0, I) (the
reparameterisation trick), so both mu and log_sigma receive gradients. For video, pass
`init_slots` (the previous frame's slots) to continue tracking instead of resampling.
Nothing in the update depends on the slot index, so permuting the initial slots permutes
the outputs in the same way (slot-permutation equivariance), and any K works at inference.

With `implicit`, the iterations before the last run without gradient and the last starts
from their detached slots, so only one step is differentiated: the first-order form of
implicit differentiation through slot attention's fixed point (Chang, Griffiths and Levine,
"Object Representations as Fixed Points", NeurIPS 2022), which keeps training from
following the unrolled iterations' unstable gradients. The slots and attention it returns
are the same numbers as without it; the initial Gaussian then gets no gradient.

`farthest_point_slots` reads initial slots from the scene instead of sampling them, so that
one pass of slot attention starts from distinct regions (DSlate.infer, `slot_init`).

Shapes: inputs (B, N, Din); slots (B, K, D); attention (B, K, N).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["SlotAttention"]


class SlotAttention(nn.Module):
    def __init__(self, input_dim: int, slot_dim: int, num_slots: int, iterations: int = 3,
                 heads: int = 1, mlp_hidden: int | None = None, eps: float = 1e-8,
                 implicit: bool = False):
        super().__init__()
        self.implicit = implicit
        if slot_dim % heads:
            raise ValueError(f"slot_dim {slot_dim} must be divisible by heads {heads}")
        self.slot_dim, self.num_slots, self.iterations, self.heads, self.eps = (
            slot_dim, num_slots, iterations, heads, eps)
        self.mu = nn.Parameter(torch.randn(1, 1, slot_dim) * slot_dim ** -0.5)
        # sigma starts at 1 (the paper is silent): slots drawn far apart break the symmetry
        # between them sooner (the run: docs/HISTORY.md, "Moved from the docstrings")
        self.log_sigma = nn.Parameter(torch.zeros(1, 1, slot_dim))
        self.norm_inputs = nn.LayerNorm(input_dim)
        self.to_kv = nn.Linear(input_dim, 2 * slot_dim, bias=False)   # one big matmul for k and v
        self.norm_slots = nn.LayerNorm(slot_dim)
        self.to_q = nn.Linear(slot_dim, slot_dim, bias=False)
        self.gru = nn.GRUCell(slot_dim, slot_dim)
        mlp_hidden = mlp_hidden or slot_dim
        self.mlp = nn.Sequential(nn.LayerNorm(slot_dim), nn.Linear(slot_dim, mlp_hidden), nn.ReLU(),
                                 nn.Linear(mlp_hidden, slot_dim))

    def initial_slots(self, batch: int, num_slots: int | None = None,
                      generator: torch.Generator | None = None) -> torch.Tensor:
        """Sample (B, K, D) slots from the learned Gaussian N(mu, exp(log_sigma)^2)."""
        k = num_slots or self.num_slots
        eps = torch.randn(batch, k, self.slot_dim, generator=generator, device=self.mu.device,
                          dtype=self.mu.dtype)
        return self.mu + self.log_sigma.exp() * eps

    @torch.no_grad()
    def farthest_point_slots(self, inputs: torch.Tensor, num_slots: int | None = None) -> torch.Tensor:
        """Initial slots (B, K, D) read from the inputs (B, N, Din) instead of drawn.

        K seeds by farthest-point sampling on the values: the first the value farthest from
        their mean, each next the value farthest from every seed so far. Each input goes to
        its nearest seed, and each slot takes one update from the learned mean `mu`, with that
        hard partition in place of the softmax. Slot attention is a soft k-means, and as
        k-means++ seeds k-means this starts it from K distinct parts of the scene rather than
        K random draws that can settle on one object together. Deterministic; it reads the
        image only and trains nothing."""
        B = inputs.shape[0]
        K = num_slots or self.num_slots
        _, v = self.to_kv(self.norm_inputs(inputs)).chunk(2, dim=-1)          # (B, N, D)
        rows = torch.arange(B, device=v.device)
        far = (v - v.mean(1, keepdim=True)).pow(2).sum(-1)                     # (B, N)
        to_seeds = []                                                          # K x (B, N)
        for k in range(K):
            seed = v[rows, far.argmax(1)]                                      # (B, D)
            to_seeds.append((v - seed[:, None]).pow(2).sum(-1))
            far = to_seeds[-1] if k == 0 else torch.minimum(far, to_seeds[-1])
        part = F.one_hot(torch.stack(to_seeds, -1).argmin(-1), K).transpose(1, 2).to(v.dtype)  # (B, K, N)
        updates = part @ v / part.sum(-1, keepdim=True).clamp(min=1)          # (B, K, D)
        new = self.gru(updates.reshape(B * K, -1), self.mu.reshape(1, -1).expand(B * K, -1)).reshape(B, K, -1)
        return new + self.mlp(new)

    def forward(self, inputs: torch.Tensor, init_slots: torch.Tensor | None = None,
                iterations: int | None = None, num_slots: int | None = None,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """inputs (B, N, Din) -> (slots (B, K, D), attention (B, K, N) summing to 1 over K)."""
        B, N, _ = inputs.shape
        H, Dh = self.heads, self.slot_dim // self.heads
        slots = init_slots if init_slots is not None else self.initial_slots(B, num_slots, generator)
        k, v = self.to_kv(self.norm_inputs(inputs)).chunk(2, dim=-1)
        k = k.reshape(B, N, H, Dh).transpose(1, 2) * Dh ** -0.5     # (B, H, N, Dh)
        v = v.reshape(B, N, H, Dh).transpose(1, 2)                  # (B, H, N, Dh)
        steps = iterations or self.iterations
        if self.implicit and steps > 1:
            with torch.no_grad():
                for _ in range(steps - 1):
                    slots, _ = self._update(slots, k, v)
            slots, steps = slots.detach(), 1
        for _ in range(steps):
            slots, attn = self._update(slots, k, v)
        return slots, attn.mean(dim=1)                              # (B, K, D), (B, K, N)

    def _update(self, slots: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One iteration: slots (B, K, D), keys and values (B, H, N, Dh) -> (new slots,
        per-head attention (B, H, K, N) summing to 1 over K)."""
        B, K, _ = slots.shape
        H, Dh = self.heads, self.slot_dim // self.heads
        q = self.to_q(self.norm_slots(slots)).reshape(B, K, H, Dh).transpose(1, 2)  # (B, H, K, Dh)
        logits = q @ k.transpose(-1, -2)                            # (B, H, K, N)
        attn = torch.softmax(logits.float(), dim=2)                 # over slots
        w = attn / (attn.sum(dim=-1, keepdim=True) + self.eps)      # weighted mean over inputs
        updates = (w.to(v.dtype) @ v).transpose(1, 2).reshape(B, K, self.slot_dim)
        new = self.gru(updates.reshape(B * K, -1).to(slots.dtype),
                       slots.reshape(B * K, -1)).reshape(B, K, -1)
        return new + self.mlp(new), attn
