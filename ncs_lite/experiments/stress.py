"""Appendix D.2-D.3 (Figs. 10 and 11): success against the interaction horizon and action noise.

    python -m ncs_lite reproduce fig10 [--preset reduced] [--executor local|submitit]
    python -m ncs_lite reproduce fig11 [--preset reduced] [--executor local|submitit]

Both on robogym-rearrange, 4 objects, complete goals, from `comparison_assets(preset,
env="robogym-rearrange")` (`reduced`: the shipped files):

* fig10: success against the horizon multiplier (1, 2, 4, 8 x the minimum steps) of Random,
  NF, MPC (planning horizon 1, and `mpc-h2`, `mpc-h3`), NCS (learned, the oracle) and
  `ncs-paper`, NCS as the paper specifies it (`PAPER_NCS`); the claims: NCS at 1x reaches
  at least 50x the success of the model-based baselines at 8x (Fig. 10's caption), NF is
  like Random, MPC is below Random (D.2).
* fig11: success against the std of Gaussian noise added to every action (0 ... 0.08 m) at
  4x, for NCS and the baselines (left), and NCS against the horizon multiplier (right,
  fig10's cells: each cell is cached by its inputs, `evaluate_method`, so it runs once);
  the claims: NCS above every baseline up to noise comparable with the 0.05 m pick and
  place thresholds, and NCS at 1x keeping its success (D.3).

Every cell is an independent seeded job (`sweeps.run_sweep`: this machine's processes or a
submitit cluster, the same rows). A claim's verdict reads the 95 % intervals: `ratio_claim`
and `gap_claim` give the rule.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path

from ..baselines import mpc_config
from ..config import STRESS_TASKS, to_dict
from ..evaluation import METHODS, NEEDS, TaskSet, evaluate_job, summarize, wilson_interval
from ..sweeps import check_executor, require_submitit, run_sweep
from ..utils import provenance, relative_to_repo, sha256_file
from .comparison import COMPARED, PAPER_NCS, comparison_assets
from .tables import table_dir, write_table

__all__ = ["FIGURES", "PAPER_NCS", "TASKS", "VARIANTS", "all_of", "available", "cell_jobs",
           "gap_claim", "katz_ratio_interval", "newcombe_interval", "ratio_claim", "stress_table", "tasks_per_point"]

ENV, NUM_OBJECTS, GOAL = "robogym-rearrange", 4, "complete"
HORIZONS = (1.0, 2.0, 4.0, 8.0)                         # horizon multipliers, Figs. 10 and 11 (right)
NOISES = (0.0, 0.01, 0.02, 0.03, 0.05, 0.08)            # action-noise std (m), Fig. 11 (left)
NOISE_HORIZON = 4.0                                     # the main paper's horizon
THRESHOLD = 0.05                                        # pick and place thresholds (m), Appendix C
SIMILAR_MARGIN = 0.1     # "similar" success rates: within 0.1 of each other (the paper gives no margin)

# label: (method of `evaluation.METHODS`, NCSConfig overrides, MPCConfig overrides)
VARIANTS = {
    "random": ("random", {}, {}),
    "random-object": ("random-object", {}, {}),
    "nf": ("nf", {}, {}),
    "mpc": ("mpc", {}, {}),
    "mpc-h2": ("mpc", {}, {"horizon": 2}),
    "mpc-h3": ("mpc", {}, {"horizon": 3}),
    "bc": ("bc", {}, {}),
    "iql": ("iql", {}, {}),
    "ncs": ("ncs", {}, {}),
    "ncs-oracle": ("ncs-oracle", {}, {}),
    "ncs-paper": ("ncs", PAPER_NCS, {}),
}
BASELINES = ("random", "random-object", "nf", "mpc", "mpc-h2", "mpc-h3", "bc", "iql")
# figure: panels of (varied field, its values, methods); the other field stays at its default
FIGURES = {
    "fig10": (("horizon_multiplier", HORIZONS, ("random", "random-object", "nf", "mpc", "mpc-h2", "mpc-h3",
                                                 "ncs", "ncs-oracle", "ncs-paper")),),
    "fig11": (("action_noise", NOISES, ("ncs", "ncs-oracle", "ncs-paper", "random", "random-object", "nf", "mpc",
                                         "bc", "iql")),
              ("horizon_multiplier", HORIZONS, ("ncs", "ncs-oracle"))),
}
TASKS = STRESS_TASKS        # tasks per point at each preset: config.py, beside the other presets


# ---------------------------------------------------------------------- claims
def newcombe_interval(s1: int, n1: int, s2: int, n2: int, z: float = 1.96) -> tuple[float, float, float]:
    """p1 - p2 and its 95 % interval from the two Wilson intervals (Newcombe 1998, method 10):
    sound at 0 and n successes, where the Wald interval collapses."""
    p1, p2 = s1 / n1, s2 / n2
    (l1, u1), (l2, u2) = wilson_interval(s1, n1), wilson_interval(s2, n2)
    d = p1 - p2
    return d, d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2), d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2)


def katz_ratio_interval(s1: int, n1: int, s2: int, n2: int, z: float = 1.96) -> tuple[float, float, float]:
    """p1 / p2 and its 95 % interval on the log scale (Katz et al. 1978); p2 must be > 0. A
    numerator of 0 successes reads 0.5 in the interval (the ratio itself is 0)."""
    if s2 <= 0:
        raise ValueError(f"the ratio needs a denominator above 0, got {s2} of {n2}")
    a = s1 if s1 > 0 else 0.5
    ratio = (s1 / n1) / (s2 / n2)
    se = math.sqrt(1 / a - 1 / n1 + 1 / s2 - 1 / n2)
    centre = math.log((a / n1) / (s2 / n2))
    return ratio, (0.0 if s1 == 0 else math.exp(centre - z * se)), math.exp(centre + z * se)


def _cell(label: str, row: dict) -> dict:
    """The part of a table row a claim reads: label, where, successes of episodes."""
    n = int(row["episodes"])
    return {"label": label, "successes": int(round(row["success"] * n)), "episodes": n}


def _name(c: dict) -> str:
    return f"{c['label']} ({c['successes']}/{c['episodes']})"


def ratio_claim(statement: str, num: dict, den: dict, at_least: float) -> dict:
    """Is num's success at least `at_least` x den's? num, den: {"label", "successes", "episodes"}.

    Denominator above 0: the ratio with its 95 % interval (`katz_ratio_interval`): "held"
    when the interval lies at or above `at_least`, "not held" when below, else "not
    testable" (too few tasks to tell). Denominator 0: the ratio is undefined; the gap
    num - den with its interval (`newcombe_interval`) is reported instead, and the claim is
    "held" only when num's lower Wilson bound is at least `at_least` x den's upper one
    (else "not testable": no number of successes of num could show it at these sizes)."""
    s1, n1, s2, n2 = num["successes"], num["episodes"], den["successes"], den["episodes"]
    gap, gap_lo, gap_hi = newcombe_interval(s1, n1, s2, n2)
    out = {"statement": statement, "numerator": num, "denominator": den, "at_least": at_least,
           "gap": round(gap, 4), "gap_ci": [round(gap_lo, 4), round(gap_hi, 4)]}
    if s2 > 0:
        ratio, lo, hi = katz_ratio_interval(s1, n1, s2, n2)
        out.update(ratio=round(ratio, 4), ratio_ci=[round(lo, 4), round(hi, 4)],
                   ours=f"ratio {ratio:.2f} [{lo:.2f}, {hi:.2f}] ({_name(num)} / {_name(den)})")
        if lo >= at_least:
            out.update(verdict="held", reason=f"the ratio's 95 % interval lies at or above {at_least:g}")
        elif hi < at_least:
            out.update(verdict="not held", reason=f"the ratio's 95 % interval lies below {at_least:g}")
        else:
            out.update(verdict="not testable",
                       reason=f"the ratio's 95 % interval contains {at_least:g}: too few tasks to tell")
        return out
    num_lo, den_hi = wilson_interval(s1, n1)[0], wilson_interval(s2, n2)[1]
    out.update(ratio=None, ratio_ci=None,
               ours=f"ratio undefined ({den['label']} solved 0 of {n2}); gap {gap:.2f} [{gap_lo:.2f}, {gap_hi:.2f}] "
                    f"({_name(num)} - {_name(den)})")
    if num_lo >= at_least * den_hi:
        out.update(verdict="held", reason=f"ratio undefined; {num['label']}'s lower bound {num_lo:.3f} is at least "
                                          f"{at_least:g} x {den['label']}'s upper bound {den_hi:.3f}")
    else:
        out.update(verdict="not testable",
                   reason=f"ratio undefined: {den['label']} solved none of its {n2} tasks, and {at_least:g} x its "
                          f"upper bound {den_hi:.3f} is above {num['label']}'s lower bound {num_lo:.3f}")
    return out


def gap_claim(statement: str, a: dict, b: dict, expect: str, margin: float = SIMILAR_MARGIN) -> dict:
    """a's success against b's, by the gap a - b and its 95 % interval (`newcombe_interval`).
    expect "greater" / "less": "held" when the interval lies above / below 0, "not held"
    when it lies on the other side, else "not testable" (it contains 0); "similar": "held"
    when the interval lies within +-`margin` (two one-sided tests: a gap of 0 on few tasks
    shows nothing), "not held" when it excludes 0, else "not testable"."""
    if expect not in ("greater", "less", "similar"):
        raise ValueError(f"expect must be 'greater', 'less' or 'similar', got {expect!r}")
    gap, lo, hi = newcombe_interval(a["successes"], a["episodes"], b["successes"], b["episodes"])
    out = {"statement": statement, "a": a, "b": b, "expect": expect, "gap": round(gap, 4),
           "gap_ci": [round(lo, 4), round(hi, 4)],
           "ours": f"gap {gap:.2f} [{lo:.2f}, {hi:.2f}] ({_name(a)} - {_name(b)})"}
    above, below = lo > 0, hi < 0
    if expect == "similar":
        if -margin <= lo and hi <= margin:
            return {**out, "verdict": "held", "reason": f"the gap's 95 % interval lies within +-{margin:g}"}
        if above or below:
            return {**out, "verdict": "not held", "reason": "the gap's 95 % interval excludes 0"}
        return {**out, "verdict": "not testable",
                "reason": f"the gap's 95 % interval contains 0 but reaches beyond +-{margin:g}: too few tasks to tell"}
    right, wrong = (above, below) if expect == "greater" else (below, above)
    side = "above" if expect == "greater" else "below"
    if right:
        return {**out, "verdict": "held", "reason": f"the gap's 95 % interval lies {side} 0"}
    if wrong:
        return {**out, "verdict": "not held", "reason": "the gap's 95 % interval lies on the other side of 0"}
    return {**out, "verdict": "not testable", "reason": "the gap's 95 % interval contains 0: too few tasks to tell"}


def all_of(statement: str, parts: list[dict]) -> dict:
    """One claim made of several: "held" if every part is, "not held" if any is not, else
    "not testable"; `parts` keeps each."""
    verdicts = [p["verdict"] for p in parts]
    if not parts:
        return {"statement": statement, "verdict": "not testable", "reason": "no cells to compare", "parts": []}
    verdict = ("not held" if "not held" in verdicts else "held" if set(verdicts) == {"held"} else "not testable")
    counts = ", ".join(f"{verdicts.count(v)} {v}" for v in ("held", "not held", "not testable") if v in verdicts)
    return {"statement": statement, "verdict": verdict, "reason": f"of {len(parts)} comparisons: {counts}",
            "ours": "; ".join(p["ours"] for p in parts), "parts": parts}


def _claims(figure: str, rows: list[dict]) -> list[dict]:
    """The paper's claims on `figure`'s rows (those whose cells the table holds)."""
    cells = {(r["varied"], r["method"], r["x"]): r for r in rows}

    def at(label, x, varied="horizon_multiplier"):
        row = cells.get((varied, label, float(x)))
        return None if row is None else _cell(f"{label} at {x:g}{'x' if varied == 'horizon_multiplier' else ' m'}", row)

    ncs_labels = [m for m in ("ncs", "ncs-paper") if at(m, 1) is not None or at(m, 0.0, "action_noise") is not None]
    out = []
    if figure == "fig10":
        for ncs in ncs_labels:
            for base in ("mpc", "mpc-h2", "mpc-h3", "nf"):
                if at(ncs, 1) and at(base, 8):
                    out.append(ratio_claim(f"NCS ({ncs}) at a 1x horizon reaches at least 50x the success of the "
                                           f"model-based baseline {base} at 8x (Fig. 10's caption)",
                                           at(ncs, 1), at(base, 8), 50.0))
        if at("nf", 8) and at("random", 8):
            out.append(gap_claim("NF performs similar to the random baseline (D.2; at 8x)", at("nf", 8),
                                 at("random", 8), "similar"))
        if at("mpc", 8) and at("random", 8):
            out.append(gap_claim("MPC performs worse than random (D.2; at 8x)", at("mpc", 8), at("random", 8), "less"))
        return out
    for ncs in ncs_labels:
        parts = []
        for noise in (n for n in NOISES if n <= THRESHOLD):
            bases = [(b, at(b, noise, "action_noise")) for b in BASELINES if at(b, noise, "action_noise")]
            mine = at(ncs, noise, "action_noise")
            if mine and bases:
                label, best = max(bases, key=lambda b: b[1]["successes"] / b[1]["episodes"])
                parts.append(gap_claim(f"{ncs} above the best baseline ({label}) at noise {noise:g} m",
                                       mine, best, "greater"))
        if parts:
            out.append(all_of(f"NCS ({ncs}) is more robust than the baselines to Gaussian action noise up to a noise "
                              f"comparable with the {THRESHOLD:g} m pick and place thresholds (D.3, Fig. 11 left): "
                              "above the best baseline at every noise up to it", parts))
    if at("ncs", 1) and at("ncs", 4):
        claim = ratio_claim("NCS's performance remains high given significantly fewer interaction steps (D.3, "
                            "Fig. 11 right): read as its success at 1x being at least half its success at 4x",
                            at("ncs", 1), at("ncs", 4), 0.5)
        out.append(claim)
    return out


# ---------------------------------------------------------------------- the sweep
def available(labels) -> list[str]:
    """The labels whose method this kit has (`evaluation.METHODS`; e.g. "random-object" once added)."""
    unknown = sorted(set(labels) - set(VARIANTS))
    if unknown:
        raise ValueError(f"unknown methods {unknown}; expected some of {', '.join(VARIANTS)}")
    return [label for label in labels if VARIANTS[label][0] in METHODS]


def tasks_per_point(preset: str, episodes: int | None = None, mpc_episodes: int | None = None) -> dict:
    """{"tasks", "mpc"}: seeded tasks per point of every method and of MPC at `preset`."""
    if preset not in TASKS:
        raise ValueError(f"unknown preset {preset!r}; expected one of {', '.join(TASKS)}")
    tasks = episodes or TASKS[preset]["tasks"]
    return {"tasks": tasks, "mpc": min(tasks, mpc_episodes or TASKS[preset]["mpc"])}


def _asset_kwargs(method: str, assets: dict) -> dict:
    """What `evaluate_method` reads for `method` from `comparison_assets`' dict."""
    if method in COMPARED:
        needs = COMPARED[method][1]
    elif not NEEDS[method]:
        needs = ()
    else:
        raise ValueError(f"method {method!r} needs {NEEDS[method]}, which comparison_assets does not name")
    return {"graph": next((assets[a] for a in needs if a.endswith("graph")), None),
            "model": assets["model"] if "model" in needs else None,
            "policy": assets[method] if method in ("bc", "iql") else None}


