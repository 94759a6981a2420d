"""NCS for objects that depend on each other (ncs.dependencies): supports, the rules, and the
oracle solving block-stacking with them where the paper's independent NCS does not."""
from collections import Counter

import numpy as np
import pytest
import torch

from ncs_lite.config import NCSConfig
from ncs_lite.data import collect
from ncs_lite.evaluation import TaskSet, evaluate_method
from ncs_lite.ncs import graph_from_buffer
from ncs_lite.ncs.dependencies import first_hop, graph_reach, on_graph, select_dependent, support_relation
from ncs_lite.ncs.graph import TransitionGraph


def test_support_is_the_node_that_always_comes_along():
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(400):
        row = [int(rng.integers(3, 6))]                 # one entity on a floor node 3..5
        if row[0] == 3 and rng.random() < 0.5:
            row.append(0)                                # ... node 0 (under 1) often
        if 0 in row and rng.random() < 0.5:
            row.append(1)                                # 1 only ever on top of 0
        row += [5] * (3 - len(row))                      # pad with a floor node
        frames.append(row)
    nodes = np.array(frames)
    supports = support_relation(nodes, np.ones_like(nodes, bool), 6)
    assert supports[0] == [3]                            # 0 is only ever seen on 3 here ...
    assert supports[1] == [0, 3]                         # ... so 1 stands on both, as a cube on a 2-stack
    assert supports[2] == [] and supports[4] == [] and supports[5] == []
    # an entity off the graph (the floor's slot) supports nothing
    off = nodes == 0
    assert support_relation(nodes, ~off, 6)[1] == [3]


def test_reach_keeps_objects_and_drops_the_floor():
    centroids = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    members = centroids.repeat(10, 1) + 0.01
    reach = graph_reach(members, centroids, "sqeuclidean")
    nodes, on = on_graph(torch.tensor([[0.02, 0.01], [5.0, 5.0]]), centroids, "sqeuclidean", reach)
    assert nodes[0] == 0 and on.tolist() == [True, False]


def _graph(edges, supports):
    return TransitionGraph(torch.zeros(len(supports), 2), "sqeuclidean",
                           {e: Counter({(float(e[0]), float(e[1]), 0.0, 0.0, 0.0, 0.0): 1}) for e in edges},
                           {"supports": supports, "reach": 1.0})


def test_first_hop_goes_through_allowed_nodes_only():
    g = _graph([(0, 1), (1, 2), (0, 3), (3, 2)], [[], [], [], []])
    assert first_hop(g, 0, 2, allowed={1}) == 1
    assert first_hop(g, 0, 2, allowed={3}) == 3
    assert first_hop(g, 0, 2, allowed=set()) is None


def test_a_covered_cube_is_uncovered_then_placed():
    # nodes: 0, 1, 3 floor places; 2 = on top of 0
    supports = [[], [], [0], []]
    g = _graph([(2, 3), (0, 1), (3, 0), (2, 1)], supports)
    rng = np.random.default_rng(0)
    on = np.ones(2, bool)
    pairs = (np.array([0, 1]), np.array([0, 1]))          # goal entity j <-> current entity j
    # X (entity 0) at 0 under Y (entity 1) at 2; goal: X at 1, Y at 0
    d = select_dependent(np.array([0, 2]), on, np.array([1, 0]), on, *pairs, np.ones(2), g, supports, rng)
    assert d.satisfiable.tolist() == [False, False]       # X is covered; Y's goal is X's place
    assert (d.rule, d.entity, d.src, d.dst) == ("clear", 1, 2, 3)
    # Y cleared to 3: X is on top and its goal is free
    d = select_dependent(np.array([0, 3]), on, np.array([1, 0]), on, *pairs, np.ones(2), g, supports, rng)
    assert (d.rule, d.entity, d.src, d.dst) == ("direct", 0, 0, 1)
    # X placed: Y's goal is free
    d = select_dependent(np.array([1, 3]), on, np.array([1, 0]), on, *pairs, np.ones(2), g, supports, rng)
    assert d.in_place.tolist() == [True, False] and (d.rule, d.entity, d.dst) == ("direct", 1, 0)
    d = select_dependent(np.array([1, 0]), on, np.array([1, 0]), on, *pairs, np.ones(2), g, supports, rng)
    assert d.rule is None and d.in_place.all()


