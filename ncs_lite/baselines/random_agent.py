"""Random (Rand, Appendix B) and a calibration row beside it, `random-object`.

Rand samples the whole action Box, so most of its picks find no object; `RandomObjectAgent`
always picks one (reading the true positions, like the oracles) and drops it anywhere the
env can put it: the chance level of a policy that does move objects.
"""
from __future__ import annotations

import numpy as np

from ..utils import task_seed_of


class RandomAgent:
    """`env.action_space.sample()` every step: a uniform point of the Box (w, dw), each of its
    6 numbers uniform between the Box's bounds (block-rearrange: w over the grid, dw over
    twice its width; robogym-rearrange: w over the table, dw over twice its size).

    Most such actions reach nothing: w + dw leaves the grid or table on 3 draws in 4 (per
    axis, w + dw stays on it with probability 1/2), and w picks nothing unless it falls
    within the 5 cm pick threshold of an object."""

    def __init__(self, action_space, seed: int = 0):
        self.action_space, self.seed = action_space, int(seed)
        self.action_space.seed(self.seed)

    def reset(self, obs, info, seed: int | None = None) -> None:
        """A new task; with the task's env seed `seed`, draw anew from a seed of it and the
        agent's (`task_seed_of`), else go on drawing."""
        if seed is not None:
            self.action_space.seed(task_seed_of(self.seed, seed))

    def act(self, obs, info):
        return self.action_space.sample(), True


class RandomObjectAgent:
    """Calibration (not a method of the paper): each step, a uniformly random object, picked
    at its true position (`info["positions"]`: ground truth, like the oracles), dropped at
    a uniformly random place the env can reach: a grid cell (block-rearrange, `env.cells`)
    or a point of the table (robogym-rearrange, `config.table_x` x `config.table_y`). A drop
    onto an occupied cell or overlapping place is refused by the env, as any action's.

    The action is the envs' (w, dw): w = the object's (x, y) and its height clipped to the
    Box's z range (z is ignored by both envs), dw = (drop - w, 0). Every action counts as random (`act`'s second value)."""

    def __init__(self, env, seed: int = 0):
        cfg = env.config
        if hasattr(env, "cells"):                                 # block-rearrange: the grid
            self.cells = np.asarray(env.cells, np.float32)        # (C, 2)
            self.half = None
        elif hasattr(cfg, "table_x") and hasattr(cfg, "table_y"):  # robogym-rearrange: the table
            self.cells = None
            self.half = np.array([cfg.table_x / 2, cfg.table_y / 2], np.float32)
        else:
            raise ValueError(f"RandomObjectAgent needs a grid env (env.cells) or a table env (config.table_x, "
                             f"config.table_y), got a {type(env).__name__}")
        self.action_space, self.seed = env.action_space, int(seed)
        self.rng = np.random.default_rng(self.seed)

    def reset(self, obs, info, seed: int | None = None) -> None:
        """As `RandomAgent.reset`."""
        if seed is not None:
            self.rng = np.random.default_rng(task_seed_of(self.seed, seed))

    def drop(self) -> np.ndarray:
        """(2,) a uniformly random place: a cell's centre, or a point of the table."""
        if self.cells is not None:
            return self.cells[self.rng.integers(len(self.cells))]
        return self.rng.uniform(-self.half, self.half).astype(np.float32)

    def act(self, obs, info):
        positions = np.asarray(info["positions"], np.float32)    # (k, 3)
        w = positions[self.rng.integers(len(positions))]
        low, high = self.action_space.low, self.action_space.high
        wz = np.clip(w[2], low[2], high[2])
        dw = self.drop() - w[:2]
        # in the Box: w is on the grid or table, and so is the drop, so |dw| is at most its width
        return np.array([w[0], w[1], wz, dw[0], dw[1], 0.0], np.float32), True
