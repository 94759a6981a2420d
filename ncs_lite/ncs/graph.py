"""The NCS transition graph (Section 4.1, Appendix A.2, Tables 3-4): isolate, cluster, bind.

From a buffer of transitions (entity states before and after, and the action taken), each step
a function of this module (`build_graph` runs the three; `graph_from_buffer`, the one path from
a buffer to a graph, reads the buffer first):

1. **isolate**: the moved entity of a transition is argmax_k d(s_t^k, s_{t+1}^k), d the
   cosine distance (Table 3). Every other entity is assumed untouched.
2. **cluster**: K-means over the isolated states (both ends of every isolated transition)
   gives the nodes; the metric is IoU for attention masks and squared Euclidean for slot
   states (Table 3); the number of nodes is Table 4's (30 for block-rearrange).
3. **bind**: a state's node is its nearest centroid (cosine for masks, squared Euclidean
   for slot states). Each isolated transition adds the edge bind(s_t) -> bind(s_{t+1}),
   labelled with its action; identical actions are merged with a count.

How an edge becomes an action (`edge_action`, a decision the paper leaves open):
- "most_common" (block-rearrange): the edge's most frequent action. States are grid
  cells, so every action on an edge picks the same cube and puts it in the same cell.
- With continuous positions (robogym-rearrange) a node spans several centimetres, more
  than the 0.05 m pick and goal thresholds, so an arbitrary action of the edge usually picks
  nothing or places wide. The graph then keeps each transition's two entity states with its
  action (self-loops too: a move within one node is a move), and the action is realised from
  the current state and the goal state:
  - "nearest": the action of the edge's transition whose start and end states are nearest
    (bind metric, summed) to the current and goal states;
  - "compose": the pick of the transition leaving the source node whose start is nearest the
    current state, and the place of the transition entering the destination node whose end
    is nearest the goal state (two transitions, so a pick and a place each find their best
    exemplar);
  - "readout": the pick point read from the current state and the place point read from the
    goal state by two quadratic least-squares read-outs fitted on every kept transition
    (start state -> its pick point, end state -> its place point): the transitions label the
    states with where their objects were, and the read-out interpolates between them.
  The edge must exist in every mode: the graph still decides which moves are possible. `rank`
  > 0 retries after a move that changed nothing with the next nearest transition(s)
  ("readout" retries with "compose"'s nearest, then the next). With slot states, distances
  are taken in the subspace the buffer's moves span (`moved_subspace`: the principal
  directions of the displacements s_{t+1} - s_t that hold `ncs.nearest_variance` of their
  energy): a learned s holds a little more than where the object is, and those other
  directions, though small, are as large as the pick threshold. The position oracle's
  states (x, y, z) move in x and y only, so its comparisons leave out z, the object's
  resting height. docs/HISTORY.md gives the step outcomes of each mode.

Shapes: M transitions, K entities per frame, D state features, N nodes.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from ..cache import digest
from ..config import CLUSTERS_BY_ENV, DEPENDENCIES_BY_ENV, EDGE_ACTION_BY_ENV, EDGE_ACTIONS, STATE_BY_ENV
from ..data import load_manifest, manifest_hash
from ..tensor_files import atomic_torch_save, file_kind, load_tensor_file
from ..utils import relative_to_repo
from .dependencies import graph_reach, on_graph, support_relation
from .kmeans import KMeansResult, assign, kmeans, pairwise_distances
from .perception import buffer_transitions, graph_perception, scene_slots, slot_read

# Table 3 (state representation -> metrics) and Table 4 (nodes per environment).
METRICS_BY_STATE = {
    "mask": {"isolate": "cosine", "cluster": "iou", "bind": "cosine"},
    "slot": {"isolate": "cosine", "cluster": "sqeuclidean", "bind": "sqeuclidean"},
}
BIND_METRICS = {m["bind"] for m in METRICS_BY_STATE.values()}
EXAMPLE_ACTIONS = EDGE_ACTIONS[1:]      # those that read the transitions' states (`examples`)
READOUT_RIDGE = 1e-4                    # ridge of the read-out's least squares, x each feature's variance
ACTION_DECIMALS = 4  # actions equal to 0.1 mm are merged into one edge label
# the NCSConfig fields that only building a graph reads, never an agent acting on one
BUILD_FIELDS = ("ncs.clusters", "ncs.graph_restarts", "ncs.seed", "ncs.dependencies")


def isolate_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Table 3's isolate distance d, the cosine distance 1 - cos(a, b) over the last axis:
    (..., D), (..., D) -> (...). The same d for both state kinds; select-constraint ranks
    goal constraints with it too (`policy.constraint_distances`)."""
    return 1 - torch.nn.functional.cosine_similarity(a.float(), b.float(), dim=-1, eps=1e-8)


