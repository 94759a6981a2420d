"""Block-stacking semantics: only top cubes move, no floating or interpenetrating cubes, pick and
goal thresholds (cell and level), towers as goals, exact minimum moves against a breadth-first
search written here, heights visible in the image, determinism, refusals by name."""
import math
import re
from collections import deque

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ncs_lite.envs import make
from ncs_lite.envs.block_stacking import BlockStacking, apply_move, legal_moves, min_moves, random_stacks, where


@pytest.fixture
def env():
    e = make("block-stacking", num_objects=4, horizon_multiplier=100.0)
    e.reset(seed=0)
    yield e
    e.close()


# ------------------------------------------------------------------ helpers
def successors(stacks, max_height):
    """Every (move (src, dst), configuration) one move away: the top cube of a stack onto another
    stack with room. Written here, apart from the module's legal_moves / apply_move."""
    for i, src in enumerate(stacks):
        if not src:
            continue
        for j, dst in enumerate(stacks):
            if j != i and len(dst) < max_height:
                nxt = [list(s) for s in stacks]
                nxt[j].append(nxt[i].pop())
                yield (i, j), tuple(tuple(s) for s in nxt)


def reaches(goal):
    """A test of configurations: is every cube of `goal` (cube -> (cell, level)) in its place?"""
    return lambda s: all(level < len(s[cell]) and s[cell][level] == cube for cube, (cell, level) in goal.items())


def bfs_plan(start, done, max_height):
    """A shortest list of moves (src, dst) from `start` to a configuration where `done` holds,
    by breadth-first search over configurations; None if none is reachable."""
    start = tuple(tuple(s) for s in start)
    parent = {start: None}
    queue = deque([start])
    while queue:
        state = queue.popleft()
        if done(state):
            path = []
            while parent[state] is not None:
                state, move = parent[state]
                path.append(move)
            return path[::-1]
        for move, nxt in successors(state, max_height):
            if nxt not in parent:
                parent[nxt] = (state, move)
                queue.append(nxt)
    return None


def move(env, src, dst):
    """Step the pick-and-move action that puts the top cube of `src` on `dst`; it must move it."""
    cube = env.stacks[src][-1]
    out = env.step(env.pick_and_move(cube, dst))
    assert out[4]["moved"] == cube and out[4]["picked"] == cube, (cube, src, dst, env.stacks)
    return out


def build(env, target):
    """Reach configuration `target` (per cell, cubes bottom to top) by pick_and_move steps: every
    cube first alone on a cell the target leaves empty, then the target's stacks bottom up. Cubes
    the target leaves out end alone on cells it leaves empty. Returns the steps' outcomes."""
    used = {c for c, s in enumerate(target) if s}
    parking = [c for c in range(len(target)) if c not in used]
    outs = []
    while todo := [c for c, s in enumerate(env.stacks) if len(s) > 1 or (s and c in used)]:
        outs.append(move(env, todo[0], next(p for p in parking if not env.stacks[p])))
    for cell, stack in enumerate(target):
        for cube in stack:
            outs.append(move(env, where(env.stacks)[cube][0], cell))
    assert all(env.stacks[c] == tuple(target[c]) for c in used)
    return outs


def config(cells, **stacks_at):
    """A configuration from {"c<cell>": (cubes bottom to top)}."""
    return tuple(tuple(stacks_at.get(f"c{c}", ())) for c in range(cells))


def goal_places(env, info):
    """The constrained cubes' goal (cell, level), read from info."""
    cells = np.linalg.norm(info["goal_positions"][:, None, :2] - env.cells[None], axis=2).argmin(1)
    return {int(c): (int(cells[c]), int(info["goal_levels"][c])) for c in np.flatnonzero(info["constrained"])}


def observe(env):
    """(obs, info) of the current configuration, without a step."""
    return env._observe(-1)


def stacks_from(places, cells):
    """The configuration that puts each cube of `places` (cube -> (cell, level)) in its place."""
    out = [[None] * sum(1 for c, _ in places.values() if c == cell) for cell in range(cells)]
    for cube, (cell, level) in places.items():
        out[cell][level] = cube
    return tuple(tuple(s) for s in out)


