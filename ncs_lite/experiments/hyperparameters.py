"""Fig. 9 of Appendix D: NCS against its hyperparameters (robogym-rearrange, 4 objects).

    table = fig9_table("reduced")          # figures/tables/fig9_reduced.csv / .json

Three axes, each varied alone around the shipped graph (Table 4's 45 nodes, the 20,000
graph episodes, one slot per object plus the floor's):

- clusters: the graph's number of nodes (k-means on the same transitions);
- data: the graph built from the first n episodes of the graph buffer;
- slots: how many slots the agent reads every scene with (`ncs.slots`), whatever the object
  count; fewer slots than objects must merge objects, more leave spare slots.

Learned NCS and the oracle (the same graph code on ground-truth positions) on the first two
axes; the oracle has one entity per object, so it has no slot axis. Every graph is a rebuild
of the shipped one (`graph_like`) and cached by its inputs and code; every evaluation is a
job of one sweep (`sweeps.run_sweep`), cached too (`evaluate_method`).
"""
from __future__ import annotations

import time
from dataclasses import asdict, replace

from ..cache import buffer_digest, cached, code_digest
from ..config import NCSConfig, to_dict
from ..data import find_buffer, load_manifest
from ..evaluation import TaskSet, evaluate_job, summarize
from ..ncs.graph import TransitionGraph, graph_from_buffer
from ..ncs.perception import graph_perception
from ..sweeps import check_executor, run_sweep
from ..utils import REPO_DIR, provenance, relative_to_repo
from .comparison import comparison_assets
from .stress import all_of, gap_claim
from .tables import table_dir, write_table

__all__ = ["AXES", "fig9_jobs", "fig9_table", "graph_like"]

ENV = "robogym-rearrange"
# the values of each axis per preset; `reduced` spans the paper's Fig. 9 (clusters 16-50,
# data up to the shipped graph's, slots from fewer than the 4 objects to double)
AXES = {
    "ci": {"clusters": (4, 8), "data": (30, 60), "slots": (3, 5, 10)},
    "reduced": {"clusters": (16, 20, 30, 40, 45, 50), "data": (2500, 5000, 10000, 20000),
                "slots": (2, 3, 4, 5, 6, 8, 10)},
    "paper": {"clusters": (16, 20, 30, 40, 45, 50), "data": (2500, 5000, 10000, 20000),
              "slots": (2, 3, 4, 5, 6, 8, 10)},
}
TASKS = {"ci": 2, "reduced": 100, "paper": 100}
OBJECTS = 4


def graph_like(graph, model=None, *, clusters: int | None = None, episodes: int | None = None):
    """The graph `graph` would be with `clusters` nodes or from its buffer's first `episodes`
    episodes: `graph_from_buffer` on the same buffer (`graph.info["data"]`, or the cache's buffer
    with its manifest hash: `data.find_buffer`), with the same reading of it (`model`'s entities
    with the slots the graph recorded, or ground truth for an oracle graph, `model` None) and the
    same settings (`graph.info["ncs"]`). Cached by the buffer, the reading, the settings and the
    code."""
    info = graph.info
    ncs = NCSConfig(**info["ncs"])
    ncs = replace(ncs, clusters=clusters or ncs.clusters)
    data = find_buffer(REPO_DIR / info["data"], info.get("manifest_sha256"))
    read_slots = info.get("read_slots")

    def build():
        return graph_from_buffer(ncs, model, data, num_slots=read_slots, episodes=episodes).state_dict()

    reading = graph_perception(ncs, model, num_slots=read_slots).describe()
    every = load_manifest(data)["episodes"]               # all of them: one graph, one key, given or not
    sd = cached("graph", build, buffer=buffer_digest(data), reading=reading, ncs=asdict(ncs),
                episodes=every if episodes is None else episodes, code=code_digest("ncs"))
    return TransitionGraph.from_state_dict(sd)


def fig9_jobs(assets: dict, preset: str = "reduced", seed: int = 0) -> tuple[list[dict], list[tuple]]:
    """Fig. 9's points ({"varied": the axis, "x": its value, "method", "edges"}) and their
    evaluation jobs (`evaluation.evaluate_method`'s arguments), one per point, in order: for each axis of AXES[preset] and each value, learned
    NCS and, on the graph axes, the oracle. `assets`: `comparison.comparison_assets(preset,
    env="robogym-rearrange")`."""
    axes, tasks = AXES[preset], TaskSet(env=ENV, num_objects=OBJECTS, episodes=TASKS[preset], seed=seed)
    model, ncs = assets["model"], assets["ncs"]
    points, jobs = [], []
    for axis, values in axes.items():
        for value in values:
            for method, graph, reader in (("ncs", assets["graph"], model), ("ncs-oracle", assets["oracle_graph"], None)):
                if axis == "slots" and reader is None:           # the oracle reads one entity per object
                    continue
                acting = ncs
                if axis == "clusters":
                    graph = graph_like(graph, reader, clusters=value)
                elif axis == "data":
                    graph = graph_like(graph, reader, episodes=value)
                else:
                    acting = replace(ncs, slots=value)
                acting = replace(acting, clusters=graph.num_nodes)
                points.append({"varied": axis, "x": value, "method": method, "edges": graph.num_edges})
                jobs.append((method, tasks, {"graph": graph, "model": model if reader is not None else None,
                                             "ncs": acting, "seed": seed, "label": method}))
    return points, jobs


