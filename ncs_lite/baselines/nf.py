"""Non-factorized graph search (NF, Appendix B): the ablation of NCS's factorization.

NCS's graph has a node per *entity* state and an edge per isolated entity transition
(s^k, a, s^k'). NF keeps whole scenes: a node is the exact set of bound entity states of a
frame, an edge is the transition of the whole set (s, a, s') labelled with its action.

- **bind an entity**: its nearest node among per-entity centroids: by default those of
  the NCS graph (`TransitionGraph.centroids` under its bind metric), so NF and NCS see a
  scene at the same resolution and differ only in the factorization; without a graph,
  NF clusters every entity state of the buffer itself (same k-means and metrics, Table 3).
- **bind a scene**: the sorted tuple of its entities' node ids (a multiset: two entities
  may bind to one node). Types are not part of it: the paper's NF works on entity states.
- **act**: Dijkstra (`scipy.sparse.csgraph.dijkstra`, every edge of length 1) from the
  current scene's node to the goal scene's node, every step; the action of the path's
  first edge (its most frequent label). A random action when the current or the goal
  scene is unbound (that exact set was never seen in the buffer), when no path exists, or
  when the current node already is the goal's (no edge left, yet the task is unsolved).

What follows from "exact set" (the paper's own words) and shows in the results: a scene
with another number of entities than the buffer's frames never binds (more objects than
in the buffer; a partial goal image, which shows only the constrained objects), and since
types are left out, reaching the goal's set can leave two objects in each other's places.

Shapes: M transitions, K entities per frame, D state features, C entity centroids,
N scene nodes.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from ..ncs.graph import (ACTION_DECIMALS, METRICS_BY_STATE, bind, check_features, check_graph_file, cluster,
                         content_digest, edge_tensors)
from ..tensor_files import atomic_torch_save, file_kind, load_tensor_file
from ..utils import task_seed_of
from .goal_conditioned import as_buffer

GRAPH_KIND = "nf-graph"
GRAPH_FORMAT = 1
FALLBACKS = ("current set unbound", "goal set unbound", "no path", "at the goal's node")


@dataclass
class SetGraph:
    """Scene nodes (sorted tuples of entity node ids) and action-labelled edges.

    centroids (C, D) and bind_metric bind one entity; sets[i] is scene node i;
    edges: {(src, dst): Counter{action tuple: count}}."""

    centroids: torch.Tensor
    bind_metric: str
    sets: list[tuple[int, ...]] = field(default_factory=list)
    edges: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.index = {s: i for i, s in enumerate(self.sets)}
        if len(self.index) != len(self.sets):
            raise ValueError("sets must be distinct scene nodes, got duplicates")
        self._matrix = None
        self._paths: dict = {}

    @property
    def num_nodes(self) -> int:
        return len(self.sets)

    @property
    def state(self) -> str:
        """The kind of entity state its scenes are sets of (Table 3: "mask" or "slot")."""
        return self.info.get("state", "mask")

    def check_state(self, state: str, features: int | None = None) -> None:
        """ValueError unless an agent reading `state` states (of `features` numbers, when
        given) can bind to this graph."""
        if state != self.state:
            raise ValueError(f"the NF graph was built on {self.state!r} states but the agent would read "
                             f"{state!r} states: evaluate with --state {self.state} (ncs.state), or build "
                             f"it with `python -m ncs_lite graph-nf --state {state}`")
        check_features(self, features, "graph-nf")

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    # ------------------------------------------------------------------ bind
    def bind(self, states: torch.Tensor) -> list[tuple[int, ...]]:
        """Entity states (..., K, D) -> one sorted tuple of K entity node ids per scene."""
        states = torch.as_tensor(states)
        if states.ndim < 2 or states.shape[-1] != self.centroids.shape[1]:
            raise ValueError(f"states must have shape (..., K, {self.centroids.shape[1]}), got {tuple(states.shape)}")
        k = states.shape[-2]
        rows = bind(states, self.centroids, self.bind_metric).reshape(-1, k).sort(dim=1).values.tolist()   # (scenes, K)
        return [tuple(r) for r in rows]

    def node(self, states: torch.Tensor) -> int | None:
        """Scene node of one frame's entity states (K, D), or None when that set is unseen."""
        if torch.as_tensor(states).ndim != 2:
            raise ValueError(f"states must have shape (K, D) for one scene, got {tuple(torch.as_tensor(states).shape)}")
        return self.index.get(self.bind(states)[0])

    # ------------------------------------------------------------------ build
    def add(self, sets_t: list[tuple], sets_t1: list[tuple], actions) -> None:
        """Add transitions between scenes (new scenes become nodes); no-op moves are dropped."""
        actions = np.round(np.asarray(actions, np.float64).reshape(-1, 6), ACTION_DECIMALS)
        if not len(sets_t) == len(sets_t1) == len(actions):
            raise ValueError(f"need one action per transition, got {len(sets_t)} and {len(sets_t1)} sets "
                             f"and {len(actions)} actions")
        for s, d, a in zip(sets_t, sets_t1, actions):
            i, j = self._add_node(s), self._add_node(d)
            if i != j:
                self.edges.setdefault((i, j), Counter())[tuple(float(v) for v in a)] += 1
        self._matrix, self._paths = None, {}

    def _add_node(self, s: tuple) -> int:
        if s not in self.index:
            self.index[s] = len(self.sets)
            self.sets.append(s)
        return self.index[s]

    # ------------------------------------------------------------------ plan
    @property
    def matrix(self) -> csr_matrix:
        """(N, N) sparse adjacency, 1 on every edge (unit length: shortest = fewest moves)."""
        if self._matrix is None:
            n = self.num_nodes
            if self.edges:
                src, dst = np.array(list(self.edges)).T
            else:
                src = dst = np.zeros(0, np.int64)
            self._matrix = csr_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
        return self._matrix

    def shortest_path(self, src: int, dst: int) -> list[int] | None:
        """Nodes of a shortest path src -> dst (Dijkstra), [src] when src == dst, None when
        dst is unreachable. Memoised: the graph is fixed once built."""
        for name, v in (("src", src), ("dst", dst)):
            if not 0 <= int(v) < self.num_nodes:
                raise ValueError(f"{name} must be a node index in 0..{self.num_nodes - 1}, got {v!r}")
        key = (int(src), int(dst))
        if key not in self._paths:
            dist, pred = dijkstra(self.matrix, directed=True, indices=key[0], return_predecessors=True)
            if not np.isfinite(dist[key[1]]):
                self._paths[key] = None
            else:
                path = [key[1]]
                while path[-1] != key[0]:
                    path.append(int(pred[path[-1]]))
                self._paths[key] = path[::-1]
        return self._paths[key]

    def action(self, src: int, dst: int) -> np.ndarray | None:
        """The most frequent action on edge src -> dst, or None when there is no such edge."""
        labels = self.edges.get((int(src), int(dst)))
        if not labels:
            return None
        return np.asarray(labels.most_common(1)[0][0], np.float32)

    # ------------------------------------------------------------- save/load
    def state_dict(self) -> dict:
        """Only tensors, strings and numbers: loads with torch.load(weights_only=True)."""
        width = max((len(s) for s in self.sets), default=0)
        sets = torch.full((self.num_nodes, width), -1, dtype=torch.int64)
        for i, s in enumerate(self.sets):
            sets[i, :len(s)] = torch.tensor(s, dtype=torch.int64)
        sd = {"kind": GRAPH_KIND, "format": GRAPH_FORMAT, "centroids": self.centroids.float(),
              "bind_metric": self.bind_metric, "sets": sets, **edge_tensors(self.edges), "info": dict(self.info)}
        return {**sd, "content_digest": content_digest(sd)}

    def save(self, path: str | Path) -> Path:
        atomic_torch_save(self.state_dict(), path)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "SetGraph":
        sd = load_tensor_file(path, "NF graph", "build one with `python -m ncs_lite graph-nf`")
        if sd.get("kind") != GRAPH_KIND or "sets" not in sd:
            raise ValueError(f"{path} is not an ncs-lite NF graph (kind {GRAPH_KIND!r}); it holds {file_kind(sd)}")
        check_graph_file(sd, path, GRAPH_KIND, "NF graph")
        c, ids = sd["centroids"].shape[0], sd["sets"]
        if ids.ndim != 2 or (ids.numel() and not -1 <= int(ids.min()) <= int(ids.max()) < c):
            raise ValueError(f"{path}: scene nodes must be rows of entity node ids 0..{c - 1} (-1 = none)")
        sets = [tuple(v for v in row if v >= 0) for row in sd["sets"].tolist()]
        if len(set(sets)) != len(sets):
            raise ValueError(f"{path}: its scene nodes must be distinct, got duplicates")
        graph = cls(sd["centroids"], sd["bind_metric"], sets, {}, sd["info"])
        for (s, d), a, n in zip(sd["edge_index"].tolist(), sd["edge_action"].tolist(), sd["edge_count"].tolist()):
            graph.edges.setdefault((s, d), Counter())[tuple(round(v, ACTION_DECIMALS) for v in a)] += n
        return graph


