"""NCS graph (isolate, cluster, bind), policy (align, select-constraint) and the harness."""
import numpy as np
import pytest
import torch

from ncs_lite.config import NCSConfig
from ncs_lite.data import collect, load_buffer
from ncs_lite.evaluation import (TaskSet, agent_factory, check_graph_reading, evaluate, summarize, task_seed,
                                 wilson_interval, write_csv)
from ncs_lite.ncs.graph import TransitionGraph, build_graph, graph_from_buffer, isolate
from ncs_lite.ncs.perception import OraclePerception, pool_masks
from ncs_lite.ncs.policy import align, constraint_distances, type_distances


@pytest.fixture(scope="module")
def buffer_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("buf")
    collect(path, episodes=600, seed=0)   # 2400 moves: all 240 cell pairs seen
    return path


@pytest.fixture(scope="module")
def buffer(buffer_dir):
    return load_buffer(buffer_dir)


@pytest.fixture(scope="module")
def oracle_graph(buffer_dir):
    with pytest.warns(RuntimeWarning, match="empty cluster"):   # 16 cells, 30 clusters
        return graph_from_buffer(NCSConfig(clusters=30), None, buffer_dir)


def test_isolate_finds_the_changed_entity():
    st = torch.rand(5, 4, 10) + 0.1
    st1 = st.clone()
    moved = torch.tensor([0, 3, 1, 2, 3])
    st1[torch.arange(5), moved] = torch.rand(5, 10) + 0.1
    assert torch.equal(isolate(st, st1), moved)
    with pytest.raises(ValueError, match=r"\(M, K, D\)"):
        isolate(st, st1[:, :3])


def test_oracle_graph_has_every_move(oracle_graph):
    assert oracle_graph.info["coverage"] == 1.0
    # 16 cells -> 16 distinct mask states; every cell-to-cell move is an edge (240)
    assert oracle_graph.num_edges == 240
    # the labelled action of an edge moves a cube between the two nodes' cells
    (src, dst), = [e for e in oracle_graph.edges][:1]
    pos = oracle_graph.node_positions()
    a = oracle_graph.action(src, dst)
    to_px = lambda xy: (np.array([xy[0], -xy[1]]) + 0.24) / 0.48 * 64   # arena -> image, approx.
    assert np.linalg.norm(to_px(a[:2]) - pos[src]) < 4
    assert np.linalg.norm(to_px(a[:2] + a[3:5]) - pos[dst]) < 4
    assert oracle_graph.action(src, src) is None