def check_physical(env, info):
    """No cube floats or interpenetrates another, stacks respect max_height, and positions,
    levels and env.stacks tell the same configuration."""
    cfg, stacks = env.config, env.stacks
    k, pos = cfg.num_objects, info["positions"]
    assert len(stacks) == len(env.cells)
    assert sorted(c for s in stacks for c in s) == list(range(k))          # each cube exactly once
    assert max(len(s) for s in stacks) <= cfg.max_height
    for cell, stack in enumerate(stacks):
        for level, cube in enumerate(stack):
            np.testing.assert_allclose(pos[cube], [*env.cells[cell], (level + 0.5) * cfg.cube], atol=1e-6)
            assert info["levels"][cube] == level
    # from the positions alone: cells, levels, support and overlap
    cells = np.linalg.norm(pos[:, None, :2] - env.cells[None], axis=2)
    assert np.allclose(cells.min(1), 0, atol=1e-6)                          # on a cell centre
    levels = pos[:, 2] / cfg.cube - 0.5
    np.testing.assert_allclose(levels, np.round(levels), atol=1e-5)
    places = {(int(c), int(round(lv))) for c, lv in zip(cells.argmin(1), levels)}
    assert len(places) == k                                                  # no shared (cell, level)
    assert 0 <= levels.min() and levels.max() < cfg.max_height - 0.5
    for i in range(k):
        others = np.delete(pos, i, 0)
        assert np.all(np.abs(others - pos[i]).max(1) >= cfg.cube - 1e-6)    # boxes disjoint
        if levels[i] > 0.5:                                                  # rests on a cube
            assert np.any(np.abs(others - (pos[i] - [0, 0, cfg.cube])).max(1) < 1e-6), (i, pos)


def assert_same_info(a, b):
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def one_line_error(call, text):
    """`call` raises a one-line ValueError containing `text`."""
    with pytest.raises(ValueError, match=re.escape(text)) as err:
        call()
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------- the API
def test_check_env_and_registration():
    e = gym.make("ncs_lite/BlockStacking-v0", num_objects=3)
    assert isinstance(e.unwrapped, BlockStacking)
    check_env(e.unwrapped)
    e.close()


@pytest.mark.parametrize("k, seeds", [(3, range(4)), (4, range(6)), (6, range(2))])
def test_observation_info_and_starts_away_from_the_goal(k, seeds):
    e = make("block-stacking", num_objects=k)
    for seed in seeds:
        obs, info = e.reset(seed=seed)
        assert obs.keys() == {"image", "goal"} and obs in e.observation_space
        for key in ("image", "goal"):
            assert obs[key].shape == (64, 64, 3) and obs[key].dtype == np.uint8
        for key, shape, dtype in (("positions", (k, 3), np.float32), ("goal_positions", (k, 3), np.float32),
                                  ("colors", (k, 3), np.float32), ("masks", (k, 64, 64), bool),
                                  ("goal_masks", (k, 64, 64), bool), ("constrained", (k,), bool),
                                  ("satisfied", (k,), bool), ("levels", (k,), np.int64),
                                  ("goal_levels", (k,), np.int64)):
            assert info[key].shape == shape and info[key].dtype == dtype, key
        assert (info["moved"], info["picked"], info["steps"]) == (-1, -1, 0)
        assert len({tuple(c) for c in info["colors"]}) == k                  # distinct colours
        assert not (info["masks"].sum(0) > 1).any()                          # masks are disjoint
        assert info["constrained"].all()                                     # complete goal
        # every constrained cube starts away from its goal place (so must move at least once)
        c = info["constrained"]
        assert (np.linalg.norm(info["positions"] - info["goal_positions"], axis=1)[c] > 0.05).all()
        assert not info["satisfied"][c].any() and not info["is_success"]
        assert info["min_steps"] >= c.sum() and info["horizon"] == math.ceil(4.0 * info["min_steps"])
        cube = e.config.cube
        np.testing.assert_allclose(info["positions"][:, 2], (info["levels"] + 0.5) * cube, atol=1e-6)
        np.testing.assert_allclose(info["goal_positions"][:, 2], (info["goal_levels"] + 0.5) * cube, atol=1e-6)
        check_physical(e, info)
        assert e.tops() == [s[-1] for s in e.stacks if s]
    e.close()
    small = make("block-stacking", num_objects=3, image_size=32)
    obs, info = small.reset(seed=0)
    assert obs["image"].shape == obs["goal"].shape == (32, 32, 3) and info["masks"].shape == (3, 32, 32)
    small.close()


