"""Figures of what the agent did draw what the agent used (notebooks 05-06).

The agent records its decision in `NCSAgent.last`; notebook 06 draws `aligned_masks(last)`
and the recorded distances and probabilities. These tests run the learned agent (shipped
checkpoint and graph) one step on real tasks and check that the recorded masks are the ones
its perception kept (the best of its restarts) and that they reproduce, pair by pair, the
distances, node bindings and probabilities the agent sampled from.
"""
import numpy as np
import pytest
import torch

from ncs_lite.evaluation import TaskSet, agent_factory, task_seed
from ncs_lite.inference import SHIPPED_CHECKPOINT, SHIPPED_GRAPH, load_dslate
from ncs_lite.ncs.graph import TransitionGraph
from ncs_lite.ncs.perception import pool_masks
from ncs_lite.ncs.policy import align, aligned_masks, constraint_distances

pytestmark = pytest.mark.skipif(not (SHIPPED_CHECKPOINT.exists() and SHIPPED_GRAPH.exists()),
                                reason="needs the shipped checkpoint and graph")


@pytest.fixture(scope="module")
def model():
    return load_dslate(SHIPPED_CHECKPOINT, device="cpu")


@pytest.fixture(scope="module")
def graph():
    return TransitionGraph.load(SHIPPED_GRAPH)


def kept_restart_masks(model, image, perception):
    """The masks of the restart `infer` keeps, rebuilt by hand: run every restart as its own
    image (row r of a batch of R copies starts from restart r's initial slots: the first from
    the farthest-point seeds when the perception's `slot_init` says so, the others drawn from
    the learned Gaussian with `infer`'s seed) and take the one the model reconstructs best."""
    R, K = perception.restarts, perception.num_slots
    copies = np.repeat(np.asarray(image)[None], R, 0)
    farthest = perception.slot_init == "farthest"
    init = model.slot_attn.initial_slots(R - farthest, K, torch.Generator(device=model.device).manual_seed(0))
    if farthest:
        x = torch.as_tensor(np.asarray(image)[None], device=model.device).float() / 255.0
        init = torch.cat([model.slot_attn.farthest_point_slots(model._slot_inputs(x), K), init])
    r = model.infer(copies, iterations=perception.iterations, num_slots=K, init_slots=init)
    err = model.reconstruction_error(torch.as_tensor(copies).float() / 255.0, r.slots, r.attention)
    return r.masks[int(err.argmin())].float(), r.masks[0].float()


@pytest.mark.parametrize("num_objects", [4, 7])
def test_recorded_masks_are_the_kept_restart(model, graph, num_objects):
    env = TaskSet(num_objects=num_objects).make_env()
    obs, info = env.reset(seed=task_seed(0, 0))
    agent = agent_factory("ncs", graph=graph, model=model)(env)
    agent.reset(obs, info)
    agent.act(obs, info)
    env.close()
    last, perception = agent.last, agent.perception
    assert perception.restarts > 1
    for entities, image in ((last["current"], obs["image"]), (last["goal"], obs["goal"])):
        kept, _ = kept_restart_masks(model, image, perception)
        torch.testing.assert_close(entities.masks, kept, rtol=0, atol=1e-6)
        # the states the agent compared are exactly those masks, pooled
        torch.testing.assert_close(entities.states, pool_masks(entities.masks), rtol=0, atol=0)
        # the perception gives the same entities again (seeded): what a figure asks it for
        again = perception.current({"image": image})
        assert torch.equal(again.masks, entities.masks) and torch.equal(again.types, entities.types)


@pytest.mark.parametrize("num_objects", [4, 7])
def test_aligned_masks_reproduce_the_decision(model, graph, num_objects):
    """What notebook 06 draws (aligned_masks and the recorded numbers) is what the agent
    computed: the drawn masks, pooled, give its distances and node bindings pair by pair,
    its alignment is align() on the recorded types, and its probabilities follow from the
    same-node rule."""
    env = TaskSet(num_objects=num_objects).make_env()
    agent = agent_factory("ncs", graph=graph, model=model)(env)
    for i in range(3):
        obs, info = env.reset(seed=task_seed(0, i))
        agent.reset(obs, info)
        action, was_random = agent.act(obs, info)
        last = agent.last
        goal_masks, current_masks = aligned_masks(last)
        g, c, _ = align(last["current"].types, last["goal"].types, agent.align)
        np.testing.assert_array_equal(g, last["goal_index"])
        np.testing.assert_array_equal(c, last["current_index"])
        assert len(goal_masks) == len(current_masks) == len(g) <= max(model.cfg.slots.num_slots, num_objects + 1)
        raw = constraint_distances(pool_masks(current_masks), pool_masks(goal_masks)).numpy()
        np.testing.assert_allclose(raw, last["raw_distances"], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(graph.bind(pool_masks(current_masks)).numpy(), last["src_nodes"])
        np.testing.assert_array_equal(graph.bind(pool_masks(goal_masks)).numpy(), last["dst_nodes"])
        np.testing.assert_array_equal(last["same_node"], last["src_nodes"] == last["dst_nodes"])
        np.testing.assert_array_equal(last["distances"], np.where(last["same_node"], 0.0, last["raw_distances"]))
        if last["distances"].sum() > 0:
            np.testing.assert_allclose(last["probabilities"], last["distances"] / last["distances"].sum())
            j = last["selected"]
            assert last["probabilities"][j] > 0
            assert (last["src"], last["dst"]) == (last["src_nodes"][j], last["dst_nodes"][j])
        assert was_random == (last["fallback"] is not None)
        np.testing.assert_array_equal(np.asarray(last["action"]), np.asarray(action))
    env.close()
