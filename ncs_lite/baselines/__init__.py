"""The baselines of Appendix B. All act through `reset(obs, info)` / `act(obs, info)`.

- `RandomAgent` (Rand): `env.action_space.sample()`.
- `RandomObjectAgent` (`random-object`, a calibration row): a random object, at its true
  position, dropped at a random cell or point of the table (`random_agent.py`).
- `BCAgent` (BC): a goal-conditioned CNN policy trained with MSE on hindsight goals (`bc.py`).
- `IQLAgent` (IQL): implicit Q-learning, objectives (1)-(3) of Appendix B (`iql.py`).
- `NFAgent` (NF): Dijkstra over a graph of whole entity sets (`nf.py`).
- `MPCAgent` (MPC): CEM (`cem.py`) over rollouts of dSLATE's dynamics (`mpc.py`).
"""
from .bc import BC_PRESETS, BCAgent, BCConfig, BCPolicy, bc_config, bc_mse, load_bc, mean_action_mse, save_bc, train_bc
from .iql import (IQL_PRESETS, IQLAgent, IQLConfig, IQLNetworks, advantage_weights, expectile_loss, iql_config,
                  iql_losses, load_iql, polyak_update, save_iql, train_iql)
from .cem import CEMConfig, cem_minimize
from .mpc import MPC_PRESETS, MPCAgent, MPCConfig, mpc_config, rollout_cost
from .nf import FALLBACKS, NFAgent, SetGraph, build_set_graph, set_graph_from_buffer, set_graph_from_transitions
from .random_agent import RandomAgent, RandomObjectAgent

__all__ = ["CEMConfig", "MPCAgent", "MPCConfig", "MPC_PRESETS", "cem_minimize", "mpc_config", "rollout_cost",
           "BCAgent", "BCConfig", "BCPolicy", "BC_PRESETS", "FALLBACKS", "IQLAgent", "IQLConfig", "IQLNetworks",
           "IQL_PRESETS", "NFAgent", "RandomAgent", "RandomObjectAgent", "SetGraph", "advantage_weights", "bc_config",
           "bc_mse", "build_set_graph", "expectile_loss", "iql_config", "iql_losses", "load_bc", "load_iql",
           "mean_action_mse", "polyak_update", "save_bc", "save_iql", "set_graph_from_buffer",
           "set_graph_from_transitions", "train_bc", "train_iql"]
