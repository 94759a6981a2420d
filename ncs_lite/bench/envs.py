"""Environment throughput: transitions per second, rendering included, on one core.

Reference: a bare render loop over the same scene in the same run that renders what one
observation is made of. For block-rearrange and block-stacking that is the env's own
`pybullet.getCameraImage` call (its camera and light), which draws the RGB image, depth and
segmentation in one call; MuJoCo draws the segmentation in a pass of its own, so for
robogym-rearrange it is a bare `mujoco.Renderer` loop of the RGB image and then the
segmentation from the env's camera (the masks of `info`, as the block envs' come from their
one call). A block-rearrange step is that render plus bookkeeping (a block-stacking
step's bookkeeping also finds the top cubes and the stacks with room); a
robogym-rearrange step is the two passes plus the kinematics of the placed pose.
`ratio_to_render` says how close to that floor an env runs. For robogym-rearrange,
`ratio_to_one_rgb_pass` is the step rate against one bare RGB pass (a reference that leaves
out the segmentation pass every step must draw; kept to compare with earlier runs),
`ms_per_call` times the parts of a step on the scene the steps left (both passes, the
kinematics, the random action's free-spot search), and `ratio_to_both_passes` is the step rate
against the env's own two passes.
"""
from __future__ import annotations

import time

import mujoco
import numpy as np
import pybullet as pb

from ..envs import make
from ..envs.robogym_rearrange import HIDDEN_GROUP


def _rate(fn, seconds: float = 2.0) -> float:
    """Calls per second of `fn`, timed over at least `seconds` (after a short warm-up)."""
    for _ in range(20):
        fn()
    n, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(50):
            fn()
        n += 50
    return n / elapsed


def _measure(env, bare_render, targets: dict, seconds: float, parts: dict | None = None) -> dict:
    """Random pick-and-move steps per second against `bare_render` calls per second; then
    milliseconds per call of each of `parts` (name -> fn(env, rng)), on the scene the steps left."""
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    step_rate = _rate(lambda: env.step(env.random_pick_and_move(rng)), seconds)
    render_rate = _rate(bare_render, seconds)
    out = {"transitions_per_s": round(step_rate, 1), "bare_render_per_s": round(render_rate, 1),
           "ratio_to_render": round(step_rate / render_rate, 3), "targets": targets}
    if parts:
        out["ms_per_call"] = {"step": round(1e3 / step_rate, 3),
                              **{name: round(1e3 / _rate(lambda: fn(env, rng), seconds), 3) for name, fn in parts.items()}}
    env.close()
    return out


def run(seconds: float = 2.0) -> dict:
    # PyBullet's TinyRenderer is single-threaded: this is a one-core figure.
    block = make("block-rearrange", num_objects=4, horizon_multiplier=1e6)
    s = block.config.image_size

    def bare_pybullet_render():
        pb.getCameraImage(s, s, block._view, block._proj, shadow=0, renderer=pb.ER_TINY_RENDERER,
                          physicsClientId=block._client)

    stacking = make("block-stacking", num_objects=4, horizon_multiplier=1e6)
    size_s = stacking.config.image_size

    def bare_stacking_render():           # the env's own call: its tilted camera and its light
        pb.getCameraImage(size_s, size_s, stacking._view, stacking._proj, shadow=0, lightDirection=[0.4, -1.0, 2.0],
                          renderer=pb.ER_TINY_RENDERER, physicsClientId=stacking._client)

    robogym = make("robogym-rearrange", num_objects=4, horizon_multiplier=1e6)
    size = robogym.config.image_size
    renderer = mujoco.Renderer(robogym.model, size, size)
    segmenter = mujoco.Renderer(robogym.model, size, size)
    segmenter.enable_segmentation_rendering()
    shown = mujoco.MjvOption()
    shown.geomgroup[HIDDEN_GROUP] = 0

    def bare_mujoco_render():
        renderer.update_scene(robogym.data, "top", scene_option=shown)
        renderer.render()

    def bare_rgb_and_segmentation():
        bare_mujoco_render()
        segmenter.update_scene(robogym.data, "top", scene_option=shown)
        segmenter.render()

    parts = {"rgb_and_segmentation": lambda env, rng: env._render(), "kinematics": lambda env, rng: env._update_kinematics(),
             "random_action": lambda env, rng: env.random_pick_and_move(rng)}
    rg = _measure(robogym, bare_rgb_and_segmentation,
                  {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 150"}, seconds, parts)
    both_passes = 1e3 / rg["ms_per_call"]["rgb_and_segmentation"]
    rg["own_passes_per_s"] = round(both_passes, 1)
    rg["ratio_to_both_passes"] = round(rg["transitions_per_s"] / both_passes, 3)
    one_pass = _rate(bare_mujoco_render, seconds)
    rg["bare_rgb_pass_per_s"] = round(one_pass, 1)
    rg["ratio_to_one_rgb_pass"] = round(rg["transitions_per_s"] / one_pass, 3)
    renderer.close()
    segmenter.close()
    pybullet_targets = {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 300"}
    return {"block-rearrange": _measure(block, bare_pybullet_render, pybullet_targets, seconds),
            "block-stacking": _measure(stacking, bare_stacking_render, pybullet_targets, seconds),
            "robogym-rearrange": rg}
