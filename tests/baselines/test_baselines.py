"""Baselines of Appendix B: NF (graph over entity sets), BC and IQL (hindsight goals)."""
from collections import deque

import numpy as np
import pytest
import torch

from ncs_lite.baselines import (FALLBACKS, BCAgent, IQLAgent, NFAgent, SetGraph, advantage_weights,
                                bc_config, bc_mse, build_set_graph, expectile_loss, iql_config,
                                iql_losses, load_bc, load_iql, mean_action_mse, polyak_update, save_bc,
                                save_iql, set_graph_from_buffer, train_bc, train_iql)
from ncs_lite.baselines.goal_conditioned import ActionBox, HindsightGoals
from ncs_lite.baselines.iql import IQLNetworks
from ncs_lite.config import NCSConfig
from ncs_lite.data import cached_buffer, load_buffer
from ncs_lite.envs import make
from ncs_lite.evaluation import TaskSet, evaluate, summarize
from ncs_lite.ncs.graph import graph_from_buffer
from ncs_lite.ncs.perception import Entities, OraclePerception
from ncs_lite.utils import seed_everything


@pytest.fixture(scope="module")
def action_space():
    env = make("block-rearrange", num_objects=4)
    space = env.action_space
    env.close()
    return space


@pytest.fixture(scope="module")
def tiny_buffer():
    return load_buffer(cached_buffer(16))      # 16 episodes x 4 moves, 4 cubes


# ------------------------------------------------------------------------------------ NF
def chain_graph(n: int, edges) -> SetGraph:
    """A scene graph whose node i is the one-entity set (i,); edge (s, d) is labelled with
    the action (s, d, 0, 0, 0, 0), so an action names its edge."""
    g = SetGraph(torch.eye(n), "sqeuclidean", [(i,) for i in range(n)])
    g.add([(s,) for s, _ in edges], [(d,) for _, d in edges], [[s, d, 0, 0, 0, 0] for s, d in edges])
    return g


def random_edges(n: int, m: int, seed: int):
    rng = np.random.default_rng(seed)
    return sorted({(int(s), int(d)) for s, d in rng.integers(n, size=(m, 2)) if s != d})


def bfs_distances(n: int, edges, src: int) -> list:
    out = {s: [] for s in range(n)}
    for s, d in edges:
        out[s].append(d)
    dist, queue = [None] * n, deque([src])
    dist[src] = 0
    while queue:
        u = queue.popleft()
        for v in out[u]:
            if dist[v] is None:
                dist[v] = dist[u] + 1
                queue.append(v)
    return dist


def test_dijkstra_path_and_first_action_match_bfs():
    n = 25
    edges = random_edges(n, 45, seed=3)          # sparse: some pairs have no path
    g = chain_graph(n, edges)
    unreachable = 0
    for src in range(n):
        from_src = bfs_distances(n, edges, src)
        for dst in range(n):
            path = g.shortest_path(src, dst)
            if from_src[dst] is None:
                assert path is None
                unreachable += 1
                continue
            assert path[0] == src and path[-1] == dst and len(path) - 1 == from_src[dst]
            assert all((a, b) in g.edges for a, b in zip(path[:-1], path[1:]))
            if src != dst:
                # the first edge's action is that edge's label and starts a shortest path
                np.testing.assert_array_equal(g.action(path[0], path[1]), [src, path[1], 0, 0, 0, 0])
                assert bfs_distances(n, edges, path[1])[dst] == from_src[dst] - 1
    assert 0 < unreachable < n * n                # both cases were exercised


def test_dijkstra_agrees_with_networkx():
    nx = pytest.importorskip("networkx")
    n, edges = 30, random_edges(30, 90, seed=5)
    g = chain_graph(n, edges)
    ref = dict(nx.all_pairs_shortest_path_length(nx.DiGraph(edges)))
    for src in range(n):
        for dst in range(n):
            path = g.shortest_path(src, dst)
            expected = ref.get(src, {}).get(dst, 0 if src == dst else None)
            assert (None if path is None else len(path) - 1) == expected


class FixedPerception:
    """Returns given entity states (a list per call for the current scene)."""

    def __init__(self, goal, currents):
        self.goal_states, self.currents = goal, list(currents)

    def goal(self, obs, info):
        return Entities(torch.zeros(len(self.goal_states), 1), torch.as_tensor(self.goal_states).float())

    def current(self, obs, info):
        s = torch.as_tensor(self.currents.pop(0)).float()
        return Entities(torch.zeros(len(s), 1), s)