def test_a_cube_at_its_place_on_the_wrong_cube_is_not_in_place():
    supports = [[], [], [0], []]
    g = _graph([(2, 3), (0, 1), (3, 0)], supports)
    on = np.ones(2, bool)
    # Y (entity 1) is at its goal node 2, but on X, whose goal is elsewhere (node 1)
    d = select_dependent(np.array([0, 2]), on, np.array([1, 2]), on, np.array([0, 1]), np.array([0, 1]),
                         np.ones(2), g, supports, np.random.default_rng(0))
    assert d.in_place.tolist() == [False, False]
    assert (d.rule, d.entity) == ("clear", 1)


def test_a_pair_off_the_graph_is_no_constraint():
    supports = [[], [], [0], []]
    g = _graph([(0, 1)], supports)
    d = select_dependent(np.array([0, 3]), np.array([True, False]), np.array([1, 3]), np.array([True, False]),
                         np.array([0, 1]), np.array([0, 1]), np.ones(2), g, supports, np.random.default_rng(0))
    assert (d.rule, d.entity, d.dst) == ("direct", 0, 1)
    assert not d.in_place[1] and not d.satisfiable[1]


@pytest.fixture(scope="module")
def stacking_oracle_graph(tmp_path_factory):
    data = collect(tmp_path_factory.mktemp("stacking") / "buffer", episodes=400, env="block-stacking", workers=1)
    return {dep: graph_from_buffer(NCSConfig(clusters=47, state="slot", dependencies=dep), None, data)
            for dep in (True, False)}


def test_the_oracle_stacks_towers_with_dependencies(stacking_oracle_graph):
    tasks = TaskSet(env="block-stacking", num_objects=3, episodes=12, seed=3)
    rows = {dep: evaluate_method("ncs-oracle", tasks, graph=g, ncs=NCSConfig(state="slot", dependencies=dep),
                                 cache=False) for dep, g in stacking_oracle_graph.items()}
    with_rules = np.mean([r["success"] for r in rows[True]])
    assert with_rules >= 0.75
    assert with_rules > np.mean([r["success"] for r in rows[False]])
    assert sum(r["rule_direct"] for r in rows[True]) > 0
    assert "rule_direct" not in rows[False][0]            # no rules without dependencies


def test_the_dependent_path_reads_actions_from_states_and_retries_a_missed_move(stacking_oracle_graph):
    """On block-stacking the graph's edges act through their transitions ("nearest"): the rules'
    move takes the action of the edge's nearest transition, and the same move chosen again
    (the scene did not change: the last try missed) takes the next nearest."""
    from ncs_lite.evaluation import agent_factory
    graph = stacking_oracle_graph[True]
    assert graph.edge_action == "nearest"
    env = TaskSet(env="block-stacking", num_objects=3, episodes=1, seed=3).make_env()
    try:
        agent = agent_factory("ncs-oracle", graph=graph, ncs=NCSConfig(state="slot"))(env)
        for seed in range(20):                           # a task whose first move is direct
            obs, info = env.reset(seed=seed)
            agent.reset(obs, info, seed=seed)
            first, _ = agent.act(obs, info)
            if agent.last["rule"] == "direct":
                break
        ranks = [agent.last["rank"]]
        again, _ = agent.act(obs, info)                 # the same scene: the same decision, retried
        ranks.append(agent.last["rank"])
    finally:
        env.close()
    assert agent.last["rule"] == "direct" and ranks == [0, 1]
    src, dst = agent.last["src"], agent.last["dst"]
    assert any(np.allclose(first, a, atol=1e-6) for a in graph.edges[src, dst])     # one of the edge's own actions
