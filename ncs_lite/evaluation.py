"""The evaluation harness shared by every method (NCS, the oracle, every baseline).

A task set is fixed by (env, num_objects, goal, horizon multiplier, action noise, seed,
episodes): task i is `env.reset(seed=task_seed(seed, i))`, so every method faces the same
tasks, and the agent is reset with that seed too (`agent.reset(obs, info, seed=...)`: it draws
from a seed of the task's and its own, `utils.task_seed_of`), so a task's row does not depend
on the tasks run before it. Each episode gives one tidy row; `summarize` turns rows into two success measures,
each with a 95% interval: `success`, the share of tasks whose every constraint holds at the
end, and `constraints`, the mean share of a task's constraints that hold at the end (the
per-constraint measure the paper's Random numbers are; docs/environments.md), with mean steps
and the fraction of random fallback actions.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from .baselines import (BCAgent, BCPolicy, IQLAgent, IQLNetworks, MPCAgent, MPCConfig, NFAgent, RandomAgent,
                        RandomObjectAgent, SetGraph)
from .cache import cached, code_digest, digest
from .config import NCSConfig
from .envs import env_name, make
from .envs.common import outside_action_space
from .metrics import in_floor_slot, shared_with_another, slot_assignment
from .ncs.graph import TransitionGraph
from .ncs.perception import (ORACLE_STATES, STATE_GRID, DSlatePerception, OraclePerception, acting_masks,
                             acting_restarts, acting_slot_init, acting_slot_position, built_slot_position,
                             scene_slots)
from .ncs.policy import NCSAgent
from .sweeps import run_sweep
from .utils import atomic_write_text, check_file_env, progress, recorded_env

# what a step did (`step_outcome`), counted per episode
STEP_OUTCOMES = ("placed", "picked_nothing", "refused", "moved_done", "off_goal")
COLUMNS = ("method", "env", "num_objects", "goal", "num_constrained", "horizon_multiplier",
           "action_noise", "seed", "episode", "task_seed", "success", "satisfied_fraction", "steps",
           "min_steps", "horizon", "random_actions", "noop_actions", *STEP_OUTCOMES)
PER_EPISODE = ("episode", "task_seed", "success", "satisfied_fraction", "steps", "min_steps", "horizon",
               "random_actions", "noop_actions", *STEP_OUTCOMES)


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
        # 4 and 4.0 are one task set: one cache key and one CSV value
        for name in ("horizon_multiplier", "action_noise"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{name} must be a number, got {value!r}")
            object.__setattr__(self, name, float(value))
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
    return _wilson(successes / n, n, z)


def _wilson(p: float, n: int, z: float) -> tuple[float, float]:
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # exact ends at p = 0 and p = 1 (the formula gives them up to rounding)
    return (0.0 if p == 0 else max(0.0, centre - half)), (1.0 if p == 1 else min(1.0, centre + half))


def mean_interval(values, z: float = 1.96) -> tuple[float, float]:
    """95% interval for the mean of n values in [0, 1] (e.g. each task's share of satisfied
    constraints): the Wilson score interval with p = their mean and n = how many there are.

    Why this one: a value in [0, 1] with mean m has variance at most m (1 - m), the variance
    the Wilson interval assumes, so the interval is sound for any such values and
    conservative (wider than needed) when they are fractions; it equals `wilson_interval`
    when every value is 0 or 1 (one constraint per task), and it keeps a width at a mean of
    0 or 1 (all 0: [0, z^2 / (n + z^2)]), where a t interval or a bootstrap collapses to a
    point. Closed form, so deterministic."""
    v = np.asarray(values, np.float64).reshape(-1)
    if len(v) == 0:
        raise ValueError("values must hold at least one value, got none")
    if not np.all((v >= 0) & (v <= 1)):
        bad = float(v[~((v >= 0) & (v <= 1))][0])
        raise ValueError(f"values must lie in [0, 1], got {bad}")
    return _wilson(float(v.mean()), len(v), z)


def step_outcome(before: dict, after: dict) -> str:
    """What one step did, from the env's `info` before and after it (STEP_OUTCOMES):
    "picked_nothing" (no object within the pick threshold), "refused" (an object was picked
    but its place was refused: occupied, overlapping or off the table), "moved_done" (it moved
    an object already at its goal), "placed" (it put a constrained object at its goal),
    "off_goal" (it moved an object elsewhere)."""
    moved = after["moved"]
    if moved < 0:
        return "picked_nothing" if after["picked"] < 0 else "refused"
    if before["constrained"][moved] and before["satisfied"][moved]:
        return "moved_done"
    if after["constrained"][moved] and after["satisfied"][moved]:
        return "placed"
    return "off_goal"


def satisfied_fraction(info: dict) -> float:
    """The share of the constrained objects that are at their goal, from an env's `info`
    (`constrained` and `satisfied`, (k,) bool each): 1.0 exactly when the task is solved."""
    constrained = np.asarray(info["constrained"], bool)
    satisfied = np.asarray(info["satisfied"], bool)
    if constrained.shape != satisfied.shape or not constrained.any():
        raise ValueError(f"info must constrain at least one object, with `satisfied` of the same shape; got "
                         f"constrained {constrained.tolist()}, satisfied {satisfied.tolist()}")
    return float((satisfied & constrained).sum() / constrained.sum())


def run_episode(agent, env, seed: int, on_step=None) -> dict:
    """One task: the episode's row (success, the share of constraints satisfied at its end
    `satisfied_fraction`, steps, random fallbacks, no-ops and the count of each step
    outcome). `on_step(agent, before, action, after, outcome)`, if given, sees every step
    (`step_trace`)."""
    obs, info = env.reset(seed=seed)
    agent.reset(obs, info, seed=seed)          # the agent reseeds too: each task's row is its own
    steps = randoms = 0
    outcomes = dict.fromkeys(STEP_OUTCOMES, 0)
    terminated = truncated = False
    while not (terminated or truncated):
        action, was_random = agent.act(obs, info)
        before = info
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        randoms += bool(was_random)
        outcome = step_outcome(before, info)
        outcomes[outcome] += 1
        if on_step is not None:
            on_step(agent, before, action, info, outcome)
    return {"success": int(terminated), "satisfied_fraction": satisfied_fraction(info), "steps": steps,
            "min_steps": info["min_steps"], "horizon": info["horizon"], "random_actions": randoms,
            "noop_actions": outcomes["picked_nothing"] + outcomes["refused"], **outcomes,
            **getattr(agent, "episode_counts", dict)()}


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


def step_trace(make_agent, tasks: TaskSet) -> list[dict]:
    """Every step of an NCS agent (`ncs`, `ncs-oracle`) on `tasks`, one row each: its outcome
    (`step_outcome`) and, for a step along an edge, which object the selected entity holds
    (the object under most of its mask, `held` its share of the mask; `area` the mask's share
    of the image), how far the action's
    pick lands from that object (`pick_error`, m) and, on a graph that keeps its transitions,
    how far the pick point read from the entity's state is from it (`read_error`, m: the
    graph's `readout`): a miss by a slot that holds no object, or by a state that places its
    object wrongly, or by an action that does not follow its state."""
    env = tasks.make_env()
    agent = make_agent(env)
    rows = []

    def record(agent, before, action, after, outcome):
        last = agent.last
        row = {"episode": episode, "step": after["steps"], "outcome": outcome,
               "fallback": last.get("fallback"), "object": -1, "held": float("nan"),
               "pick_error": float("nan"), "read_error": float("nan"), "object_done": False,
               "area": float("nan")}
        if last.get("selected") is not None and last["current"].masks is not None:
            entity = int(last["current_index"][last["selected"]])
            mask = np.asarray(last["current"].masks[entity], np.float64)          # (H, W)
            truth = np.asarray(before["masks"], np.float64)                       # (k, H, W)
            mass = (truth * mask).sum((1, 2))
            obj = int(mass.argmax())
            where = np.asarray(before["positions"])[obj, :2]
            row.update(object=obj, held=float(mass[obj] / max(mask.sum(), 1e-12)), area=float(mask.mean()),
                       pick_error=float(np.linalg.norm(np.asarray(action)[:2] - where)),
                       object_done=bool(before["constrained"][obj] and before["satisfied"][obj]))
            graph = agent.graph
            if graph.examples is not None:
                state = last["current"].states[entity].reshape(1, -1)
                read = graph.read_points(state, state)[0].numpy()[0]
                row["read_error"] = float(np.linalg.norm(read - where))
        rows.append(row)

    try:
        for episode in progress(range(tasks.episodes), desc=f"trace k={tasks.num_objects}", leave=False):
            run_episode(agent, env, task_seed(tasks.seed, episode), on_step=record)
    finally:
        env.close()
    return rows


def trace_summary(rows: list[dict]) -> dict:
    """A step trace in numbers: the share of each outcome, and over the steps whose pick
    found nothing, the share whose entity held an object (held >= 0.5), the median pick and
    read errors (m) and the share of reads within 5 cm."""
    n = max(1, len(rows))
    out = {f"{o}_fraction": sum(r["outcome"] == o for r in rows) / n for o in STEP_OUTCOMES}
    missed = [r for r in rows if r["outcome"] == "picked_nothing" and r["object"] >= 0]
    held = [r for r in missed if r["held"] >= 0.5]
    reads = np.array([r["read_error"] for r in rows if np.isfinite(r["read_error"])])
    out.update(steps=len(rows), missed_picks=len(missed),
               missed_held_object=len(held) / max(1, len(missed)),
               missed_pick_error_median=float(np.median([r["pick_error"] for r in missed])) if missed else float("nan"),
               missed_read_error_median=float(np.nanmedian([r["read_error"] for r in missed])) if missed else float("nan"),
               read_error_median=float(np.median(reads)) if len(reads) else float("nan"),
               read_within_5cm=float((reads <= 0.05).mean()) if len(reads) else float("nan"))
    return out


def summarize(rows: list[dict]) -> list[dict]:
    """Rows grouped by everything but the episode -> the two success measures, mean steps, and
    the shares of actions that were random fallbacks and that changed nothing (no-ops):

      success, ci_low, ci_high: the share of tasks solved (all constraints satisfied at the
        end) and its 95% Wilson interval (`wilson_interval`);
      constraints, constraints_ci_low, constraints_ci_high: the mean over tasks of the share
        of constraints satisfied at the end (`satisfied_fraction`) and its 95% interval
        (`mean_interval`: the Wilson interval at the mean, conservative for fractions)."""
    keys = [c for c in COLUMNS if c not in PER_EPISODE]
    missing = [r.get("episode") for r in rows if "satisfied_fraction" not in r]
    if missing:
        raise ValueError(f"{len(missing)} rows (episodes {missing[:5]}) lack `satisfied_fraction`: rows made "
                         "before it was measured; evaluate again")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    for key, rs in groups.items():
        n, s = len(rs), sum(r["success"] for r in rs)
        lo, hi = wilson_interval(s, n)
        fractions = [r["satisfied_fraction"] for r in rs]
        c_lo, c_hi = mean_interval(fractions)
        steps = sum(r["steps"] for r in rs)
        out.append({**dict(zip(keys, key)), "episodes": n, "success": s / n, "ci_low": lo,
                    "ci_high": hi, "constraints": float(np.mean(fractions)), "constraints_ci_low": c_lo,
                    "constraints_ci_high": c_hi, "mean_steps": steps / n,
                    "random_fraction": sum(r["random_actions"] for r in rs) / max(1, steps),
                    "noop_fraction": sum(r["noop_actions"] for r in rs) / max(1, steps),
                    **{f"{o}_fraction": sum(r.get(o, 0) for r in rs) / max(1, steps) for o in STEP_OUTCOMES}})
    return out


def write_csv(rows: list[dict], path: str | Path) -> Path:
    """Tidy CSV, one row per episode (atomic write). The columns are every row's, in the order
    they first appear: an agent with the dependency rules adds its `rule_*` counts
    (`NCSAgent.episode_counts`), left empty in the rows of the other methods."""
    buf = io.StringIO()
    fields = list(dict.fromkeys(key for row in rows for key in row)) if rows else list(COLUMNS)
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(path, buf.getvalue())
    return Path(path)


METHODS = ("ncs", "ncs-oracle", "nf", "nf-oracle", "mpc", "bc", "iql", "random", "random-object")
# what each method needs besides the task: a transition graph (NCS's, or NF's scene graph),
# a dSLATE model, a trained policy (BC, IQL); `random-object` is a calibration row that reads
# the objects' true positions from `info`, like the oracles
NEEDS = {"ncs": ("graph", "model"), "ncs-oracle": ("graph",), "nf": ("graph", "model"),
         "nf-oracle": ("graph",), "mpc": ("model",), "bc": ("policy",), "iql": ("policy",),
         "random": (), "random-object": ()}
NEED_NAMES = {"graph": "transition graph (--graph)", "model": "dSLATE checkpoint (--checkpoint)",
              "policy": "trained policy (--policy)"}


def learned_perception(model, num_objects: int, ncs=None):
    """The perception the learned agents (`ncs`, `nf`, `mpc`) read a scene of `num_objects`
    objects with: `scene_slots` slots (one per object plus `acting_extra_slots`, the
    background's and any spare, at least the model's K; or exactly `ncs.slots`), and the
    restarts (`acting_restarts`), iterations, first start (`acting_slot_init`), kind of state,
    slot position and masks of `ncs` (an `NCSConfig`, default the env's reading)."""
    ncs = ncs or NCSConfig()
    return DSlatePerception(model, iterations=ncs.iterations, num_slots=scene_slots(model, num_objects, ncs),
                            restarts=acting_restarts(ncs, model), state=ncs.state,
                            slot_position=acting_slot_position(ncs, model), masks=acting_masks(ncs, model),
                            slot_init=acting_slot_init(ncs, model))


def state_features(method: str, state: str, model=None) -> int | None:
    """How many numbers a state has that the graph agent `method` reads: a pooled mask
    (STATE_GRID^2) or, for slot states, the oracle's position (3) or the model's state half
    (its state_dim); None when that is not known (no model)."""
    if state == "mask":
        return STATE_GRID ** 2
    if method.endswith("oracle"):
        return 3
    return getattr(model, "state_dim", None)      # None: no model, or a stand-in that does not say


def check_graph_reading(graph, method: str, ncs, model=None) -> None:
    """ValueError unless the agent `method` with `ncs` reads states as `graph` was built on:
    the same kind and size of state (`TransitionGraph.check_state`) and, for a model's slot
    states, the same `slot_position` (`built_slot_position`), and for a model's slots the same
    masks (`acting_masks`; a graph that does not say is not checked)."""
    graph.check_state(ncs.state, state_features(method, ncs.state, model))
    learned = not method.endswith("oracle") and model is not None
    if learned and "masks" in graph.info:
        acting = acting_masks(ncs, model)
        if acting != graph.info["masks"]:
            raise ValueError(f"the graph was built on slots read with {graph.info['masks']!r} masks; "
                             f"the agent would act with {acting!r} (set ncs.masks={graph.info['masks']})")
    built = built_slot_position(graph.info)
    if learned and ncs.state == "slot" and built:
        acting = acting_slot_position(ncs, model)
        if acting != built:
            raise ValueError(f"the graph was built on slot states read with slot_position {built!r}; "
                             f"the agent would act with {acting!r} (set ncs.slot_position={built})")


def check_graph_actions(graph, action_space) -> None:
    """ValueError unless every edge action of `graph` (NCS's or NF's) lies in `action_space`:
    a graph of another env, or a spoilt file without a digest, would be refused mid-episode."""
    actions = np.asarray([a for labels in graph.edges.values() for a in labels], np.float32).reshape(-1, 6)
    outside = outside_action_space(actions, action_space)
    if outside.any():
        bad = [round(float(v), 4) for v in actions[outside][0]]
        raise ValueError(f"{int(outside.sum())} of its {len(actions)} edge actions lie outside the env's "
                         f"action space (low {action_space.low.tolist()}, high {action_space.high.tolist()}), "
                         f"e.g. {bad}: a graph of another env, or a spoilt file")


def agent_factory(method: str, graph=None, model=None, seed: int = 0, ncs=None, policy=None, mpc=None):
    """A function env -> agent for `method` (see METHODS and what each NEEDS).

    graph: NCS's `TransitionGraph` (ncs, ncs-oracle) or NF's `SetGraph` (nf, nf-oracle);
    model: a dSLATE (ncs, nf, mpc); policy: a trained BC or IQL model; mpc: an `MPCConfig`.
    `ncs` (an `NCSConfig`, default the paper's reading) sets how the learned agents read the
    model: restarts, iterations, and `extra_slots` slots beyond one per object (the
    background's) when the scene holds more objects than the model's K
    (`learned_perception`). `ncs.state` is the kind of state the graph agents read (the
    oracle's stand-in: `ORACLE_STATES`); it must be the one the graph was built on. MPC
    always reads slot states as the model's s (`slot_position` "attention": it rolls whole
    slots through the dynamics, which learned on them)."""
    make = _make_agent(method, graph, model, seed, ncs, policy, mpc)
    made_on = {"graph": recorded_env(graph.info) if graph is not None else None,
               "dSLATE checkpoint": (getattr(model, "checkpoint_info", None) or {}).get("env"),
               "policy": (getattr(policy, "info", None) or {}).get("env")}

    def factory(env):
        for what, made in made_on.items():       # a file made on one env is refused on another
            check_file_env(f"{method}'s", what, made, env_name(env))
        return make(env)
    return factory


def _make_agent(method: str, graph, model, seed: int, ncs, policy, mpc):
    """`agent_factory`'s function env -> agent, its inputs checked."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    given = {"graph": graph, "model": model, "policy": policy}
    for need in NEEDS[method]:
        if given[need] is None:
            raise ValueError(f"method {method!r} needs a {NEED_NAMES[need]}")
    ncs = ncs or NCSConfig()
    if method == "random":
        return lambda env: RandomAgent(env.action_space, seed)
    if method == "random-object":
        return lambda env: RandomObjectAgent(env, seed)
    if method in ("bc", "iql"):
        agent, kind = (BCAgent, BCPolicy) if method == "bc" else (IQLAgent, IQLNetworks)
        if not isinstance(policy, kind):
            raise ValueError(f"method {method!r} needs a {method.upper()} policy ({kind.__name__}), "
                             f"got a {type(policy).__name__}")
        return lambda env: agent(policy)
    if method == "mpc":
        return lambda env: MPCAgent(model, learned_perception(model, env.config.num_objects,
                                                              replace(ncs, state="slot", slot_position="attention")),
                                    env.action_space, mpc, seed, align=ncs.align)
    agent, kind, command = ((NCSAgent, TransitionGraph, "graph") if method.startswith("ncs") else
                            (NFAgent, SetGraph, "graph-nf"))
    if not isinstance(graph, kind):
        raise ValueError(f"method {method!r} needs a {kind.__name__} (python -m ncs_lite {command}), "
                         f"got a {type(graph).__name__}")
    check_graph_reading(graph, method, ncs, model)
    extra = ({"align": ncs.align, "nearest_variance": ncs.nearest_variance, "edge_action": ncs.edge_action,
              "dependencies": ncs.dependencies} if agent is NCSAgent else {})
    if method.endswith("oracle"):
        return lambda env: agent(graph, OraclePerception(ORACLE_STATES[ncs.state]), env.action_space, seed, **extra)
    return lambda env: agent(graph, learned_perception(model, env.config.num_objects, ncs), env.action_space, seed,
                             **extra)


# The code an evaluation's rows depend on (a cache key): the envs, the model, the agents and
# this harness. Any edit there recomputes the cached rows.
EVALUATION_CODE = ("envs", "models", "ncs", "baselines", "evaluation.py", "config.py")


def evaluate_method(method: str, tasks: TaskSet, *, graph=None, model=None, seed: int = 0, ncs=None,
                    policy=None, mpc=None, label: str | None = None, cache: bool = True) -> list[dict]:
    """`evaluate(agent_factory(method, graph, model, seed, ncs, policy, mpc), tasks, label or method)`.

    With `cache` the rows are loaded from the kit's cache (`ncs_lite.cache`) when an earlier
    run stored them under the same method, task set, seed, settings, graph, model and policy
    (their digests) and code (EVALUATION_CODE); otherwise they are computed and stored.
    """
    make = agent_factory(method, graph=graph, model=model, seed=seed, ncs=ncs, policy=policy, mpc=mpc)
    name = label or method
    if not cache:
        return evaluate(make, tasks, name)
    ncs = ncs or NCSConfig()
    needs = NEEDS[method]
    key = {"method": method, "label": name, "tasks": asdict(tasks), "seed": seed,
           "ncs": asdict(ncs) if "model" in needs else None,           # holds ncs.state
           "state": ncs.state if "graph" in needs else None,
           "mpc": asdict(mpc or MPCConfig()) if method == "mpc" else None,
           "graph": digest(graph) if "graph" in needs else None,
           "model": digest(model) if "model" in needs else None,
           "policy": digest(policy) if "policy" in needs else None,
           "code": code_digest(*EVALUATION_CODE)}
    return cached("evaluation", lambda: evaluate(make, tasks, name), **key)


def evaluate_job(method: str, tasks: TaskSet, kwargs: dict) -> list[dict]:
    """One job of a sweep of evaluations: `evaluate_method(method, tasks, **kwargs)` (cached
    by its inputs)."""
    return evaluate_method(method, tasks, **kwargs)


def evaluate_methods(jobs, workers: int | None = None, first=None, desc: str = "evaluate") -> list[list[dict]]:
    """[evaluate_method(method, tasks, **kwargs) for method, tasks, kwargs in jobs], the jobs
    run side by side in `workers` processes (`sweeps.run_sweep` on this machine: task sets are
    seeded, so the rows are a serial run's, bit for bit); `first`: the order to start them
    (costliest first)."""
    return run_sweep(evaluate_job, jobs, workers=workers, first=first, desc=desc)


def segmentation_failures(model, tasks: TaskSet, ncs=None, cache: bool = True) -> dict[str, np.ndarray]:
    """Which objects the `ncs` agent's perception fails to give a slot of their own, in the
    start and goal image of every task of `tasks` (E tasks, k objects):

      absorbed (E, 2, k) bool: the object is in the floor's slot (`metrics.slot_assignment`)
      shared   (E, 2, k) bool: it shares its slot with another object
    (image 0 = start, 1 = goal). The masks are the ones the agent acts on at reset and at
    its first step: the same perception (`learned_perception`), seeded, so the same
    restart. Ground truth is read here to *measure* only. Cached like `evaluate_method`.
    """
    perception = learned_perception(model, tasks.num_objects, ncs)

    def compute():
        env = tasks.make_env()
        absorbed, shared = [], []
        try:
            for i in progress(range(tasks.episodes), desc=f"segmentation k={tasks.num_objects}", leave=False):
                obs, info = env.reset(seed=task_seed(tasks.seed, i))
                masks = np.stack([perception.current(obs).masks.numpy(), perception.goal(obs).masks.numpy()])
                owner, background = slot_assignment(masks, np.stack([info["masks"], info["goal_masks"]]))
                absorbed.append(in_floor_slot(owner, background))                            # (2, k)
                shared.append(shared_with_another(owner, background))
        finally:
            env.close()
        return {"absorbed": np.stack(absorbed), "shared": np.stack(shared)}

    if not cache:
        return compute()
    return cached("segmentation", compute, tasks=asdict(tasks), model=digest(model),
                  ncs=asdict(ncs or NCSConfig()), code=code_digest(*EVALUATION_CODE, "metrics.py"))
