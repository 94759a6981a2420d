"""Robogym-rearrange semantics: the object catalogue, overlap rules, pick and goal thresholds,
orientation, determinism, bad input; and NCS's "nearest" edge actions on its continuous states."""
import hashlib
import os

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from ncs_lite.envs import make
from ncs_lite.envs import robogym_rearrange as rr
from ncs_lite.envs.objects import COLOURS, OBJECTS, RANDOM_CHOSEN, chunkiness, load_mesh
from ncs_lite.ncs.graph import build_graph


@pytest.fixture(scope="module")
def env():
    e = make("robogym-rearrange", num_objects=4)
    yield e
    e.close()


def footprints_clear(xy, radii):
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    need = radii[:, None] + radii[None]
    off = ~np.eye(len(xy), dtype=bool)
    return bool(np.all(d[off] >= need[off] - 1e-6))


def test_catalogue_is_94_objects_and_13_colours_and_the_random_ones_follow_the_rule():
    assert len(OBJECTS) == 94 and len({o[0] for o in OBJECTS}) == 94
    assert len(COLOURS) == 13 and len({tuple(c) for c in COLOURS}) == 13
    scores = []
    for i in range(1000):
        try:
            scores.append(chunkiness(load_mesh(f"random_urdfs/{i:03d}/{i:03d}.obj", (1, 1, 1), 0)[0]))
        except ValueError:                      # one file has NaN vertices
            scores.append(-1.0)
    chosen = np.argsort(-np.asarray(scores), kind="stable")[:69]
    assert sorted(chosen.tolist()) == list(RANDOM_CHOSEN)


def test_every_object_is_scaled_to_the_same_longest_dimension():
    for j, entry in enumerate(OBJECTS):
        g = rr.object_geometry(entry, 0.12, f"s{j}")
        assert 0 < g["rest"] <= 0.06 + 1e-9 and 0 < g["radius"] <= 0.12 * np.sqrt(0.5) + 1e-9, entry[0]


def test_check_env():
    e = gym.make("ncs_lite/RobogymRearrange-v0", num_objects=2)
    check_env(e.unwrapped)
    e.close()


def test_observation_info_and_overlap_rules(env):
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        assert obs["image"].shape == (64, 64, 3) and obs["goal"].dtype == np.uint8
        masks = info["masks"]
        assert masks.shape == (4, 64, 64) and (masks.sum((1, 2)) >= 15).all()   # every object visible
        assert not (masks.sum(0) > 1).any()
        radii = env._radius[info["shapes"]]
        start, goal = info["positions"][:, :2], info["goal_positions"][:, :2]
        # starts never overlap; goals avoid each other and every start
        assert footprints_clear(np.concatenate([start, goal]), np.concatenate([radii, radii]))
        assert not info["satisfied"].any() and info["min_steps"] == 4 and info["horizon"] == 16
        assert len({tuple(c) for c in info["colors"]}) == 4 and len(set(info["shapes"].tolist())) == 4
        assert info["types"].shape == (4, 3 + 94)


def test_seven_objects_always_fit():
    e = make("robogym-rearrange", num_objects=7)
    for seed in range(10):
        _, info = e.reset(seed=seed)
        assert (info["masks"].sum((1, 2)) > 0).all()
    e.close()


def test_pick_threshold_move_and_orientation(env):
    _, info = env.reset(seed=1)
    quat = env.data.qpos.reshape(-1, 7)[:, 3:].copy()
    pos = info["positions"]
    spot = env._free_spot(env._radius[info["shapes"][0]], pos[1:, :2], env._radius[info["shapes"][1:]],
                          np.random.default_rng(0))
    miss = env.pick_and_move(0, spot)
    miss[0] += 0.06 * (1 if pos[0, 0] < 0 else -1)        # w 6 cm from the object: beyond 0.05
    miss[3] -= miss[0] - pos[0, 0]
    _, _, _, _, info = env.step(miss)
    assert info["moved"] == -1 and np.allclose(info["positions"], pos, atol=1e-3)
    hit = env.pick_and_move(0, spot)
    hit[:2] += 0.03                                       # 4.2 cm off: within the threshold
    hit[3:5] -= 0.03
    _, _, _, _, info = env.step(hit)
    assert info["moved"] == 0
    assert np.linalg.norm(info["positions"][0, :2] - spot) < 0.01    # put where it was asked
    assert np.allclose(np.abs(env.data.qpos.reshape(-1, 7)[0, 3:]), np.abs(quat[0]), atol=0.02)


