"""The environments of Appendix C, as gymnasium Envs registered under `ncs_lite/...-v0`.

    env = ncs_lite.envs.make("block-rearrange", num_objects=4, goal="complete")
    env = gymnasium.make("ncs_lite/BlockRearrange-v0", num_objects=4)
    env = ncs_lite.envs.make("robogym-rearrange", num_objects=4)   # MuJoCo, imported on first use
    env = ncs_lite.envs.make("block-stacking", num_objects=4)      # towers as goals
"""
from __future__ import annotations

import importlib

import gymnasium as gym
import numpy as np

from .block_rearrange import COLOR_NAMES, PALETTE, BlockRearrange, BlockRearrangeConfig
from .objects import COLOUR_NAMES, COLOURS

# name used by the CLI and `make` -> (gymnasium id, entry point)
ENVIRONMENTS = {
    "block-rearrange": ("ncs_lite/BlockRearrange-v0", "ncs_lite.envs.block_rearrange:BlockRearrange"),
    "robogym-rearrange": ("ncs_lite/RobogymRearrange-v0", "ncs_lite.envs.robogym_rearrange:RobogymRearrange"),
    "block-stacking": ("ncs_lite/BlockStacking-v0", "ncs_lite.envs.block_stacking:BlockStacking"),
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
    # local: each env's module is imported on first use (robogym-rearrange's loads MuJoCo)
    return getattr(importlib.import_module(module), cls)(**kwargs)


def env_name(env: gym.Env) -> str | None:
    """The short name (`make`'s) of an environment instance; None for an env of no such name."""
    cls = type(getattr(env, "unwrapped", env)).__name__
    return next((name for name, (_, entry) in ENVIRONMENTS.items() if entry.endswith(f":{cls}")), None)


# each env's object colours: (names, RGB (n, 3) in [0, 1]); robogym-rearrange's come from
# envs.objects, which needs no MuJoCo, so figures can name them without making the env
PALETTES = {"block-rearrange": (COLOR_NAMES, PALETTE), "robogym-rearrange": (COLOUR_NAMES, COLOURS),
            "block-stacking": (COLOR_NAMES, PALETTE)}


def palette(name: str) -> tuple[tuple[str, ...], np.ndarray]:
    """The colours objects of env `name` take: (names, RGB (n, 3) in [0, 1])."""
    if name not in PALETTES:
        raise ValueError(f"unknown environment {name!r}; expected one of {sorted(PALETTES)}")
    return PALETTES[name]


def colour_names(name: str, colors) -> list[str]:
    """Names of the objects' colours (k, 3) (`info["colors"]`, `buffer["colors"][e]`) in env
    `name`'s palette, nearest colour first (for figure titles and captions)."""
    names, rgb = palette(name)
    colors = np.asarray(colors, np.float64)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f"colors must have shape (k, 3), got {colors.shape}")
    return [names[i] for i in np.abs(rgb[None] - colors[:, None]).sum(-1).argmin(1)]


__all__ = ["ENVIRONMENTS", "PALETTE", "PALETTES", "BlockRearrange", "BlockRearrangeConfig", "colour_names",
           "make", "palette"]