def test_legal_moves_and_apply_move_agree_with_the_rules():
    rng = np.random.default_rng(0)
    for _ in range(50):
        h = int(rng.integers(1, 4))
        s = random_stacks(rng, int(rng.integers(1, 7)), 9, h, float(rng.random()))
        ours = {mv: nxt for mv, nxt in successors(s, h)}
        theirs = {(src, dst): apply_move(s, src, dst) for _, src, dst in legal_moves(s, h)}
        assert ours == theirs
        assert all(cube == s[src][-1] for cube, src, _ in legal_moves(s, h))


# ----------------------------------------------------------- stacking rules
def test_only_the_top_cube_of_a_stack_moves(env):
    rng = np.random.default_rng(1)
    tried = 0
    for seed in range(6):
        env.reset(seed=seed)
        for _ in range(40):
            covered = [(cell, s) for cell, s in enumerate(env.stacks) if len(s) >= 2]
            if not covered:                     # make a stack: a top cube onto another cube
                src = next(c for c, s in enumerate(env.stacks) if s)
                move(env, src, next(c for c, s in enumerate(env.stacks) if s and c != src))
                continue
            cell, stack = covered[rng.integers(len(covered))]
            cube, top = int(stack[rng.integers(len(stack) - 1)]), stack[-1]
            dst = int(rng.integers(len(env.cells)))
            before = env.stacks
            *_, info = env.step(env.pick_and_move(cube, dst))
            assert info["picked"] == top and info["moved"] in (top, -1) and info["moved"] != cube
            if dst != cell and len(before[dst]) < env.config.max_height:
                assert info["moved"] == top and env.stacks == apply_move(before, cell, dst)
            else:
                assert info["moved"] == -1 and env.stacks == before
            tried += 1
    assert tried >= 100


def test_a_full_stack_refuses_and_a_stack_with_room_accepts(env):
    build(env, config(16, c5=(0, 1, 2), c10=(3,)))
    obs, info = observe(env)
    obs2, _, _, _, info2 = env.step(env.pick_and_move(3, 5))           # onto the full stack
    assert (info2["picked"], info2["moved"]) == (3, -1) and env.stacks == config(16, c5=(0, 1, 2), c10=(3,))
    np.testing.assert_array_equal(obs2["image"], obs["image"])
    np.testing.assert_array_equal(info2["positions"], info["positions"])
    move(env, 5, 0)                                                     # the stack has room again
    move(env, 10, 5)
    assert env.stacks == config(16, c0=(2,), c5=(0, 1, 3))
    check_physical(env, observe(env)[1])


def test_own_cell_off_grid_and_empty_cell_are_noops(env):
    build(env, config(16, c0=(0,), c5=(1, 2), c15=(3,)))
    obs, info = observe(env)

    def noop(action, picked):
        o, reward, terminated, _, i = env.step(action)
        assert (i["picked"], i["moved"]) == (picked, -1) and reward == 0.0 and not terminated
        assert env.stacks == config(16, c0=(0,), c5=(1, 2), c15=(3,))
        np.testing.assert_array_equal(o["image"], obs["image"])
        np.testing.assert_array_equal(i["positions"], info["positions"])

    noop(env.pick_and_move(2, 5), 2)                                    # its own cell
    noop(env.pick_and_move(1, 5), 2)                                    # covered cube, own cell
    a = env.pick_and_move(3, 15)
    a[3:5] = (0.055, 0.0)                                               # x = 0.205 > 0.2: off the grid
    noop(a, 3)
    a[3:5] = (-0.4, 0.4)
    noop(a, 3)
    e = env.cells[7]                                                    # an empty cell
    noop(np.array([e[0], e[1], 0.03, -0.1, 0.0, 0.0], np.float32), -1)
    a = env.pick_and_move(3, 15)
    a[3:5] = (0.045, 0.0)                                               # x = 0.195: still on the grid, cell 15
    noop(a, 3)
    a[3:5] = (0.045, -0.1)                                              # snaps to cell 11, which is empty
    _, _, _, _, i = env.step(a)
    assert i["moved"] == 3 and env.stacks[11] == (3,)