def cell_jobs(figure: str, assets: dict, preset: str, sizes: dict, methods=None, cache: bool = True):
    """(points, jobs): every point of `figure` as (varied, x, label), and the distinct
    `evaluate_method` jobs (method, TaskSet, kwargs) with, per point, its job's index."""
    points, jobs, index = [], [], {}
    for varied, values, labels in FIGURES[figure]:
        for label in available([m for m in labels if methods is None or m in methods]):
            method, ncs_over, mpc_over = VARIANTS[label]
            n = sizes["mpc"] if method == "mpc" else sizes["tasks"]
            for x in values:
                setting = {"horizon_multiplier": NOISE_HORIZON if varied == "action_noise" else x,
                           "action_noise": x if varied == "action_noise" else 0.0}
                tasks = TaskSet(env=ENV, num_objects=NUM_OBJECTS, goal=GOAL, episodes=n, seed=0, **setting)
                key = (label, tasks)
                if key not in index:
                    kwargs = {**_asset_kwargs(method, assets), "ncs": replace(assets["ncs"], **ncs_over).validate(),
                              "mpc": mpc_config(preset, **mpc_over) if method == "mpc" else None,
                              "seed": 0, "label": label, "cache": cache}
                    index[key] = len(jobs)
                    jobs.append((method, tasks, kwargs))
                points.append((varied, float(x), label, index[key]))
    return points, jobs


