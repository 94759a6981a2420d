"""Environment throughput: transitions per second, rendering included, on one core.

Reference: a bare render loop over the same scene in the same run (`pybullet.getCameraImage`
for block-rearrange; MuJoCo's `Renderer.update_scene` + `render` of the RGB image for
robogym-rearrange). A block-rearrange step is one render plus bookkeeping, so the render is
the floor of its cost; a robogym-rearrange step is an RGB pass, a segmentation pass (the
masks of `info`) and the settle's physics, so its ratio is below 0.5 unless the second pass
is cheaper than the first. `ratio_to_render` says how close to the floor an env runs;
for robogym-rearrange `ratio_to_both_passes` is the same against a bare loop of the two passes
its step must make (the env's own `_render`: RGB, then segmentation).
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


def _measure(env, bare_render, targets: dict, seconds: float) -> dict:
    """Random pick-and-move steps per second against `bare_render` calls per second."""
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    step_rate = _rate(lambda: env.step(env.random_pick_and_move(rng)), seconds)
    render_rate = _rate(bare_render, seconds)
    env.close()
    return {"transitions_per_s": round(step_rate, 1), "bare_render_per_s": round(render_rate, 1),
            "ratio_to_render": round(step_rate / render_rate, 3), "targets": targets}


def run(seconds: float = 2.0) -> dict:
    # PyBullet's TinyRenderer is single-threaded: this is a one-core figure.
    block = make("block-rearrange", num_objects=4, horizon_multiplier=1e6)
    s = block.config.image_size

    def bare_pybullet_render():
        pb.getCameraImage(s, s, block._view, block._proj, shadow=0, renderer=pb.ER_TINY_RENDERER,
                          physicsClientId=block._client)

    robogym = make("robogym-rearrange", num_objects=4, horizon_multiplier=1e6)

    def bare_mujoco_render():
        robogym._renderer.update_scene(robogym.data, "top", scene_option=robogym._scene_option)
        robogym._renderer.render()

    both_passes = _rate(robogym._render, seconds)     # before _measure closes the env
    out = {
        "block-rearrange": _measure(block, bare_pybullet_render,
                                    {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 300"}, seconds),
        "robogym-rearrange": _measure(robogym, bare_mujoco_render,
                                      {"ratio_to_render": ">= 0.5", "transitions_per_s": ">= 150"}, seconds),
    }
    rg = out["robogym-rearrange"]
    rg["bare_rgb_and_segmentation_per_s"] = round(both_passes, 1)
    rg["ratio_to_both_passes"] = round(rg["transitions_per_s"] / both_passes, 3)
    return out