@pytest.mark.parametrize("k", [3, 4, 5, 6])
@pytest.mark.parametrize("kind", ["pick_and_move", "uniform", "noisy"])
def test_no_cube_floats_or_interpenetrates_after_any_action(k, kind):
    e = make("block-stacking", num_objects=k, horizon_multiplier=100.0,
             action_noise=0.04 if kind == "noisy" else 0.0)
    for seed in range(2):
        _, info = e.reset(seed=seed)
        check_physical(e, info)
        rng = np.random.default_rng(seed)
        e.action_space.seed(seed)
        moved = 0
        for _ in range(40 if kind != "uniform" else 150):
            a = e.action_space.sample() if kind == "uniform" else e.random_pick_and_move(rng)
            *_, info = e.step(a)
            check_physical(e, info)
            moved += info["moved"] >= 0
        assert moved > 0                            # the actions did change the configuration
    e.close()


# ------------------------------------------------------------ determinism
def test_same_seed_same_task_and_same_actions_same_trajectory():
    def run(env):
        obs, info = env.reset(seed=7)
        rng = np.random.default_rng(3)
        out = [(obs, info, env.stacks)]
        for t in range(12):
            a = env.random_pick_and_move(rng) if t % 2 else \
                rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
            obs, reward, terminated, truncated, info = env.step(a)
            out.append((obs, info, env.stacks, reward, terminated, truncated))
        return out

    a = make("block-stacking", num_objects=4, action_noise=0.02)
    b = make("block-stacking", num_objects=4, action_noise=0.02)
    b.reset(seed=3)
    b.step(b.random_pick_and_move(np.random.default_rng(0)))          # a used env resets alike
    ra, rb = run(a), run(b)
    for x, y in zip(ra, rb):
        for key in ("image", "goal"):
            np.testing.assert_array_equal(x[0][key], y[0][key])
        assert_same_info(x[1], y[1])
        assert x[2:] == y[2:]
    assert any(x[1]["moved"] >= 0 for x in ra[1:])
    tasks = set()
    for seed in range(5):
        _, info = a.reset(seed=seed)
        tasks.add((a.stacks, frozenset(goal_places(a, info).items())))
    assert len(tasks) == 5                                             # seeds give different tasks
    a.close()
    b.close()


# ------------------------------------------------------------- thresholds
def test_pick_threshold(env):
    build(env, config(16, c5=(0, 1), c10=(2,), c15=(3,)))
    dst = 6
    for offset, picked in (((0.045, 0.0), 1), ((0.0, -0.045), 1), ((0.035, 0.035), 1),
                           ((0.04, 0.04), -1), ((-0.04, -0.04), -1), ((0.04, -0.04), -1)):
        before = env.stacks
        a = env.pick_and_move(1, dst)
        a[:2] += offset
        a[3:5] -= offset                                                 # same target: cell 6
        *_, info = env.step(a)
        assert info["picked"] == picked, offset
        if picked >= 0:
            assert info["moved"] == 1 and env.stacks[dst] == (1,)
            move(env, dst, 5)                                            # back for the next try
        else:
            assert info["moved"] == -1 and env.stacks == before


