"""Model predictive control with CEM (MPC, Appendix B): plan through dSLATE's dynamics.

Every step:
1. read the current image's slots h = (z, s) with the same perception as NCS (slot
   states; restarts and iterations of `NCSConfig`); the goal image's slots h_g are read
   once, at reset;
2. align goal slots to current slots by type, as NCS does (`ncs.policy.align`): the
   dynamics copies z, so the alignment holds along every imagined rollout;
3. CEM (`cem.cem_minimize`) over action sequences (horizon H, 6 actions each, within the
   env's action Box): each candidate is rolled out through `DSlate.predict` from the
   current slots, and its cost is sum_k ||h_T^k - h_g^k||^2 over the aligned pairs (whole
   slots, as the appendix writes it; the z part is constant because z is copied);
4. act with the first action of the best sequence; keep the rest, shifted by one step, as
   the next step's first CEM mean (warm start, mbrl-lib's `keep_last_solution`).

Planning horizon (the appendix does not give one): H = 1 by default. In block-rearrange
(and robogym-rearrange) one pick-and-move places one object and objects do not interact,
so placing the object that lowers the cost most is also the first step of a shortest plan:
a longer horizon adds nothing a perfect model could use, while it multiplies the search
space (6H dimensions for the same 250 x 10 samples). `--set mpc.horizon=2` measures that.

The CEM settings are the appendix's (10 iterations, elite ratio 0.05, population 250) in
`reduced` and `paper`; `ci` shrinks them to run in seconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..config import ALIGN_RULES
from ..ncs.policy import align
from ..utils import task_seed_of
from .cem import CEMConfig, cem_minimize
from .goal_conditioned import preset_config


@dataclass
class MPCConfig(CEMConfig):
    horizon: int = 1             # actions per plan (see the module docstring)

    def validate(self) -> "MPCConfig":
        super().validate()
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"mpc.horizon must be an integer >= 1, got {self.horizon!r}")
        return self


MPC_PRESETS = {
    "ci": MPCConfig(iterations=2, population=16, elite_ratio=0.25),
    "reduced": MPCConfig(),
    "paper": MPCConfig(),
}


def mpc_config(preset: str = "reduced", **overrides) -> MPCConfig:
    """A fresh copy of a named preset, with field overrides."""
    return preset_config(MPC_PRESETS, preset, overrides, "MPC")


def slots_of(entities) -> torch.Tensor:
    """An `Entities` of slot states -> whole slots (K, Dz + Ds)."""
    return torch.cat([entities.types, entities.states], dim=-1).float()


@torch.no_grad()
def rollout_cost(model, slots: torch.Tensor, goal_slots: torch.Tensor, plans: torch.Tensor,
                 current_index, goal_index) -> torch.Tensor:
    """Costs (P,) of action sequences `plans` (P, H, A) from `slots` (K, D): roll out the
    dynamics H steps, then sum_k ||h_T^k - h_g^k||^2 over the aligned pairs."""
    h = slots[None].expand(plans.shape[0], -1, -1)
    for t in range(plans.shape[1]):
        h = model.predict(h, plans[:, t]).float()
    diff = h[:, torch.as_tensor(current_index)] - goal_slots[torch.as_tensor(goal_index)][None]
    return diff.square().sum((-1, -2))


class MPCAgent:
    """MPC with CEM through a dSLATE's dynamics, acting through `reset` / `act`.

    `perception` must read slot states (a `DSlatePerception(state="slot")`). `last` records
    the latest decision: the aligned indices, the plan, its cost and the cost of doing
    nothing (the current slots against the goal's, i.e. a plan the model says changes
    nothing)."""

    def __init__(self, model, perception, action_space, cfg: MPCConfig | None = None, seed: int = 0,
                 align: str = "near"):
        if align not in ALIGN_RULES:
            raise ValueError(f"align must be one of {', '.join(map(repr, ALIGN_RULES))}, got {align!r}")
        self.align = align             # the same pairs as NCS's (`ncs.align`)
        if getattr(perception, "graph_state", None) != "slot":
            raise ValueError("MPC plans on whole slots: its perception must read slot states "
                             f"(state='slot'), got {getattr(perception, 'graph_state', None)!r}")
        self.model, self.perception, self.cfg = model, perception, (cfg or MPCConfig()).validate()
        low, high = (torch.as_tensor(np.asarray(v, np.float32)) for v in (action_space.low, action_space.high))
        self.lower = low.expand(self.cfg.horizon, -1).clone()         # (H, A)
        self.upper = high.expand(self.cfg.horizon, -1).clone()
        self.seed = int(seed)
        self.generator = torch.Generator().manual_seed(self.seed)
        self._goal = self._plan = None
        self.last: dict = {}

    def reset(self, obs, info, seed: int | None = None) -> None:
        """A new task: read its goal; with the task's env seed `seed`, CEM samples anew from a
        seed of it and the agent's (`task_seed_of`)."""
        if seed is not None:
            self.generator.manual_seed(task_seed_of(self.seed, seed))
        self._goal = slots_of(self.perception.goal(obs, info))     # the goal image is fixed per episode
        self._plan = None
        self.last = {}

    def act(self, obs, info) -> tuple[np.ndarray, bool]:
        if self._goal is None:
            raise ValueError("call reset(obs, info) before act: MPC reads the goal's slots at reset")
        cur = self.perception.current(obs, info)
        slots = slots_of(cur)
        g_idx, c_idx, _ = align(cur.types, self._goal[:, :cur.types.shape[1]], self.align)
        initial = None
        if self._plan is not None:         # warm start: the rest of the last plan, then the middle
            initial = torch.cat([self._plan[1:], ((self.lower + self.upper) / 2)[:1]])

        def cost(plans):
            return rollout_cost(self.model, slots, self._goal, plans, c_idx, g_idx)

        plan, plan_cost = cem_minimize(cost, self.lower, self.upper, self.cfg, initial=initial,
                                       generator=self.generator)
        self._plan = plan
        still = float((slots[c_idx] - self._goal[g_idx]).square().sum())
        self.last = {"current": cur, "goal_index": g_idx, "current_index": c_idx, "plan": plan,
                     "cost": plan_cost, "no_change_cost": still}
        return plan[0].numpy().astype(np.float32), False


__all__ = ["MPCAgent", "MPCConfig", "MPC_PRESETS", "mpc_config", "rollout_cost", "slots_of"]
