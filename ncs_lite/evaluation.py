"""The evaluation harness shared by every method (NCS, the oracle, every baseline).

A task set is fixed by (env, num_objects, goal, horizon multiplier, action noise, seed,
episodes): task i is `env.reset(seed=task_seed(seed, i))`, so every method faces the same
tasks. Each episode gives one tidy row; `summarize` turns rows into success rates with 95%
Wilson intervals, mean steps and the fraction of random fallback actions.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .envs import make
from .utils import atomic_write_text, progress

COLUMNS = ("method", "env", "num_objects", "goal", "num_constrained", "horizon_multiplier",
           "action_noise", "seed", "episode", "task_seed", "success", "steps", "min_steps",
           "horizon", "random_actions")


@dataclass(frozen=True)
class TaskSet:
    env: str = "block-rearrange"
    num_objects: int = 4
    goal: str = "complete"
    num_constrained: int | None = None
    horizon_multiplier: float = 4.0
    action_noise: float = 0.0
    episodes: int = 100
    seed: int = 0

    def __post_init__(self):
        if not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"episodes must be a positive integer, got {self.episodes!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")

    def make_env(self):
        return make(self.env, num_objects=self.num_objects, goal=self.goal,
                    num_constrained=self.num_constrained,
                    horizon_multiplier=self.horizon_multiplier, action_noise=self.action_noise)


def task_seed(seed: int, episode: int) -> int:
    """The env seed of task `episode` in the task set seeded `seed` (same for every method)."""
    return int(np.random.SeedSequence([seed, episode, 0xE7A1]).generate_state(1)[0])


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval for a binomial proportion (sound at 0 and n successes)."""
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # exact ends at 0 and n successes (the formula gives them up to rounding)
    return (0.0 if successes == 0 else centre - half), (1.0 if successes == n else centre + half)


def run_episode(agent, env, seed: int) -> dict:
    obs, info = env.reset(seed=seed)
    agent.reset(obs, info)
    steps = randoms = 0
    terminated = truncated = False
    while not (terminated or truncated):
        action, was_random = agent.act(obs, info)
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        randoms += bool(was_random)
    return {"success": int(terminated), "steps": steps, "min_steps": info["min_steps"],
            "horizon": info["horizon"], "random_actions": randoms}


def evaluate(make_agent, tasks: TaskSet, method: str) -> list[dict]:
    """Run `make_agent(env)`'s agent on every task of `tasks`; one row per episode."""
    env = tasks.make_env()
    agent = make_agent(env)
    rows = []
    try:
        for i in progress(range(tasks.episodes), desc=f"{method} k={tasks.num_objects}", leave=False):
            seed = task_seed(tasks.seed, i)
            rows.append({"method": method, **{k: v for k, v in asdict(tasks).items() if k != "episodes"},
                         "episode": i, "task_seed": seed, **run_episode(agent, env, seed)})
    finally:
        env.close()
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """Rows grouped by everything but the episode -> success, 95% CI, mean steps, randoms."""
    keys = [c for c in COLUMNS if c not in ("episode", "task_seed", "success", "steps",
                                            "min_steps", "horizon", "random_actions")]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    for key, rs in groups.items():
        n, s = len(rs), sum(r["success"] for r in rs)
        lo, hi = wilson_interval(s, n)
        steps = sum(r["steps"] for r in rs)
        out.append({**dict(zip(keys, key)), "episodes": n, "success": s / n, "ci_low": lo,
                    "ci_high": hi, "mean_steps": steps / n,
                    "random_fraction": sum(r["random_actions"] for r in rs) / max(1, steps)})
    return out


def write_csv(rows: list[dict], path: str | Path) -> Path:
    """Tidy CSV, one row per episode (atomic write)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else list(COLUMNS))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(path, buf.getvalue())
    return Path(path)


METHODS = ("ncs", "ncs-oracle", "random")


def agent_factory(method: str, graph=None, model=None, seed: int = 0, ncs=None):
    """A function env -> agent for `method` (see METHODS); NCS methods need a graph, `ncs`
    also a dSLATE model. `ncs` (an `NCSConfig`, default the paper's reading) sets how the
    learned agent reads the model: restarts, iterations, and `extra_slots` slots beyond one
    per object (the background's) when the scene holds more objects than the model's K."""
    from .baselines import RandomAgent
    from .ncs.perception import DSlatePerception, OraclePerception
    from .ncs.policy import NCSAgent

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
    if method == "random":
        return lambda env: RandomAgent(env.action_space, seed)
    if graph is None:
        raise ValueError(f"method {method!r} needs a transition graph (--graph)")
    if method == "ncs-oracle":
        return lambda env: NCSAgent(graph, OraclePerception(), env.action_space, seed)
    if model is None:
        raise ValueError("method 'ncs' needs a dSLATE checkpoint (--checkpoint)")

    from .config import NCSConfig

    ncs = ncs or NCSConfig()

    def make_ncs(env):
        slots = max(model.cfg.slots.num_slots, env.config.num_objects + ncs.extra_slots)
        perception = DSlatePerception(model, iterations=ncs.iterations, num_slots=slots,
                                      restarts=ncs.restarts)
        return NCSAgent(graph, perception, env.action_space, seed)

    return make_ncs