def isolate(states_t: torch.Tensor, states_t1: torch.Tensor) -> torch.Tensor:
    """Index of the moved entity per transition: argmax_k cosine distance, (M,) int64.

    states_t, states_t1: (M, K, D), entity k at t and t+1 (same k = same entity).
    """
    if states_t.shape != states_t1.shape or states_t.ndim != 3:
        raise ValueError("states_t and states_t1 must both have shape (M, K, D), got "
                         f"{tuple(states_t.shape)} and {tuple(states_t1.shape)}")
    return isolate_distance(states_t, states_t1).argmax(dim=1)


def cluster(states: torch.Tensor, clusters: int, state: str = "mask", *, seed: int = 0,
            max_iter: int = 100) -> KMeansResult:
    """The graph's nodes: K-means of isolated entity states (M, D) into `clusters` centroids
    (N, D), under Table 3's cluster metric for `state` states (IoU for masks, squared Euclidean
    for slot states), k-means++ seeded by `seed` (`kmeans`)."""
    if state not in METRICS_BY_STATE:
        raise ValueError(f"state must be one of {sorted(METRICS_BY_STATE)}, got {state!r}")
    return kmeans(states, clusters, METRICS_BY_STATE[state]["cluster"], seed=seed, max_iter=max_iter)


def bind(states: torch.Tensor, centroids: torch.Tensor, metric: str) -> torch.Tensor:
    """The node of each state: (..., D) states -> (...) int64 index of the nearest centroid
    (N, D) under `metric`, Table 3's bind metric (cosine for masks, squared Euclidean for slot
    states; ties go to the lowest index, `assign`)."""
    flat = states.reshape(-1, states.shape[-1]).float()
    labels, _ = assign(flat, centroids, metric)
    return labels.reshape(states.shape[:-1])


GRAPH_KIND = "ncs-graph"
GRAPH_KEYS = ("centroids", "bind_metric", "edge_index", "edge_action", "edge_count", "info")


def content_digest(sd: dict) -> str:
    """Digest of a graph file's tensors and metric (checked on load: a flipped byte shows)."""
    return digest([sd[k] for k in GRAPH_KEYS[:-1]] + [sd.get("sets")]
                  + ([sd["edge_before"], sd["edge_after"]] if "edge_before" in sd else []))


