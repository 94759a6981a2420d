"""Transformer dynamics of dSLATE: next slot states from the current slots and an action.

The K slots and one action token form a set of K + 1 tokens; a (non-causal, position-free)
transformer lets every slot read the action and the other slots, then a linear head gives
each slot's state *change*. The type part z of each slot is copied unchanged
(z_{t+1} = z_t), so the type is action-invariant by construction and a slot keeps its
identity through a predicted rollout. Without positional encodings over slots, permuting
the slots permutes the predictions.

Shapes: slots (B, K, D) with D = Dz + Ds; actions (B, A); next slots (B, K, D).
Leading dimensions may also be (B, T): slots (B, T, K, D), actions (B, T, A).
"""
from __future__ import annotations

import torch
from torch import nn

from .split import split
from .transformer import Block

__all__ = ["Dynamics"]


class Dynamics(nn.Module):
    def __init__(self, type_dim: int, state_dim: int, action_dim: int, hidden: int, layers: int,
                 heads: int, dropout: float = 0.0):
        super().__init__()
        self.type_dim, self.state_dim = type_dim, state_dim
        self.slot_in = nn.Linear(type_dim + state_dim, hidden)
        self.action_in = nn.Linear(action_dim, hidden)
        self.blocks = nn.ModuleList(Block(hidden, heads, dropout) for _ in range(layers))
        self.norm = nn.LayerNorm(hidden)
        self.head = nn.Linear(hidden, state_dim)
        nn.init.zeros_(self.head.weight)   # start as the identity map: s_{t+1} = s_t
        nn.init.zeros_(self.head.bias)

    def forward(self, slots: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        lead = slots.shape[:-2]
        K, D = slots.shape[-2:]
        s = slots.reshape(-1, K, D)                                   # (B', K, D)
        a = actions.reshape(-1, 1, actions.shape[-1])                 # (B', 1, A)
        x = torch.cat([self.slot_in(s), self.action_in(a.to(s.dtype))], dim=1)   # (B', K+1, h)
        for blk in self.blocks:
            x = blk(x)
        delta = self.head(self.norm(x[:, :K]))                        # (B', K, Ds)
        types, states = split(s, self.type_dim)                       # the type is carried unchanged
        return torch.cat([types, states + delta.to(s.dtype)], dim=-1).reshape(*lead, K, D)
