"""NCS for objects that depend on each other: the kit's extension of Appendix F (block-stacking).

The paper assumes objects move independently and leaves dependencies "for future work"
(Appendix F). In block-stacking a cube under another cannot be picked and a tower is built
bottom up, so a constraint can be satisfiable or not depending on the other objects. This
module adds what NCS needs for that, learned from the same buffer as the graph and with no
ground truth:

1. **support** (`support_relation`): node b supports node a when an entity at a almost always
   comes with another entity at b in the buffer's frames, far more often than b is occupied
   at all (P(b | a) - P(b) >= `SUPPORT_LIFT`). In block-stacking the supports of a cube's
   place are the places under it. `above(n)` are the nodes n supports. A node without
   supports is a floor place. Entities far from every node (the floor's slot) are left out:
   an entity is on the graph when its bind distance is within `RADIUS_SCALE` x its node's
   radius (the `RADIUS_QUANTILE` of the node's members' distances).
2. **select-constraint over satisfiable constraints** (`select_dependent`): a pair is *in
   place* when its two states share a node and every support of that node holds a pair in
   place (so a cube at its goal on the wrong cube is not); a pair is *satisfiable now* when
   it is not in place, its entity is on top (no entity above it), nothing occupies its goal
   node or above, and every support of its goal node holds a pair in place. One is sampled
   in proportion to its isolate distance, as in `policy.select_constraint`.
3. **clear** when none is satisfiable: an entity on top that blocks (it sits above an entity
   that must move, or on the goal node of a pair not in place or above it) is moved to a free
   floor place that no goal needs.
4. **shortest path** when no edge joins the two nodes: the first move of a shortest path
   through the graph whose intermediate nodes are free and supported (`first_hop`).

Each decision records which rule fired ("direct", "path", "clear"); `evaluation.run_episode`
counts them. On a graph without supports (block-rearrange, robogym-rearrange) none of this
runs and the agent is the paper's.
"""
from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np
import torch

from .kmeans import assign, pairwise_distances

SUPPORT_LIFT = 0.5        # P(b | a) - P(b) for b to support a
RADIUS_QUANTILE = 0.99    # the nodes' radius: this quantile of their members' bind distances
RADIUS_SCALE = 2.0        # an entity further than this x the radius is off the graph ...
REACH_FLOOR = 0.25        # ... and one nearer than this x the median distance between nodes is on it
RULES = ("direct", "path", "clear")


def graph_reach(states: torch.Tensor, centroids: torch.Tensor, metric: str) -> float:
    """How far from its node an entity may lie and still be an object: RADIUS_SCALE x the
    RADIUS_QUANTILE of the bind distances of the states (M, D) the nodes were made from, and
    at least REACH_FLOOR x the median distance between two nodes (ground-truth masks of one
    place are identical, so their quantile can be 0)."""
    _, dist = assign(states.float(), centroids, metric)
    between = pairwise_distances(centroids.float(), centroids.float(), metric)
    off_diagonal = between[~torch.eye(len(centroids), dtype=torch.bool)]
    return max(RADIUS_SCALE * float(torch.quantile(dist.double(), RADIUS_QUANTILE)),
               REACH_FLOOR * float(off_diagonal.median()) if len(off_diagonal) else 0.0)