def test_set_graph_binds_multisets_in_any_entity_order():
    centroids = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    st = torch.tensor([[[0.1, 0.0], [0.9, 0.1]], [[0.0, 0.9], [0.0, 1.1]]])   # (M=2, K=2, D=2)
    st1 = torch.tensor([[[0.0, 1.0], [1.0, 0.0]], [[0.1, 0.0], [0.0, 1.0]]])
    g = build_set_graph(st, st1, np.arange(12).reshape(2, 6), centroids, "sqeuclidean")
    assert g.sets == [(0, 1), (1, 2), (2, 2), (0, 2)]        # (2, 2): two entities on one node
    assert g.node(st[0].flip(0)) == g.node(st[0]) == 0       # entity order does not matter
    assert g.node(torch.tensor([[1.0, 0.0], [1.0, 0.1]])) is None   # the set (1, 1) was never seen
    with pytest.raises(ValueError, match=r"\(M, K, D\)"):
        build_set_graph(st, st1[:, :1], np.zeros((2, 6)), centroids, "sqeuclidean")
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 6\)"):
        build_set_graph(st, st1, np.zeros((2, 5)), centroids, "sqeuclidean")


def test_nf_agent_falls_back_to_random_and_says_why(action_space, tmp_path):
    # entity nodes 0..3 at the corners of a square; scenes of one entity; edges 0->1->2
    centroids = torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    g = SetGraph(centroids, "sqeuclidean", [(0,), (1,), (2,), (3,)])
    g.add([(0,), (1,)], [(1,), (2,)], [[0.1, 0, 0.03, 0, 0, 0], [0.2, 0, 0.03, 0, 0, 0]])
    s = centroids[:, None]                       # s[i]: a scene with its entity at node i
    cases = [  # goal scene, current scene, fallback reason (None = planned action)
        (s[2], s[0], None), (s[2], [[5.0, 5.0], [5.0, 5.0]], "current set unbound"),
        ([[9.0, 9.0], [9.0, 9.0]], s[0], "goal set unbound"), (s[0], s[2], "no path"),
        (s[3], s[2], "no path"), (s[2], s[2], "at the goal's node")]
    for goal, current, why in cases:
        agent = NFAgent(g, FixedPerception(goal, [current]), action_space, seed=0)
        agent.reset(None, None)
        action, was_random = agent.act(None, None)
        assert was_random == (why is not None) and agent.last["fallback"] == why
        assert why is None or why in FALLBACKS
        if why is None:   # first edge of 0 -> 1 -> 2
            np.testing.assert_allclose(action, [0.1, 0, 0.03, 0, 0, 0])
            assert agent.last["path"] == [0, 1, 2]
        else:
            assert action_space.contains(action) and agent.fallbacks[why] == 1
    with pytest.raises(ValueError, match="call reset"):
        NFAgent(g, FixedPerception(s[2], [s[0]]), action_space).act(None, None)
    loaded = SetGraph.load(g.save(tmp_path / "nf.pt"))
    assert loaded.sets == g.sets and loaded.edges == g.edges and loaded.shortest_path(0, 2) == [0, 1, 2]
    torch.save({"weights": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an ncs-lite NF graph"):
        SetGraph.load(tmp_path / "other.pt")


def test_nf_oracle_solves_two_object_tasks():
    buffer = load_buffer(cached_buffer(200, num_objects=2))
    nf = set_graph_from_buffer(buffer, OraclePerception(), clusters=16)   # 16 cells = 16 mask states
    assert nf.num_nodes == 120                  # every pair of cells (16 choose 2) was seen
    # binding to the NCS graph's centroids (same 16 cells) gives the same scene graph
    ncs_graph = graph_from_buffer(NCSConfig(clusters=16), None, cached_buffer(200, num_objects=2))
    same = set_graph_from_buffer(buffer, OraclePerception(), graph=ncs_graph)
    assert (same.num_nodes, same.num_edges) == (nf.num_nodes, nf.num_edges)
    agents = []

    def make_agent(env):
        agents.append(NFAgent(nf, OraclePerception(), env.action_space, seed=0))
        return agents[-1]

    rows = evaluate(make_agent, TaskSet(num_objects=2, episodes=12), "nf-oracle")
    summary = summarize(rows)[0]
    assert summary["success"] >= 0.25            # random: ~0 on these tasks in 8 steps
    assert summary["random_fraction"] < 1
    agent = agents[0]
    assert set(agent.fallbacks) <= set(FALLBACKS)
    assert sum(agent.fallbacks.values()) == sum(r["random_actions"] for r in rows)


def test_nf_runs_on_learned_states(action_space):
    from ncs_lite.inference import SHIPPED_CHECKPOINT, SHIPPED_GRAPH, load_dslate
    from ncs_lite.ncs.graph import TransitionGraph
    from ncs_lite.ncs.perception import DSlatePerception

    if not (SHIPPED_CHECKPOINT.exists() and SHIPPED_GRAPH.exists()):
        pytest.skip("the shipped reduced dSLATE and graph are not present")
    perception = DSlatePerception(load_dslate(device="cpu"), restarts=1, num_slots=5)
    nf = set_graph_from_buffer(load_buffer(cached_buffer(3, seed=1000)), perception,
                               graph=TransitionGraph.load(SHIPPED_GRAPH))
    assert nf.num_nodes >= 2 and all(len(s) == 5 for s in nf.sets)    # 5 slots per scene
    env = make("block-rearrange", num_objects=4)
    agent = NFAgent(nf, perception, env.action_space, seed=0)
    obs, info = env.reset(seed=0)
    agent.reset(obs, info)
    for _ in range(2):
        action, _ = agent.act(obs, info)
        assert action_space.contains(np.asarray(action, np.float32))
        obs, _, _, _, info = env.step(action)
    env.close()


# ------------------------------------------------------------------------ hindsight goals
def test_hindsight_goals_are_later_frames_and_reward_the_next_one(tiny_buffer):
    goals = HindsightGoals(tiny_buffer, seed=7)
    e, t, j = goals.indices(step=3, batch=500)
    assert (t < j).all() and (j <= 4).all() and set(j - t) == {1, 2, 3, 4}
    np.testing.assert_array_equal(goals.indices(3, 500)[2], j)           # a function of (seed, step)
    b = goals.batch(e, t, j)
    np.testing.assert_array_equal(b["reached"].numpy(), j == t + 1)     # no move is undone here
    torch.testing.assert_close(b["goal"], torch.as_tensor(tiny_buffer["frames"][e, j]))
    torch.testing.assert_close(b["action"], torch.as_tensor(tiny_buffer["actions"][e, t]))
    assert len(goals.all_indices()[0]) == 16 * 10                       # 4 + 3 + 2 + 1 pairs per episode


# -------------------------------------------------------------------------------------- BC
def test_bc_beats_the_mean_action_and_acts_in_the_box(tiny_buffer, action_space, tmp_path):
    cfg = bc_config("ci", channels=(8, 16, 16), feature_dim=32, hidden=64, batch_size=32, lr=3e-3, steps=300)
    model, log = train_bc(tiny_buffer, action_space, cfg)
    baseline = mean_action_mse(tiny_buffer, action_space)
    assert len(log) == 300 and np.mean([r["loss"] for r in log[-20:]]) < np.mean([r["loss"] for r in log[:20]])
    assert bc_mse(model, tiny_buffer) < 0.5 * baseline
    env = make("block-rearrange", num_objects=4)
    agent = BCAgent(model)
    obs, info = env.reset(seed=1)
    agent.reset(obs, info)
    action, was_random = agent.act(obs, info)
    env.close()
    assert action_space.contains(action) and not was_random
    loaded = load_bc(save_bc(tmp_path / "bc.pt", model, log))
    np.testing.assert_array_equal(BCAgent(loaded).act(obs, info)[0], action)
    assert loaded.log == log
    with pytest.raises(ValueError, match="is a 'bc' checkpoint, expected 'iql'"):
        load_iql(tmp_path / "bc.pt")


def test_bc_resume_gives_the_uninterrupted_run(tiny_buffer, action_space, tmp_path, monkeypatch):
    cfg = bc_config("ci", steps=6)
    full, full_log = train_bc(tiny_buffer, action_space, cfg)
    sample = HindsightGoals.sample

    def interrupted(self, step, batch):
        if step == 4:
            raise KeyboardInterrupt
        return sample(self, step, batch)

    monkeypatch.setattr(HindsightGoals, "sample", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_bc(tiny_buffer, action_space, cfg, out=tmp_path / "bc.pt", checkpoint_every=2)
    monkeypatch.setattr(HindsightGoals, "sample", sample)
    resumed, log = train_bc(tiny_buffer, action_space, cfg, out=tmp_path / "bc.pt", resume=True)
    assert [r["step"] for r in log] == list(range(1, 7)) and log == full_log
    for (name, a), b in zip(full.state_dict().items(), resumed.state_dict().values()):
        assert torch.equal(a, b), name
    with pytest.raises(ValueError, match="another config"):
        train_bc(tiny_buffer, action_space, bc_config("ci", steps=7), out=tmp_path / "bc.pt", resume=True)


def test_bc_and_iql_reject_bad_settings(tiny_buffer, action_space):
    with pytest.raises(ValueError, match="unknown BC preset 'huge'"):
        bc_config("huge")
    with pytest.raises(ValueError, match=r"unknown BCConfig fields \['width'\]"):
        bc_config("ci", width=3)
    with pytest.raises(ValueError, match="bc.lr must be a finite number > 0, got -1"):
        bc_config("ci", lr=-1)
    with pytest.raises(ValueError, match="divisible by 128"):
        bc_config("ci", channels=(4,) * 7)
    with pytest.raises(ValueError, match=r"iql.expectile must be in \(0, 1\), got 1.5"):
        iql_config("ci", expectile=1.5)
    with pytest.raises(ValueError, match=r"iql.discount must be in \[0, 1\), got 1"):
        iql_config("ci", discount=1)
    bad = {**tiny_buffer, "actions": tiny_buffer["actions"][:, :3]}
    with pytest.raises(ValueError, match=r"buffer\['actions'\] must have shape \(16, 4, 6\)"):
        train_bc(bad, action_space, bc_config("ci"))
    with pytest.raises(ValueError, match="leave the action Box"):
        train_iql({**tiny_buffer, "actions": tiny_buffer["actions"] * 10}, action_space, iql_config("ci"))


# ------------------------------------------------------------------------------------- IQL
def test_expectile_loss_is_half_mse_at_one_half_and_asymmetric_otherwise():
    u = torch.randn(1000, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(expectile_loss(u, 0.5), 0.5 * u.square().mean())
    pos = u.abs()
    torch.testing.assert_close(expectile_loss(pos, 0.7), 0.7 * pos.square().mean())
    torch.testing.assert_close(expectile_loss(-pos, 0.7), 0.3 * pos.square().mean())
    assert expectile_loss(pos, 0.7) > expectile_loss(-pos, 0.7)     # V below Q costs more
    torch.testing.assert_close(expectile_loss(u, 0.7), expectile_loss(-u, 0.3))


def test_advantage_weight_is_exp_beta_a_capped_at_100():
    adv = torch.tensor([-2.0, 0.0, 0.5, 1.0, 50.0, 1e6])
    w = advantage_weights(adv, beta=3.0, max_weight=100.0)
    torch.testing.assert_close(w[:4], torch.exp(3.0 * adv[:4]))
    torch.testing.assert_close(w[4:], torch.full((2,), 100.0))
    assert bool(torch.isfinite(w).all()) and float(w.max()) <= 100.0


def test_polyak_update_moves_the_target_by_the_rule(tiny_buffer, action_space):
    online, target = torch.nn.Linear(4, 3), torch.nn.Linear(4, 3)
    before = [p.detach().clone() for p in target.parameters()]
    polyak_update(target, online, 0.005)
    for t, o, b in zip(target.parameters(), online.parameters(), before):
        torch.testing.assert_close(t, 0.995 * b + 0.005 * o, rtol=0, atol=1e-7)
    # in training: one step from the shared initialisation theta0 gives 0.995 theta0 + 0.005 theta1
    cfg = iql_config("ci", steps=1)
    seed_everything(cfg.seed)
    init = IQLNetworks(cfg, ActionBox.from_space(action_space))       # the init train_iql draws
    model, _ = train_iql(tiny_buffer, action_space, cfg)
    for name in ("encoder", "q"):
        pairs = zip(getattr(init, name).parameters(), getattr(model, name).parameters(),
                    model.target[name].parameters())
        for theta0, theta1, target_p in pairs:
            assert not torch.equal(theta0, theta1)                   # the step moved the online net
            torch.testing.assert_close(target_p, 0.995 * theta0 + 0.005 * theta1, rtol=0, atol=1e-7)


def test_iql_tiny_run_is_finite_and_acts_in_the_box(tiny_buffer, action_space, tmp_path):
    cfg = iql_config("ci", steps=8)
    model, log = train_iql(tiny_buffer, action_space, cfg)
    assert len(log) == 8 and all(np.isfinite(v) for r in log for v in r.values())
    assert {"v_loss", "q_loss", "policy_loss", "mean_weight", "reward_rate"} <= set(log[0])
    losses = iql_losses(model, HindsightGoals(tiny_buffer).sample(0, 16), cfg)
    assert all(bool(torch.isfinite(v)) for v in losses.values())
    assert float(losses["mean_weight"]) <= 100.0
    env = make("block-rearrange", num_objects=4)
    obs, info = env.reset(seed=2)
    env.close()
    agent = IQLAgent(model)
    agent.reset(obs, info)
    action, was_random = agent.act(obs, info)
    assert action_space.contains(action) and not was_random
    loaded = load_iql(save_iql(tmp_path / "iql.pt", model, log))
    np.testing.assert_array_equal(IQLAgent(loaded).act(obs, info)[0], action)
