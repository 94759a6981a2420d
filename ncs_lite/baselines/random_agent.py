"""Random (Rand, Appendix B): `env.action_space.sample()` every step."""
from __future__ import annotations


class RandomAgent:
    def __init__(self, action_space, seed: int = 0):
        self.action_space = action_space
        self.action_space.seed(int(seed))

    def reset(self, obs, info) -> None:
        pass

    def act(self, obs, info):
        return self.action_space.sample(), True