def test_overlapping_or_off_table_place_is_a_noop(env):
    _, info = env.reset(seed=2)
    pos = info["positions"]
    for target in (pos[1, :2], np.array([0.29, 0.0])):
        _, _, _, _, after = env.step(env.pick_and_move(0, target))
        assert after["moved"] == -1 and np.allclose(after["positions"], pos, atol=1e-3)


def test_goal_within_threshold_satisfies_and_success_terminates():
    e = make("robogym-rearrange", num_objects=2)
    _, info = e.reset(seed=4)
    for k in range(2):
        target = info["goal_positions"][k, :2] + np.array([0.03, 0.0])
        if not e.fits(k, target):
            target = info["goal_positions"][k, :2]
        _, reward, term, _, info = e.step(e.pick_and_move(k, target))
        assert info["moved"] == k and info["satisfied"][k]
    assert term and reward == 1.0 and info["is_success"]
    e.close()


def test_determinism_for_a_seed():
    runs = []
    for _ in range(2):
        e = make("robogym-rearrange", num_objects=3)
        obs, info = e.reset(seed=7)
        rng = np.random.default_rng(0)
        for _ in range(3):
            obs, *_, info = e.step(e.random_pick_and_move(rng))
        runs.append((obs["image"], obs["goal"], info["positions"]))
        e.close()
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("action, match", [
    (np.zeros(5), "shape"), (np.full(6, np.nan), "finite"), (np.array([1.0, 0, 0, 0, 0, 0]), "outside"),
    (np.array(["a"] * 6), "real dtype")])
def test_bad_actions_raise(env, action, match):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)


@pytest.mark.parametrize("kwargs, match", [
    ({"num_objects": 14}, "num_objects"), ({"object_size": 0.5}, "object_size"),
    ({"num_objects": 8}, "needs 16 footprints"), ({"num_objects": 13, "goal": "partial"}, "needs 19"),
    ({"horizon_multiplier": float("inf")}, "horizon_multiplier"),
    ({"camera_tilt": 80}, "camera_tilt")])
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make("robogym-rearrange", **kwargs)


def test_step_before_reset_and_after_close(check_closed_and_unrendered):
    e = make("robogym-rearrange", num_objects=1)
    with pytest.raises(ValueError, match="before reset"):
        e.step(np.zeros(6, np.float32))
    e.reset(seed=0)
    with pytest.raises(ValueError, match=r"obj must be an integer in 0\.\.0, got 3"):
        e.pick_and_move(3, (0.0, 0.0))
    with pytest.raises(ValueError, match=r"action must be 6 numbers \(w, dw\)"):
        e.step([[0, 0], [0]])
    e.close()
    check_closed_and_unrendered(e, "robogym-rearrange", num_objects=1)


def test_placement_is_the_one_the_shipped_data_was_made_with_and_rendering_is_deterministic():
    """The objects' positions along two seeded episodes, hashed: they come from the kit's own
    placement arithmetic, not from MuJoCo, so the digest (taken with the env that collected the
    shipped robogym data) holds on any MuJoCo version. What MuJoCo draws is checked as a
    property instead: two envs given the same seed and actions render the same images and masks."""
    def episodes():
        positions, drawn = hashlib.sha256(), hashlib.sha256()
        for k, goal in ((4, "complete"), (7, "partial")):
            e = make("robogym-rearrange", num_objects=k, goal=goal)
            obs, info = e.reset(seed=3)
            rng = np.random.default_rng(3)
            for _ in range(6):
                positions.update(np.ascontiguousarray(info["positions"]).tobytes())
                for a in (obs["image"], obs["goal"], info["masks"], info["goal_masks"]):
                    drawn.update(np.ascontiguousarray(a).tobytes())
                obs, _, _, _, info = e.step(e.random_pick_and_move(rng))
            e.close()
        return positions.hexdigest(), drawn.hexdigest()

    first, again = episodes(), episodes()
    assert first[0] == "43a4799467a9782b7118d3809c56f24e8388ce395e75d18f0013d21e93e2c96f"
    assert first == again


def test_a_render_failure_names_mujoco_gl_and_the_libraries(monkeypatch):
    def broken(*a, **k):
        raise RuntimeError("no display")
    monkeypatch.setattr(rr.mujoco, "GLContext", broken)
    with pytest.raises(RuntimeError, match="MUJOCO_GL.*EGL.*OSMesa"):
        make("robogym-rearrange", num_objects=1)


