"""The baselines of Appendix B. All act through `reset(obs, info)` / `act(obs, info)`."""
from .random_agent import RandomAgent

__all__ = ["RandomAgent"]
