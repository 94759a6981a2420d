"""Acting with the graph (Appendix A.3): align, select-constraint, act along the edge.

Each step of `NCSAgent.act` is a function of this module:
1. **align** (`align`) goal entities to current entities by type: the Hungarian algorithm
   (`scipy.optimize.linear_sum_assignment`) on Euclidean distances between types z.
2. **select-constraint** (`select_constraint`): rank the aligned pairs by the isolate
   distance (cosine, Table 3, for mask and slot states alike: `graph.isolate_distance`)
   between current and goal states, bind both states to nodes (`TransitionGraph.bind`, the
   graph's bind metric: cosine for mask graphs, squared Euclidean for slot graphs) and sample
   one pair from the categorical distribution proportional to those distances (the paper
   found sampling better than argmax).
3. take the action on the edge between the selected pair's two nodes; with no such edge take
   a random action.

Two decisions the paper leaves open. **Entities without a counterpart** (`NCSConfig.align`):
a partial goal's image shows only the constrained cubes, so the Hungarian matching (the
paper's; `align = "hungarian"`) pairs every unconstrained cube with a leftover goal slot (the
floor, or a spare slot), and select-constraint then moves cubes that no constraint names.
"either" keeps a pair only when one of its two entities is the other's nearest type and
"mutual" when both are; neither is enough: an unconstrained cube's nearest goal type is
often a spare goal slot holding a fragment of a constrained cube, so the cube is moved into
that cube's goal cell, where it blocks the goal, and the agent repeats the blocked move to
the horizon (what traces of failed partial-goal tasks at 4 objects showed). The kit's
default, "near", keeps a pair when its type distance is at most `NEAR_RATIO` (a quarter) of
the median of align's cost matrix, which is a distance between two different entities (most
of the G x C pairs are): types are nearly invariant (notebook 04: an object's z moves about
0.02x the distance between two objects'), so one entity's two types lie far below that.
The runs that chose "near": docs/HISTORY.md, "ncs.align on block-rearrange".
MPC's cost sums over the same pairs.

Second: a pair whose current and goal states bind to the *same*
node counts as satisfied (its distance is set to 0 before sampling). The graph holds no
transition for it, so selecting it could only lead to a random action, and a random action
can undo a cube already in place. Learned masks are soft, so an object already at its goal
still has a small non-zero distance and, without the rule, is sampled again and again
(docs/HISTORY.md). With ground-truth states (the oracle) same-node pairs are the
satisfied ones. `NCSAgent.last["same_node"]` records the rule's result at every decision.

With edge actions read from the transitions' states ("nearest", "compose", "readout":
continuous positions, robogym-rearrange; see `ncs.graph`) a node is wider than the goal
threshold, so the same-node rule does not apply: every pair keeps its distance, a same-node
pair acts along the node's self-loop, and the action is realised from the pair's two states.
When the agent selects the same pair on the same edge again as at its previous decision (a
missed pick, a blocked place, or a move that stayed in the node), it retries with the next
nearest transition(s) (`rank`).

`NCSAgent.last` records every quantity of the latest decision (see `NCSAgent.act`), so a
figure draws what the agent computed instead of computing it again.
"""
from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from ..config import ALIGN_RULES, NCSConfig
from ..utils import task_seed_of
from .dependencies import RULES, select_dependent
from .graph import EXAMPLE_ACTIONS, TransitionGraph, isolate_distance


def type_distances(current_types: torch.Tensor, goal_types: torch.Tensor) -> torch.Tensor:
    """Euclidean distances between goal and current types, (G, C): align's cost matrix."""
    return torch.cdist(goal_types.float(), current_types.float())


# rule "near": a pair is one entity when its types lie closer than this fraction of the scene's
# median type distance (that of two different entities: most of the G x C pairs are)
NEAR_RATIO = 0.25


class Alignment(NamedTuple):
    """What `align` returns: pair j is goal entity goal_index[j] with current entity
    current_index[j], (P,) int arrays each; type_distances (G, C) is the cost it matched on."""
    goal_index: np.ndarray
    current_index: np.ndarray
    type_distances: torch.Tensor


def align(current_types: torch.Tensor, goal_types: torch.Tensor, rule: str = "hungarian") -> Alignment:
    """Pair goal entities (G, Dz) with current entities (C, Dz) by their types: the Hungarian
    matching (`scipy.optimize.linear_sum_assignment`) on `type_distances`. With rule "mutual",
    only the pairs whose two entities are each other's nearest type are kept; with "either",
    those in which at least one entity is the other's nearest type; with "near", those whose
    type distance is below NEAR_RATIO x the median of the cost matrix (module docstring)."""
    if rule not in ALIGN_RULES:
        raise ValueError(f"align rule must be one of {', '.join(map(repr, ALIGN_RULES))}, got {rule!r}")
    distances = type_distances(current_types, goal_types)
    cost = distances.numpy()
    g, c = linear_sum_assignment(cost)
    if rule == "near":
        keep = cost[g, c] <= NEAR_RATIO * np.median(cost)     # <=: identical types stay paired
        g, c = g[keep], c[keep]
    elif rule != "hungarian":
        goal_nearest, current_nearest = cost.argmin(1)[g] == c, cost.argmin(0)[c] == g
        keep = goal_nearest & current_nearest if rule == "mutual" else goal_nearest | current_nearest
        g, c = g[keep], c[keep]
    return Alignment(g, c, distances)