def _cost(job) -> float:
    """A job's rough cost, to start the costliest first: steps x tasks x a step's planning."""
    method, tasks, kwargs = job
    per_step = 100.0 * kwargs["mpc"].horizon if method == "mpc" else (5.0 if kwargs["model"] is not None else 1.0)
    return per_step * tasks.horizon_multiplier * tasks.episodes


KEEP = ("mean_steps", "random_fraction", "noop_fraction")
CONSTRAINTS = ("constraints", "constraints_ci_low", "constraints_ci_high")     # when `summarize` gives them


def _row(varied: str, x: float, label: str, summary: dict) -> dict:
    row = {"method": label, "varied": varied, "x": x, "horizon_multiplier": summary["horizon_multiplier"],
           "action_noise": summary["action_noise"], "episodes": summary["episodes"], "success": summary["success"],
           "ci_low": summary["ci_low"], "ci_high": summary["ci_high"],
           **{c: summary[c] for c in CONSTRAINTS if summary.get(c) is not None},
           **{c: summary[c] for c in KEEP if c in summary}}
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}


def stress_table(figure: str, preset: str = "reduced", executor: str = "local", folder=None,
                 episodes: int | None = None, mpc_episodes: int | None = None, methods=None, out_dir=None,
                 allow_dirty: bool = False, workers: int | None = None, cache: bool = True) -> dict:
    """figures/tables/<figure>_<preset>.csv and .json: one row per method and point (success,
    95 % Wilson interval, the constraint columns when `summarize` has them), the claims, the
    tasks per point of each method and the assets' hashes. The cells run as one sweep
    (`sweeps.run_sweep` with `executor`), the costliest first."""
    if figure not in FIGURES:
        raise ValueError(f"unknown figure {figure!r}; expected one of {', '.join(FIGURES)}")
    check_executor(executor)
    if executor == "submitit":
        require_submitit()                      # before the assets are read or built
    sizes = tasks_per_point(preset, episodes, mpc_episodes)
    name = f"{figure}_{preset}"
    provenance(table_dir(out_dir) / f"{name}.json", allow_dirty)   # refuse a dirty tree before the work
    start = time.perf_counter()
    assets = comparison_assets(preset, env=ENV)
    points, jobs = cell_jobs(figure, assets, preset, sizes, methods, cache)
    first = sorted(range(len(jobs)), key=lambda i: (-_cost(jobs[i]), i))
    cells = run_sweep(evaluate_job, jobs, executor=executor, folder=folder, workers=workers, first=first,
                      desc=figure)
    summaries = [summarize(rows)[0] for rows in cells]
    rows = [_row(varied, x, label, summaries[i]) for varied, x, label, i in points]
    per_method = {}
    for _, _, label, i in points:
        per_method[label] = jobs[i][1].episodes
    meta = {"env": ENV, "num_objects": NUM_OBJECTS, "goal": GOAL, "preset": preset, "figure": figure,
            "episodes": sizes["tasks"], "mpc_episodes": sizes["mpc"], "tasks_per_point": per_method,
            "panels": [{"varied": v, "values": list(xs), "fixed": ({"horizon_multiplier": NOISE_HORIZON}
                                                                  if v == "action_noise" else {"action_noise": 0.0})}
                       for v, xs, _ in FIGURES[figure]],
            "ncs": to_dict(assets["ncs"]), "ncs_paper": dict(PAPER_NCS),
            "mpc": {label: to_dict(jobs[i][2]["mpc"]) for _, _, label, i in points if jobs[i][2]["mpc"] is not None},
            "executor": executor,
            "assets": {k: {"path": relative_to_repo(v), "sha256": sha256_file(v)} for k, v in assets["paths"].items()
                       if Path(v).is_file()},
            "claims": _claims(figure, rows), "minutes": round((time.perf_counter() - start) / 60, 1)}
    write_table(name, rows, meta, out_dir, allow_dirty)
    return {"rows": rows, "claims": meta["claims"], "minutes": meta["minutes"]}

