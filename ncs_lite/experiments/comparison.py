"""The main comparison (Appendix B): every method on the same seeded tasks.

    assets = comparison_assets("reduced")          # the shipped files (others: built, cached)
    rows = run_comparison(assets, counts=(4, 5, 6, 7), goals=("complete", "partial"),
                          episodes=100, mpc_episodes=20)
    summarize(rows)                                 # success, constraints, 95% intervals, random share

`python -m ncs_lite reproduce baselines` writes its summary to figures/tables/; notebook 07
draws it. Every method reads the same dSLATE checkpoint where it reads one (NCS, NF, MPC),
and the graph methods bind with the same entity nodes: NF's scenes are sets of nodes of
NCS's graph, so NF and NCS differ in the factorization only.
"""
from __future__ import annotations

from dataclasses import replace

from ..baselines import SetGraph, mpc_config, set_graph_from_transitions
from ..baselines.runs import load_trained_policy, obtain_policy
from ..config import (CLUSTERS_BY_ENV, EDGE_ACTION_BY_ENV, GRAPH_EPISODES_BY_ENV, STATE_BY_ENV, ncs_config,
                     parse_override)
from ..data import cached_buffer
from ..evaluation import TaskSet, evaluate_methods
from ..inference import load_dslate, shipped_asset
from ..ncs.graph import BUILD_FIELDS, TransitionGraph, buffer_perception, graph_from_buffer
from ..ncs.perception import buffer_transitions
from ..training import obtain_dslate

__all__ = ["COMPARED", "PAPER_NCS", "comparison_assets", "run_comparison"]

# NCS as the paper specifies it: one slot-attention pass per image from slots drawn from the
# learned Gaussian, one slot per object and the background's, Hungarian alignment with every
# matched pair a constraint, the edge's most common action (the shipped graph keeps its edge
# labels, so "most_common" acts on it too). The kit's extensions it leaves out: restarts, the
# first start seeded on the scene and the spare slot (block-rearrange's reading, config.py's
# NCS_ENV_DEFAULTS), the "near" pairs, actions read from the transitions' states
# (ncs/graph.py's docstring), the dependency rules of block-stacking (ncs/dependencies.py).
PAPER_NCS = {"restarts": 1, "slot_init": "random", "extra_slots": 1, "align": "hungarian",
             "edge_action": "most_common", "dependencies": False}
# label: (method, the assets it reads, overrides of the assets' NCSConfig); the legend's order
COMPARED = {
    "ncs": ("ncs", ("graph", "model"), {}),
    "ncs-paper": ("ncs", ("graph", "model"), PAPER_NCS),
    "ncs-oracle": ("ncs-oracle", ("oracle_graph",), {}),
    "nf": ("nf", ("nf_graph", "model"), {}),
    "nf-oracle": ("nf-oracle", ("nf_oracle_graph",), {}),
    "mpc": ("mpc", ("model",), {}),
    "bc": ("bc", ("bc",), {}),
    "iql": ("iql", ("iql",), {}),
    "random": ("random", (), {}),
}
# tasks per goal kind and object count; MPC plans with 2,500 dynamics rollouts a step, so
# `reduced` runs it on the first 25 tasks of each set: the whole comparison took 4.2 minutes
# uncached (cf06f0a, two worker processes of one thread; robogym-rearrange 6.1), under its
# 20-minute budget; with 10, MPC's 2 successes at 4 objects had the interval [0.06, 0.51],
# too wide to tell it from NCS
EPISODES = {"ci": 2, "reduced": 50, "paper": 100}
MPC_EPISODES = {"ci": 1, "reduced": 25, "paper": 100}
# the buffer the graphs are built on (notebooks 05-06 and `reproduce` too): the training buffer
# at `reduced`. As in the paper's Fig. 9, more data makes a better graph: the shipped model's
# mask graph from the first 1,000 of its 5,000 episodes solved 0.92 / 0.82 of the 4 / 7-object
# tasks (23 % / 36 % random fallbacks), from all 5,000 0.98 / 0.98 (6 % / 3 %)
GRAPH_EPISODES = {"ci": 60, "reduced": 5000, "paper": 5000}


def graph_episodes_of(preset: str, env: str) -> int:
    """How many episodes of the 4-object buffer (seed 0) the graphs of `env` read at `preset`."""
    if preset == "ci":
        return GRAPH_EPISODES["ci"]
    return GRAPH_EPISODES_BY_ENV.get(env, GRAPH_EPISODES[preset])
CI_CLUSTERS = 8                                                 # ci's tiny buffer; else Table 4's


