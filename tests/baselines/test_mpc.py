"""MPC with CEM (Appendix B), and every baseline behind the one harness and CLI."""
import math
import re

import numpy as np
import pytest
import torch

from ncs_lite.__main__ import main
from ncs_lite.baselines import CEMConfig, MPCAgent, MPCConfig, cem_minimize, mpc_config
from ncs_lite.baselines.mpc import rollout_cost
from ncs_lite.data import cached_buffer
from ncs_lite.envs import make
from ncs_lite.evaluation import METHODS, NEED_NAMES, NEEDS, TaskSet, agent_factory, evaluate, summarize
from ncs_lite.ncs.perception import Entities


# ------------------------------------------------------------------------------------ CEM
def quadratic(centre):
    centre = torch.as_tensor(centre, dtype=torch.float32)
    return lambda x: (x - centre).square().flatten(1).sum(1)


def test_cem_finds_the_minimum_of_a_quadratic_deterministically():
    lower, upper = -torch.ones(2, 3), torch.ones(2, 3)
    centre = torch.tensor([[0.3, -0.5, 0.8], [-0.2, 0.0, 0.6]])
    x, cost = cem_minimize(quadratic(centre), lower, upper, CEMConfig(), seed=3)
    assert torch.allclose(x, centre, atol=0.05) and cost < 0.01
    x2, cost2 = cem_minimize(quadratic(centre), lower, upper, CEMConfig(), seed=3)
    assert torch.equal(x, x2) and cost == cost2                        # same seed, same answer
    for clipped in (False, True):                                    # every sample inside the bounds
        seen = []

        def spy(pop):
            seen.append(pop)
            return quadratic(centre)(pop)

        cem_minimize(spy, lower, upper, CEMConfig(clipped_normal=clipped), seed=0)
        pop = torch.cat(seen)
        assert bool((pop >= lower).all() and (pop <= upper).all())


def test_cem_stays_in_the_bounds_when_the_minimum_is_outside():
    x, _ = cem_minimize(quadratic([2.0, -3.0]), -torch.ones(2), torch.ones(2), seed=0)
    assert bool((x.abs() <= 1).all()) and x[0] > 0.9 and x[1] < -0.9


def test_a_nan_cost_is_never_an_elite():
    base = quadratic([0.9])

    def cost(pop):      # the true minimum (0.9) lies where every cost is NaN
        c = base(pop)
        return torch.where(pop[:, 0] > 0.5, torch.full_like(c, math.nan), c)

    x, c = cem_minimize(cost, -torch.ones(1), torch.ones(1), CEMConfig(), seed=0)
    assert x.item() <= 0.5 and math.isfinite(c)
    assert abs(x.item() - 0.5) < 0.05                 # the best finite point, at the NaN border
    with pytest.raises(FloatingPointError, match="every cost of a CEM round is NaN"):
        cem_minimize(lambda p: torch.full((p.shape[0],), math.nan), -torch.ones(1), torch.ones(1), seed=0)


def test_cem_rejects_bad_settings():
    for bad, match in (({"iterations": 0}, "cem.iterations"), ({"elite_ratio": 0.0}, "cem.elite_ratio"),
                       ({"alpha": 1.0}, "cem.alpha"), ({"population": 2.5}, "cem.population")):
        with pytest.raises(ValueError, match=match):
            CEMConfig(**bad).validate()
    with pytest.raises(ValueError, match="mpc.horizon"):
        mpc_config("ci", horizon=0)
    with pytest.raises(ValueError, match="unknown MPC preset"):
        mpc_config("huge")
    assert (CEMConfig().iterations, CEMConfig().elite_ratio, CEMConfig().population) == (10, 0.05, 250)


# ------------------------------------------------------------------------------------ MPC
PICK = 0.4


class PointModel:
    """A stand-in dSLATE: a slot is (type (1), position (2)); an action (w, dw) moves the
    slot whose position is within `PICK` of w by dw (what a perfect block-rearrange dynamics
    does, with a pick radius wide enough for a test-sized search)."""

    def predict(self, slots, actions):
        pos = slots[..., 1:]
        near = (pos - actions[:, None, :2]).norm(dim=-1) < PICK                # (B, K)
        moved = pos + near[..., None] * actions[:, None, 3:5]
        return torch.cat([slots[..., :1], moved], dim=-1)


class PointPerception:
    graph_state = "slot"

    def __init__(self, current, goal):
        self.scenes = {"now": current, "goal": goal}

    def _entities(self, key):
        s = torch.as_tensor(self.scenes[key], dtype=torch.float32)
        return Entities(s[:, :1], s[:, 1:])

    def current(self, obs, info=None):
        return self._entities(obs["image"])

    def goal(self, obs, info=None):
        return self._entities(obs["goal"])


class Box:
    low = np.array([-1, -1, 0, -2, -2, -0.1], np.float32)
    high = np.array([1, 1, 0.1, 2, 2, 0.1], np.float32)


def test_mpc_plans_the_move_that_reaches_the_goal():
    current = [[0.0, -0.5, 0.5], [1.0, 0.5, 0.5]]        # type, x, y
    goal = [[1.0, 0.5, 0.5], [0.0, 0.5, -0.5]]           # the type-0 object must move by (1, -1)
    agent = MPCAgent(PointModel(), PointPerception(current, goal), Box(), MPCConfig(), seed=0)
    obs = {"image": "now", "goal": "goal"}
    agent.reset(obs, {})
    action, was_random = agent.act(obs, {})
    assert not was_random and agent.last["no_change_cost"] == pytest.approx(2.0)
    assert np.linalg.norm(action[:2] - [-0.5, 0.5]) < PICK          # picks the type-0 object
    assert np.abs(action[3:5] - [1.0, -1.0]).max() < 0.1            # and moves it onto its goal
    assert agent.last["cost"] < 0.01
    # the cost function itself: aligned pairs only, whole slots
    slots, goal_t = torch.tensor(current), torch.tensor(goal)
    plans = torch.tensor([[[-0.5, 0.5, 0, 1.0, -1.0, 0]], [[0, 0, 0, 0, 0, 0]]])
    cost = rollout_cost(PointModel(), slots, goal_t, plans, [0, 1], [1, 0])
    assert cost.tolist() == pytest.approx([0.0, 2.0])


