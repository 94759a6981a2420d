"""SLATE's autoregressive transformer decoder: predicts dVAE tokens from slots.

Token n is predicted from tokens < n (causal self-attention; the input is a BOS vector
followed by the embeddings of tokens 0..N-2) and from the slots (cross-attention: slots
are the keys and values). Because the decoder can only learn *where* and *what* from the
slots, slot attention is pushed to give each slot one object. Attention is PyTorch's fused
`scaled_dot_product_attention`; every projection is one batched linear.

Shapes: token embeddings (B, N, d); slots (B, K, D); logits (B, N, V).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["TransformerDecoder", "MultiHeadAttention", "Block"]


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


class TransformerDecoder(nn.Module):
    """Autoregressive decoder over N tokens of a V-word vocabulary, conditioned on slots."""

    def __init__(self, vocab_size: int, num_tokens: int, slot_dim: int, dim: int, layers: int,
                 heads: int, dropout: float = 0.0):
        super().__init__()
        self.slot_proj = nn.Linear(slot_dim, dim, bias=False)
        self.bos = nn.Parameter(torch.zeros(1, 1, dim))
        self.drop = nn.Dropout(dropout)
        self.blocks = nn.ModuleList(Block(dim, heads, dropout, context_dim=dim) for _ in range(layers))
        self.norm = nn.LayerNorm(dim)
        self.head = nn.Linear(dim, vocab_size, bias=False)

    def forward(self, token_emb: torch.Tensor, slots: torch.Tensor) -> torch.Tensor:
        """token_emb (B, N, d) embeddings of the target tokens (with positions), slots (B, K, D)
        -> logits (B, N, V) where position n predicts token n from tokens < n."""
        B = token_emb.shape[0]
        x = torch.cat([self.bos.expand(B, -1, -1).to(token_emb.dtype), token_emb[:, :-1]], dim=1)
        x = self.drop(x)
        ctx = self.slot_proj(slots)
        for blk in self.blocks:
            x = blk(x, ctx, causal=True)
        return self.head(self.norm(x))
