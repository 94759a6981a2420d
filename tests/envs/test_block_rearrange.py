"""Block-rearrange semantics: pick, no-op, snap, occupied, off-grid, success, horizon."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ncs_lite.envs import BlockRearrange, make
from ncs_lite.envs.combinatorics import count_trajectories, enumerate_trajectories


@pytest.fixture
def env():
    e = make("block-rearrange", num_objects=4)
    e.reset(seed=0)
    yield e
    e.close()


def cell_xy(env, cell):
    return env.cells[cell]


def test_check_env():
    e = gym.make("ncs_lite/BlockRearrange-v0", num_objects=3)
    check_env(e.unwrapped)
    e.close()


def test_observation_and_info(env):
    obs, info = env.reset(seed=3)
    assert obs["image"].shape == (64, 64, 3) and obs["image"].dtype == np.uint8
    assert obs["goal"].shape == (64, 64, 3)
    assert info["masks"].shape == (4, 64, 64) and info["masks"].dtype == bool
    assert (info["masks"].sum((1, 2)) > 20).all()           # every cube is visible
    assert not (info["masks"].sum(0) > 1).any()             # masks are disjoint
    # goals avoid the initial cells, so every cube must move: min_steps = k
    assert info["min_steps"] == 4 and info["horizon"] == 16
    assert not info["satisfied"].any()
    assert len({tuple(c) for c in info["colors"]}) == 4     # distinct colours


def test_pick_and_snap(env):
    obj, dest = 2, int(env.free_cells()[0])
    a = env.pick_and_move(obj, dest)
    a[:2] += 0.03                    # still within the pick threshold (0.05)
    a[3:5] += np.array([0.02, -0.04], np.float32) - 0.03   # snaps back to `dest`
    _, _, _, _, info = env.step(a)
    assert info["moved"] == obj
    np.testing.assert_allclose(info["positions"][obj, :2], cell_xy(env, dest), atol=1e-6)


def test_miss_is_noop(env):
    before = env._observe(-1)[1]["positions"]
    empty = int(env.free_cells()[0])
    w = cell_xy(env, empty)                 # nothing within the pick threshold here
    _, _, _, _, info = env.step(np.array([w[0], w[1], 0.03, 0.1, 0, 0], np.float32))
    assert info["moved"] == -1
    np.testing.assert_array_equal(info["positions"], before)


def test_occupied_target_is_noop(env):
    a = env.pick_and_move(0, int(env._cell_of[1]))
    _, _, _, _, info = env.step(a)
    assert info["moved"] == -1


def test_off_grid_target_is_noop(env):
    a = env.pick_and_move(0, 0)
    a[3:5] = (0.4, 0.0)              # the largest move: x = w + 0.4 >= 0.25, beyond the 0.2 m half-grid
    _, _, _, _, info = env.step(a)
    assert info["moved"] == -1


def test_bad_actions_and_configs_are_refused_by_name(check_closed_and_unrendered):
    from ncs_lite.envs import make

    env = make("block-rearrange", num_objects=2)
    with pytest.raises(ValueError, match=r"step\(\) before reset"):
        env.step(np.zeros(6, np.float32))
    env.reset(seed=0)
    for bad, match in ((np.full(6, 5.0), "outside the action space"), (np.ones(6, bool), "dtype bool"),
                       (np.ones(6, complex), "dtype complex")):
        with pytest.raises(ValueError, match=match):
            env.step(bad)
    for bad, match in (([[1, 2], [3]], r"action must be 6 numbers \(w, dw\), got \[\[1, 2\], \[3\]\]"),):
        with pytest.raises(ValueError, match=match):          # ragged: numpy's own error named no action
            env.step(bad)
    for call, match in ((lambda: env.pick_and_move(9, 3), r"obj must be an integer in 0\.\.1, got 9"),
                        (lambda: env.pick_and_move(0, 16), r"cell must be an integer in 0\.\.15, got 16")):
        with pytest.raises(ValueError, match=match):
            call()
    env.close()
    check_closed_and_unrendered(env, "block-rearrange", num_objects=2)
    for kwargs, match in (({"horizon_multiplier": float("nan")}, "horizon_multiplier must be a finite"),
                          ({"horizon_multiplier": float("inf")}, "horizon_multiplier must be a finite"),
                          ({"num_objects": "4"}, "num_objects must be an integer"),
                          ({"cell": 0}, "cell must be a finite number > 0"),
                          ({"pick_threshold": -1.0}, "pick_threshold must be"),
                          ({"image_size": 0}, "image_size must be an integer >= 8")):
        with pytest.raises(ValueError, match=match):
            make("block-rearrange", **kwargs)


def test_success_terminates(env):
    obs, info = env.reset(seed=11)
    for i in range(4):
        goal_cell = int(np.argmin(np.linalg.norm(env.cells - info["goal_positions"][i, :2], axis=1)))
        obs, reward, terminated, truncated, info = env.step(env.pick_and_move(i, goal_cell))
        assert info["satisfied"][i]
    assert terminated and not truncated and reward == 1.0 and info["is_success"]


def test_truncation_at_horizon():
    e = make("block-rearrange", num_objects=2, horizon_multiplier=1.5)
    _, info = e.reset(seed=0)
    assert info["horizon"] == 3
    flags = [e.step(np.zeros(6, np.float32))[3] for _ in range(3)]  # grid centre: 7 cm from any cube, no pick
    assert flags == [False, False, True]
    e.close()


def test_partial_goal_constrains_a_subset():
    e = make("block-rearrange", num_objects=5, goal="partial", num_constrained=2)
    obs, info = e.reset(seed=5)
    assert info["constrained"].sum() == 2 and info["min_steps"] == 2
    # unconstrained cubes are absent from the goal image
    assert info["goal_masks"][~info["constrained"]].sum() == 0
    assert (info["goal_masks"][info["constrained"]].sum((1, 2)) > 20).all()
    e.close()


def test_determinism_for_a_seed():
    runs = []
    for _ in range(2):
        e = make("block-rearrange", num_objects=4, action_noise=0.02)
        obs, info = e.reset(seed=42)
        a = e.pick_and_move(0, int(e.free_cells()[3]))
        obs2, *_ = e.step(a)
        runs.append((obs["image"], obs["goal"], obs2["image"], info["colors"]))
        e.close()
    for x, y in zip(*runs):
        np.testing.assert_array_equal(x, y)


def test_action_noise_changes_outcomes():
    moved = []
    for noise in (0.0, 0.08):
        e = make("block-rearrange", num_objects=4, action_noise=noise)
        hits = 0
        for s in range(30):
            e.reset(seed=s)
            hits += e.step(e.pick_and_move(0, int(e.free_cells()[0])))[4]["moved"] == 0
        moved.append(hits)
        e.close()
    assert moved[0] == 30 and moved[1] < 30


@pytest.mark.parametrize("action, match", [
    (np.zeros(3), r"shape \(6,\)"),
    (np.zeros((2, 6)), r"shape \(6,\)"),
    (np.array([0, 0, 0, np.nan, 0, 0]), "finite"),
    (np.array([0, 0, 0, np.inf, 0, 0]), "finite"),
    ("left", "6 numbers"),
])
def test_bad_actions_raise(env, action, match):
    with pytest.raises(ValueError, match=match):
        env.step(action)


@pytest.mark.parametrize("kwargs, match", [
    ({"num_objects": 0}, "num_objects"),
    ({"num_objects": 9}, "num_objects"),
    ({"goal": "tower"}, "goal"),
    ({"goal": "partial", "num_constrained": 7}, "num_constrained"),
    ({"horizon_multiplier": 0}, "horizon_multiplier"),
    ({"action_noise": -1.0}, "action_noise"),
])
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BlockRearrange(**kwargs)


def test_unknown_env_name():
    with pytest.raises(ValueError, match="block-rearrange"):
        make("block-rearange")


def test_combinatorial_count_matches_enumeration():
    for cells, k in [(4, 1), (5, 2), (6, 3)]:
        assert enumerate_trajectories(cells, k) == count_trajectories(cells, k)
    assert 4.5e16 <= count_trajectories(16, 7) < 4.6e16   # Appendix E
