"""Environment throughput: transitions per second, rendering included, on one core.

Reference: a bare render loop over the same scene in the same run (`pybullet.getCameraImage`
for block-rearrange; MuJoCo's `Renderer.update_scene` + `render` of the RGB image for
robogym-rearrange). A block-rearrange step is one render plus bookkeeping, so the render is
the floor of its cost; a robogym-rearrange step is an RGB pass, a segmentation pass (the
masks of `info`) and the settle's physics, so its ratio is below 0.5 unless the second pass
is cheaper than the first. `ratio_to_render` says how close to the floor an env runs.
"""
from __future__ import annotations

import time

import numpy as np
import pybullet as pb

from ..envs import make


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


def run(seconds: float = 2.0) -> dict:
    # PyBullet's TinyRenderer is single-threaded: this is a one-core figure.
    results = {}
    env = make("block-rearrange", num_objects=4, horizon_multiplier=1e6)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    step_rate = _rate(lambda: env.step(env.random_pick_and_move(rng)), seconds)
    s = env.config.image_size

    def bare_render():
        pb.getCameraImage(s, s, env._view, env._proj, shadow=0, renderer=pb.ER_TINY_RENDERER,
                          physicsClientId=env._client)

    render_rate = _rate(bare_render, seconds)
    env.close()
    results["block-rearrange"] = {
        "transitions_per_s": round(step_rate, 1),
        "bare_render_per_s": round(render_rate, 1),
        "ratio_to_render": round(step_rate / render_rate, 3),
        "targets": {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 300"},
    }

    env = make("robogym-rearrange", num_objects=4, horizon_multiplier=1e6)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    step_rate = _rate(lambda: env.step(env.random_pick_and_move(rng)), seconds)
    renderer, option = env._renderer, env._scene_option

    def bare_mujoco_render():
        renderer.update_scene(env.data, "top", scene_option=option)
        renderer.render()

    render_rate = _rate(bare_mujoco_render, seconds)
    env.close()
    results["robogym-rearrange"] = {
        "transitions_per_s": round(step_rate, 1),
        "bare_render_per_s": round(render_rate, 1),
        "ratio_to_render": round(step_rate / render_rate, 3),
        "targets": {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 150"},
    }
    return results
