"""The harness's two success measures (`success`, `constraints`), the interval of the second,
and the `random-object` calibration row on both envs."""
import json

import numpy as np
import pytest

from ncs_lite.baselines import RandomObjectAgent
from ncs_lite.config import ncs_config
from ncs_lite.envs import make
from ncs_lite.envs.common import outside_action_space
from ncs_lite.evaluation import (COLUMNS, METHODS, NEEDS, PER_EPISODE, TaskSet, agent_factory, evaluate,
                                 mean_interval, satisfied_fraction, summarize, task_seed, wilson_interval)
from ncs_lite.inference import shipped_asset
from ncs_lite.ncs.graph import TransitionGraph


class MovesFirstToGoal:
    """Puts the first `moves` constrained objects at their goals (ground truth), then picks the
    floor (an outer corner of the grid, where no cube can be) until the horizon."""

    def __init__(self, moves: int):
        self.moves = moves

    def reset(self, obs, info, seed=None):
        self.todo = list(np.flatnonzero(info["constrained"])[:self.moves])

    def act(self, obs, info):
        if not self.todo:
            return np.array([0.2, 0.2, 0.02, -0.1, 0.0, 0.0], np.float32), False
        i = self.todo.pop(0)
        w, goal = info["positions"][i], info["goal_positions"][i]
        return np.array([w[0], w[1], w[2], goal[0] - w[0], goal[1] - w[1], 0.0], np.float32), False


def test_satisfied_fraction_counts_constrained_objects_only():
    info = {"constrained": np.array([True, True, False, True]), "satisfied": np.array([True, False, True, False])}
    assert satisfied_fraction(info) == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match="at least one object"):
        satisfied_fraction({"constrained": np.zeros(3, bool), "satisfied": np.ones(3, bool)})


@pytest.mark.parametrize("goal, num_constrained, moves, fraction", [
    ("complete", None, 2, 0.5),          # 2 of 4 cubes placed, then nothing: unsolved, half the constraints
    ("complete", None, 4, 1.0),          # all placed: solved
    ("partial", 2, 1, 0.5),              # 1 of the 2 constrained cubes
])
def test_an_episode_row_gives_the_share_of_constraints_satisfied_at_its_end(goal, num_constrained, moves, fraction):
    tasks = TaskSet(num_objects=4, goal=goal, num_constrained=num_constrained, episodes=2, seed=1)
    rows = evaluate(lambda env: MovesFirstToGoal(moves), tasks, "scripted")
    assert [r["satisfied_fraction"] for r in rows] == [fraction, fraction]
    assert all(r["success"] == int(fraction == 1.0) for r in rows)
    assert list(rows[0]) == list(COLUMNS) and "satisfied_fraction" in PER_EPISODE
    s = summarize(rows)[0]
    assert s["success"] == int(fraction == 1.0) and s["constraints"] == fraction
    assert 0 <= s["constraints_ci_low"] <= s["constraints"] <= s["constraints_ci_high"] <= 1


def test_mean_interval_at_0_and_1_and_around_the_mean():
    n = 300
    lo, hi = mean_interval(np.zeros(n))
    assert lo == 0.0 and 0 < hi < 0.02                   # keeps a width at 0 (z^2 / (n + z^2) = 0.0126)
    lo, hi = mean_interval(np.ones(n))
    assert hi == 1.0 and 0.98 < lo < 1
    # 0/1 values: the Wilson interval of the proportion
    binary = np.r_[np.ones(30), np.zeros(70)]
    assert mean_interval(binary) == pytest.approx(wilson_interval(30, 100))
    rng = np.random.default_rng(0)
    for _ in range(20):
        values = rng.choice([0, 0.25, 0.5, 0.75, 1.0], size=int(rng.integers(1, 50)))
        lo, hi = mean_interval(values)
        assert 0 <= lo <= values.mean() <= hi <= 1 and lo < hi
    with pytest.raises(ValueError, match=r"must lie in \[0, 1\], got 1.5"):
        mean_interval([0.5, 1.5])
    with pytest.raises(ValueError, match="at least one value"):
        mean_interval([])


def test_summarize_carries_both_measures_and_refuses_rows_without_the_second():
    rows = evaluate(agent_factory("random-object", seed=0), TaskSet(num_objects=3, episodes=3, seed=0),
                    "random-object")
    s = summarize(rows)[0]
    for column in ("success", "ci_low", "ci_high", "constraints", "constraints_ci_low", "constraints_ci_high"):
        assert column in s
    assert s["constraints"] == pytest.approx(np.mean([r["satisfied_fraction"] for r in rows]))
    assert (s["constraints_ci_low"], s["constraints_ci_high"]) == \
        pytest.approx(mean_interval([r["satisfied_fraction"] for r in rows]))
    old = [{k: v for k, v in r.items() if k != "satisfied_fraction"} for r in rows]
    with pytest.raises(ValueError, match="lack `satisfied_fraction`"):
        summarize(old)


