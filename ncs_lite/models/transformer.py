"""The kit's one transformer block, shared by SLATE's decoder (decoder.py: causal self-attention
and cross-attention to the slots) and the dynamics (dynamics.py: self-attention over the slots
and the action token). Attention is PyTorch's fused `scaled_dot_product_attention`; every
projection is one batched linear.

Shapes: x (B, N, D) tokens; context (B, M, C) what cross-attention reads (the slots).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["Block", "MultiHeadAttention"]


class MultiHeadAttention(nn.Module):
    """Multi-head attention through `F.scaled_dot_product_attention` (fused kernels)."""

    def __init__(self, dim: int, heads: int, dropout: float = 0.0, kv_dim: int | None = None):
        super().__init__()
        self.heads = heads
        self.self_attn = kv_dim is None
        if self.self_attn:
            self.qkv = nn.Linear(dim, 3 * dim, bias=False)
        else:
            self.q = nn.Linear(dim, dim, bias=False)
            self.kv = nn.Linear(kv_dim, 2 * dim, bias=False)
        self.out = nn.Linear(dim, dim, bias=False)
        self.out_drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, context: torch.Tensor | None = None,
                causal: bool = False) -> torch.Tensor:
        B, N, D = x.shape
        H = self.heads
        if self.self_attn:
            q, k, v = self.qkv(x).reshape(B, N, 3, H, D // H).permute(2, 0, 3, 1, 4)  # 3 x (B, H, N, Dh)
        else:
            M = context.shape[1]
            q = self.q(x).reshape(B, N, H, D // H).transpose(1, 2)                   # (B, H, N, Dh)
            k, v = self.kv(context).reshape(B, M, 2, H, D // H).permute(2, 0, 3, 1, 4)  # 2 x (B, H, M, Dh)
        # Dropout is applied to the residual branches, not to the attention weights: a non-zero
        # dropout_p makes PyTorch leave the fused (flash) CPU kernel for the slow math path.
        y = F.scaled_dot_product_attention(q, k, v, is_causal=causal)
        return self.out_drop(self.out(y.transpose(1, 2).reshape(B, N, D)))


class Block(nn.Module):
    """Pre-norm transformer block: [causal] self-attention, optional cross-attention, MLP."""

    def __init__(self, dim: int, heads: int, dropout: float = 0.0, context_dim: int | None = None):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = MultiHeadAttention(dim, heads, dropout)
        self.cross = None
        if context_dim is not None:
            self.norm2 = nn.LayerNorm(dim)
            self.cross = MultiHeadAttention(dim, heads, dropout, kv_dim=context_dim)
        self.norm3 = nn.LayerNorm(dim)
        self.mlp = nn.Sequential(nn.Linear(dim, 4 * dim), nn.GELU(), nn.Linear(4 * dim, dim),
                                 nn.Dropout(dropout))

    def forward(self, x, context=None, causal=False):
        x = x + self.attn(self.norm1(x), causal=causal)
        if self.cross is not None:
            x = x + self.cross(self.norm2(x), context)
        return x + self.mlp(self.norm3(x))