def constraint_distances(current_states: torch.Tensor, goal_states: torch.Tensor) -> torch.Tensor:
    """The isolate distance (cosine) between aligned current and goal states, (P,) >= 0."""
    return isolate_distance(current_states, goal_states).clamp(min=0)


class Selection(NamedTuple):
    """What `select_constraint` returns, for P aligned pairs:
      raw_distances        (P,) isolate (cosine) distance of each pair's current and goal states
      src_nodes, dst_nodes (P,) node of each pair's current and goal state (`TransitionGraph.bind`)
      same_node            (P,) bool, pairs counted as satisfied (distance set to 0)
      distances            (P,) the distances sampled from (raw, 0 where same_node)
      probabilities        (P,) distances / their sum (all 0 when nothing is left)
      selected, src, dst   the sampled pair and its two nodes (None when every distance is 0)
    """
    raw_distances: np.ndarray
    src_nodes: np.ndarray
    dst_nodes: np.ndarray
    same_node: np.ndarray
    distances: np.ndarray
    probabilities: np.ndarray
    selected: int | None
    src: int | None
    dst: int | None


def select_constraint(current_states: torch.Tensor, goal_states: torch.Tensor, graph: TransitionGraph,
                      rng: np.random.Generator, same_node: bool = True) -> Selection:
    """Choose the constraint to act on among P aligned pairs (current states (P, D), goal
    states (P, D)): rank the pairs by `constraint_distances`, bind both states of each pair to
    the graph's nodes, count a pair whose two states share a node as satisfied (`same_node`;
    off for edge actions read from states, module docstring), and sample one pair from the
    categorical distribution proportional to the distances (`rng`, drawn from only when some
    distance is left)."""
    raw = constraint_distances(current_states, goal_states).numpy().astype(np.float64)
    src, dst = graph.bind(torch.stack([current_states, goal_states])).numpy()     # (P,) each
    same = (src == dst) & same_node
    dist = np.where(same, 0.0, raw)           # same node: satisfied at the graph's resolution
    total = dist.sum()
    if total <= 0:
        return Selection(raw, src, dst, same, dist, np.zeros_like(dist), None, None, None)
    probabilities = dist / total
    pick = int(rng.choice(len(dist), p=probabilities))
    return Selection(raw, src, dst, same, dist, probabilities, pick, int(src[pick]), int(dst[pick]))