def on_graph(states: torch.Tensor, centroids: torch.Tensor, metric: str, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(nodes (...), on (...) bool) of states (..., D): each state's node and whether it lies
    within `reach` of it (`graph_reach`: an object; the floor's slot lies further)."""
    flat = states.reshape(-1, states.shape[-1]).float()
    labels, dist = assign(flat, centroids, metric)
    shape = states.shape[:-1]
    return labels.reshape(shape).numpy(), (dist <= reach).reshape(shape).numpy()


def support_relation(nodes: np.ndarray, on: np.ndarray, num_nodes: int) -> list[list[int]]:
    """supports[a]: the nodes b with P(b occupied | a occupied) - P(b occupied) >= SUPPORT_LIFT
    over the frames (F, K) of entity nodes `nodes` (entities with `on` False left out)."""
    occupied = np.zeros((len(nodes), num_nodes), bool)
    rows = np.repeat(np.arange(len(nodes)), nodes.shape[1])
    keep = on.reshape(-1)
    occupied[rows[keep], nodes.reshape(-1)[keep]] = True
    count = occupied.sum(0).astype(np.float64)                    # (N,)
    both = occupied.T.astype(np.float64) @ occupied               # (N, N): frames with a and b
    given = both / np.maximum(count[:, None], 1)                  # P(b | a)
    lift = given - count[None] / len(nodes)
    np.fill_diagonal(lift, 0)
    return [np.nonzero((lift[a] >= SUPPORT_LIFT) & (count[a] > 0))[0].tolist() for a in range(num_nodes)]


class Decision(NamedTuple):
    """What `select_dependent` chose: the rule ("direct", "path", "clear") or None when nothing
    is left to do; the pair (index into the alignment; None for a clear), the entity moved
    (index into the current entities), the edge (src, dst) acted on and the node the entity is
    bound for; `in_place`, `satisfiable` (P,) bool per pair."""
    rule: str | None
    pair: int | None
    entity: int | None
    src: int | None
    dst: int | None
    target: int | None
    in_place: np.ndarray
    satisfiable: np.ndarray


def first_hop(graph, src: int, dst: int, allowed: set[int]) -> int | None:
    """The second node of a shortest path src -> dst over the graph's edges whose
    intermediate nodes are in `allowed` (breadth first; ties to the lowest node), or None."""
    nexts = graph.successors()
    first = {src: None}
    queue = deque([src])
    while queue:
        node = queue.popleft()
        for nxt in nexts.get(node, ()):
            if nxt in first:
                continue
            first[nxt] = nxt if node == src else first[node]
            if nxt == dst:
                return first[nxt]
            if nxt in allowed:
                queue.append(nxt)
    return None


def select_dependent(current_nodes: np.ndarray, current_on: np.ndarray, goal_nodes: np.ndarray,
                     goal_on: np.ndarray, goal_index: np.ndarray, current_index: np.ndarray,
                     distances: np.ndarray, graph, supports: list[list[int]],
                     rng: np.random.Generator) -> Decision:
    """The next move under dependencies (module docstring): current entities' nodes (C,) and
    whether each is on the graph, goal entities' nodes (G,) and the same, the alignment's P
    pairs and their isolate distances (P,). A pair with an entity off the graph (the floor's
    slots) is no constraint: it is never in place, satisfiable or pending."""
    constraint = current_on[current_index] & goal_on[goal_index]
    above, holder = _stacks(current_nodes, current_on, supports)
    objects = [c for c in range(len(current_nodes)) if current_on[c]]
    src = current_nodes[current_index].astype(int)
    dst = goal_nodes[goal_index].astype(int)
    pairs = range(len(src))
    in_place = _pairs_in_place(src, dst, constraint, supports)
    placed_nodes = {int(src[j]) for j in pairs if in_place[j]}

    def on_top(c: int) -> bool:
        return not any(holder.get(m) for m in above[int(current_nodes[c])])

    def free(node: int, mover: int) -> bool:        # nothing but `mover` at the node or above it
        return all(c == mover for m in [node, *above[node]] for c in holder.get(m, ()))

    satisfiable = np.array([
        not in_place[j] and constraint[j] and on_top(int(current_index[j]))
        and free(int(dst[j]), int(current_index[j])) and all(s in placed_nodes for s in supports[dst[j]])
        for j in pairs], bool)
    open_nodes = {n for n in range(len(supports)) if not holder.get(n)
                  and all(s in holder for s in supports[n]) and not any(holder.get(m) for m in above[n])}

    def move(entity: int, target: int, rule: str, pair: int | None) -> Decision | None:
        start = int(current_nodes[entity])
        if graph.edges.get((start, target)):
            return Decision(rule, pair, entity, start, target, target, in_place, satisfiable)
        hop = first_hop(graph, start, target, open_nodes)
        if hop is None:
            return None
        return Decision("path" if rule == "direct" else rule, pair, entity, start, hop, target, in_place, satisfiable)

    candidates = np.nonzero(satisfiable)[0]
    weights = np.asarray(distances, np.float64)[candidates] + 1e-12
    for j in (rng.choice(candidates, len(candidates), replace=False, p=weights / weights.sum())
              if len(candidates) else ()):
        decision = move(int(current_index[j]), int(dst[j]), "direct", int(j))
        if decision is not None:
            return decision
    pending = [j for j in pairs if constraint[j] and not in_place[j]]
    if not pending:
        return Decision(None, None, None, None, None, None, in_place, satisfiable)
    # clear: the nodes a pending pair needs (its goal node and above, and the nodes above its entity)
    needed = set()
    for j in pending:
        needed |= {int(dst[j]), *above[dst[j]], *supports[dst[j]], *above[src[j]]}
    movers = [int(current_index[j]) for j in pending]
    blockers = [c for c in objects if on_top(c) and int(current_nodes[c]) in needed
                and not (int(current_nodes[c]) in placed_nodes and c not in movers)]
    blockers = blockers or [c for c in movers if on_top(c)]
    targets = [n for n in sorted(open_nodes) if not supports[n] and n not in needed]
    for c in rng.permutation(blockers) if blockers else ():
        start = int(current_nodes[c])
        direct = [n for n in targets if n != start and graph.edges.get((start, n))]
        for n in ([int(rng.choice(direct))] if direct else []) + [n for n in targets if n != start]:
            decision = move(int(c), n, "clear", None)
            if decision is not None:
                return decision
    return Decision(None, None, None, None, None, None, in_place, satisfiable)


def _stacks(current_nodes: np.ndarray, current_on: np.ndarray,
            supports: list[list[int]]) -> tuple[list[list[int]], dict[int, list[int]]]:
    """above[n]: the nodes node n supports; holder[n]: the current entities (on the graph)
    at node n."""
    above: list[list[int]] = [[] for _ in supports]
    for m, under in enumerate(supports):
        for n in under:
            above[n].append(m)
    holder: dict[int, list[int]] = {}
    for c in range(len(current_nodes)):
        if current_on[c]:
            holder.setdefault(int(current_nodes[c]), []).append(c)
    return above, holder


def _pairs_in_place(src: np.ndarray, dst: np.ndarray, constraint: np.ndarray,
                    supports: list[list[int]]) -> np.ndarray:
    """The constraint pairs whose entity is at its goal node with every support of that node
    held by a pair in place too (a fixed point: a cube on a wrong base is not in place)."""
    pairs = range(len(src))
    in_place = (src == dst) & constraint
    while True:
        placed_nodes = {int(src[j]) for j in pairs if in_place[j]}
        keep = np.array([in_place[j] and all(s in placed_nodes for s in supports[dst[j]]) for j in pairs], bool)
        if (keep == in_place).all():
            return in_place
        in_place = keep