def build_set_graph(states_t: torch.Tensor, states_t1: torch.Tensor, actions, centroids: torch.Tensor,
                    bind_metric: str) -> SetGraph:
    """Scene graph of M transitions of K entity states (M, K, D) -> (M, K, D), actions (M, 6)."""
    states_t, states_t1 = torch.as_tensor(states_t), torch.as_tensor(states_t1)
    if states_t.shape != states_t1.shape or states_t.ndim != 3:
        raise ValueError("states_t and states_t1 must both have shape (M, K, D), got "
                         f"{tuple(states_t.shape)} and {tuple(states_t1.shape)}")
    actions = np.asarray(actions, np.float32)
    if actions.shape != (states_t.shape[0], 6):
        raise ValueError(f"actions must have shape ({states_t.shape[0]}, 6), got {actions.shape}")
    graph = SetGraph(torch.as_tensor(centroids).float(), bind_metric)
    graph.add(graph.bind(states_t), graph.bind(states_t1), actions)
    graph.info = {"transitions": int(states_t.shape[0]), "entities": int(states_t.shape[1]),
                  "entity_nodes": int(graph.centroids.shape[0]), "bind_metric": bind_metric}
    return graph


def set_graph_from_transitions(transitions, graph=None, *, clusters: int = 30, state: str = "mask",
                               seed: int = 0) -> SetGraph:
    """NF graph from `perception.transitions(buffer)` (or `buffer_transitions`): a tuple
    (states_t, states_t1 (M, K, D), actions (M, 6), ...) of `state` states ("mask" or "slot").

    graph: an NCS `TransitionGraph` whose centroids bind entities (built on `state` states).
    Without it, k-means (`clusters` nodes, Table 3's cluster metric for `state`) over every
    entity state of the buffer: both ends of every transition, all entities (not only the
    moved one)."""
    if state not in METRICS_BY_STATE:
        raise ValueError(f"state must be one of {sorted(METRICS_BY_STATE)}, got {state!r}")
    if len(transitions) < 3:
        raise ValueError(f"transitions must be (states_t, states_t1, actions, ...), got {len(transitions)} items")
    states_t, states_t1 = torch.as_tensor(transitions[0]), torch.as_tensor(transitions[1])
    actions = np.asarray(transitions[2], np.float32).reshape(-1, 6)
    if graph is not None:
        if hasattr(graph, "check_state"):
            graph.check_state(state, features=states_t.shape[-1])
        centroids, metric, source = graph.centroids, graph.bind_metric, "ncs graph"
    else:
        everything = torch.cat([states_t, states_t1]).reshape(-1, states_t.shape[-1]).float()
        centroids = cluster(everything, clusters, state, seed=seed).centroids
        metric, source = METRICS_BY_STATE[state]["bind"], f"k-means ({clusters}, seed {seed})"
    out = build_set_graph(states_t, states_t1, actions, centroids, metric)
    out.info.update(entity_nodes_from=source, state=state)
    return out