def test_importing_mujoco_before_the_kit_is_named_in_the_render_error():
    """MuJoCo fixes its GL backend at its first import: after `import ncs_lite` it is headless;
    imported before, it keeps GLFW (needs a display), and the error says so and what to do."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY")}
    make_it = "from ncs_lite.envs import make; make('robogym-rearrange', num_objects=1).close(); print('ok')"
    for first, expect in (("import ncs_lite; import mujoco", "ok"),
                          ("import mujoco", "mujoco was imported before ncs_lite")):
        run = subprocess.run([sys.executable, "-c", f"{first}; {make_it}"], env=env, capture_output=True, text=True)
        assert expect in run.stdout + run.stderr, (first, run.stderr[-800:])


def test_nearest_edge_action_takes_the_closest_transition_and_the_next_on_retry():
    # two transitions on one edge between the same two clusters: from (0, 0) to (1, 0) and
    # from (0.1, 0) to (0.9, 0); the state nearest the second gets its action first
    before = torch.tensor([[[0.0, 0.0]], [[0.1, 0.0]], [[5.0, 5.0]], [[5.1, 5.0]]])
    after = torch.tensor([[[1.0, 0.0]], [[0.9, 0.0]], [[5.0, 6.0]], [[5.1, 6.0]]])
    actions = np.arange(24, dtype=np.float32).reshape(4, 6)
    g = build_graph(before, after, actions, clusters=4, state="slot", edge_action="nearest")
    src, dst = g.bind(torch.tensor([[0.1, 0.0], [0.9, 0.0]])).tolist()
    assert g.bind(torch.tensor([[0.0, 0.0], [1.0, 0.0]])).tolist() == [src, dst]   # one edge
    near = g.action(src, dst, torch.tensor([0.12, 0.0]), torch.tensor([0.88, 0.0]))
    second = g.action(src, dst, torch.tensor([0.12, 0.0]), torch.tensor([0.88, 0.0]), rank=1)
    assert np.array_equal(near, actions[1]) and np.array_equal(second, actions[0])
    assert np.array_equal(g.action(src, dst), actions[0])      # without states: the most common
    assert g.edge_action == "nearest" and g.info["edge_action"] == "nearest"


def test_nearest_compares_states_along_the_directions_moves_span():
    # every move goes +1 in x; y differs between examples (what a learned s holds beside the
    # position) and should not decide which transition's start is nearest the object
    from ncs_lite.ncs.graph import TransitionGraph

    g = TransitionGraph(torch.zeros(2, 2), "sqeuclidean")
    before = torch.tensor([[0.3, 5.0], [0.01, 0.0], [0.5, 2.0]])
    actions = np.arange(18, dtype=np.float32).reshape(3, 6)
    after = before + torch.tensor([1.0, 0.0])
    g.add(torch.zeros(3, dtype=torch.long), torch.ones(3, dtype=torch.long), actions, before, after)
    basis = g.moved_subspace(0.95)
    assert basis.shape == (2, 1) and torch.allclose(basis.abs()[:, 0], torch.tensor([1.0, 0.0]))
    now, goal = torch.tensor([0.0, 5.0]), torch.tensor([1.0, 5.0])
    assert np.array_equal(g.action(0, 1, now, goal), actions[0])                 # whole states
    assert np.array_equal(g.action(0, 1, now, goal, basis=basis), actions[1])    # along x
    assert g.moved_subspace(1.0) is None
    with pytest.raises(ValueError, match="variance must be in"):
        g.moved_subspace(0.0)


def test_nearest_graph_round_trips(tmp_path):
    before = torch.rand(50, 3, 3)
    after = before.clone()
    after[:, 0] += 0.5              # entity 0 moves; small moves make self-loops, which are kept
    g = build_graph(before, after, np.random.rand(50, 6).astype(np.float32), clusters=5, state="slot",
                    edge_action="nearest")
    g.save(tmp_path / "g.pt")
    h = type(g).load(tmp_path / "g.pt")
    assert h.edge_action == "nearest" and h.edges == g.edges
    key = next(iter(g.edges))
    b, a = torch.rand(3), torch.rand(3)
    assert np.array_equal(g.action(*key, b, a), h.action(*key, b, a))


def test_agent_on_a_nearest_graph_retries_with_the_next_transition_and_ignores_same_node():
    from gymnasium import spaces

    from ncs_lite.ncs.perception import Entities
    from ncs_lite.ncs.policy import NCSAgent

    # one entity, states (x, 1) (cosine select-constraint needs a constant nonzero axis, like the
    # oracle's z); three transitions from x near 0 to x near 1
    before = torch.tensor([[[0.0, 1.0]], [[0.05, 1.0]], [[0.1, 1.0]]])
    after = torch.tensor([[[1.0, 1.0]], [[0.95, 1.0]], [[0.9, 1.0]]])
    actions = np.eye(6, dtype=np.float32)[:3]
    graph = build_graph(before, after, actions, clusters=2, state="slot", edge_action="nearest")

    class Fixed:
        graph_state = "slot"

        def __init__(self, state):
            self.state = state

        def current(self, obs, info):
            return Entities(torch.zeros(1, 2), torch.tensor([self.state]))

        def goal(self, obs, info):
            return Entities(torch.zeros(1, 2), torch.tensor([[0.92, 1.0]]))

    agent = NCSAgent(graph, Fixed([0.09, 1.0]), spaces.Box(-1, 1, (6,)), seed=0)
    agent.reset(None, None)
    first, random1 = agent.act(None, None)
    second, random2 = agent.act(None, None)          # the same pair and edge again: next nearest
    assert not random1 and not random2
    assert np.array_equal(first, actions[2]) and np.array_equal(second, actions[1])
    assert agent.last["rank"] == 1
    # an entity in its goal's node still acts (a node is wider than the goal threshold)
    near = NCSAgent(graph, Fixed([0.93, 1.0]), spaces.Box(-1, 1, (6,)), seed=0)
    near.reset(None, None)
    near.act(None, None)
    assert not near.last["same_node"].any()


def test_untouched_objects_keep_their_pose_in_the_simulator():
    """Appendix C fixes orientation: MuJoCo's own state of every object but the moved one is
    exactly what it was, however often an object is put down beside them."""
    e = make("robogym-rearrange", num_objects=4)
    _, info = e.reset(seed=7)
    before = e.data.qpos.reshape(-1, 7).copy()
    rng = np.random.default_rng(0)
    for _ in range(16):
        _, _, _, _, info = e.step(e.pick_and_move(0, info["positions"][0, :2]))
        assert info["moved"] == 0
    for _ in range(10):
        _, _, _, _, info = e.step(e.random_pick_and_move(rng))
        if info["moved"] >= 0:
            before[info["moved"], :3] = e.data.qpos.reshape(-1, 7)[info["moved"], :3]  # only its place changes
    after = e.data.qpos.reshape(-1, 7)
    assert np.array_equal(after[:, 3:], before[:, 3:])       # every orientation, bit for bit
    assert np.array_equal(after[:, :3], before[:, :3])       # every untouched object's place
    assert np.array_equal(e.data.xpos[1:], after[:, :3])     # the poses the camera draws
    assert footprints_clear(info["positions"][:, :2], e._radius[info["shapes"]])
    e.close()


@pytest.mark.parametrize("k", [4, 5, 6, 7])
def test_task_sampling_never_fails_and_keeps_footprints_clear(k):
    """Random sampling, then the lattice: any radii up to the largest fit, at every count the
    constructor accepts; a seed whose random draw hit dead ends (7 objects, seed 12345) resets."""
    e = make("robogym-rearrange", num_objects=k)
    rmax = e._radius.max()
    for seed in range(20):
        rng = np.random.default_rng(seed)
        radii = np.full(2 * k, rmax) if seed % 2 else rng.uniform(e._radius.min(), rmax, 2 * k)
        xy = e._sample_spots(radii, rng)
        assert footprints_clear(xy, radii + e.config.gap / 2)
        assert np.all(np.abs(xy) <= np.array([0.3, 0.4]) - radii[:, None] + 1e-9)
    if k == 7:
        _, info = e.reset(seed=12345)
        both = np.concatenate([info["positions"][:, :2], info["goal_positions"][:, :2]])
        assert footprints_clear(both, np.tile(e._radius[info["shapes"]], 2))
    e.close()


def test_lattice_holds_the_largest_footprint_in_each_cell():
    cfg = rr.RobogymRearrangeConfig()
    cells = rr.lattice(cfg, 0.0778)
    assert len(cells) == 15                                   # 3 x 5 on 0.6 x 0.8 m
    assert footprints_clear(cells, np.full(len(cells), 0.0778 + cfg.gap / 2))
    assert np.all(np.abs(cells) <= np.array([0.3, 0.4]) - 0.0778 + 1e-9)


def _two_node_graph(edge_action):
    """Entity 0 moves from around x = 0 to around x = 1 (states (x, y, 1)); actions pick at the
    state's (x, y) and place at the end state's (x, y), as a perfect perception would see."""
    rng = np.random.default_rng(0)
    start = np.c_[rng.uniform(-0.1, 0.1, (40, 2)), np.ones(40)]
    end = start + np.array([1.0, 0.0, 0.0])
    end[:, :2] += rng.uniform(-0.1, 0.1, (40, 2))
    actions = np.zeros((40, 6), np.float32)
    actions[:, :2], actions[:, 3:5] = start[:, :2], end[:, :2] - start[:, :2]
    graph = build_graph(torch.tensor(start, dtype=torch.float32)[:, None],
                        torch.tensor(end, dtype=torch.float32)[:, None], actions, clusters=2, state="slot",
                        edge_action=edge_action)
    return graph, start, end, actions


def test_compose_and_readout_edge_actions_land_where_the_states_say():
    graph, start, end, actions = _two_node_graph("readout")
    assert graph.edge_action == "readout" and graph.info["edge_action"] == "readout"
    now, goal = torch.tensor([0.033, -0.021, 1.0]), torch.tensor([1.047, 0.061, 1.0])
    src, dst = graph.bind(torch.stack([now, goal])).tolist()
    read = graph.action(src, dst, now, goal)
    assert np.allclose(read[:2], now[:2], atol=1e-3) and np.allclose(read[:2] + read[3:5], goal[:2], atol=1e-3)
    # compose: the pick of the transition whose start is nearest now, the place of the one
    # whose end is nearest the goal (here two different transitions)
    comp = graph.action(src, dst, now, goal, mode="compose")
    i = np.argmin(((start - now.numpy()) ** 2).sum(1))
    j = np.argmin(((end - goal.numpy()) ** 2).sum(1))
    assert i != j
    assert np.allclose(comp[:2], actions[i, :2], atol=1e-4)      # actions are kept to 0.1 mm
    assert np.allclose(comp[:2] + comp[3:5], end[j, :2], atol=2e-4)
    # a retry of "readout" takes compose's nearest, then the next
    assert np.allclose(graph.action(src, dst, now, goal, rank=1), comp)
    nearest = graph.action(src, dst, now, goal, mode="nearest")
    assert not np.allclose(nearest, read)
    # the modes that read states need a graph that kept them
    plain, *_ = _two_node_graph("most_common")
    with pytest.raises(ValueError, match="kept none"):
        plain.check_edge_action("readout")
    with pytest.raises(ValueError, match="edge_action must be one of"):
        graph.check_edge_action("closest")


def test_a_refused_place_names_the_picked_object_and_step_outcomes_say_why():
    from ncs_lite.evaluation import step_outcome

    e = make("robogym-rearrange", num_objects=3)
    _, info = e.reset(seed=2)
    pos = info["positions"]
    _, _, _, _, after = e.step(e.pick_and_move(0, pos[1, :2]))          # onto object 1: refused
    assert after["moved"] == -1 and after["picked"] == 0 and step_outcome(info, after) == "refused"
    far = np.array([0.29, 0.39]) if np.linalg.norm(pos[:, :2] - [0.29, 0.39], axis=1).min() > 0.05 else np.array([-0.29, -0.39])
    miss = np.array([*far, 0.0, 0.0, 0.0, 0.0], np.float32)
    _, _, _, _, nothing = e.step(miss)
    assert nothing["picked"] == -1 and step_outcome(after, nothing) == "picked_nothing"
    _, _, _, _, placed = e.step(e.pick_and_move(0, info["goal_positions"][0, :2]))
    assert placed["moved"] == 0 and step_outcome(nothing, placed) == "placed"
    spot = e._free_spot(e._radius[info["shapes"][0]], placed["positions"][1:, :2],
                        e._radius[info["shapes"][1:]], np.random.default_rng(0))
    _, _, _, _, undone = e.step(e.pick_and_move(0, spot))
    assert undone["moved"] == 0 and step_outcome(placed, undone) == "moved_done"
    _, _, _, _, elsewhere = e.step(e.pick_and_move(1, undone["positions"][1, :2] + [0.0, 0.001]))
    assert elsewhere["moved"] == 1 and step_outcome(undone, elsewhere) == "off_goal"
    e.close()


def test_readout_points_stay_within_the_box_of_the_transitions():
    graph, start, end, actions = _two_node_graph("readout")
    far = torch.tensor([[5.0, -7.0, 1.0]])                         # unlike any transition's state
    pick, place = graph.read_points(far, far)
    assert torch.all(pick >= torch.tensor(actions[:, :2].min(0)) - 1e-4)    # actions kept to 0.1 mm
    assert torch.all(pick <= torch.tensor(actions[:, :2].max(0)) + 1e-4)
    assert torch.all(place <= torch.tensor(end[:, :2].max(0)) + 1e-4)