@pytest.mark.parametrize("env_id", ["block-rearrange", "robogym-rearrange"])
def test_random_object_picks_an_object_every_step_with_actions_in_the_box(env_id):
    assert "random-object" in METHODS and NEEDS["random-object"] == ()
    env = make(env_id, num_objects=4)
    try:
        agent = agent_factory("random-object", seed=0)(env)
        assert isinstance(agent, RandomObjectAgent)
        obs, info = env.reset(seed=0)
        agent.reset(obs, info)
        picked, drops = set(), []
        for _ in range(12):
            action, was_random = agent.act(obs, info)
            assert was_random and action.shape == (6,) and action.dtype == np.float32
            assert not outside_action_space(action, env.action_space)
            before = info["positions"]
            obs, _, terminated, truncated, info = env.step(action)
            assert info["picked"] >= 0                        # w is the object's true position
            assert np.allclose(action[:2], before[info["picked"], :2])
            picked.add(info["picked"])
            drops.append(action[:2] + action[3:5])
            if terminated or truncated:
                obs, info = env.reset(seed=1)
                agent.reset(obs, info)
        assert len(picked) > 1                                 # a random object, not always one
        drops = np.array(drops)
        if env_id == "block-rearrange":                        # a grid cell's centre
            assert np.min(np.linalg.norm(drops[:, None] - env.cells[None], axis=-1), axis=1).max() < 1e-5
        else:                                                  # a point of the table
            half = np.array([env.config.table_x, env.config.table_y]) / 2
            assert np.all(np.abs(drops) <= half + 1e-6)
    finally:
        env.close()


def test_cli_evaluate_reports_both_measures(tmp_path, capsys):
    from ncs_lite.__main__ import main

    assert main(["evaluate", "--method", "random-object", "--num-objects", "2", "--episodes", "2",
                 "--out", str(tmp_path / "r.csv")]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["method"] == "random-object" and summary["episodes"] == 2
    assert 0 <= summary["constraints_ci_low"] <= summary["constraints"] <= summary["constraints_ci_high"] <= 1
    assert "satisfied_fraction" in (tmp_path / "r.csv").read_text().splitlines()[0].split(",")


def test_table_rows_carry_the_constraints_beside_success():
    from ncs_lite.experiments.reproduce import _constraints

    row = {"ncs_4": 0.5}
    _constraints(row, "ncs_4", {"constraints": 0.71234, "constraints_ci_low": 0.6, "constraints_ci_high": 0.8})
    assert row == {"ncs_4": 0.5, "ncs_4_constraints": 0.7123, "ncs_4_constraints_ci": "[0.60, 0.80]"}


def test_an_agent_refuses_a_graph_made_on_another_env():
    """The shipped block-stacking oracle graph, used on block-rearrange tasks, is refused in
    one line naming both envs; on its own env it runs."""
    graph = TransitionGraph.load(shipped_asset("block-stacking", "ncs-oracle", "graph", "slot"))
    factory = agent_factory("ncs-oracle", graph=graph, ncs=ncs_config(state="slot", dependencies=True))
    with pytest.raises(ValueError, match="^ncs-oracle's graph was made on 'block-stacking', not 'block-rearrange'"):
        evaluate(factory, TaskSet(env="block-rearrange", num_objects=3, episodes=1), "ncs-oracle")
    rows = evaluate(factory, TaskSet(env="block-stacking", num_objects=3, episodes=1), "ncs-oracle")
    assert len(rows) == 1 and rows[0]["env"] == "block-stacking"


@pytest.fixture(scope="module")
def oracle_graph_small(tmp_path_factory):
    """The oracle's mask graph of a small block-rearrange buffer (16 nodes)."""
    from ncs_lite.config import NCSConfig
    from ncs_lite.data import collect
    from ncs_lite.ncs.graph import graph_from_buffer
    path = collect(tmp_path_factory.mktemp("buf") / "buf", episodes=100, seed=0)
    return graph_from_buffer(NCSConfig(clusters=16), None, path)


@pytest.mark.parametrize("method", ["random", "random-object", "ncs-oracle"])
def test_an_agent_reseeds_per_task_so_a_task_does_not_depend_on_the_tasks_before_it(method, oracle_graph_small):
    """`run_episode` resets the agent with the task's env seed and the agent draws from a seed
    of it and its own: on task 2 a fresh agent moves as the agent that ran tasks 0 and 1
    first, and an agent seeded otherwise moves otherwise."""
    from ncs_lite.evaluation import run_episode
    tasks = TaskSet(num_objects=2, episodes=3, seed=5, horizon_multiplier=2.0)
    graph = oracle_graph_small if method == "ncs-oracle" else None
    env = tasks.make_env()

    def moves(agent, episodes):
        steps = []
        for i in episodes:
            steps = []
            run_episode(agent, env, task_seed(tasks.seed, i), on_step=lambda a, b, action, c, d: steps.append(action))
        return np.stack(steps)

    try:
        after_others = moves(agent_factory(method, graph=graph, seed=3)(env), range(3))
        alone = moves(agent_factory(method, graph=graph, seed=3)(env), [2])
        other_seed = moves(agent_factory(method, graph=graph, seed=4)(env), [2])
    finally:
        env.close()
    np.testing.assert_array_equal(after_others, alone)
    if method != "ncs-oracle":        # the oracle draws only for a fallback or between tied constraints
        assert other_seed.shape != alone.shape or not np.allclose(other_seed, alone)