def set_graph_from_buffer(buffer, perception, graph=None, **kwargs) -> SetGraph:
    """NF graph of a buffer (`load_buffer` dict or directory) as `perception` sees it
    (`OraclePerception` or `DSlatePerception`); kwargs as `set_graph_from_transitions`, whose
    `state` defaults to the perception's kind of state (`graph_state`)."""
    kwargs.setdefault("state", getattr(perception, "graph_state", "mask"))
    return set_graph_from_transitions(perception.transitions(as_buffer(buffer)), graph, **kwargs)


class NFAgent:
    """Dijkstra over the scene graph, with a given perception (oracle or learned).

    `fallbacks` counts the random actions by reason (FALLBACKS) over the agent's lifetime,
    `decisions` counts every action; `last` records the latest decision (current and goal
    sets and nodes, the path, the action, the fallback reason or None)."""

    def __init__(self, graph: SetGraph, perception, action_space, seed: int = 0):
        self.graph, self.perception, self.action_space = graph, perception, action_space
        self.seed = int(seed)
        self.action_space.seed(self.seed)
        self.fallbacks: Counter = Counter()
        self.decisions = 0
        self._goal_set = self._goal_node = None
        self.last: dict = {}

    @property
    def random_fraction(self) -> float:
        """Fraction of all decisions so far that were random fallbacks."""
        return sum(self.fallbacks.values()) / max(1, self.decisions)

    def reset(self, obs, info, seed: int | None = None) -> None:
        """A new task: bind its goal; with the task's env seed `seed`, the fallbacks draw
        anew from a seed of it and the agent's (`task_seed_of`)."""
        if seed is not None:
            self.action_space.seed(task_seed_of(self.seed, seed))
        goal = self.perception.goal(obs, info)      # the goal image is fixed per episode
        self._goal_set = self.graph.bind(goal.states)[0]
        self._goal_node = self.graph.index.get(self._goal_set)
        self.last = {}

    def act(self, obs, info) -> tuple[np.ndarray, bool]:
        if self._goal_set is None:
            raise ValueError("call reset(obs, info) before act: NF binds the goal at reset")
        cur_set = self.graph.bind(self.perception.current(obs, info).states)[0]
        cur = self.graph.index.get(cur_set)
        self.decisions += 1
        self.last = {"current_set": cur_set, "current_node": cur, "goal_set": self._goal_set,
                     "goal_node": self._goal_node, "path": None, "action": None, "fallback": None}
        if cur is None:
            return self._random("current set unbound")
        if self._goal_node is None:
            return self._random("goal set unbound")
        if cur == self._goal_node:
            return self._random("at the goal's node")
        path = self.graph.shortest_path(cur, self._goal_node)
        self.last["path"] = path
        if path is None:
            return self._random("no path")
        action = self.graph.action(path[0], path[1])
        self.last["action"] = action
        return action, False

    def _random(self, why: str):
        action = self.action_space.sample()
        self.fallbacks[why] += 1
        self.last.update(fallback=why, action=action)
        return action, True


__all__ = ["FALLBACKS", "NFAgent", "SetGraph", "build_set_graph", "set_graph_from_buffer",
           "set_graph_from_transitions"]