def test_graph_save_load_round_trip(oracle_graph, tmp_path):
    path = oracle_graph.save(tmp_path / "g.pt")
    loaded = TransitionGraph.load(path)
    assert loaded.edges == oracle_graph.edges
    torch.testing.assert_close(loaded.centroids, oracle_graph.centroids)
    assert loaded.info["coverage"] == 1.0
    torch.save({"weights": torch.zeros(2)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an ncs-lite transition graph"):
        TransitionGraph.load(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError, match="python -m ncs_lite graph"):
        TransitionGraph.load(tmp_path / "missing.pt")


def test_the_papers_steps_by_name_make_the_graph(buffer):
    """`from ncs_lite.ncs import ...` the six steps; build_graph is isolate, cluster and bind."""
    from ncs_lite.ncs import align, bind, cluster, select_constraint, split  # noqa: F401

    st, st1, actions, _ = OraclePerception().transitions(buffer)
    st, st1, actions = st[:200], st1[:200], actions[:200]
    graph = build_graph(st, st1, actions, clusters=8)
    moved = isolate(st, st1)
    rows = torch.arange(len(moved))
    before, after = st[rows, moved], st1[rows, moved]                    # (M, D) each
    nodes = cluster(torch.cat([before, after]), 8, "mask")
    assert torch.equal(graph.centroids, nodes.centroids) and graph.bind_metric == "cosine"
    src, dst = bind(before, nodes.centroids, "cosine"), bind(after, nodes.centroids, "cosine")
    assert set(graph.edges) == {(s, d) for s, d in zip(src.tolist(), dst.tolist()) if s != d}
    assert torch.equal(graph.bind(before), src)
    slots = torch.rand(2, 3, 10)
    types, states = split(slots, 4)                                       # [type z ; state s]
    assert types.shape == (2, 3, 4) and torch.equal(torch.cat([types, states], -1), slots)


def test_build_graph_checks_actions():
    st = torch.rand(3, 2, 4)
    with pytest.raises(ValueError, match=r"actions must have shape \(3, 6\)"):
        build_graph(st, st, np.zeros((3, 5)), clusters=2)


def test_align_matches_types_despite_permutation():
    types = torch.eye(5)[:4] * 3
    perm = torch.tensor([2, 0, 3, 1])
    g, c, cost = align(types, types[perm] + 0.01)
    np.testing.assert_array_equal(c[np.argsort(g)], perm.numpy())
    assert torch.equal(cost, type_distances(types, types[perm] + 0.01))      # what it matched on, (G, C)


def test_mutual_align_drops_entities_without_a_counterpart():
    # a partial goal: the goal shows cubes 0 and 2 and the floor (3); the current image also
    # cube 1, which the plain matching pairs with a leftover goal slot (4, far from every type)
    current = torch.tensor([[0.0, 0], [5, 0], [0, 5], [9, 9]])
    goal = torch.tensor([[0.1, 0], [0, 5.1], [9, 9.1], [-20, -20]])
    g, c, _ = align(current, goal)
    assert sorted(zip(g.tolist(), c.tolist())) == [(0, 0), (1, 2), (2, 3), (3, 1)]
    for rule in ("mutual", "either", "near"):
        g, c, _ = align(current, goal, rule)
        assert sorted(zip(g.tolist(), c.tolist())) == [(0, 0), (1, 2), (2, 3)]
    # a spare goal slot that copies part of cube 0 is cube 0's nearest type: "mutual" drops
    # the cube's pair, "either" keeps it (the cube is still its own goal slot's nearest)
    current = torch.tensor([[0.0, 0], [5, 0], [1, 0]])        # cube 0, cube 1, a spare slot
    goal = torch.tensor([[0.0, 0.2], [5, 0.1], [0.1, 0]])       # cube 0, cube 1, a spare slot
    assert sorted(zip(*(a.tolist() for a in align(current, goal, "either")[:2]))) == [(0, 0), (1, 1), (2, 2)]
    assert sorted(zip(*(a.tolist() for a in align(current, goal, "mutual")[:2]))) == [(1, 1)]
    # "near" keeps the two cubes and drops the spare slots' pair (far apart for one entity)
    assert sorted(zip(*(a.tolist() for a in align(current, goal, "near")[:2]))) == [(0, 0), (1, 1)]
    # a partial goal: cube 1 is unconstrained and its nearest goal type is a spare slot far from
    # it; "either" pairs them (cube 1 would be moved), "near" does not
    current = torch.tensor([[0.0, 0], [5, 0], [0, 9]])         # cube 0, cube 1, floor
    goal = torch.tensor([[0.1, 0], [0, 9.1], [6, 4]])           # cube 0, floor, a spare slot
    assert (2, 1) in zip(*(a.tolist() for a in align(current, goal, "either")[:2]))
    assert sorted(zip(*(a.tolist() for a in align(current, goal, "near")[:2]))) == [(0, 0), (1, 2)]
    same = torch.zeros(4, 3)                                    # identical types stay paired
    assert [a.tolist() for a in align(same, same[:2], "near")[:2]] == [[0, 1], [0, 1]]
    types = torch.eye(5)[:4] * 3                               # counterparts all round: no change
    perm = torch.tensor([2, 0, 3, 1])
    for rule in ("mutual", "either", "near"):
        for a, b in zip(align(types, types[perm] + 0.01, "hungarian")[:2], align(types, types[perm] + 0.01, rule)[:2]):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="align rule must be one of 'hungarian', 'mutual', 'either', 'near', got 'best'"):
        align(types, types, "best")


def test_select_constraint_samples_only_unsatisfied_pairs():
    """select-constraint: a pair whose two states bind to one node is satisfied (unless
    `same_node` is off, as for edge actions read from states); the pair is drawn in proportion
    to the rest of the distances, and with none left nothing is drawn from the generator."""
    from ncs_lite.ncs.policy import select_constraint

    graph = TransitionGraph(torch.eye(4), "cosine")                 # node i = unit vector e_i
    current = torch.eye(4)[[0, 1, 2]] + torch.tensor([[0.0, 0, 0, 0], [0, 0, 0.1, 0], [0, 0, 0, 0]])
    goal = torch.eye(4)[[0, 3, 2]] + torch.tensor([[0.0, 0.05, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    rng = np.random.default_rng(0)
    chosen = select_constraint(current, goal, graph, rng)
    assert chosen.same_node.tolist() == [True, False, True] and chosen.raw_distances[0] > 0
    assert chosen.probabilities.tolist() == [0.0, 1.0, 0.0] and (chosen.selected, chosen.src, chosen.dst) == (1, 1, 3)
    loose = select_constraint(current, goal, graph, rng, same_node=False)
    assert not loose.same_node.any() and loose.probabilities[0] > 0
    np.testing.assert_array_equal(loose.distances, loose.raw_distances)
    before = rng.bit_generator.state
    done = select_constraint(current[[0, 2]], goal[[0, 2]], graph, rng)
    assert done.selected is None and done.src is None and not done.probabilities.any()
    assert rng.bit_generator.state == before


def test_constraint_distance_zero_when_satisfied():
    s = torch.rand(3, 8)
    d = constraint_distances(s, torch.cat([s[:2], torch.rand(1, 8)]))
    assert d[:2].abs().max() < 1e-6 and d[2] > 0


def test_agent_treats_same_node_pairs_as_satisfied():
    """A pair whose current and goal states bind to one node is never selected: the graph
    has no transition for it (policy.py). Only the other pair can be chosen."""
    from collections import Counter

    import gymnasium as gym

    from ncs_lite.ncs.perception import Entities
    from ncs_lite.ncs.policy import NCSAgent

    centroids = torch.eye(4)                       # node i = unit vector e_i
    graph = TransitionGraph(centroids, "cosine", {(2, 3): Counter({(1.0,) * 6: 1})})
    types = torch.eye(2)
    # pair 0: current e_0 + noise vs goal e_0 (same node 0, distance > 0); pair 1: e_2 -> e_3
    current = Entities(types, torch.stack([torch.tensor([1.0, 0.3, 0, 0]), torch.eye(4)[2]]))
    goal = Entities(types, torch.stack([torch.eye(4)[0], torch.eye(4)[3]]))

    class Fixed:
        def current(self, obs, info):
            return current

        def goal(self, obs, info):
            return goal

    space = gym.spaces.Box(-1, 1, (6,))
    agent = NCSAgent(graph, Fixed(), space, seed=0)
    agent.reset(None, None)
    for _ in range(20):
        action, was_random = agent.act(None, None)
        assert not was_random and agent.last["selected"] == 1
        np.testing.assert_array_equal(action, np.ones(6, np.float32))
    assert agent.last["distances"][0] == 0


def test_pool_masks():
    m = np.zeros((2, 64, 64), bool)
    m[0, :4, :4] = True
    p = pool_masks(m)
    assert p.shape == (2, 256) and p[0, 0] == 1 and p.sum() == 1
    with pytest.raises(ValueError, match="multiple"):
        pool_masks(np.zeros((1, 30, 30)))


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(50, 100)
    assert abs(lo - 0.4038) < 1e-3 and abs(hi - 0.5962) < 1e-3
    assert wilson_interval(0, 10)[0] == 0 and wilson_interval(10, 10)[1] == pytest.approx(1)
    with pytest.raises(ValueError):
        wilson_interval(0, 0)


def test_oracle_solves_tasks_and_random_does_not(oracle_graph, tmp_path):
    tasks = TaskSet(num_objects=5, episodes=10, seed=3)
    oracle = evaluate(agent_factory("ncs-oracle", graph=oracle_graph), tasks, "ncs-oracle")
    rand = evaluate(agent_factory("random"), tasks, "random")
    # identical task sets across methods
    assert [r["task_seed"] for r in oracle] == [r["task_seed"] for r in rand]
    assert [r["task_seed"] for r in oracle] == [task_seed(3, i) for i in range(10)]
    s_oracle, s_rand = summarize(oracle)[0], summarize(rand)[0]
    assert s_oracle["success"] == 1.0 and s_oracle["mean_steps"] == 5 and s_oracle["random_fraction"] == 0
    assert s_rand["success"] == 0.0 and s_rand["random_fraction"] == 1.0
    # every oracle action moves a cube; a random pick mostly finds none
    assert s_oracle["noop_fraction"] == 0 and 0.5 < s_rand["noop_fraction"] <= 1
    path = write_csv(oracle + rand, tmp_path / "r.csv")
    assert path.read_text().splitlines()[0].startswith("method,env,num_objects")
    assert len(path.read_text().splitlines()) == 21
    # rows with more columns than the first (an agent with the dependency rules counts them) add them
    ruled = [{**r, "rule_direct": 3} for r in oracle[:2]]
    lines = write_csv(rand[:1] + ruled, tmp_path / "m.csv").read_text().splitlines()
    assert lines[0].endswith(",rule_direct") and lines[1].endswith(",") and lines[2].endswith(",3")


def test_an_action_that_moves_nothing_is_counted_as_a_noop():
    class PicksTheFloor:                    # a pick at an outer corner, where no cube can be
        def reset(self, obs, info, seed=None):
            pass

        def act(self, obs, info):
            return np.array([0.2, 0.2, 0.02, -0.1, 0.0, 0.0], np.float32), False

    tasks = TaskSet(num_objects=2, episodes=2, seed=0)
    rows = evaluate(lambda env: PicksTheFloor(), tasks, "floor")
    assert all(r["noop_actions"] == r["steps"] > 0 and r["random_actions"] == 0 for r in rows)
    assert summarize(rows)[0]["noop_fraction"] == 1.0


def test_oracle_partial_goals(oracle_graph):
    tasks = TaskSet(num_objects=6, goal="partial", num_constrained=3, episodes=5)
    s = summarize(evaluate(agent_factory("ncs-oracle", graph=oracle_graph), tasks, "o"))[0]
    assert s["success"] == 1.0 and s["mean_steps"] == 3


def test_agent_factory_errors():
    with pytest.raises(ValueError, match="unknown method"):
        agent_factory("ncs-magic")
    with pytest.raises(ValueError, match="needs a transition graph"):
        agent_factory("ncs-oracle")
    with pytest.raises(ValueError, match="episodes must be"):
        TaskSet(episodes=0)


def test_cli_graph_and_evaluate(tmp_path, capsys):
    import json

    from ncs_lite.__main__ import main

    collect(tmp_path / "buf", episodes=30, seed=0)
    assert main(["graph", "--oracle", "--data", str(tmp_path / "buf"), "--clusters", "16",
                 "--out", str(tmp_path / "g.pt")]) == 0
    built = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert built["nodes"] == 16 and built["coverage"] == 1.0
    assert main(["evaluate", "--method", "ncs-oracle", "--graph", str(tmp_path / "g.pt"),
                 "--num-objects", "3", "--episodes", "4", "--out", str(tmp_path / "r.csv")]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["method"] == "ncs-oracle" and summary["episodes"] == 4
    assert 0 <= summary["ci_low"] <= summary["success"] <= summary["ci_high"] <= 1
    assert (tmp_path / "r.csv").exists()
    # errors are reported, not raised
    assert main(["graph", "--data", str(tmp_path / "buf"), "--out", str(tmp_path / "x.pt")]) == 2
    assert "exactly one of --checkpoint" in capsys.readouterr().err
    assert main(["evaluate", "--method", "ncs-oracle", "--graph", str(tmp_path / "g.pt"), "--state", "slot",
                 "--episodes", "2"]) == 2
    assert "built on 'mask' states" in capsys.readouterr().err
    # without --graph: the shipped oracle graph
    assert main(["evaluate", "--method", "ncs-oracle", "--episodes", "2", "--num-objects", "3"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["success"] == 1.0


def test_agent_records_a_fallback_and_the_oracle_masks(oracle_graph):
    """`last` says why an action was random, and the oracle's entities carry their masks."""
    import gymnasium as gym

    from ncs_lite.envs import make
    from ncs_lite.ncs.perception import Entities
    from ncs_lite.ncs.policy import NCSAgent, aligned_masks

    env = make("block-rearrange", num_objects=4)
    obs, info = env.reset(seed=1)
    env.close()
    agent = NCSAgent(oracle_graph, OraclePerception(), gym.spaces.Box(-1, 1, (6,)), seed=0)
    agent.reset(obs, info)
    action, was_random = agent.act(obs, info)
    last = agent.last
    assert not was_random and last["fallback"] is None and np.array_equal(last["action"], action)
    goal_masks, current_masks = aligned_masks(last)
    np.testing.assert_array_equal(current_masks.bool().numpy(), info["masks"][last["current_index"]])
    np.testing.assert_array_equal(goal_masks.bool().numpy(), info["goal_masks"][last["goal_index"]])
    assert last["probabilities"].sum() == pytest.approx(1.0) and not last["same_node"].any()

    # a graph without the needed edge: a random action, and `last` says so
    empty = TransitionGraph(oracle_graph.centroids, oracle_graph.bind_metric, {})
    agent = NCSAgent(empty, OraclePerception(), gym.spaces.Box(-1, 1, (6,)), seed=0)
    agent.reset(obs, info)
    action, was_random = agent.act(obs, info)
    assert was_random and agent.last["fallback"] == "no edge" and agent.last["selected"] is not None
    # a perception without masks cannot be drawn
    with pytest.raises(ValueError, match="records no masks"):
        aligned_masks({**agent.last, "current": Entities(torch.zeros(1, 2), torch.zeros(1, 4))})


def test_adjacency_and_node_order(oracle_graph):
    adj = oracle_graph.adjacency()
    assert adj.shape == (30, 30) and int((adj > 0).sum()) == oracle_graph.num_edges == 240
    assert int(adj.sum()) == sum(sum(c.values()) for c in oracle_graph.edges.values())
    assert int(adj.diagonal().sum()) == 0                                      # no self-loops
    order = oracle_graph.node_order()
    assert sorted(order.tolist()) == list(range(30))
    used = [i for i in order if adj[i].sum() + adj[:, i].sum() > 0]           # the 16 cells' nodes
    xy = oracle_graph.node_positions()[used]
    rows = np.concatenate([[0], np.cumsum(np.diff(xy[:, 1]) > 6)])
    assert rows[-1] == 3 and np.all(np.diff(xy[:, 1]) > -6)                    # 4 rows, top to bottom
    for r in range(4):
        assert np.all(np.diff(xy[rows == r, 0]) >= 0)                          # each row left to right


def test_cached_loads_what_it_stored_and_recomputes_on_a_new_key(tmp_path, monkeypatch, capsys):
    from ncs_lite.cache import cache_path, cached, digest

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return (torch.arange(3), np.array([True, False]), {"rows": [{"a": 1, "b": None}]})

    first = cached("thing", compute, model=digest(torch.ones(2)), k=4)
    again = cached("thing", compute, model=digest(torch.ones(2)), k=4)
    assert len(calls) == 1 and "loaded thing" in capsys.readouterr().out
    assert isinstance(again, tuple) and isinstance(again[1], np.ndarray) and again[1].dtype == bool
    assert torch.equal(again[0], first[0]) and again[2] == first[2]
    cached("thing", compute, model=digest(torch.ones(2)), k=5)                 # another parameter
    cached("thing", compute, model=digest(torch.zeros(2)), k=4)               # another input
    assert len(calls) == 3
    # an unreadable file is recomputed and replaced, and the message says why
    cache_path("thing", model=digest(torch.ones(2)), k=4).write_bytes(b"not a torch file")
    cached("thing", compute, model=digest(torch.ones(2)), k=4)
    assert len(calls) == 4 and "cannot be read" in capsys.readouterr().out
    with pytest.raises(TypeError, match="cannot cache"):
        cached("other", lambda: object())
    with pytest.raises(TypeError, match="must hold digests"):
        cached("other", compute, model=torch.ones(2))
    assert digest(torch.ones(2)) != digest(torch.ones(2, dtype=torch.float64))
    assert digest({"a": 1, "b": 2}) == digest({"b": 2, "a": 1}) != digest({"a": 1, "b": 3})


def test_load_or_train_loads_resumes_or_retrains(tmp_path, capsys):
    """The one "load if present, else train" of obtain_dslate and obtain_policy: a finished,
    fitting run is loaded; an unfinished one resumed; an unfit one, or any asked from scratch,
    retrained; each decision but loading printed."""
    from ncs_lite.cache import load_or_train

    path, trained = tmp_path / "run.pt", []
    state = {"step": 0, "fits": True}

    def train(resume, force):
        trained.append((resume, force))
        path.write_text("run")
        state["step"] = 10

    def obtain(from_scratch=False):
        return load_or_train(path, unfit=lambda p: None if state["fits"] else "another config",
                             unfinished=lambda p: None if state["step"] >= 10 else f"at step {state['step']}",
                             train=train, load=lambda p: p.read_text(), who="obtain", from_scratch=from_scratch)

    assert obtain() == "run" and trained == [(False, False)]             # no run: trained
    assert obtain() == "run" and len(trained) == 1 and capsys.readouterr().out == ""   # finished: loaded
    state["step"] = 4
    obtain()
    assert trained[-1] == (True, False) and "obtain: resuming" in capsys.readouterr().out
    state["fits"] = False
    obtain()
    assert trained[-1] == (False, True) and "from scratch: another config" in capsys.readouterr().out
    state["fits"] = True
    obtain(from_scratch=True)
    assert trained[-1] == (False, True) and "train_from_scratch=True" in capsys.readouterr().out


def test_load_or_train_waits_for_another_process_making_the_same_run(tmp_path, capsys):
    """Two callers asking for one run at once (two notebooks, two test workers): the second
    waits while the first trains, then loads the run instead of training it again (the run's
    own lock would otherwise fail it). Threads stand in for processes: each opens the lock file
    itself, and flock excludes two open files as it excludes two processes."""
    import threading

    from ncs_lite.cache import load_or_train

    path, trained, training = tmp_path / "run.pt", [], threading.Event()
    release = threading.Event()

    def train(resume, force):
        trained.append(threading.current_thread().name)
        training.set()
        assert release.wait(10)
        path.write_text("run")

    def obtain(results):
        results.append(load_or_train(path, unfit=lambda p: None, unfinished=lambda p: None, train=train,
                                     load=lambda p: p.read_text(), who="obtain"))

    results = []
    first = threading.Thread(target=obtain, args=(results,), name="first")
    first.start()
    assert training.wait(10)
    second = threading.Thread(target=obtain, args=(results,), name="second")
    second.start()
    second.join(0.5)
    assert second.is_alive() and "waiting for it" in capsys.readouterr().out     # blocked, not failed
    release.set()
    for thread in (first, second):
        thread.join(10)
    assert results == ["run", "run"] and trained == ["first"]


def test_buffer_transitions_cached_by_buffer_perception_and_code(tmp_path, monkeypatch, capsys):
    from ncs_lite.cache import code_digest
    from ncs_lite.ncs.perception import buffer_transitions

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path / "cache"))
    collect(tmp_path / "small", episodes=3, seed=0)
    perception = OraclePerception()
    first = buffer_transitions(perception, tmp_path / "small")
    assert "computed transitions" in capsys.readouterr().out
    again = buffer_transitions(perception, tmp_path / "small")
    assert "loaded transitions" in capsys.readouterr().out
    for a, b in zip(first, again):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    expected = perception.transitions(load_buffer(tmp_path / "small"))
    torch.testing.assert_close(again[0], expected[0])
    # another buffer is another key
    collect(tmp_path / "other", episodes=3, seed=1)
    buffer_transitions(perception, tmp_path / "other")
    assert "computed transitions" in capsys.readouterr().out
    # the code digest changes with the source
    assert code_digest("models") != code_digest("ncs/perception.py")


# ------------------------------------------------------------------ slot states (Table 3, s)
@pytest.fixture(scope="module")
def position_graph(buffer_dir):
    """The oracle's graph on cube positions, the ground-truth stand-in for slot states."""
    return graph_from_buffer(NCSConfig(clusters=16, state="slot"), None, buffer_dir)


def test_ncs_config_state_error():
    from ncs_lite.config import ENTITY_STATES, NCSConfig, ncs_config
    from ncs_lite.ncs.graph import METRICS_BY_STATE

    assert NCSConfig().state == "mask" and ncs_config(["ncs.state=slot"]).state == "slot"
    with pytest.raises(ValueError, match=r"^ncs\.state must be one of 'mask', 'slot', got 'pixel'$"):
        ncs_config(state="pixel")
    with pytest.raises(ValueError, match=r"ncs\.state must be one of 'mask', 'slot', got 'Slot'"):
        ncs_config(["ncs.state=Slot"])
    assert tuple(METRICS_BY_STATE) == ENTITY_STATES     # config's states are Table 3's columns


def test_slot_graph_binds_with_sqeuclidean():
    """Three slot states A = (1, 0), B = (0, 1), C = (2, 0); moves A -> B and B -> C. Under
    cosine A and C are one direction; the slot graph's squared Euclidean tells them apart."""
    a, b, c = torch.tensor([1.0, 0]), torch.tensor([0, 1.0]), torch.tensor([2.0, 0])
    still = torch.tensor([-1.0, -1.0])                 # the other entity never moves
    st = torch.stack([torch.stack([a, still]), torch.stack([still, b])] * 4)      # (8, 2, 2)
    st1 = torch.stack([torch.stack([b, still]), torch.stack([still, c])] * 4)
    actions = np.array([[1.0] * 6, [2.0] * 6] * 4, np.float32)
    graph = build_graph(st, st1, actions, clusters=3, state="slot", true_entity=np.array([0, 1] * 4))
    assert graph.bind_metric == "sqeuclidean" and graph.state == "slot"
    assert graph.info["metrics"] == {"isolate": "cosine", "cluster": "sqeuclidean", "bind": "sqeuclidean"}
    assert graph.info["coverage"] == 1.0
    na, nb, nc = graph.bind(torch.stack([a, b, c])).tolist()
    assert len({na, nb, nc}) == 3
    assert graph.bind(torch.tensor([[1.8, 0.0], [1.1, 0.0]])).tolist() == [nc, na]
    np.testing.assert_array_equal(graph.action(nb, nc), np.full(6, 2.0, np.float32))
    assert build_graph(st, st1, actions, clusters=3).bind_metric == "cosine"   # the mask column
    # the loaded graph keeps its state; a graph without one (written before it was recorded) is a mask graph
    assert TransitionGraph(graph.centroids, "cosine", {}, {}).state == "mask"


def test_agent_on_slot_graph_ranks_by_cosine_and_binds_sqeuclidean():
    """select-constraint ranks by the isolate (cosine) distance, bind uses the graph's metric:
    the goal (2.2, 0) binds to C, so the agent takes the edge B -> C; a perception of
    another kind of state is refused."""
    from collections import Counter

    import gymnasium as gym

    from ncs_lite.ncs.perception import Entities
    from ncs_lite.ncs.policy import NCSAgent

    centroids = torch.tensor([[1.0, 0], [0, 1.0], [2.0, 0]])          # A, B, C
    graph = TransitionGraph(centroids, "sqeuclidean", {(1, 2): Counter({(2.0,) * 6: 1})}, {"state": "slot"})
    types = torch.eye(2)
    current = Entities(types, torch.tensor([[1.0, 0], [0, 1.0]]))    # pair 0 at A, pair 1 at B
    goal = Entities(types, torch.tensor([[1.1, 0], [2.2, 0]]))       # A again; C

    class Fixed:
        graph_state = "slot"

        def current(self, obs, info):
            return current

        def goal(self, obs, info):
            return goal

    agent = NCSAgent(graph, Fixed(), gym.spaces.Box(-1, 1, (6,)), seed=0)
    agent.reset(None, None)
    action, was_random = agent.act(None, None)
    last = agent.last
    assert not was_random and last["selected"] == 1 and (last["src"], last["dst"]) == (1, 2)
    np.testing.assert_array_equal(action, np.full(6, 2.0, np.float32))
    np.testing.assert_allclose(last["raw_distances"], [0.0, 1.0], atol=1e-6)   # cosine, not Euclidean
    assert last["src_nodes"].tolist() == [0, 1] and last["dst_nodes"].tolist() == [0, 2]
    assert last["same_node"].tolist() == [True, False] and last["probabilities"].tolist() == [0.0, 1.0]
    Fixed.graph_state = "mask"
    with pytest.raises(ValueError, match="built on 'slot' states but the agent would read 'mask'"):
        NCSAgent(graph, Fixed(), gym.spaces.Box(-1, 1, (6,)), seed=0)


def test_oracle_position_state(buffer, position_graph):
    """Positions: D = 3, every move isolated and every cell-to-cell move an edge."""
    from ncs_lite.ncs.graph import isolate_distance

    perception = OraclePerception("position")
    assert perception.graph_state == "slot" and OraclePerception().graph_state == "mask"
    assert perception.describe()["state"] == "position" != OraclePerception().describe()["state"]
    st, st1, actions, moved = perception.transitions(buffer)
    assert st.shape == (600 * 4, 4, 3)
    torch.testing.assert_close(st[5], torch.as_tensor(buffer["positions"][1, 1]))   # episode 1, t = 1
    assert position_graph.bind_metric == "sqeuclidean" and position_graph.state == "slot"
    assert position_graph.info["coverage"] == 1.0 and position_graph.num_edges == 240
    # why z stays in the state: (x, y) alone has no cosine distance along a ray through the
    # grid's centre, so such a move would not be isolated (coverage < 1)
    p, q = torch.tensor([0.05, 0.05, 0.03]), torch.tensor([0.15, 0.15, 0.03])
    assert isolate_distance(p[:2], q[:2]) < 1e-6 < isolate_distance(p, q)
    with pytest.raises(ValueError, match="oracle state must be one of \\['mask', 'position'\\], got 'slot'"):
        OraclePerception("slot")


def test_oracle_position_solves_tasks_random_does_not(position_graph):
    from ncs_lite.config import NCSConfig

    tasks = TaskSet(num_objects=5, episodes=8, seed=3)
    slot = NCSConfig(state="slot")
    oracle = summarize(evaluate(agent_factory("ncs-oracle", graph=position_graph, ncs=slot), tasks, "o"))[0]
    rand = summarize(evaluate(agent_factory("random"), tasks, "random"))[0]
    assert oracle["success"] == 1.0 > rand["success"]
    assert oracle["mean_steps"] == 5 and oracle["random_fraction"] == 0     # one move per cube
    partial = TaskSet(num_objects=6, goal="partial", num_constrained=3, episodes=4)
    s = summarize(evaluate(agent_factory("ncs-oracle", graph=position_graph, ncs=slot), partial, "o"))[0]
    assert s["success"] == 1.0 and s["mean_steps"] == 3
    with pytest.raises(ValueError, match="built on 'slot' states but the agent would read 'mask'"):
        agent_factory("ncs-oracle", graph=position_graph)       # default ncs.state = mask


def test_state_reaches_perception_and_cache_keys(position_graph, oracle_graph, monkeypatch):
    from types import SimpleNamespace

    import ncs_lite.evaluation
    from ncs_lite.config import NCSConfig
    from ncs_lite.evaluation import evaluate_method, learned_perception
    from ncs_lite.ncs.perception import RESTARTS, RESTARTS_BY_ENV

    model = SimpleNamespace(cfg=SimpleNamespace(slots=SimpleNamespace(num_slots=3, position_state=False)))
    assert learned_perception(model, 4, NCSConfig(state="slot")).state == "slot"
    assert learned_perception(model, 4).state == "mask"
    # restarts: the config's, else those of the env the model was trained on
    assert learned_perception(model, 4).restarts == RESTARTS            # a model that names no env
    for env, restarts in RESTARTS_BY_ENV.items():
        model.checkpoint_info = {"env": env}
        assert learned_perception(model, 4).restarts == restarts
        assert learned_perception(model, 4, NCSConfig(restarts=3)).restarts == 3
    assert RESTARTS_BY_ENV["block-rearrange"] > NCSConfig().graph_restarts == RESTARTS
    keys = []
    monkeypatch.setattr(ncs_lite.evaluation, "cached", lambda name, compute, **key: keys.append(key) or [])
    tasks = TaskSet(episodes=1)
    evaluate_method("ncs", tasks, graph=position_graph, model=torch.nn.Linear(1, 1), ncs=NCSConfig(state="slot"))
    evaluate_method("ncs", tasks, graph=oracle_graph, model=torch.nn.Linear(1, 1), ncs=NCSConfig())
    evaluate_method("ncs-oracle", tasks, graph=position_graph, ncs=NCSConfig(state="slot"))
    evaluate_method("ncs-oracle", tasks, graph=oracle_graph)
    assert [k["state"] for k in keys] == ["slot", "mask", "slot", "mask"]
    assert keys[0]["ncs"]["state"] == "slot" and keys[1]["ncs"]["state"] == "mask"
    assert keys[0]["ncs"] != keys[1]["ncs"] and keys[2] != keys[3]


def test_cli_slot_state_and_mismatch(tmp_path, capsys, monkeypatch):
    import json

    from ncs_lite.__main__ import main

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path / "cache"))
    collect(tmp_path / "buf", episodes=30, seed=0)
    data = ["--data", str(tmp_path / "buf"), "--clusters", "16"]
    slot, mask = str(tmp_path / "slot.pt"), str(tmp_path / "mask.pt")
    assert main(["graph", "--oracle", *data, "--state", "slot", "--out", slot]) == 0
    built_slot = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert built_slot["state"] == "slot" and built_slot["coverage"] == 1.0
    g = TransitionGraph.load(slot)
    assert (g.state, g.bind_metric, g.centroids.shape[1]) == ("slot", "sqeuclidean", 3)
    assert g.info["ncs"]["state"] == "slot" and g.info["perception_state"] == "position"
    assert main(["graph", "--oracle", *data, "--set", "ncs.state=mask", "--out", mask]) == 0
    built_mask = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert TransitionGraph.load(mask).state == built_mask["state"] == "mask"
    # ground truth either way: the same 16 cells, the same cell-to-cell moves
    assert built_slot["edges"] == built_mask["edges"] == TransitionGraph.load(mask).num_edges
    run = ["evaluate", "--method", "ncs-oracle", "--num-objects", "3", "--episodes", "2"]
    # without --state the agent reads the graph's state
    assert main([*run, "--graph", slot]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["episodes"] == 2
    assert main([*run, "--graph", slot, "--state", "slot"]) == 0
    capsys.readouterr()
    # a state the graph was not built on is refused, in one line naming both
    for graph, flag, built in ((slot, ["--state", "mask"], "slot"), (mask, ["--state", "slot"], "mask"),
                               (mask, ["--set", "ncs.state=slot"], "mask")):
        assert main([*run, "--graph", graph, *flag]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and len(captured.err.strip().splitlines()) == 1
        assert f"--graph {graph}: the graph was built on {built!r} states" in captured.err
    # a graph written before the state was recorded is a mask graph
    sd = torch.load(mask, weights_only=True)
    del sd["info"]["state"]
    torch.save(sd, tmp_path / "old.pt")
    assert main([*run, "--graph", str(tmp_path / "old.pt"), "--state", "slot"]) == 2
    assert "built on 'mask' states" in capsys.readouterr().err
    assert main([*run, "--graph", str(tmp_path / "old.pt")]) == 0
    capsys.readouterr()
    assert main(["graph", "--oracle", *data, "--state", "pixel", "--out", str(tmp_path / "x.pt")]) == 2
    assert "ncs.state must be one of 'mask', 'slot', got 'pixel'" in capsys.readouterr().err


def test_learned_slot_states_end_to_end(tmp_path):
    """An untrained `ci` dSLATE (no training: only the code path): slot states are the state
    half s of the slot, the graph on them binds with squared Euclidean, and the `ncs` agent
    acts on them."""
    from ncs_lite.config import NCSConfig, get_preset
    from ncs_lite.models import DSlate
    from ncs_lite.ncs.perception import DSlatePerception

    torch.manual_seed(0)
    model = DSlate(get_preset("ci")).eval()
    state_dim = model.cfg.slots.state_dim
    collect(tmp_path / "buf", episodes=3, seed=0)
    buf = load_buffer(tmp_path / "buf")
    st, st1, actions, _ = DSlatePerception(model, iterations=2, state="slot", restarts=1).transitions(buf)
    assert st.shape == (3 * 4, 3, state_dim)
    expected = model.infer_video(buf["frames"], iterations=2).states[:, 1:].flatten(0, 1)
    torch.testing.assert_close(st1, expected.float())
    graph = build_graph(st, st1, actions, clusters=4, state="slot")
    assert graph.bind_metric == "sqeuclidean" and graph.centroids.shape == (4, state_dim)
    ncs = NCSConfig(state="slot", restarts=1, iterations=2)
    tasks = TaskSet(num_objects=2, episodes=1, horizon_multiplier=1.0)
    env = tasks.make_env()
    try:
        agent = agent_factory("ncs", graph=graph, model=model, ncs=ncs)(env)
        obs, info = env.reset(seed=0)
        agent.reset(obs, info)
        agent.act(obs, info)
    finally:
        env.close()
    assert agent.perception.state == "slot" and agent.last["current"].states.shape == (3, state_dim)
    assert agent.last["src_nodes"].shape == agent.last["raw_distances"].shape == (3,)   # 3 slots each
    with pytest.raises(ValueError, match="built on 'slot' states but the agent would read 'mask'"):
        agent_factory("ncs", graph=graph, model=model)


def test_assigned_slot_states_read_the_cells_each_slot_wins(tmp_path):
    """`slot_position` "assigned": a slot's centroid and spread over the cells where its
    attention is the largest, with the model's prior; a slot that wins none reads the prior
    alone. Block-rearrange models read this way, with one slot per object plus the floor's."""
    from ncs_lite.config import NCSConfig, apply_overrides, get_preset, ncs_config
    from ncs_lite.evaluation import learned_perception
    from ncs_lite.models import DSlate
    from ncs_lite.ncs.perception import DSlatePerception

    torch.manual_seed(0)
    model = DSlate(get_preset("ci")).eval()
    coords, prior = model.grid_coords.float(), model.cfg.slots.position_prior
    attn = torch.rand(2, 3, coords.shape[0])
    attn[:, 2] = 0.0                                                   # slot 2 wins no cell
    attn = attn / attn.sum(1, keepdim=True)
    states = torch.randn(2, 3, model.cfg.slots.state_dim)
    got = model.assigned_states(states, attn)
    for b in range(2):
        for k in range(3):
            won = coords[attn[b].argmax(0) == k]                       # (n, 2)
            mass = len(won) + prior
            centre = won.sum(0) / mass
            spread = ((won.pow(2).sum(0) + prior / 3) / mass - centre.pow(2)).sqrt()
            torch.testing.assert_close(got[b, k, -4:], torch.cat([centre, spread]))
    torch.testing.assert_close(got[:, 2, -4:], torch.tensor([0.0, 0.0, 3 ** -0.5, 3 ** -0.5]).expand(2, 4))
    torch.testing.assert_close(got[..., :-4], states[..., :-4])         # the rest of s is kept
    # the perception reads it for graphs and agents alike; the model's own s by default
    collect(tmp_path / "buf", episodes=2, seed=0)
    buf = load_buffer(tmp_path / "buf")
    read = DSlatePerception(model, iterations=2, state="slot", restarts=1, slot_position="assigned")
    st, st1, _, _ = read.transitions(buf)
    r = model.infer_video(buf["frames"], iterations=2)
    torch.testing.assert_close(st1, model.assigned_states(r.states, r.attention)[:, 1:].flatten(0, 1).float())
    assert DSlatePerception(model, state="slot").slot_position == "attention"     # a model that names no env
    assert read.describe()["slot_position"] == "assigned"
    masks = [DSlatePerception(model, slot_position=p).describe() for p in ("assigned", "attention")]
    assert masks[0] == masks[1]                         # a mask pass reads no position: one cache entry
    # block-rearrange's default: assigned, with exactly one slot per object, the floor's and the
    # env's spare one, never raised to K (1 object: 3 slots; with extra_slots 1, 2 < ci's K of 3)
    model.checkpoint_info = {"env": "block-rearrange"}
    slot = learned_perception(model, 1, NCSConfig(state="slot"))
    assert (slot.slot_position, slot.num_slots) == ("assigned", 3)
    assert learned_perception(model, 1, NCSConfig(state="slot", extra_slots=1)).num_slots == 2
    assert learned_perception(model, 1, NCSConfig(state="slot", slot_position="attention")).num_slots == 3
    assert learned_perception(model, 1).num_slots == 3                             # masks: at least K
    env = TaskSet(num_objects=1, episodes=1).make_env()
    try:   # MPC rolls the model's own s through the dynamics, which learned on it
        mpc = agent_factory("mpc", model=model, ncs=NCSConfig(state="slot"))(env).perception
    finally:
        env.close()
    assert (mpc.slot_position, mpc.num_slots) == ("attention", 3)
    # an agent reading slot states another way than its graph was built with is refused
    st, st1, actions, _ = read.transitions(buf)
    graph = build_graph(st, st1, actions, clusters=4, state="slot")
    graph.info["slot_position"] = "assigned"
    agent_factory("ncs", graph=graph, model=model, ncs=NCSConfig(state="slot"))
    with pytest.raises(ValueError, match="slot_position 'assigned'; the agent would act with 'attention'"):
        agent_factory("ncs", graph=graph, model=model, ncs=NCSConfig(state="slot", slot_position="attention"))
    del graph.info["slot_position"]                              # as `graph` wrote it before reads were recorded
    graph.info.update(perception_state="slot", oracle=False)
    with pytest.raises(ValueError, match="slot_position 'attention'; the agent would act with 'assigned'"):
        agent_factory("ncs", graph=graph, model=model, ncs=NCSConfig(state="slot"))
    assigned = NCSConfig(clusters=4, state="slot", iterations=2, graph_restarts=1, slot_position="assigned")
    assert graph_from_buffer(assigned, model, tmp_path / "buf").info["slot_position"] == "assigned"
    assert "slot_position" not in graph_from_buffer(assigned, None, tmp_path / "buf").info
    with pytest.raises(ValueError, match=r"ncs\.slot_position must be one of 'attention', 'assigned', 'base' or None "
                                         r"\(the env's\), got 'hard'"):
        ncs_config(["ncs.slot_position=hard"])
    plain = DSlate(apply_overrides(get_preset("ci"), ["slots.position_state=false"]))   # no position features
    plain.checkpoint_info = {"env": "block-rearrange"}
    assert DSlatePerception(plain, state="slot").slot_position == "attention"
    with pytest.raises(ValueError, match="this model has none"):
        DSlatePerception(plain, state="slot", slot_position="assigned")


def test_base_slot_states_read_where_each_slot_stands(tmp_path):
    """`slot_position` "base": the lowest row and the mean column of the pixels a slot wins in
    its mask, then zeros; a slot that wins none reads zeros. The base does not move
    when the top of an object's region is taken by another slot (a cube put on it), where
    the centroid does. Block-stacking models read this way, graphs with as many slots as
    their agents (one per object plus the floor's)."""
    from ncs_lite.config import NCSConfig, get_preset
    from ncs_lite.evaluation import learned_perception
    from ncs_lite.models import DSlate

    model = DSlate(get_preset("ci")).eval()
    g, S = model.cfg.mask_grid, model.cfg.image_size
    attn = torch.zeros(1, 3, g, g)
    attn[0, 0] = 1.0                                     # slot 0: the floor, everywhere else
    attn[0, 0, 8:16, 4:12] = 0.0
    attn[0, 1, 8:16, 4:12] = 1.0                         # slot 1: a cube, rows 8-15, columns 4-11
    attn = attn.flatten(2)
    states = torch.randn(1, 3, model.cfg.slots.state_dim)
    got = model.base_states(states, model.upsample_masks(attn))
    won = model.upsample_masks(attn)[0].argmax(0) == 1                  # (S, S) the cube's pixels
    rows, cols = torch.nonzero(won, as_tuple=True)
    to_unit = lambda i: (i.float() + 0.5) / S * 2 - 1                   # noqa: E731 (pixel centre in [-1, 1])
    torch.testing.assert_close(got[0, 1, -4:], torch.stack([to_unit(rows.max()), to_unit(cols).mean(),
                                                             torch.tensor(0.0), torch.tensor(0.0)]))
    torch.testing.assert_close(got[0, 2, -4:], torch.zeros(4))          # slot 2 wins no pixel
    torch.testing.assert_close(got[..., :-4], states[..., :-4])         # the rest of s is kept
    covered = attn.reshape(1, 3, g, g).clone()
    covered[0, 2, 8:11, 4:12], covered[0, 1, 8:11, 4:12] = 1.0, 0.0    # a cube on top takes its upper rows
    covered = covered.flatten(2)
    torch.testing.assert_close(model.base_states(states, model.upsample_masks(covered))[0, 1, :-3],
                               got[0, 1, :-3])                          # same base
    assert not torch.allclose(model.assigned_states(states, covered)[0, 1, -4], model.assigned_states(states, attn)[0, 1, -4])
    model.checkpoint_info = {"env": "block-stacking"}
    read = learned_perception(model, 1, NCSConfig(state="slot"))
    assert (read.slot_position, read.num_slots, read.masks) == ("base", 2, "pixel")
    collect(tmp_path / "buf", episodes=2, seed=0, env="block-stacking", num_objects=1)
    graph = graph_from_buffer(NCSConfig(clusters=2, state="slot", iterations=2, graph_restarts=1), model, tmp_path / "buf")
    assert (graph.info["slot_position"], graph.info["read_slots"], graph.edge_action) == ("base", 2, "nearest")
    assert graph.info["masks"] == "pixel"
    check_graph_reading(graph, "ncs", NCSConfig(state="slot"), model)
    with pytest.raises(ValueError, match="built on slots read with 'pixel' masks; the agent would act with "
                                         "'attention' \\(set ncs.masks=pixel\\)"):
        check_graph_reading(graph, "ncs", NCSConfig(state="slot", masks="attention"), model)


def test_masks_default_to_the_models_env():
    """`ncs.masks` None reads block-stacking models with pixel masks and every other env's,
    and any model without the mixture decoder, with slot attention's; a bad value is refused."""
    from ncs_lite.config import NCSConfig, get_preset
    from ncs_lite.models import DSlate
    from ncs_lite.ncs.perception import DSlatePerception, acting_masks

    model = DSlate(get_preset("ci")).eval()
    for env, read in (("block-stacking", "pixel"), ("block-rearrange", "attention"), ("robogym-rearrange", "attention")):
        model.checkpoint_info = {"env": env}
        assert acting_masks(NCSConfig(), model) == read
        assert acting_masks(NCSConfig(masks="attention"), model) == "attention"
    cfg = get_preset("ci")
    cfg.mixture.weight = 0.0
    plain = DSlate(cfg).eval()
    plain.checkpoint_info = {"env": "block-stacking"}
    assert acting_masks(NCSConfig(), plain) == "attention"
    with pytest.raises(ValueError, match="masks 'pixel' read what the mixture decoder paints; this model has none"):
        DSlatePerception(plain, masks="pixel")
    with pytest.raises(ValueError, match="ncs.masks must be one of 'attention', 'pixel' or None \\(the env's\\), got 'edge'"):
        NCSConfig(masks="edge").validate()
    with pytest.raises(ValueError, match="ncs.slot_init must be one of 'random', 'farthest' or None \\(the env's\\), "
                                         "got 'grid'"):
        NCSConfig(slot_init="grid").validate()
    with pytest.raises(ValueError, match="slot_init must be one of 'random', 'farthest', got 'grid'"):
        DSlatePerception(model, slot_init="grid")


def test_block_rearrange_reads_from_the_farthest_start_with_a_spare_slot():
    """`ncs.slot_init` and `ncs.extra_slots` None read a block-rearrange model from the
    farthest-point start with two slots beyond one per object, every other env's from a draw
    with the floor's slot alone; a value set is kept, and the measures (no `ncs`) read one slot
    per object and the floor's on every env."""
    from ncs_lite.config import get_preset
    from ncs_lite.evaluation import learned_perception
    from ncs_lite.models import DSlate
    from ncs_lite.ncs.perception import acting_extra_slots, acting_slot_init, scene_slots

    model = DSlate(get_preset("ci")).eval()                 # K = 3
    for env, start, extra in (("block-rearrange", "farthest", 2), ("robogym-rearrange", "random", 1),
                              ("block-stacking", "random", 1)):
        model.checkpoint_info = {"env": env}
        assert (acting_slot_init(NCSConfig(), model), acting_extra_slots(NCSConfig(), model)) == (start, extra)
        assert acting_slot_init(NCSConfig(slot_init="random"), model) == "random"
        assert acting_extra_slots(NCSConfig(extra_slots=0), model) == 0
        assert scene_slots(model, 7, NCSConfig()) == 7 + extra
        assert scene_slots(model, 7) == 8                   # the measures' reading
        reader = learned_perception(model, 7)
        assert (reader.slot_init, reader.num_slots) == (start, 7 + extra)
    with pytest.raises(ValueError, match="ncs.extra_slots must be an integer >= 0, got -1"):
        NCSConfig(extra_slots=-1).validate()


def test_step_trace_classifies_every_step_and_names_the_selected_object(oracle_graph):
    """The oracle on block-rearrange places a cube at its goal with every edge step; each row
    names the cube its entity holds (a ground-truth mask: held 1) and the pick lands on it."""
    from ncs_lite.evaluation import STEP_OUTCOMES, step_trace, trace_summary

    tasks = TaskSet(num_objects=4, episodes=3, seed=0)
    make_agent = agent_factory("ncs-oracle", graph=oracle_graph)
    rows = step_trace(make_agent, tasks)
    summary = summarize(evaluate(make_agent, tasks, "ncs-oracle"))[0]
    assert len(rows) == round(summary["mean_steps"] * 3)
    assert {r["outcome"] for r in rows} <= set(STEP_OUTCOMES)
    edge_steps = [r for r in rows if r["fallback"] is None]
    assert edge_steps and all(r["held"] == 1.0 and r["object"] >= 0 for r in edge_steps)
    assert all(r["pick_error"] < 1e-3 for r in edge_steps)            # the cell's centre
    s = trace_summary(rows)
    assert s["steps"] == len(rows) and s["placed_fraction"] == pytest.approx(
        sum(r["outcome"] == "placed" for r in rows) / len(rows))
    assert s["placed_fraction"] == pytest.approx(summary["placed_fraction"])
    assert np.isnan(s["read_error_median"])          # a "most_common" graph keeps no states to read


def test_files_of_another_env_are_refused_in_one_line():
    from ncs_lite.utils import check_file_env, recorded_env

    assert recorded_env({"env": "robogym-rearrange"}) == "robogym-rearrange"
    assert recorded_env({"data": ".cache/buffers/block-rearrange-k4-e5000-s0-v1"}) == "block-rearrange"
    assert recorded_env({"data": None}) is None
    check_file_env("--graph", "g.pt", None, "block-rearrange")                 # names none: passes
    check_file_env("--graph", "g.pt", "block-rearrange", "block-rearrange")
    with pytest.raises(ValueError, match=r"--graph g\.pt was made on 'block-rearrange', not 'robogym-rearrange'"):
        check_file_env("--graph", "g.pt", "block-rearrange", "robogym-rearrange")
