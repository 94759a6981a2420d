"""The type/state split of a slot (Section 4, Appendix A.1): [type z ; state s].

dSLATE's slots are vectors of `slot_dim = type_dim + state_dim` numbers (Table 2: 96 + 96);
the first `type_dim` are the entity's type z, which the dynamics carries unchanged (what the
entity is: align matches on it), the rest its state s, which actions change (where the entity
is: the graph's nodes are states). Every part of the kit that reads a type or a state takes
it from a slot with `split`.
"""
from __future__ import annotations

import torch


def split(slots: torch.Tensor, type_dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """slots (..., D) -> (types (..., type_dim), states (..., D - type_dim)), views of `slots`."""
    return slots[..., :type_dim], slots[..., type_dim:]


__all__ = ["split"]