def test_a_constraint_holds_only_at_its_goal_cell_and_level():
    e = make("block-stacking", num_objects=3, horizon_multiplier=100.0)
    for seed in range(3):
        _, info = e.reset(seed=seed)
        goal = goal_places(e, info)
        gpos = info["goal_positions"]
        for cube, (cell, level) in goal.items():
            others = [c for c in range(3) if c != cube]
            # on its goal cell at another level
            wrong = config(16, **{f"c{cell}": (cube,) if level else (others[0], cube)})
            build(e, wrong)
            _, info = observe(e)
            xyz = info["positions"][cube]
            np.testing.assert_allclose(xyz[:2], gpos[cube, :2], atol=1e-6)
            assert np.linalg.norm(xyz - gpos[cube]) > e.config.success_threshold
            assert not info["satisfied"][cube]
            # at its goal level on a neighbouring cell
            nxt = (cell + 1) % 16
            build(e, config(16, **{f"c{nxt}": (*others[:level], cube)}))
            _, info = observe(e)
            assert info["levels"][cube] == level and not info["satisfied"][cube]
        # the goal configuration satisfies every constraint
        build(e, stacks_from(goal, 16))
        _, info = observe(e)
        assert info["satisfied"].all() and info["is_success"]
        np.testing.assert_allclose(info["positions"], gpos, atol=1e-6)
    e.close()


# ---------------------------------------------------- success and horizon
@pytest.mark.parametrize("goal, k, m", [("complete", 3, None), ("partial", 3, 2), ("partial", 4, 1)])
def test_an_optimal_plan_succeeds_in_min_steps(goal, k, m):
    e = make("block-stacking", num_objects=k, goal=goal, num_constrained=m)
    for seed in range(3):
        _, info = e.reset(seed=seed)
        plan = bfs_plan(e.stacks, reaches(goal_places(e, info)), e.config.max_height)
        assert len(plan) == info["min_steps"]
        flags = []
        for src, dst in plan:
            obs, reward, terminated, truncated, info = move(e, src, dst)
            flags.append((reward, terminated, truncated, info["is_success"]))
        assert flags == [(0.0, False, False, False)] * (len(plan) - 1) + [(1.0, True, False, True)]
        assert info["satisfied"][info["constrained"]].all()
    e.close()


def test_a_longer_plan_also_succeeds_on_the_last_move():
    e = make("block-stacking", num_objects=5, horizon_multiplier=100.0)
    _, info = e.reset(seed=4)
    outs = build(e, stacks_from(goal_places(e, info), 16))
    assert len(outs) >= info["min_steps"]
    assert [o[2] for o in outs] == [False] * (len(outs) - 1) + [True]
    assert outs[-1][1] == 1.0 and outs[-1][4]["is_success"]
    e.close()


@pytest.mark.parametrize("multiplier", [1.0, 1.3, 1.5, 2.0])
def test_truncation_at_the_horizon(multiplier):
    e = make("block-stacking", num_objects=3, horizon_multiplier=multiplier)
    for seed in range(2):
        _, info = e.reset(seed=seed)
        assert info["horizon"] == math.ceil(multiplier * info["min_steps"])
        empty = next(c for c, s in enumerate(e.stacks) if not s)
        x, y = e.cells[empty]
        flags = []
        for _ in range(info["horizon"]):
            _, reward, terminated, truncated, info = e.step(np.array([x, y, 0.03, 0.0, 0.1, 0.0], np.float32))
            flags.append((reward, terminated, truncated))
        assert flags == [(0.0, False, False)] * (info["horizon"] - 1) + [(0.0, False, True)]
        assert info["steps"] == info["horizon"]
    e.close()


# ----------------------------------------------------- minimum moves: exact
def closed_subset(rng, goal_stacks):
    """A random non-empty set of cubes closed downwards in the goal towers: each chosen cube
    brings the cubes under it."""
    at = where(goal_stacks)
    pick = rng.choice(sorted(at), size=int(rng.integers(1, len(at) + 1)), replace=False)
    return {int(c) for p in pick for c in goal_stacks[at[int(p)][0]][: at[int(p)][1] + 1]}


@pytest.mark.parametrize("max_height, k", [(1, 3), (2, 2), (2, 3), (2, 4), (3, 2), (3, 3), (3, 4)])
def test_min_moves_equals_breadth_first_search(max_height, k):
    rng = np.random.default_rng(100 * max_height + k)
    for _ in range(25):
        p = float(rng.choice([0.0, 0.5, 1.0]))
        start, goal = (random_stacks(rng, k, 4, max_height, p) for _ in range(2))
        at = where(goal)
        for cubes in (set(at), closed_subset(rng, goal)):
            target = {c: at[c] for c in cubes}
            want = len(bfs_plan(start, reaches(target), max_height))
            assert min_moves(start, target, max_height) == want, (start, target)