class NCSAgent:
    """Neural Constraint Satisfaction on a transition graph, with a given perception.

    A perception that names its kind of state (`graph_state`) must read the kind the graph
    was built on (`TransitionGraph.check_state`)."""

    def __init__(self, graph: TransitionGraph, perception, action_space, seed: int = 0,
                 align: str = "near", nearest_variance: float = NCSConfig.nearest_variance,
                 edge_action: str | None = None, dependencies: bool | None = None):
        if getattr(perception, "graph_state", None) is not None:
            graph.check_state(perception.graph_state)
        if align not in ALIGN_RULES:
            raise ValueError(f"align must be one of {', '.join(map(repr, ALIGN_RULES))}, got {align!r}")
        self.edge_action = edge_action or graph.edge_action     # how an edge becomes an action
        graph.check_edge_action(self.edge_action)
        self.align = align
        # the dependency rules run on a graph that learned supports, unless switched off (False)
        self.supports = None if dependencies is False else graph.supports
        self._basis = graph.moved_subspace(nearest_variance)   # edge actions from states compare along it
        self.graph, self.perception, self.action_space = graph, perception, action_space
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.action_space.seed(self.seed)
        self._goal = None
        self.last = {}
        self._retry = None          # ((pair, src, dst), rank) of the latest action read from states
        self.rules = Counter()      # with dependencies: how often each rule chose this episode's moves

    def reset(self, obs, info, seed: int | None = None) -> None:
        """A new task: read its goal; with the task's env seed `seed`, select-constraint and
        the fallbacks draw anew from a seed of it and the agent's (`task_seed_of`)."""
        if seed is not None:
            drawn = task_seed_of(self.seed, seed)
            self.rng = np.random.default_rng(drawn)
            self.action_space.seed(drawn)
        self._goal = self.perception.goal(obs, info)   # the goal image is fixed per episode
        self.last = {}
        self._retry = None
        self.rules = Counter()

    def episode_counts(self) -> dict:
        """This episode's count of each dependency rule ("rule_direct", ...; `ncs.dependencies`),
        or {} on a graph without dependencies."""
        return {} if self.supports is None else {f"rule_{r}": self.rules[r] for r in RULES}

    def act(self, obs, info) -> tuple[np.ndarray, bool]:
        """The next action and whether it was a random fallback: `align`, `select_constraint`,
        then the action on the edge between the selected pair's two nodes.

        Records the decision in `self.last` (P aligned pairs, pair j = goal entity
        goal_index[j] with current entity current_index[j]):
          current, goal        the Entities acted on (types, states, masks: the restart kept)
          type_distances       (G, C) align's cost matrix
          goal_index, current_index   (P,) the alignment
          raw_distances, src_nodes, dst_nodes, same_node, distances, probabilities,
          selected, src, dst   select_constraint's `Selection`
          action               the action returned
          fallback             None, or why the action is random
        """
        cur, goal = self.perception.current(obs, info), self._goal
        g_idx, c_idx, cost = align(cur.types, goal.types, self.align)
        if self.supports is not None:
            return self._act_dependent(cur, goal, g_idx, c_idx, cost)
        from_states = self.edge_action in EXAMPLE_ACTIONS
        choice = select_constraint(cur.states[c_idx], goal.states[g_idx], self.graph, self.rng,
                                   same_node=not from_states)
        self.last = {"current": cur, "goal": goal, "type_distances": cost, "goal_index": g_idx,
                     "current_index": c_idx, **choice._asdict(), "action": None, "fallback": None}
        if choice.selected is None:
            return self._random("every constraint looks satisfied")
        pick = choice.selected
        if from_states:
            action = self._action_from_states(int(g_idx[pick]), choice.src, choice.dst,
                                              cur.states[c_idx[pick]], goal.states[g_idx[pick]])
        else:
            action = self.graph.action(choice.src, choice.dst)
        if action is None:
            return self._random("no edge")
        self.last["action"] = action
        return action, False

    def _act_dependent(self, cur, goal, g_idx, c_idx, cost):
        """`act` on a graph with dependencies (`dependencies.select_dependent`): a satisfiable
        constraint along its edge or a shortest path's first edge, else a blocker cleared.
        `self.last` adds rule, entity, target, in_place and satisfiable."""
        cur_nodes, cur_on = self.graph.locate(cur.states)
        goal_nodes, goal_on = self.graph.locate(goal.states)
        raw = constraint_distances(cur.states[c_idx], goal.states[g_idx]).numpy().astype(np.float64)
        d = select_dependent(cur_nodes, cur_on, goal_nodes, goal_on, g_idx, c_idx, raw, self.graph,
                             self.supports, self.rng)
        self.last = {"current": cur, "goal": goal, "type_distances": cost, "goal_index": g_idx,
                     "current_index": c_idx, "raw_distances": raw, "src_nodes": cur_nodes[c_idx],
                     "dst_nodes": goal_nodes[g_idx], "selected": d.pair, "src": d.src, "dst": d.dst,
                     "rule": d.rule, "entity": d.entity, "target": d.target, "in_place": d.in_place,
                     "satisfiable": d.satisfiable, "action": None, "fallback": None}
        if d.rule is None:
            return self._random("every constraint looks satisfied, or no move is possible")
        self.rules[d.rule] += 1
        if self.edge_action in EXAMPLE_ACTIONS:
            # a move onto the pair's goal node aims at the goal entity's state, any other
            # move (a path's hop, a clear) at the node it goes to
            onto_goal = d.pair is not None and d.dst == goal_nodes[g_idx[d.pair]]
            after = goal.states[g_idx[d.pair]] if onto_goal else self.graph.centroids[d.dst]
            action = self._action_from_states(d.pair, d.src, d.dst, cur.states[d.entity], after)
        else:
            action = self.graph.action(d.src, d.dst)
        self.last["action"] = action
        return action, False

    def _action_from_states(self, pair, src: int, dst: int, before, after):
        """The action on edge src -> dst read from the states `before` (the entity's) and `after`
        (its target's) (`edge_action` "nearest", "compose" or "readout"): the rank-th
        candidate, where the rank counts how many times in a row `pair` (a goal entity; None
        for a clear) was moved along this edge. The same decision again means the last try
        missed (a move that worked leaves another node behind, or lands within the goal's node
        short of the goal), so the next candidate is tried."""
        key = (pair, src, dst)
        rank = self._retry[1] + 1 if self._retry is not None and self._retry[0] == key else 0
        self._retry = (key, rank)
        self.last["rank"] = rank
        return self.graph.action(src, dst, before, after, rank, basis=self._basis, mode=self.edge_action)

    def _random(self, why: str):
        action = self.action_space.sample()
        self.last.update(fallback=why, action=action)
        return action, True


def aligned_masks(last: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """The masks of a recorded decision in pair order: (goal (P, H, W), current (P, H, W)).

    Pair j's two masks are those of the entities whose states gave `last["raw_distances"][j]`
    and bound to `src_nodes[j]`, `dst_nodes[j]` (with mask states, the masks those states
    were pooled from): what an align figure should draw."""
    cur, goal = last["current"], last["goal"]
    if cur.masks is None or goal.masks is None:
        raise ValueError("this perception records no masks (Entities.masks is None)")
    return goal.masks[last["goal_index"]], cur.masks[last["current_index"]]
