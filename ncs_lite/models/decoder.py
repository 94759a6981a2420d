"""SLATE's autoregressive transformer decoder: predicts dVAE tokens from slots.

Token n is predicted from tokens < n (causal self-attention; the input is a BOS vector
followed by the embeddings of tokens 0..N-2) and from the slots (cross-attention: slots
are the keys and values). Because the decoder can only learn *where* and *what* from the
slots, slot attention is pushed to give each slot one object. Its blocks are the kit's one
transformer `Block` (transformer.py), with cross-attention to the slots.

Shapes: token embeddings (B, N, d); slots (B, K, D); logits (B, N, V).
"""
from __future__ import annotations

import torch
from torch import nn

from .transformer import Block

__all__ = ["TransformerDecoder"]


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