def test_min_moves_on_goals_that_leave_a_support_free():
    """A goal dict that constrains a cube but not the cube it rests on (not one the env draws,
    whose goals are closed downwards): any support will do."""
    assert min_moves(((0, 1), (), (), ()), {1: (0, 1)}, 2) == 0
    assert min_moves(((1,), (0,), (), ()), {1: (0, 1)}, 2) == 3
    rng = np.random.default_rng(5)
    for _ in range(60):
        h, k = int(rng.integers(2, 4)), int(rng.integers(2, 5))
        start, goal = (random_stacks(rng, k, 4, h, 0.7) for _ in range(2))
        at = where(goal)
        target = {int(c): at[int(c)] for c in rng.choice(k, size=int(rng.integers(1, k + 1)), replace=False)}
        assert min_moves(start, target, h) == len(bfs_plan(start, reaches(target), h)), (start, target)


@pytest.mark.parametrize("kwargs", [dict(num_objects=3), dict(num_objects=4, max_height=3),
                                    dict(num_objects=4, goal="partial", num_constrained=2)])
def test_the_envs_min_steps_is_the_breadth_first_distance(kwargs):
    e = make("block-stacking", grid_size=2, **{"max_height": 2, **kwargs})
    for seed in range(8):
        _, info = e.reset(seed=seed)
        check_physical(e, info)
        plan = bfs_plan(e.stacks, reaches(goal_places(e, info)), e.config.max_height)
        assert info["min_steps"] == len(plan)
    e.close()


# ------------------------------------------------------------ partial goals
@pytest.mark.parametrize("k, m", [(4, None), (5, 2), (5, 3), (6, 4)])
def test_partial_goals_are_towers_closed_downwards(k, m):
    e = make("block-stacking", num_objects=k, goal="partial", num_constrained=m)
    for seed in range(2 if k == 6 else 5):
        _, info = e.reset(seed=seed)
        c = info["constrained"]
        assert c.sum() == (m if m is not None else k // 2)
        goal = goal_places(e, info)
        for cube, (cell, level) in goal.items():
            if level:
                below = [b for b, place in goal.items() if place == (cell, level - 1)]
                assert len(below) == 1, (cube, goal)              # its support is constrained too
        # the goal image shows the constrained cubes only
        assert info["goal_masks"][~c].sum() == 0
        assert (info["goal_masks"][c].sum((1, 2)) > 0).all()
        # unconstrained cubes never decide success: the constrained ones start unsatisfied
        assert not info["satisfied"][c].any() and not info["is_success"]
    e.close()


# ------------------------------------------------------------- the image
def test_heights_are_visible(env):
    """Cube 0 alone on cell 5, then on a 2-stack, then on a 3-stack (the others parked behind)."""
    masks, images = [], []
    for target in (config(16, c5=(0,), c12=(1,), c14=(2,), c15=(3,)), config(16, c5=(1, 0), c12=(2,), c15=(3,)),
                   config(16, c5=(1, 2, 0), c15=(3,))):
        build(env, target)
        obs, info = observe(env)
        masks.append(info["masks"][0])
        images.append(obs["image"])
    assert info["levels"][0] == 2
    rows = [np.nonzero(m)[0].mean() for m in masks]
    cols = [np.nonzero(m)[1].mean() for m in masks]
    assert rows[0] - rows[1] >= 2 and rows[1] - rows[2] >= 2, rows          # up the image, level by level
    assert max(cols) - min(cols) <= 1, cols
    assert np.nonzero(masks[2])[0].min() < np.nonzero(masks[1])[0].min()    # the top of the tower is higher
    span = slice(np.nonzero(masks[1])[1].min(), np.nonzero(masks[1])[1].max() + 1)
    assert not np.array_equal(images[1][:, span], images[2][:, span])        # a 2-stack is not a 3-stack


def test_every_cube_keeps_visible_pixels_and_the_scene_fits_the_image(env):
    # a covered cube right behind a 2-stack still shows its front face
    build(env, config(16, c9=(0, 1), c5=(2, 3)))
    _, info = observe(env)
    assert (info["masks"].sum((1, 2)) > 0).all()
    # the tallest tower at a back corner and cubes at the front corners stay inside the frame
    for target in (config(16, c12=(0, 1, 2), c3=(3,)), config(16, c15=(0, 1, 2), c0=(3,))):
        build(env, target)
        _, info = observe(env)
        rows, cols = np.nonzero(info["masks"].any(0))
        assert rows.min() >= 2 and rows.max() <= 61 and cols.min() >= 2 and cols.max() <= 61


# -------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, text", [
    ({"num_objects": 0}, "num_objects must be an integer >= 1, got 0"),
    ({"num_objects": 9}, "num_objects must be in 1..8, got 9"),
    ({"max_height": 0}, "max_height must be an integer >= 1, got 0"),
    ({"grid_size": 0}, "grid_size must be an integer >= 1, got 0"),
    ({"stack_probability": 1.5}, "stack_probability must be in [0, 1], got 1.5"),
    ({"stack_probability": -0.1}, "stack_probability must be a finite number >= 0, got -0.1"),
    ({"elevation": 0}, "elevation must be a finite number > 0, got 0"),
    ({"elevation": 95}, "elevation must be in (0, 90] degrees, got 95"),
    ({"elevation": float("nan")}, "elevation must be a finite number > 0, got nan"),
    ({"image_size": 0}, "image_size must be an integer >= 8, got 0"),
    ({"cube": 0}, "cube must be a finite number > 0, got 0"),
    ({"pick_threshold": -1.0}, "pick_threshold must be a finite number > 0, got -1.0"),
    ({"success_threshold": float("inf")}, "success_threshold must be a finite number > 0, got inf"),
    ({"grid_size": 2, "max_height": 1, "num_objects": 4}, "4 cubes leave no room to move on a 2x2 grid of stacks of 1"),
    ({"goal": "tower"}, "goal must be 'complete' or 'partial', got 'tower'"),
    ({"goal": "partial", "num_constrained": 5}, "num_constrained must be in 1..num_objects=4, got 5"),
    ({"render_mode": "human"}, "render_mode must be None or 'rgb_array', got 'human'"),
])
def test_bad_config_is_refused_by_name(kwargs, text):
    one_line_error(lambda: make("block-stacking", **{"num_objects": 4, **kwargs}), text)


