"""The environments of Appendix C, as gymnasium Envs registered under `ncs_lite/...-v0`.

    env = ncs_lite.envs.make("block-rearrange", num_objects=4, goal="complete")
    env = gymnasium.make("ncs_lite/BlockRearrange-v0", num_objects=4)
    env = ncs_lite.envs.make("robogym-rearrange", num_objects=4)   # MuJoCo, imported on first use
"""
from __future__ import annotations

import gymnasium as gym

from .block_rearrange import PALETTE, BlockRearrange, BlockRearrangeConfig

# name used by the CLI and `make` -> (gymnasium id, entry point)
ENVIRONMENTS = {
    "block-rearrange": ("ncs_lite/BlockRearrange-v0", "ncs_lite.envs.block_rearrange:BlockRearrange"),
    "robogym-rearrange": ("ncs_lite/RobogymRearrange-v0", "ncs_lite.envs.robogym_rearrange:RobogymRearrange"),
}

for _env_id, _entry in ENVIRONMENTS.values():
    if _env_id not in gym.registry:
        gym.register(id=_env_id, entry_point=_entry)


def make(name: str, **kwargs) -> gym.Env:
    """Build an environment by its short name (the unwrapped env, no time-limit wrapper:
    each env truncates at its own horizon = horizon_multiplier x minimum steps)."""
    if name not in ENVIRONMENTS:
        raise ValueError(f"unknown environment {name!r}; expected one of {sorted(ENVIRONMENTS)}")
    _, entry = ENVIRONMENTS[name]
    module, cls = entry.split(":")
    import importlib

    return getattr(importlib.import_module(module), cls)(**kwargs)


__all__ = ["ENVIRONMENTS", "PALETTE", "BlockRearrange", "BlockRearrangeConfig", "make"]