def comparison_assets(preset: str = "reduced", seed: int = 0, env: str = "block-rearrange", overrides=()) -> dict:
    """What every method runs from on `env`, and where each came from (`paths`); `ncs`, the
    NCS settings the graph agents read (Table 3's state of `env`, its graph's nodes and edge
    actions, then the `ncs.*` `overrides`).

    `reduced`: the shipped assets (`inference.shipped_asset`, built by `make baseline-assets`
    and `make robogym-baseline-assets`), so an override of how a graph is built
    (`ncs.graph.BUILD_FIELDS`) is refused. Other presets: the dSLATE of `obtain_dslate`, the
    policies of `obtain_policy`, and the graphs built here from the cached graph buffer
    (`graph_from_buffer`, with `ncs`; k-means seeded by `seed`)."""
    if env not in STATE_BY_ENV:
        raise ValueError(f"env must be one of {sorted(STATE_BY_ENV)}, got {env!r}")
    ncs = ncs_config(overrides, state=STATE_BY_ENV[env], clusters=CI_CLUSTERS if preset == "ci" else CLUSTERS_BY_ENV[env],
                     edge_action=EDGE_ACTION_BY_ENV[env], seed=seed)
    if preset == "reduced":
        built = [o for o in overrides if parse_override(o)[0] in BUILD_FIELDS]
        if built:
            raise ValueError(f"--set {built[0]}: at preset 'reduced' the graphs are the shipped ones (their nodes, "
                             f"k-means seed and buffer pass are fixed); set {', '.join(BUILD_FIELDS)} at another "
                             "preset, which builds its graphs")
        state = ncs.state
        paths = {"model": shipped_asset(env, "ncs", "model"), "graph": shipped_asset(env, "ncs", "graph", state),
                 "oracle_graph": shipped_asset(env, "ncs-oracle", "graph", state),
                 "nf_graph": shipped_asset(env, "nf", "graph", state),
                 "nf_oracle_graph": shipped_asset(env, "nf-oracle", "graph", state),
                 "bc": shipped_asset(env, "bc", "policy"), "iql": shipped_asset(env, "iql", "policy")}
        graph = TransitionGraph.load(paths["graph"])
        return {"model": load_dslate(paths["model"]), "graph": graph,
                "oracle_graph": TransitionGraph.load(paths["oracle_graph"]),
                "nf_graph": SetGraph.load(paths["nf_graph"]), "nf_oracle_graph": SetGraph.load(paths["nf_oracle_graph"]),
                "bc": load_trained_policy(paths["bc"], "bc"), "iql": load_trained_policy(paths["iql"], "iql"),
                "paths": {k: str(v) for k, v in paths.items()}, "preset": preset, "env": env,
                "ncs": replace(ncs, clusters=graph.num_nodes)}
    model, model_path = obtain_dslate(preset, seed=seed, env=env)
    data = cached_buffer(graph_episodes_of(preset, env), env=env, seed=seed)
    out = {"model": model, "paths": {"model": str(model_path), "graph_buffer": str(data)}, "preset": preset,
           "env": env, "ncs": ncs}
    # the 4-object buffer read with the slots the agents read 4 objects with (`buffer_perception`)
    for name, reader in (("", model), ("oracle_", None)):
        out[f"{name}graph"] = graph = graph_from_buffer(ncs, reader, data)
        transitions = buffer_transitions(buffer_perception(ncs, reader, data), data)   # cached
        out[f"nf_{name}graph"] = set_graph_from_transitions(transitions[:3], graph, state=ncs.state)
        out[f"nf_{name}graph"].info["env"] = env
    for method in ("bc", "iql"):
        out[method], path = obtain_policy(method, preset, seed, env=env)
        out["paths"][method] = str(path)
    return out


def run_comparison(assets: dict, counts=(4, 5, 6, 7), goals=("complete", "partial"), episodes: int = 100,
                   mpc_episodes: int | None = None, horizon_multiplier: float = 4.0, seed: int = 0,
                   methods=tuple(COMPARED), cache: bool = True, workers: int | None = None) -> list[dict]:
    """Per-episode rows (`evaluation.COLUMNS`) of every method in `methods` on the same task
    sets: for each goal kind and object count, `episodes` seeded tasks (MPC: the first
    `mpc_episodes` of them, default all; its planning costs the most). Cached per method and
    task set (`evaluate_method`). The cells run side by side in `workers` processes
    (`evaluate_methods`: the rows of a serial run, bit for bit), the costliest (MPC, most
    objects) first."""
    unknown = sorted(set(methods) - set(COMPARED))
    if unknown:
        raise ValueError(f"unknown methods {unknown}; expected some of {', '.join(COMPARED)}")
    mpc = mpc_config(assets.get("preset", "reduced"))     # ci: a small CEM; reduced, paper: Appendix B's
    jobs = []
    for goal in goals:
        for k in counts:
            for label in methods:
                method, needs, ncs_overrides = COMPARED[label]
                ncs = assets.get("ncs")
                n = (mpc_episodes or episodes) if method == "mpc" else episodes
                tasks = TaskSet(env=assets.get("env", "block-rearrange"), num_objects=k, goal=goal,
                                horizon_multiplier=horizon_multiplier, episodes=n, seed=seed)
                kw = {"graph": next((assets[a] for a in needs if a.endswith("graph")), None), "ncs": replace(ncs, **ncs_overrides).validate() if ncs_overrides else ncs,
                      "model": assets["model"] if "model" in needs else None,
                      "policy": assets[method] if method in ("bc", "iql") else None,
                      "mpc": mpc if method == "mpc" else None, "seed": seed, "label": label, "cache": cache}
                jobs.append((method, tasks, kw))
    costliest = sorted(range(len(jobs)), key=lambda i: (jobs[i][0] != "mpc", -jobs[i][1].num_objects, i))
    cells = evaluate_methods(jobs, workers=workers, first=costliest, desc="comparison")
    return [row for rows in cells for row in rows]