def test_bad_actions_are_refused_by_name(check_closed_and_unrendered):
    e = make("block-stacking", num_objects=3)
    one_line_error(lambda: e.step(np.zeros(6, np.float32)), "step() before reset()")
    e.reset(seed=0)
    before = e.stacks
    for bad, text in ((np.zeros(3), "action must have shape (6,) = (w, dw), got (3,)"),
                      (np.zeros((2, 6)), "action must have shape (6,) = (w, dw), got (2, 6)"),
                      (np.ones(6, bool), "dtype bool"), (np.ones(6, complex), "dtype complex"),
                      ("left", "dtype <U4"),
                      (np.full(6, 5.0), "action [5.0, 5.0, 5.0, 5.0, 5.0, 5.0] is outside the action space"),
                      (np.array([0, 0, 0, np.nan, 0, 0]), "action must be finite, got [0.0, 0.0, 0.0, nan"),
                      ([[1, 2], [3]], "action must be 6 numbers (w, dw), got [[1, 2], [3]]")):
        one_line_error(lambda: e.step(bad), text)
    assert e.stacks == before and e._steps == 0                       # a refused action is no step
    for call, text in ((lambda: e.pick_and_move(3, 0), "obj must be an integer in 0..2, got 3"),
                       (lambda: e.pick_and_move(-1, 0), "obj must be an integer in 0..2, got -1"),
                       (lambda: e.pick_and_move(True, 0), "obj must be an integer in 0..2, got True"),
                       (lambda: e.pick_and_move(0, 16), "cell must be an integer in 0..15, got 16"),
                       (lambda: e.pick_and_move(0, 2.0), "cell must be an integer in 0..15, got 2.0")):
        one_line_error(call, text)
    e.close()
    check_closed_and_unrendered(e, "block-stacking", num_objects=3)
