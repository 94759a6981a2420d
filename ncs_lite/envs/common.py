"""What every rearrangement env shares: config checks, action checks, the goal contract.

Both rearrangement envs take the same task options (object count, goal kind, horizon,
action noise) and the same action (w, dw); the checks live here so that a bad value gets
the same message from either env.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np


def check_integer(cfg, name: str, low: int) -> None:
    v = getattr(cfg, name)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")


def check_number(cfg, name: str, allow_zero: bool = False) -> None:
    v = getattr(cfg, name)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
            or not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {v!r}")


def check_task(cfg, max_objects: int) -> None:
    """The task options shared by the rearrangement configs (fields of the same names)."""
    check_integer(cfg, "num_objects", 1)
    check_integer(cfg, "image_size", 8)
    if cfg.num_constrained is not None:
        check_integer(cfg, "num_constrained", 1)
    check_number(cfg, "horizon_multiplier")
    check_number(cfg, "action_noise", allow_zero=True)
    if cfg.goal not in ("complete", "partial"):
        raise ValueError(f"goal must be 'complete' or 'partial', got {cfg.goal!r}")
    if not 1 <= cfg.num_objects <= max_objects:
        raise ValueError(f"num_objects must be in 1..{max_objects}, got {cfg.num_objects}")
    if cfg.num_constrained is not None and not 1 <= cfg.num_constrained <= cfg.num_objects:
        raise ValueError(f"num_constrained must be in 1..num_objects={cfg.num_objects}, "
                         f"got {cfg.num_constrained}")
    if cfg.goal == "complete" and cfg.num_constrained not in (None, cfg.num_objects):
        raise ValueError("complete goals constrain every object; leave num_constrained unset "
                         f"(got {cfg.num_constrained})")


def constrained_count(cfg) -> int:
    """How many objects a goal constrains: all (complete) or num_constrained (default k // 2)."""
    if cfg.goal == "complete":
        return cfg.num_objects
    return cfg.num_constrained if cfg.num_constrained is not None else max(1, cfg.num_objects // 2)


def outside_action_space(actions, action_space) -> np.ndarray:
    """(...,) bool: which actions (..., 6) lie outside the Box, with a slack of 1e-6 of its
    range for float32 rounding of values on the bounds."""
    low, high = action_space.low, action_space.high
    slack = 1e-6 * (high - low)
    a = np.asarray(actions)
    return ((a < low - slack) | (a > high + slack)).any(-1)


def check_action(action, action_space, *, closed: bool, reset: bool) -> np.ndarray:
    """A step's action as float32 (6,), or a ValueError naming what is wrong with it."""
    if closed:
        raise ValueError("step() on a closed env; make a new one")
    if not reset:
        raise ValueError("step() before reset(): call env.reset(seed=...) first")
    try:
        raw = np.asarray(action)
    except (ValueError, TypeError):        # ragged nesting: [[1, 2], [3]]
        raise ValueError(f"action must be 6 numbers (w, dw), got {action!r}") from None
    if raw.dtype.kind not in "fiu":        # bool, complex, strings, objects
        raise ValueError(f"action must be 6 numbers (w, dw) of a real dtype, got dtype {raw.dtype}: {action!r}")
    a = raw.astype(np.float32)
    if a.shape != (6,):
        raise ValueError(f"action must have shape (6,) = (w, dw), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action must be finite, got {a.tolist()}")
    if outside_action_space(a, action_space):
        raise ValueError(f"action {np.round(a, 4).tolist()} is outside the action space: low "
                         f"{action_space.low.tolist()}, high {action_space.high.tolist()} (metres)")
    return a


def check_index(name: str, value, n: int) -> int:
    """`value` as an index in 0..n-1, or a ValueError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < n:
        raise ValueError(f"{name} must be an integer in 0..{n - 1}, got {value!r}")
    return int(value)


def horizon(cfg, min_steps: int) -> int:
    """ceil(horizon_multiplier x minimum steps), at least 1."""
    return max(1, int(np.ceil(cfg.horizon_multiplier * min_steps)))


class RearrangeEnv(gym.Env):
    """The step loop both rearrangement envs share. A subclass sets `config`, `action_space`,
    `horizon`, `_steps`, `_image` (None before the first reset) and provides `_closed()`,
    `_apply(action) -> (picked object or -1, moved object or -1)`, `_after_move()` and
    `_observe(moved, picked)`. `info["picked"]` names the object the pick found even when the
    place was refused (then `info["moved"]` is -1): why a step changed nothing."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def _check_open(self, call: str) -> None:
        if self._closed():
            raise ValueError(f"{call}() on a closed env; make a new one")

    def step(self, action):
        action = check_action(action, self.action_space, closed=self._closed(), reset=self._image is not None)
        if self.config.action_noise > 0:
            action = action + self.np_random.normal(0.0, self.config.action_noise, 6).astype(np.float32)
        picked, moved = self._apply(action)
        if moved >= 0:
            self._after_move()
        self._steps += 1
        obs, info = self._observe(moved, picked)
        terminated = bool(info["is_success"])
        truncated = (not terminated) and self._steps >= self.horizon
        return obs, float(terminated), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._image is None:
            raise ValueError("render() before reset(): call env.reset(seed=...) first")
        return self._image.copy()

    def __del__(self):          # an env dropped without close() must free what it holds
        try:
            self.close()
        except Exception:  # noqa: BLE001 - the interpreter may be shutting down
            pass
