"""Acting with the graph (Appendix A.3): align, select-constraint, act along the edge.

Each step:
1. **align** goal entities to current entities by type: the Hungarian algorithm
   (`scipy.optimize.linear_sum_assignment`) on Euclidean distances between types z.
2. **select-constraint**: rank the aligned pairs by the isolate distance (cosine) between
   current and goal states and sample one from the categorical distribution proportional
   to those distances (the paper found sampling better than argmax).
3. bind both states to nodes and take the action on the edge between them; with no such
   edge take a random action.

One decision the paper leaves open: a pair whose current and goal states bind to the *same*
node counts as satisfied (its distance is set to 0 before sampling). The graph holds no
transition for it, so selecting it could only lead to a random action, and a random action
can undo a cube already in place. Learned masks are soft, so an object already at its goal
still has a small non-zero distance and was sampled again and again: before the rule, 104
of 362 decisions (30 tasks, 4 objects) picked a cube already in place and acted at random.
With ground-truth states (the oracle) same-node pairs are the satisfied ones.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from .graph import TransitionGraph


def align(current_types: torch.Tensor, goal_types: torch.Tensor):
    """Hungarian matching on type distances. Returns (goal index, current index) arrays."""
    cost = torch.cdist(goal_types.float(), current_types.float()).numpy()
    return linear_sum_assignment(cost)


def constraint_distances(current_states: torch.Tensor, goal_states: torch.Tensor) -> torch.Tensor:
    """Cosine distance between aligned current and goal states, (P,) >= 0."""
    cos = torch.nn.functional.cosine_similarity(current_states.float(), goal_states.float(), dim=-1, eps=1e-8)
    return (1 - cos).clamp(min=0)


class NCSAgent:
    """Neural Constraint Satisfaction on a transition graph, with a given perception."""

    def __init__(self, graph: TransitionGraph, perception, action_space, seed: int = 0):
        self.graph, self.perception, self.action_space = graph, perception, action_space
        self.rng = np.random.default_rng(seed)
        self.action_space.seed(int(seed))
        self._goal = None
        self.last = {}

    def reset(self, obs, info) -> None:
        self._goal = self.perception.goal(obs, info)   # the goal image is fixed per episode

    def act(self, obs, info) -> tuple[np.ndarray, bool]:
        """The next action and whether it was a random fallback."""
        cur = self.perception.current(obs, info)
        g_idx, c_idx = align(cur.types, self._goal.types)
        dist = constraint_distances(cur.states[c_idx], self._goal.states[g_idx]).numpy().astype(np.float64)
        src, dst = self.graph.bind(torch.stack([cur.states[c_idx], self._goal.states[g_idx]])).numpy()  # (P,) each
        dist[src == dst] = 0.0                    # same node: satisfied at the graph's resolution
        self.last = {"goal_index": g_idx, "current_index": c_idx, "distances": dist}
        if dist.sum() <= 0:
            return self._random("every constraint looks satisfied")
        pick = int(self.rng.choice(len(dist), p=dist / dist.sum()))
        self.last.update(selected=pick, src=int(src[pick]), dst=int(dst[pick]))
        action = self.graph.action(src[pick], dst[pick])
        if action is None:
            return self._random("no edge")
        return action, False

    def _random(self, why: str):
        self.last["fallback"] = why
        return self.action_space.sample(), True