def test_mpc_refuses_mask_states():
    class MaskPerception(PointPerception):
        graph_state = "mask"

    with pytest.raises(ValueError, match="must read slot states"):
        MPCAgent(PointModel(), MaskPerception([[0, 0, 0]], [[0, 0, 0]]), Box())


# ------------------------------------------------------------------------- the harness
def test_every_method_names_what_it_needs():
    assert set(NEEDS) == set(METHODS)
    for method in METHODS:
        if NEEDS[method]:
            with pytest.raises(ValueError, match=re.escape(f"needs a {NEED_NAMES[NEEDS[method][0]]}")):
                agent_factory(method)
    with pytest.raises(ValueError, match="unknown method 'dqn'"):
        agent_factory("dqn")


def test_wrong_kinds_of_graph_and_policy_are_refused(tmp_path):
    from ncs_lite.baselines import SetGraph, bc_config, train_bc
    from ncs_lite.config import NCSConfig
    from ncs_lite.data import load_buffer
    from ncs_lite.ncs.graph import graph_from_buffer

    env = make("block-rearrange", num_objects=4)
    bc, _ = train_bc(load_buffer(cached_buffer(16)), env.action_space, bc_config("ci", steps=2))
    env.close()
    with pytest.raises(ValueError, match=r"needs a IQL policy \(IQLNetworks\), got a BCPolicy"):
        agent_factory("iql", policy=bc)
    ncs_graph = graph_from_buffer(NCSConfig(clusters=8), None, cached_buffer(16))
    with pytest.raises(ValueError, match="needs a SetGraph"):
        agent_factory("nf-oracle", graph=ncs_graph)
    with pytest.raises(ValueError, match="needs a TransitionGraph"):
        agent_factory("ncs-oracle", graph=SetGraph(torch.eye(2), "cosine"))


def test_cli_trains_evaluates_and_never_replaces_a_run(tmp_path, capsys):
    data = str(cached_buffer(16))
    out = str(tmp_path / "bc.pt")
    args = ["train-baseline", "--method", "bc", "--preset", "ci", "--data", data, "--out", out]
    assert main(args + ["--set", "bc.steps=3"]) == 0
    assert main(args) == 2 and "already holds a bc run" in capsys.readouterr().err
    assert main(args + ["--set", "iql.steps=3", "--force"]) == 2
    assert "takes BC fields only" in capsys.readouterr().err
    other = str(cached_buffer(40))
    assert main(["train-baseline", "--method", "bc", "--preset", "ci", "--data", other, "--out", out,
                 "--resume"]) == 2
    assert "was trained with manifest_sha256" in capsys.readouterr().err
    assert main(["evaluate", "--method", "iql", "--policy", out, "--episodes", "1"]) == 2
    assert "is a 'bc' checkpoint, expected 'iql'" in capsys.readouterr().err
    assert main(["evaluate", "--method", "bc", "--policy", out, "--episodes", "2", "--num-objects", "2"]) == 0
    assert '"episodes": 2' in capsys.readouterr().out


def test_nf_graph_cli_and_nf_oracle_on_the_harness(tmp_path, capsys):
    from ncs_lite.baselines import SetGraph

    data, out = str(cached_buffer(16)), str(tmp_path / "nf.pt")
    assert main(["graph-nf", "--oracle", "--data", data, "--clusters", "16", "--out", out]) == 0
    graph = SetGraph.load(out)
    assert graph.num_nodes > 0 and graph.info["oracle"] and graph.state == "mask"
    rows = evaluate(agent_factory("nf-oracle", graph=graph), TaskSet(num_objects=4, episodes=2), "nf-oracle")
    assert summarize(rows)[0]["episodes"] == 2
    assert main(["evaluate", "--method", "nf-oracle", "--graph", out, "--state", "slot", "--episodes", "1"]) == 2
    assert "built on 'mask' states" in capsys.readouterr().err
    # bound by another graph's nodes, NF records that graph's node count; another --clusters is refused
    bound = str(tmp_path / "nf_bound.pt")
    assert main(["graph", "--oracle", "--data", data, "--clusters", "12", "--out", str(tmp_path / "nodes.pt")]) == 0
    assert main(["graph-nf", "--oracle", "--data", data, "--bind-graph", str(tmp_path / "nodes.pt"), "--out", bound]) == 0
    assert SetGraph.load(bound).info["ncs"]["clusters"] == 12
    capsys.readouterr()
    assert main(["graph-nf", "--oracle", "--data", data, "--bind-graph", str(tmp_path / "nodes.pt"),
                 "--clusters", "16", "--out", str(tmp_path / "nf2.pt")]) == 2
    assert "--clusters 16: the entities bind to --bind-graph's 12 nodes" in capsys.readouterr().err


def test_a_task_set_is_one_key_whatever_the_number_type():
    from dataclasses import asdict

    from ncs_lite.cache import digest

    assert digest(asdict(TaskSet(horizon_multiplier=4))) == digest(asdict(TaskSet(horizon_multiplier=4.0)))
    with pytest.raises(ValueError, match="horizon_multiplier must be a number"):
        TaskSet(horizon_multiplier="4")