def fig9_claims(rows: list[dict], num_objects: int = OBJECTS) -> list[dict]:
    """Appendix D.1's statements, each checked on learned NCS's points of `rows` by the gap
    between two points and its 95% interval (`stress.gap_claim`)."""
    def point(axis, value):
        r = next(r for r in rows if r["varied"] == axis and r["x"] == value and r["method"] == "ncs")
        return {"label": f"ncs, {value} {axis}", "successes": r["successes"], "episodes": r["episodes"]}

    def values(axis):
        return sorted({r["x"] for r in rows if r["varied"] == axis and r["method"] == "ncs"})

    def missing(statement, why):
        return {"statement": statement, "ours": "", "verdict": "not testable", "reason": why}

    claims = []
    clusters = values("clusters")
    best = max(clusters, key=lambda c: point("clusters", c)["successes"])
    statement = "too few and too many clusters both lower success (it peaks inside the range)"
    if best in (clusters[0], clusters[-1]):
        claims.append({"statement": statement, "ours": f"the best of {clusters} is {best} clusters, at an end",
                       "verdict": "not held", "reason": "success peaks at an end of the range"})
    else:
        claims.append(all_of(statement, [gap_claim(f"{best} above {c} clusters", point("clusters", best),
                                                   point("clusters", c), "greater") for c in (clusters[0], clusters[-1])]))
    data = values("data")
    claims.append(gap_claim("more buffer data for the graph raises success", point("data", data[-1]),
                            point("data", data[0]), "greater"))
    slots = values("slots")
    needed = num_objects + 1                                         # one per object and the floor's
    few = [s for s in slots if s < num_objects]
    statement = "too few slots to represent every object lower success"
    claims.append(gap_claim(statement, point("slots", needed), point("slots", few[-1]), "greater")
                  if needed in slots and few else missing(statement, f"the slot axis {slots} lacks {needed} or a "
                                                                     f"count below {num_objects}"))
    statement = "double the necessary slots barely changes success"
    claims.append(gap_claim(statement, point("slots", 2 * needed), point("slots", needed), "similar")
                  if {needed, 2 * needed} <= set(slots) else missing(statement, f"the slot axis {slots} lacks "
                                                                                 f"{needed} or {2 * needed}"))
    return claims


def fig9_table(preset: str = "reduced", executor: str = "local", folder=None, seed: int = 0, out_dir=None,
               allow_dirty: bool = False, overrides=()) -> dict:
    """figures/tables/fig9_<preset>.csv / .json: one row per axis (`varied`), value (`x`) and method (success
    and its 95% Wilson interval, the mean share of constraints satisfied when the harness
    reports it, random-fallback share, the graph's edges), and Appendix D.1's claims checked
    on them (`fig9_claims`). The points run as one sweep (`sweeps.run_sweep` on `executor`);
    `ncs.*` `overrides` set how NCS builds its graphs and acts (`comparison_assets`)."""
    check_executor(executor)
    if preset not in AXES:
        raise ValueError(f"unknown preset {preset!r}; expected one of {', '.join(AXES)}")
    name = f"fig9_{preset}"
    provenance(table_dir(out_dir) / f"{name}.json", allow_dirty)      # a dirty tree is refused first
    start = time.perf_counter()
    assets = comparison_assets(preset, env=ENV, overrides=overrides)
    points, jobs = fig9_jobs(assets, preset, seed)
    summaries = [summarize(rows)[0] for rows in run_sweep(evaluate_job, jobs, executor=executor, folder=folder,
                                                          desc="fig9")]
    rows = []
    for point, s in zip(points, summaries):
        row = {**point, "episodes": s["episodes"], "successes": round(s["success"] * s["episodes"]),
               "success": round(s["success"], 4), "ci_low": round(s["ci_low"], 4), "ci_high": round(s["ci_high"], 4)}
        for extra in ("constraints", "constraints_ci_low", "constraints_ci_high", "random_fraction", "noop_fraction"):
            if extra in s:
                row[extra] = round(s[extra], 4)
        rows.append(row)
    meta = {"env": ENV, "preset": preset, "num_objects": OBJECTS, "goal": "complete", "horizon_multiplier": 4.0,
            "tasks_per_point": TASKS[preset], "axes": {a: list(v) for a, v in AXES[preset].items()},
            "ncs": to_dict(assets["ncs"]), "executor": executor, "claims": fig9_claims(rows),
            "assets": {k: relative_to_repo(v) for k, v in assets["paths"].items()},
            "minutes": round((time.perf_counter() - start) / 60, 1),
            **({"ncs_overrides": list(overrides)} if overrides else {})}
    write_table(name, rows, meta, out_dir, allow_dirty)
    return {"rows": rows, "claims": meta["claims"], "minutes": meta["minutes"]}