def check_graph_file(sd: dict, path, kind: str, what: str) -> dict:
    """ValueError naming `path` unless `sd` is a sound graph file of `kind`: the keys, the
    kind tag (files from before the tag have none), the content digest when stored, finite
    centroids, a known bind metric, edges between existing nodes."""
    if sd.get("kind", kind) != kind or sd.get("format") != 1 or any(k not in sd for k in GRAPH_KEYS):
        raise ValueError(f"{path} is not an ncs-lite {what} (kind {kind!r}, format 1); it holds {file_kind(sd)}")
    if "content_digest" in sd and content_digest(sd) != sd["content_digest"]:
        raise ValueError(f"{path} is corrupted: its content does not match the digest stored when it was saved")
    tensors = ["centroids", "edge_index", "edge_action", "edge_count"] + ["sets"] * ("sets" in sd) \
        + ["edge_before", "edge_after"] * ("edge_before" in sd)
    for key in tensors:
        if not isinstance(sd.get(key), torch.Tensor):
            raise ValueError(f"{path} is corrupted: its {key} is a {type(sd.get(key)).__name__}, expected a tensor")
    for key in ("edge_index", "edge_count", "sets"):
        if key in sd and (sd[key].is_floating_point() or sd[key].is_complex()):
            raise ValueError(f"{path} is corrupted: its {key} has dtype {sd[key].dtype}, expected integers")
    if not isinstance(sd["info"], dict):
        raise ValueError(f"{path} is corrupted: its info is a {type(sd['info']).__name__}, expected a dict")
    if sd["info"].get("state", "mask") not in METRICS_BY_STATE:
        raise ValueError(f"{path}: unknown state {sd['info'].get('state')!r}; expected one of {sorted(METRICS_BY_STATE)}")
    c, index = sd["centroids"], sd["edge_index"]
    if not (c.is_floating_point() and c.ndim == 2 and c.shape[0] > 0 and bool(torch.isfinite(c).all())):
        raise ValueError(f"{path}: centroids must be a finite (N, D) float tensor with N >= 1")
    if not isinstance(sd["bind_metric"], str) or sd["bind_metric"] not in BIND_METRICS:
        raise ValueError(f"{path}: unknown bind metric {sd['bind_metric']!r}; expected one of {sorted(BIND_METRICS)}")
    nodes = len(sd["sets"]) if "sets" in sd else c.shape[0]
    if index.ndim != 2 or index.shape[1] != 2 or (index.numel() and (index.min() < 0 or index.max() >= nodes)):
        raise ValueError(f"{path}: edges must join nodes 0..{nodes - 1}")
    if not (sd["edge_action"].shape == (index.shape[0], 6) and sd["edge_count"].shape == (index.shape[0],)):
        raise ValueError(f"{path}: every edge needs one action (6,) and one count")
    if not bool(torch.isfinite(sd["edge_action"]).all()):
        raise ValueError(f"{path}: edge actions must be finite, got non-finite ones")
    if sd["edge_count"].numel() and int(sd["edge_count"].min()) < 1:
        raise ValueError(f"{path}: edge counts must be >= 1, got {int(sd['edge_count'].min())}")
    if "edge_before" in sd and not (sd["edge_before"].shape == sd["edge_after"].shape == (index.shape[0], c.shape[1])):
        raise ValueError(f"{path}: every edge action needs its start and end states ({c.shape[1]} features each)")
    return sd


def check_features(graph, features: int | None, command: str) -> None:
    """ValueError unless the graph's nodes are states of `features` numbers (None: unchecked),
    those of the perception that will read scenes: a graph built from the oracle's positions
    (3) cannot bind a model's slot states (its state_dim), nor the other way round."""
    width = int(graph.centroids.shape[1])
    if features is not None and int(features) != width:
        raise ValueError(f"the graph's nodes are {graph.state!r} states of {width} numbers but the perception "
                         f"reads states of {int(features)}: it was built with another perception (the oracle's "
                         f"or another model's); build it with `python -m ncs_lite {command}` and the same "
                         "--checkpoint (or --oracle)")


def edge_tensors(edges: dict, examples: dict | None = None) -> dict:
    """{(src, dst): Counter{action: count}} -> "edge_index" (E, 2), "edge_action" (E, 6),
    "edge_count" (E,) tensors, one row per (edge, action), in sorted order (for saving);
    with `examples` ({(src, dst): {action: (before, after)}}) also "edge_before",
    "edge_after" (E, D), the states of each row's transition."""
    rows = [(s, d, a, n) for (s, d), c in sorted(edges.items()) for a, n in c.items()]
    out = {"edge_index": torch.tensor([[r[0], r[1]] for r in rows], dtype=torch.int64).reshape(-1, 2),
           "edge_action": torch.tensor([r[2] for r in rows], dtype=torch.float32).reshape(-1, 6),
           "edge_count": torch.tensor([r[3] for r in rows], dtype=torch.int64)}
    if examples is not None:
        for i, key in enumerate(("edge_before", "edge_after")):
            states = [examples[(r[0], r[1])][r[2]][i] for r in rows]
            out[key] = torch.stack(states).float() if states else torch.zeros(0, 0)
    return out


@dataclass
class TransitionGraph:
    """Nodes (centroids) and action-labelled edges between them.

    centroids (N, D); edges: {(src, dst): Counter{action tuple: count}}; examples (with
    edge_action "nearest"): {(src, dst): {action tuple: (state before (D,), state after (D,))}}.
    """

    centroids: torch.Tensor
    bind_metric: str
    edges: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)   # how it was built, coverage, counts
    examples: dict | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)   # derived from edges, examples

    @property
    def edge_action(self) -> str:
        """How the graph was built to act (`build_graph`): "most_common", or one of
        EXAMPLE_ACTIONS when it keeps its transitions' states (graphs that did not record
        which acted "nearest")."""
        if self.examples is None:
            return "most_common"
        return self.info.get("edge_action", "nearest")

    def check_edge_action(self, edge_action: str) -> None:
        """ValueError unless an agent can realise edges as `edge_action` on this graph: the
        modes that read transitions' states need a graph that kept them."""
        if edge_action not in EDGE_ACTIONS:
            raise ValueError(f"edge_action must be one of {', '.join(map(repr, EDGE_ACTIONS))}, got {edge_action!r}")
        if edge_action in EXAMPLE_ACTIONS and self.examples is None:
            raise ValueError(f"edge_action {edge_action!r} reads the states of the graph's transitions, but this "
                             "graph kept none (built with edge_action 'most_common'); build it with "
                             "--set ncs.edge_action=nearest")

    @property
    def supports(self) -> list[list[int]] | None:
        """supports[n]: the nodes under node n (`ncs.dependencies`), for a graph built with
        dependencies; None otherwise (objects move independently)."""
        return self.info.get("supports")

    def successors(self) -> dict[int, list[int]]:
        """{node: the other nodes an edge leads to, ascending} (computed once per graph)."""
        if "successors" not in self._cache:
            nexts: dict[int, set[int]] = {}
            for s, d in self.edges:
                if s != d:
                    nexts.setdefault(s, set()).add(d)
            self._cache["successors"] = {s: sorted(ds) for s, ds in nexts.items()}
        return self._cache["successors"]

    def locate(self, states: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """(nodes, on the graph) of states (..., D), for a graph built with dependencies
        (`dependencies.on_graph`: the floor's slot lies off every node)."""
        return on_graph(states, self.centroids, self.bind_metric, self.info["reach"])

    @property
    def num_nodes(self) -> int:
        return int(self.centroids.shape[0])

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    @property
    def state(self) -> str:
        """The kind of entity state the graph was built on (a METRICS_BY_STATE key). Graphs
        written before `build_graph` recorded it were all built on masks."""
        return self.info.get("state", "mask")

    def check_state(self, state: str, features: int | None = None) -> None:
        """ValueError unless an agent reading `state` states (of `features` numbers, when
        given) can act on this graph: its nodes are centroids of one kind of state, bound
        with that kind's metric, read by the same kind of perception."""
        if state != self.state:
            raise ValueError(f"the graph was built on {self.state!r} states but the agent would read "
                             f"{state!r} states: evaluate with --state {self.state} (ncs.state), or "
                             f"build the graph with `python -m ncs_lite graph --state {state}`")
        check_features(self, features, "graph")

    def bind(self, states: torch.Tensor) -> torch.Tensor:
        """Node of each state (..., D) -> (...) int64: `bind` to these centroids under `bind_metric`."""
        return bind(states, self.centroids, self.bind_metric)

    def moved_subspace(self, variance: float = 1.0) -> torch.Tensor | None:
        """(D, P) orthonormal directions along which the examples' states move: the fewest
        principal directions of their displacements (after - before) that hold `variance` of
        the displacements' energy. None (compare whole states) for `variance` 1, for a graph
        without examples and for a graph bound by another metric than squared Euclidean."""
        if not 0.0 < variance <= 1.0:
            raise ValueError(f"variance must be in (0, 1], got {variance!r}")
        if variance == 1.0 or not self.examples or self.bind_metric != "sqeuclidean":
            return None
        key = ("subspace", variance)
        if key not in self._cache:
            moves = torch.stack([a - b for ex in self.examples.values() for b, a in ex.values()]).double()
            _, energy, directions = torch.linalg.svd(moves, full_matrices=False)
            share = torch.cumsum(energy ** 2, 0) / (energy ** 2).sum()
            keep = int(torch.searchsorted(share, torch.tensor(variance, dtype=share.dtype))) + 1
            self._cache[key] = directions[:keep].T.float()
        return self._cache[key]

    def transitions(self) -> dict:
        """Every kept transition as arrays: src, dst (E,) nodes, before, after (E, D) states,
        actions (E, 6); in the order of `edges`."""
        if "transitions" not in self._cache:
            rows = [(s, d, a, b, e) for (s, d), ex in self.examples.items() for a, (b, e) in ex.items()]
            self._cache["transitions"] = {
                "src": torch.tensor([r[0] for r in rows]), "dst": torch.tensor([r[1] for r in rows]),
                "actions": torch.tensor([r[2] for r in rows], dtype=torch.float32),
                "before": torch.stack([r[3] for r in rows]), "after": torch.stack([r[4] for r in rows])}
        return self._cache["transitions"]

    def readout(self) -> tuple[tuple, tuple]:
        """The read-outs of "readout" edge actions, fitted on every kept transition: for the
        pick and for the place, (F, 2) weights from `readout_features` of the start state to
        the pick point (w's x, y), and of the end state to the place point (w + dw's x, y), by
        ridge least squares (float64), with the low and high corners (2,) of the fitted points."""
        if "readout" not in self._cache:
            t = self.transitions()
            picks, places = t["actions"][:, :2], t["actions"][:, :2] + t["actions"][:, 3:5]
            # with each read-out, the box of the points it was fitted on: the quadratic read-out
            # extrapolates past the transitions' states (few transitions, or a state unlike any
            # of theirs), and an action must stay in the env's action space
            self._cache["readout"] = tuple((_ridge(readout_features(x), y), y.min(0).values.double(),
                                            y.max(0).values.double())
                                           for x, y in ((t["before"], picks), (t["after"], places)))
        return self._cache["readout"]

    def read_points(self, before: torch.Tensor, after: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(1, 2) pick point read from the state `before` (1, D) and (1, 2) place point read from
        the state `after` (1, D) ("readout"; float64), each within the box of its fitted points."""
        (pick_w, pick_lo, pick_hi), (place_w, place_lo, place_hi) = self.readout()
        pick = torch.clamp(readout_features(before) @ pick_w, pick_lo, pick_hi)
        place = torch.clamp(readout_features(after) @ place_w, place_lo, place_hi)
        return pick, place

    def action(self, src: int, dst: int, before=None, after=None, rank: int = 0,
               basis: torch.Tensor | None = None, mode: str | None = None) -> np.ndarray | None:
        """The action for edge src -> dst, or None when there is no such edge. `mode` (default
        the graph's `edge_action`; see the module docstring): "most_common", the edge's most
        frequent action; given the current state `before` and goal state `after`,
        "nearest", that of the edge's rank-th nearest transition; "compose", the pick of the
        rank-th nearest transition leaving src and the place of the rank-th nearest entering
        dst; "readout", the pick and place read from the two states (`readout`), and on a
        retry (rank r > 0) "compose"'s (rank r - 1). Distances are taken along `basis` (D, P)
        if given (`moved_subspace`)."""
        mode = mode or self.edge_action
        labels = self.edges.get((int(src), int(dst)))
        if not labels:
            return None
        if mode == "most_common" or before is None:
            return np.asarray(labels.most_common(1)[0][0], np.float32)
        self.check_edge_action(mode)
        t = self.transitions()
        before = torch.as_tensor(before, dtype=torch.float32).reshape(1, -1)
        after = torch.as_tensor(after, dtype=torch.float32).reshape(1, -1)
        if mode == "readout" and rank == 0:
            pick, place = self.read_points(before, after)                                       # (1, 2) each
            z = self.action(src, dst, before, after, 0, basis, "nearest")[2]     # the edge's nearest pick height
            return np.array([*pick[0].tolist(), z, *(place - pick)[0].tolist(), 0.0], np.float32)
        rank = rank - 1 if mode == "readout" else rank

        def rank_th(rows, *pairs):     # index into t of the rank-th nearest of `rows`: the distances
            idx = torch.nonzero(rows).reshape(-1)      # of each (states (E, D), state (1, D)) pair, summed
            cost = 0
            for states, state in pairs:
                x = states[idx]
                if basis is not None:
                    x, state = x @ basis, state @ basis
                cost = cost + pairwise_distances(x, state, self.bind_metric)[:, 0]
            return int(idx[torch.argsort(cost, stable=True)[rank % len(idx)]])

        if mode == "nearest":
            on_edge = (t["src"] == int(src)) & (t["dst"] == int(dst))
            return t["actions"][rank_th(on_edge, (t["before"], before), (t["after"], after))].numpy().copy()
        leave = t["actions"][rank_th(t["src"] == int(src), (t["before"], before))]
        enter = t["actions"][rank_th(t["dst"] == int(dst), (t["after"], after))]
        place = enter[:2] + enter[3:5]
        return np.array([*leave[:3].tolist(), *(place - leave[:2]).tolist(), 0.0], np.float32)

    def add(self, src: torch.Tensor, dst: torch.Tensor, actions: np.ndarray, before=None, after=None) -> None:
        """Edges for transitions src -> dst with their actions; with before/after states (M, D)
        the graph keeps examples ("nearest") and self-loops too."""
        keep = before is not None
        self._cache.clear()                # what was derived from the edges and examples is stale
        if keep and self.examples is None:
            self.examples = {}
        for m, (s, d, a) in enumerate(zip(src.tolist(), dst.tolist(),
                                          np.round(np.asarray(actions, np.float64), ACTION_DECIMALS))):
            if s == d and not keep:   # between cells a self-loop carries no usable transition
                continue
            a = tuple(float(v) for v in a)
            self.edges.setdefault((s, d), Counter())[a] += 1
            if keep:
                self.examples.setdefault((s, d), {}).setdefault(a, (before[m].float(), after[m].float()))

    # -------------------------------------------------------------- save/load
    def state_dict(self) -> dict:
        """Only tensors, strings and numbers: loads with torch.load(weights_only=True)."""
        sd = {"kind": GRAPH_KIND, "format": 1, "centroids": self.centroids.float(), "bind_metric": self.bind_metric,
              **edge_tensors(self.edges, self.examples), "info": dict(self.info)}
        return {**sd, "content_digest": content_digest(sd)}

    def save(self, path: str | Path) -> Path:
        atomic_torch_save(self.state_dict(), path)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "TransitionGraph":
        return cls.from_state_dict(load_tensor_file(path, "transition graph",
                                                    "build one with `python -m ncs_lite graph`"), path)

    @classmethod
    def from_state_dict(cls, sd: dict, path: str | Path = "a state dict") -> "TransitionGraph":
        """The graph `state_dict` gave (checked: kind, format, shapes and content digest)."""
        sd = check_graph_file(sd, path, GRAPH_KIND, "transition graph")
        graph = cls(sd["centroids"], sd["bind_metric"], {}, sd["info"])
        if "edge_before" in sd:
            graph.examples = {}
        for i, ((s, d), a, n) in enumerate(zip(sd["edge_index"].tolist(), sd["edge_action"].tolist(),
                                                sd["edge_count"].tolist())):
            a = tuple(round(v, ACTION_DECIMALS) for v in a)
            graph.edges.setdefault((s, d), Counter())[a] += n
            if graph.examples is not None:
                graph.examples.setdefault((s, d), {})[a] = (sd["edge_before"][i], sd["edge_after"][i])
        return graph

    # ------------------------------------------------------------------ draw
    def node_positions(self, image_size: int = 64) -> np.ndarray:
        """(N, 2) image (x, y) of each node: the centre of mass of its centroid mask."""
        n, d = self.centroids.shape
        side = int(round(d ** 0.5))
        if side * side != d:
            raise ValueError(f"node positions need square mask centroids, got D={d}")
        m = self.centroids.reshape(n, side, side).clamp(min=0).numpy()
        ys, xs = np.mgrid[0:side, 0:side] + 0.5
        total = m.sum((1, 2)) + 1e-8
        scale = image_size / side
        return np.stack([(m * xs).sum((1, 2)) / total, (m * ys).sum((1, 2)) / total], 1) * scale

    def adjacency(self) -> torch.Tensor:
        """(N, N) int64 edge counts: entry [s, d] = transitions bound to the edge s -> d."""
        adj = torch.zeros(self.num_nodes, self.num_nodes, dtype=torch.int64)
        for (s, d), labels in self.edges.items():
            adj[s, d] = sum(labels.values())
        return adj

    def node_order(self, row_gap: float = 6.0) -> np.ndarray:
        """Node indices in reading order of their image positions: sorted by y, a new row
        where y jumps by more than `row_gap` pixels, each row sorted by x. On a grid the
        nodes of one cell come out next to each other, so an adjacency matrix drawn in this
        order shows the grid's structure."""
        pos = self.node_positions()
        by_y = np.argsort(pos[:, 1], kind="stable")
        row = np.concatenate([[0], np.cumsum(np.diff(pos[by_y, 1]) > row_gap)])
        rows = np.empty(len(pos), np.int64)
        rows[by_y] = row
        return np.lexsort((pos[:, 0], rows))


def readout_features(states: torch.Tensor) -> torch.Tensor:
    """(M, D) states -> (M, 1 + D + D(D+1)/2): a constant, the states and their pairwise
    products, so that a linear read-out can bend with the camera's perspective."""
    states = states.double()
    i, j = torch.triu_indices(states.shape[1], states.shape[1])
    return torch.cat([torch.ones(len(states), 1, dtype=states.dtype), states, states[:, i] * states[:, j]], 1)


def _ridge(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """(F, O) least-squares weights from features x (M, F) to targets y (M, O), each feature's
    ridge READOUT_RIDGE x its variance (scale-free; a constant feature, such as the oracle's
    resting height, gets a vanishing one that only keeps the system solvable)."""
    y = y.double()
    penalty = torch.diag(READOUT_RIDGE * x.var(0, unbiased=False) + 1e-9)
    return torch.linalg.solve(x.T @ x + penalty * len(x), x.T @ y)


def build_graph(states_t: torch.Tensor, states_t1: torch.Tensor, actions: np.ndarray, *,
                clusters: int, state: str = "mask", seed: int = 0, max_iter: int = 100,
                true_entity: np.ndarray | None = None, edge_action: str = "most_common",
                dependencies: bool = False) -> TransitionGraph:
    """isolate -> cluster -> bind over M transitions of K entity states (M, K, D).

    actions (M, 6). `true_entity` (M,) optional: for each transition, the entity index k
    that truly moved (from ground truth); it gives the graph's coverage, the fraction of
    isolated transitions that found the right entity. With `dependencies` the graph also
    records its reach and each node's supports (`ncs.dependencies`), read from every entity of
    every frame.
    """
    if state not in METRICS_BY_STATE:
        raise ValueError(f"state must be one of {sorted(METRICS_BY_STATE)}, got {state!r}")
    if edge_action not in EDGE_ACTIONS:
        raise ValueError(f"edge_action must be one of {EDGE_ACTIONS}, got {edge_action!r}")
    metrics = METRICS_BY_STATE[state]
    actions = np.asarray(actions, np.float32)
    if actions.shape != (states_t.shape[0], 6):
        raise ValueError(f"actions must have shape ({states_t.shape[0]}, 6), got {actions.shape}")
    moved = isolate(states_t, states_t1)                               # (M,)
    rows = torch.arange(len(moved))
    before, after = states_t[rows, moved].float(), states_t1[rows, moved].float()  # (M, D)
    result = cluster(torch.cat([before, after]), clusters, state, seed=seed, max_iter=max_iter)
    graph = TransitionGraph(result.centroids, metrics["bind"])
    examples = (before, after) if edge_action in EXAMPLE_ACTIONS else (None, None)
    graph.add(bind(before, graph.centroids, graph.bind_metric), bind(after, graph.centroids, graph.bind_metric),
              actions, *examples)
    graph.info = {"transitions": int(len(moved)), "clusters": int(clusters), "state": state,
                  "edge_action": edge_action,
                  "metrics": metrics, "seed": seed, "kmeans_inertia": result.inertia,
                  "kmeans_iterations": result.n_iter}
    if true_entity is not None:
        graph.info["coverage"] = float((moved.numpy() == np.asarray(true_entity)).mean())
    if dependencies:
        graph.info["reach"] = graph_reach(torch.cat([before, after]), graph.centroids, graph.bind_metric)
        nodes, on = graph.locate(states_t)                                       # (M, K) each
        graph.info["supports"] = support_relation(nodes, on, graph.num_nodes)
    return graph


def buffer_perception(ncs, model, data, num_slots: int | None = None):
    """How a graph reads the frames of the buffer at `data` (`graph_perception`): with
    `num_slots` slots, or when None those an agent reads a scene of the buffer's object count
    with (`scene_slots`), so the graph's states and the agent's are read alike."""
    if model is not None and num_slots is None:
        num_slots = scene_slots(model, load_manifest(data)["env"]["num_objects"], ncs)
    return graph_perception(ncs, model, num_slots=num_slots)


def graph_from_buffer(ncs, model, data, *, num_slots: int | None = None,
                      episodes: int | None = None) -> TransitionGraph:
    """The transition graph of the buffer at `data` (a directory, `ncs_lite.data.collect`) as
    NCS reads it, with every graph field of `ncs` (an `NCSConfig`): the one path from a buffer
    to a graph, used by `python -m ncs_lite graph`, the tables and notebooks 05-06.

    1. perception (`graph_perception`): `model`'s entities (`ncs.iterations`,
       `ncs.graph_restarts`, `ncs.state`, `ncs.slot_position`, `num_slots` slots; None: those
       an agent reads a scene of the buffer's object count with, `scene_slots`), or ground
       truth with `model` None;
    2. the buffer's transitions as it reads them (`buffer_transitions`, cached), the first
       `episodes` episodes of them (None: all);
    3. `build_graph` with `ncs.clusters`, `ncs.state`, `ncs.seed`, `ncs.edge_action` and
       `ncs.dependencies` (None: the buffer's env's, EDGE_ACTION_BY_ENV, DEPENDENCIES_BY_ENV).
    The graph's info records the buffer, its env and manifest hash, the settings (`ncs`, with
    the edge action resolved), how it read slot states (`slot_read`) and the episodes read.
    """
    manifest = load_manifest(data)
    env = manifest["env"]["env"]
    ncs = replace(ncs, edge_action=ncs.edge_action or EDGE_ACTION_BY_ENV.get(env, "most_common"),
                  dependencies=DEPENDENCIES_BY_ENV.get(env, False) if ncs.dependencies is None else ncs.dependencies)
    total = manifest["episodes"]
    episodes = total if episodes is None else episodes
    if isinstance(episodes, bool) or not isinstance(episodes, int) or not 1 <= episodes <= total:
        raise ValueError(f"episodes must be an integer in [1, {total}] (the graph buffer's), got {episodes!r}")
    perception = buffer_perception(ncs, model, data, num_slots)
    states_t, states_t1, actions, moved = buffer_transitions(perception, data)
    keep = episodes * (len(actions) // total)             # transitions in episode order (M = E (T - 1))
    graph = build_graph(states_t[:keep], states_t1[:keep], actions[:keep], clusters=ncs.clusters, state=ncs.state,
                        seed=ncs.seed, true_entity=moved[:keep], edge_action=ncs.edge_action,
                        dependencies=ncs.dependencies)
    graph.info.update(env=env, data=relative_to_repo(data), manifest_sha256=manifest_hash(data), episodes=episodes,
                      ncs=asdict(ncs), oracle=model is None, perception_state=perception.state,
                      **slot_read(perception), **({} if model is None else {"read_slots": perception.num_slots}))
    return graph


__all__ = ["BUILD_FIELDS", "buffer_perception", "CLUSTERS_BY_ENV", "EDGE_ACTION_BY_ENV", "EDGE_ACTIONS", "readout_features", "STATE_BY_ENV", "METRICS_BY_STATE", "TransitionGraph", "bind", "build_graph", "cluster",
           "graph_from_buffer", "isolate", "isolate_distance"]
