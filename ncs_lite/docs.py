"""The README's generated blocks and docs/results.md, written from the committed tables.

Every number the README and docs/results.md give comes from a file a command wrote:
`figures/tables/**/*.json` (`python -m ncs_lite reproduce TABLE`) and
`figures/notebook_times.json` (`make reproduce`). This module renders them; nothing is
typed by hand, so a table that changes changes the text with it.

    python -m ncs_lite.docs            # rewrite the README's blocks and docs/results.md
    python -m ncs_lite.docs --check    # compare only; exit 1 naming each stale file

The README holds three blocks, each between two marker lines (`<!-- NAME:begin -->` and
`<!-- NAME:end -->`): `results` (the headline numbers of both environments and the main
comparison), `times` (what `make reproduce` takes) and `notebooks` (one line per notebook
with its measured time); docs/recipe.md holds one, `ablations` (the recipe's drop-one
ablations, `render_ablations_block`). A table that is absent (one still being computed) is left out;
a table of an unknown shape is rendered generically. Each table's command is rebuilt from
its own metadata (`table_command`). tests/test_docs.py fails when the committed text
differs from what this module writes.

Why generated: a number copied by hand goes stale without anyone noticing (docs/HISTORY.md
keeps the dated measurements that are not regenerated).
"""
from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import sys
from pathlib import Path

from .config import NCS_ENV_DEFAULTS, STRESS_TASKS, NCSConfig, ncs_env_default
from .envs.block_rearrange import BlockRearrangeConfig
from .utils import ENV_SHORT_NAMES, NOTEBOOK_ENV_SUFFIX, REPO_DIR, atomic_write_text, split_notebook_run

__all__ = ["write_docs", "load_tables", "render_table", "render_results_md", "readme_blocks",
           "replace_block", "render_ablations_block", "table_command", "format_value", "format_mean_sd", "main"]

BLOCK_ENVS = ("block-rearrange", "robogym-rearrange")
# the order of the environments in the headline table
HEADLINE_ENVS = (*BLOCK_ENVS, "block-stacking")
# the per-env tables of `reproduce robogym|stacking` (robogym_reduced, stacking_reduced)
ENV_TABLE_PREFIXES = tuple(f"{short}_" for short in ENV_SHORT_NAMES.values() if short)
# the envs whose main comparison the README shows in full (the others': docs/results.md)
README_COMPARISONS = ("block-rearrange", "robogym-rearrange")
# the envs `make reproduce` runs notebooks on, in the order of the times' columns (an env beyond
# BLOCK_ENVS only once it has a time: `_timed_envs`)
NOTEBOOK_ENVS = tuple(NOTEBOOK_ENV_SUFFIX)
# `reproduce`'s defaults (its options in ncs_lite/__main__.py, and `reproduce.seeds_table`): a
# command names an argument only where its table differs from them
DEFAULT_EPISODES = 100
DEFAULT_OBJECTS = {"block-rearrange": [4, 7], "robogym-rearrange": [4, 5, 6, 7], "block-stacking": [3, 4, 5, 6]}
DEFAULT_PRESET = "reduced"
# what `make reproduce` should take at `reduced` on a two-core laptop (the README says by how much,
# and where the time goes, when the measured runs exceed it)
REPRODUCE_TARGET_MINUTES = 30
SHIPPED_ASSETS = "ncs_lite/assets/"    # a table read from a shipped asset used the command's default
# NCSConfig fields that `reproduce seeds` sets from the env (Tables 3-4): never overrides
ENV_NCS_FIELDS = ("clusters", "edge_action", "state")

# --------------------------------------------------------------------- what a column means
# (pattern over a column name, label, kind, which direction is better: "high", "low" or None).
# Only columns that match are rendered ("columns of interest"); the order here is the order
# of the rows. {state} is the table's NCS state ("masks" or "slot states"); {k} an object
# count; {r} a number of slot-attention starts.
_SPLIT = {
    "type_invariance": ("type invariance: z's change across a move / distance between two objects' z", "num3", "low"),
    "identity_from_z": ("identity (colour) from z, nearest centroid", "num2", "high"),
    "position_r2_from_s": ("position R² from s", "num2", "high"),
    "position_r2_from_z": ("position R² from z", "num2", "low"),
    "own_slot_share": ("objects with a slot of their own", "num2", "high"),
    "position_r2_own_slots": ("position R² from s, objects with a slot of their own", "num2", "high"),
    "moved_slot_accuracy": ("dynamics: largest predicted change on the moved object's slot", "num2", "high"),
    "moved_misses_objectless": ("dynamics: share of its misses on a slot holding no object", "num2", None),
    "predicted_position_r2": ("dynamics: R² of the next position from the predicted s", "num2", "high"),
    "no_change_position_r2": ("... the same R² predicting no change (reference)", "num2", None),
    "render_fg_error": ("image drawn from the slots alone, error on the objects", "num2", "low"),
    "floor_fg_error": ("... the empty floor's error on the objects (reference)", "num2", None),
    "predicted_render_error": ("image drawn from predicted slots, error on the moved object", "num2", "low"),
    "no_change_error": ("... the current frame's error on the moved object (reference)", "num2", None),
    "dvae_floor_max": ("dVAE: largest share of a colour's pixels coded as floor", "num3", "low"),
}
COLUMNS = [
    (r"ncs_(?P<k>\d+)", "`ncs` on {state}, {k} objects", "rate", "high"),
    (r"ncs_slot_(?P<k>\d+)", "`ncs` on slot states, {k} objects", "rate", "high"),
    (r"ncs_(?P<k>\d+)_r1", "`ncs` on {state}, one slot-attention pass, {k} objects", "rate", "high"),
    (r"ncs_slot_(?P<k>\d+)_r1", "`ncs` on slot states, one slot-attention pass, {k} objects", "rate", "high"),
    (r"ncs_oracle_(?P<k>\d+)", "`ncs-oracle` (ground truth), {k} objects", "rate", "high"),
    (r"random_(?P<k>\d+)", "`random`, {k} objects", "rate", None),
    # block-stacking (`reproduce stacking`): both NCS agents without the dependency rules
    (r"ncs_independent_(?P<k>\d+)", "`ncs` without the dependency rules, {k} objects", "rate", "high"),
    (r"ncs_oracle_independent_(?P<k>\d+)", "`ncs-oracle` without the dependency rules, {k} objects", "rate", "high"),
    (r"ncs_rule_(?P<rule>direct|path|clear)_(?P<k>\d+)", "decisions by the rule {rule}, `ncs`, {k} objects", "pct",
     None),
    (r"ncs_oracle_rule_(?P<rule>direct|path|clear)_(?P<k>\d+)", "decisions by the rule {rule}, `ncs-oracle`, "
     "{k} objects", "pct", None),
    # the second measure (`evaluation.summarize`'s `constraints`): not in the headline, which
    # gives the share of tasks solved
    (r"ncs_(?P<k>\d+)_constraints", "`ncs` on {state}, share of constraints satisfied, {k} objects", "rate", "high"),
    (r"ncs_slot_(?P<k>\d+)_constraints", "`ncs` on slot states, share of constraints satisfied, {k} objects", "rate",
     "high"),
    (r"ncs_oracle_(?P<k>\d+)_constraints", "`ncs-oracle` (ground truth), share of constraints satisfied, {k} objects",
     "rate", "high"),
    (r"random_(?P<k>\d+)_constraints", "`random`, share of constraints satisfied, {k} objects", "rate", None),
    (r"fg_ari_(?P<k>\d+)_r(?P<r>\d+)", "fg-ARI, {k} objects, {starts}", "num2", "high"),
    (r"absorbed_(?P<k>\d+)_r(?P<r>\d+)", "objects absorbed into the floor's slot, {k} objects, {starts}", "pct", "low"),
    (r"shared_(?P<k>\d+)_r(?P<r>\d+)", "objects sharing a slot with another, {k} objects, {starts}", "pct", "low"),
    *[(rf"split_{m}", f"{label}, one start", kind, better) for m, (label, kind, better) in _SPLIT.items()],
    *[(rf"split_r(?P<r>\d+)_{m}", f"{label}, {{starts}}", kind, better) for m, (label, kind, better) in _SPLIT.items()],
    (r"random_fraction_(?P<k>\d+)", "random fallback actions, `ncs` on {state}, {k} objects", "pct", "low"),
    (r"random_fraction_slot_(?P<k>\d+)", "random fallback actions, `ncs` on slot states, {k} objects", "pct", "low"),
    (r"ncs_random_fraction_(?P<k>\d+)", "random fallback actions, `ncs`, {k} objects", "pct", "low"),
    (r"noop_fraction_(?P<k>\d+)", "actions that changed nothing, `ncs` on {state}, {k} objects", "pct", "low"),
    (r"noop_fraction_slot_(?P<k>\d+)", "actions that changed nothing, `ncs` on slot states, {k} objects", "pct", "low"),
    (r"ncs_noop_fraction_(?P<k>\d+)", "actions that changed nothing, `ncs`, {k} objects", "pct", "low"),
    (r"placed_fraction_(?P<k>\d+)", "actions that put a constrained object at its goal, `ncs` on {state}, {k} objects",
     "pct", "high"),
    (r"placed_fraction_slot_(?P<k>\d+)", "actions that put a constrained object at its goal, `ncs` on slot states, "
     "{k} objects", "pct", "high"),
    (r"picked_nothing_fraction_(?P<k>\d+)", "actions whose pick found no object, `ncs` on {state}, {k} objects",
     "pct", "low"),
    (r"picked_nothing_fraction_slot_(?P<k>\d+)",
     "actions whose pick found no object, `ncs` on slot states, {k} objects",
     "pct", "low"),
    (r"refused_fraction_(?P<k>\d+)", "actions whose place was refused, `ncs` on {state}, {k} objects", "pct", "low"),
    (r"refused_fraction_slot_(?P<k>\d+)", "actions whose place was refused, `ncs` on slot states, {k} objects",
     "pct", "low"),
    (r"edges", "graph edges", "int", None),
    (r"graph_edges", "graph edges, {state}", "int", None),
    (r"graph_edges_slot", "graph edges, slot states", "int", None),
    (r"oracle_graph_edges", "graph edges, the oracle's graph", "int", None),
    (r"coverage", "isolate coverage, {state}", "num2", "high"),
    (r"coverage_slot", "isolate coverage, slot states", "num2", "high"),
    (r"heldout_error", "held-out reconstruction error, 4 objects, one start", "sig3", "low"),
    (r"heldout_error_(?P<k>\d+)_r(?P<r>\d+)", "held-out reconstruction error, {k} objects, {starts}", "sig3", "low"),
    (r"train_minutes", "training minutes", "min", "low"),
]
_COLUMNS = [(re.compile(p + r"\Z"), label, kind, better) for p, label, kind, better in COLUMNS]
STATE_NAMES = {"mask": "masks", "slot": "slot states"}


def _column(name: str):
    """(order, numbers, label template, groups, kind, better) of a column name, or None."""
    for order, (pattern, label, kind, better) in enumerate(_COLUMNS):
        m = pattern.match(name)
        if m:
            numbers = tuple(int(v) for v in m.groupdict().values() if v is not None and v.isdigit())
            return order, numbers, label, m.groupdict(), kind, better
    return None


def _label(template: str, groups: dict, state: str) -> str:
    r = groups.get("r")
    starts = "" if r is None else ("one start" if r == "1" else f"{r} restarts")
    return template.format(k=groups.get("k"), starts=starts, state=state, rule=groups.get("rule"))


# --------------------------------------------------------------------------- numbers
def format_value(value, kind: str = "num2") -> str:
    """One number as the docs print it: rates and scores to 2 decimals (`num3`: 3), shares
    of actions or objects as percentages, counts as integers, minutes to 0.1; a missing or
    non-finite value as "n/a"."""
    if value is None or isinstance(value, str):
        return "n/a" if value in (None, "") else str(value)
    v = float(value)
    if not math.isfinite(v):
        return "n/a"
    if kind == "pct":
        return f"{100 * v:.{_pct_digits(v)}f} %"
    if kind == "int":
        return f"{int(round(v)):,}"
    if kind == "min":
        return f"{v:.1f} min"
    if kind == "sig3":
        return f"{v:.3g}"
    return f"{v:.{3 if kind == 'num3' else 2}f}"


def _pct_digits(v: float) -> int:
    return 1 if 0 < abs(v) < 0.1 else 0


def format_mean_sd(mean, sd, kind: str = "num2") -> str:
    """"0.96 ± 0.04" in the column's format (percentages: "4 ± 3 %")."""
    if mean is None or not math.isfinite(float(mean)):
        return "n/a"
    if sd is None or not math.isfinite(float(sd)):
        return format_value(mean, kind)
    if kind == "pct":
        d = _pct_digits(float(mean))
        return f"{100 * mean:.{d}f} ± {100 * sd:.{d}f} %"
    if kind == "min":
        return f"{mean:.1f} ± {sd:.1f} min"
    return f"{format_value(mean, kind)} ± {format_value(sd, kind)}"


def format_seconds(seconds: float) -> str:
    """A wall time: "7 s" under a minute, else "3.8 min"."""
    return f"{seconds:.0f} s" if seconds < 60 else f"{seconds / 60:.1f} min"


def _cell(row: dict, column: str, kind: str) -> str:
    """A row's value, with its 95 % interval (`<column>_ci`) where the table gives one."""
    text = format_value(row.get(column), kind)
    ci = row.get(f"{column}_ci")
    return f"{text} {ci}" if ci and text != "n/a" else text


def _summary(table: dict, column: str) -> dict | None:
    """{"mean", "sd", "n"} of a column over the table's rows (seeds): the table's own
    `summary` where it has the column, else computed the same way (sd with n - 1)."""
    given = (table.get("summary") or {}).get(column)
    if given is not None:
        return given
    values = [float(r[column]) for r in table["rows"]
              if isinstance(r.get(column), (int, float)) and math.isfinite(float(r[column]))]
    if not values:
        return None
    return {"mean": statistics.fmean(values), "sd": statistics.stdev(values) if len(values) > 1 else float("nan"),
            "n": len(values)}


def _worst(table: dict, column: str, better: str | None, kind: str) -> str:
    """The worst seed's value and which seed: the lowest where higher is better, the highest
    where lower is."""
    if better is None:
        return ""
    rows = [r for r in table["rows"] if isinstance(r.get(column), (int, float))]
    if not rows:
        return ""
    pick = min if better == "high" else max
    row = pick(rows, key=lambda r: r[column])
    who = f"seed {row['seed']}" if "seed" in row else f"row {table['rows'].index(row)}"
    return f"{format_value(row[column], kind)} ({who})"


def _seeds_cell(table: dict, column: str, kind: str, better: str | None) -> str:
    """A column over training seeds: "0.96 ± 0.04 (0.92)", the mean ± sd and the worst seed."""
    s = _summary(table, column)
    worst = _worst(table, column, better, kind).split(" (")[0]
    return f"{format_mean_sd(s['mean'], s['sd'], kind)} ({worst})"


def _constant(table: dict, column: str) -> bool:
    """Whether every row has the same value (e.g. the oracle's success, which no training
    seed changes)."""
    values = {json.dumps(r.get(column)) for r in table["rows"]}
    return len(values) == 1


def _state(table: dict) -> str:
    return STATE_NAMES.get((table.get("ncs") or {}).get("state"), "its states")


def _env(table: dict) -> str:
    return table.get("env") or "block-rearrange"


# --------------------------------------------------------------------------- commands
def _is_seeds(name: str) -> bool:
    return name.startswith("seeds_")


def _ncs_overrides(table: dict) -> list[str]:
    """The `--set ncs.*` a seeds table was read with: its `ncs` section against NCSConfig's
    defaults (tables written before `ncs_overrides` was recorded hold only the section)."""
    default = NCSConfig()
    out = []
    for field, value in sorted((table.get("ncs") or {}).items()):
        if field in ENV_NCS_FIELDS or not hasattr(default, field):
            continue
        # a table that recorded its env's value for a field whose None is the env's default
        # was read with the default
        env_default = ncs_env_default(field, _env(table)) if field in NCS_ENV_DEFAULTS else None
        if value not in (getattr(default, field), env_default):
            out.append(f"ncs.{field}={'none' if value is None else value}")
    recorded = [o for o in table.get("ncs_overrides") or [] if o not in out]
    return out + recorded


def table_command(path: str, table: dict) -> str:
    """The command that regenerates a table, rebuilt from the table's metadata. `path` is
    the table's JSON file relative to figures/tables/ (a table in a subfolder was written
    with `--out-dir`). It starts with `OMP_NUM_THREADS=N` where the table recorded its thread
    count, the condition for the same digits."""
    name = table.get("table") or Path(path).stem
    folder = Path(path).parent.as_posix()
    out_dir = [] if folder in ("", ".") else ["--out-dir", f"figures/tables/{folder}"]
    env = _env(table)
    preset = table.get("preset", DEFAULT_PRESET)
    args: list[str]
    if _is_seeds(name):
        args = ["reproduce", "seeds", "--seeds", *map(str, sorted(table.get("seeds") or [0, 1, 2]))]
        if env != "block-rearrange":
            args += ["--env", env]
        if preset != DEFAULT_PRESET:
            args += ["--preset", preset]
        objects = table.get("objects")
        if objects and list(objects) != DEFAULT_OBJECTS.get(env):
            args += ["--objects", *map(str, objects)]
        if table.get("episodes", DEFAULT_EPISODES) != DEFAULT_EPISODES:
            args += ["--episodes", str(table["episodes"])]
        if table.get("task_seed"):
            args += ["--task-seed", str(table["task_seed"])]
        recipe = list(table.get("overrides") or [])
        for override in recipe + _ncs_overrides(table):
            args += ["--set", override]
        if recipe:        # another recipe trains into runs of its own (`--runs`)
            args += ["--runs", f".cache/seeds-{Path(folder).name or 'variant'}"]
    elif name.startswith("baselines_"):
        args = ["reproduce", "baselines"]
        if env != "block-rearrange":
            args += ["--env", env]
        if preset != DEFAULT_PRESET:
            args += ["--preset", preset]
        args += ["--episodes", str(table.get("episodes")), "--mpc-episodes", str(table.get("mpc_episodes"))]
    elif name == "clusters":
        args = ["reproduce", "clusters"]
        if not str(table.get("checkpoint", SHIPPED_ASSETS)).startswith(SHIPPED_ASSETS):
            args += ["--checkpoint", table["checkpoint"]]
        if table.get("episodes", DEFAULT_EPISODES) != DEFAULT_EPISODES:
            args += ["--episodes", str(table["episodes"])]
    elif name.startswith(ENV_TABLE_PREFIXES):
        args = ["reproduce", name.split("_")[0]]
        for key, flag in (("checkpoint", "--checkpoint"), ("graph", "--graph"), ("oracle_graph", "--oracle-graph")):
            if not str(table.get(key, SHIPPED_ASSETS)).startswith(SHIPPED_ASSETS):
                args += [flag, table[key]]
        if table.get("episodes", DEFAULT_EPISODES) != DEFAULT_EPISODES:
            args += ["--episodes", str(table["episodes"])]
        objects = table.get("objects")
        if objects and list(objects) != DEFAULT_OBJECTS[env]:
            args += ["--objects", *map(str, objects)]
    elif name.startswith("fig9_"):
        args = ["reproduce", "fig9"] + (["--preset", preset] if preset != DEFAULT_PRESET else [])
    elif name.startswith(("fig10_", "fig11_")):
        args = ["reproduce", name.split("_")[0]]
        if preset != DEFAULT_PRESET:
            args += ["--preset", preset]
        sizes = STRESS_TASKS.get(preset, {})
        for key, flag, default in (("episodes", "--episodes", sizes.get("tasks")),
                                   ("mpc_episodes", "--mpc-episodes", sizes.get("mpc"))):
            if table.get(key) is not None and table[key] != default:
                args += [flag, str(table[key])]
    else:
        return "(no command recorded)"
    threads = [f"OMP_NUM_THREADS={table['threads']}"] if table.get("threads") else []
    return " ".join([*threads, "python -m ncs_lite", *args, *out_dir])


# --------------------------------------------------------------------------- one table
def _markdown(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(cells) + " |" for cells in rows]


def _measure_columns(table: dict) -> list[tuple]:
    """(column, label, kind, better) of the table's columns of interest, in COLUMNS order."""
    state = _state(table)
    found = []
    for column in table["rows"][0]:
        info = _column(column)
        if info is not None:
            order, numbers, template, groups, kind, better = info
            found.append(((order, numbers), column, _label(template, groups, state), kind, better))
    return [f[1:] for f in sorted(found)]


def _render_measures(table: dict) -> list[str]:
    """Rows are measures; columns the table's rows (seeds), then mean ± sd and the worst seed."""
    rows = table["rows"]
    columns = _measure_columns(table)
    if len(rows) == 1:
        return _markdown(["measure", "value"], [[label, _cell(rows[0], c, kind)] for c, label, kind, _ in columns])
    names = [f"seed {r['seed']}" if "seed" in r else f"row {i}" for i, r in enumerate(rows)]
    n = len(rows)
    header = ["measure", *names, f"mean ± sd (n = {n})", "worst seed"]
    body = []
    for column, label, kind, better in columns:
        s = _summary(table, column)
        spread = format_mean_sd(s["mean"], s["sd"], kind) if s else ""
        worst = "" if _constant(table, column) else _worst(table, column, better, kind)
        body.append([label, *(_cell(r, column, kind) for r in rows), spread, worst])
    shipped = table.get("shipped_seed")
    if shipped is not None:
        body.append(["the shipped seed (" + str(table.get("shipped_rule", "its rule")) + ")",
                     *["**shipped**" if r.get("seed") == shipped else "" for r in rows], "", ""])
    return _markdown(header, body)


def _render_sweep(table: dict) -> list[str]:
    """One row per point of a sweep (e.g. the number of graph nodes)."""
    rows = table["rows"]
    key = next(iter(rows[0]))
    columns = sorted((c for c in _measure_columns(table) if c[0] != key), key=lambda c: c[2] != "int")
    header = [key.replace("_", " "), *(label for _, label, _, _ in columns)]
    body = [[format_value(r[key], "int"), *(_cell(r, c, kind) for c, _, kind, _ in columns)] for r in rows]
    return _markdown(header, body)


def _comparison_cell(row: dict, episodes) -> str:
    text = f"{format_value(row.get('success'), 'rate')} [{row['ci_low']:.2f}, {row['ci_high']:.2f}]"
    notes = []
    share = row.get("random_fraction")
    if isinstance(share, (int, float)) and share > 0:
        notes.append(f"{format_value(share, 'pct')} random")
    if episodes is not None and row.get("episodes") not in (None, episodes):
        notes.append(f"n = {row['episodes']}")
    return text + (f" ({', '.join(notes)})" if notes else "")


_VARIED = {"horizon_multiplier": ("horizon multiplier", "{:g}x"), "action_noise": ("action noise (std)", "{:g} m"),
           "clusters": ("number of clusters", "{}"), "data": ("graph buffer episodes", "{:,}"),
           "slots": ("slots read per scene", "{}")}


def _render_figure(table: dict) -> list[str]:
    """A figure's panels (methods x the varied setting: success [95 % interval]), then its
    claims: the statement, our number, the verdict and why."""
    rows = table["rows"]
    lines = []
    for varied in dict.fromkeys(r["varied"] for r in rows):
        title, fmt = _VARIED.get(varied, (varied, "{}"))
        cells = {(r["method"], r["x"]): r for r in rows if r["varied"] == varied}
        methods = list(dict.fromkeys(m for m, _ in cells))
        xs = sorted({x for _, x in cells})
        body = [[f"`{m}`", *(_comparison_cell(cells[m, x], table.get("episodes")) if (m, x) in cells else "–"
                             for x in xs)] for m in methods]
        lines += [f"*success against the {title}*", ""]
        lines += _markdown(["method", *(fmt.format(x) for x in xs)], body) + [""]
    lines.append("Success with its 95 % Wilson interval; in brackets the share of random actions where it is "
                 "not 0, and the number of tasks where a method ran on fewer.")
    claims = table.get("claims") or []
    if claims:
        lines += ["", "Claims:", ""]
        lines += [f"- {c['statement']}: {c.get('ours', '')}. **{c['verdict']}** ({c['reason']})." for c in claims]
    return lines


def _constraints_cell(row: dict) -> str:
    if not isinstance(row.get("constraints"), (int, float)):
        return "n/a"
    return f"{format_value(row['constraints'], 'rate')} [{row['constraints_ci_low']:.2f}, {row['constraints_ci_high']:.2f}]"


def _render_comparison(table: dict, goals=None, notes: bool = True, constraints: bool = True) -> list[str]:
    """Methods x object counts, one markdown table per goal kind: success [95 % interval];
    with `constraints`, where the table has them (tables written before it was measured do
    not), a second one per goal kind: the mean share of constraints satisfied [95 % interval]."""
    rows = table["rows"]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    counts = sorted({r["num_objects"] for r in rows})
    measured = constraints and any("constraints" in r for r in rows)
    lines = []
    for goal in goals or list(dict.fromkeys(r["goal"] for r in rows)):
        cells = {(r["method"], r["num_objects"]): r for r in rows if r["goal"] == goal}
        if not cells:
            continue
        if len(goals or ()) != 1 or measured:
            lines += [f"*{goal} goals*", ""]
        body = [[f"`{m}`", *(_comparison_cell(cells[m, k], table.get("episodes")) if (m, k) in cells else "–"
                             for k in counts)] for m in methods]
        lines += _markdown(["method", *(f"{k} objects" for k in counts)], body) + [""]
        if measured:
            lines += [f"*{goal} goals, share of constraints satisfied*", ""]
            body = [[f"`{m}`", *(_constraints_cell(cells[m, k]) if (m, k) in cells else "–" for k in counts)]
                    for m in methods]
            lines += _markdown(["method", *(f"{k} objects" for k in counts)], body) + [""]
    if notes:
        lines.append("Success with its 95 % Wilson interval; in brackets the share of random actions where it is "
                     "not 0, and the number of tasks where a method ran on fewer.")
        if measured:
            lines.append("Share of constraints satisfied: the mean over tasks of the share of a task's constraints "
                         "that hold at its end, with its 95 % interval (the Wilson interval at the mean).")
    return lines[:-1] if lines and lines[-1] == "" else lines


def _kind(table: dict) -> str:
    rows = table.get("rows") or []
    if not rows:
        return "empty"
    if {"method", "varied", "x", "success", "ci_low", "ci_high"} <= set(rows[0]):
        return "figure"
    if {"method", "goal", "num_objects", "success"} <= set(rows[0]):
        return "comparison"
    if "seed" in rows[0] or len(rows) == 1:
        return "measures"
    return "sweep"


def _describe(path: str, table: dict) -> str:
    """One sentence on what a table measures, from its name and folder."""
    name = table.get("table") or Path(path).stem
    folder = Path(path).parent.as_posix()
    if name.startswith("baselines_"):
        what = ("The main comparison: every method on the same seeded tasks, complete and partial goals"
                + (" (block-stacking: complete goals, 3-6 cubes)." if _env(table) == "block-stacking" else "."))
    elif name == "clusters":
        what = "NCS success against the number of graph nodes (the paper's Fig. 9, left) on the shipped checkpoint."
    elif name.startswith("robogym_"):
        what = "The shipped robogym-rearrange checkpoint and graphs measured: the type/state split, fg-ARI and success."
    elif name.startswith("stacking_"):
        what = ("The shipped block-stacking checkpoint and graphs measured: the type/state split, fg-ARI, success "
                "with and without the dependency rules (the kit's extension of Appendix F), and how often each "
                "rule chose a move.")
    elif name.startswith("fig9_"):
        what = ("The paper's Fig. 9 (Appendix D.1): NCS against its number of clusters, the buffer episodes its "
                "graph reads and the slots it reads a scene with, 4 objects, complete goals; the claims with our "
                "verdicts.")
    elif name.startswith("fig10_"):
        what = ("The paper's Fig. 10 (Appendix D.2): success against the interaction horizon, NCS and the "
                "baselines, 4 objects, complete goals; the paper's claims with our verdicts.")
    elif name.startswith("fig11_"):
        what = ("The paper's Fig. 11 (Appendix D.3): success against Gaussian action noise at 4x, and NCS "
                "against the interaction horizon, 4 objects, complete goals; the paper's claims with our verdicts.")
    elif _is_seeds(name):
        what = ("The recipe trained once per seed, each seed's split, segmentation and NCS success; mean ± sd "
                "over seeds and the worst seed.")
    else:
        what = "A table of `figures/tables/`."
    if folder.startswith("variants"):
        what += " A variant, not adopted: its overrides are in the command."
    elif folder == "shipped":
        what += " The shipped seed alone"
        if table.get("task_seed"):
            what += f", on tasks no other table uses (task seed {table['task_seed']})"
        what += "."
    return what


def render_table(path: str, table: dict) -> str:
    """docs/results.md's section of one table: title, command, provenance, the table."""
    name = table.get("table") or Path(path).stem
    lines = [f"## `{path}`", "", _describe(path, table), "", f"Command: `{table_command(path, table)}`", ""]
    facts = [f"environment {_env(table)}"]
    if table.get("preset"):
        facts.append(f"preset `{table['preset']}`")
    if table.get("seeds"):
        seeds = sorted(table["seeds"])
        facts.append(("training seed " if len(seeds) == 1 else "training seeds ") + ", ".join(map(str, seeds)))
    if table.get("episodes"):
        mpc = table.get("mpc_episodes")
        facts.append(f"{table['episodes']} seeded tasks per cell" + (f" (`mpc`: {mpc})" if mpc else ""))
    ncs = table.get("ncs") or {}
    if ncs.get("clusters"):
        facts.append(f"{ncs['clusters']} graph nodes" if name != "clusters" else "nodes swept")
    overrides = list(table.get("overrides") or []) + (_ncs_overrides(table) if _is_seeds(name) else [])
    if overrides:
        facts.append("overrides " + ", ".join(f"`{o}`" for o in overrides))
    commit = table.get("commit")
    if commit:
        facts.append(f"written at commit {commit}" + (" from a tree with uncommitted changes"
                                                      if table.get("dirty") else " (clean tree)"))
    lines += ["; ".join(facts) + ".", ""]
    kind = _kind(table)
    if kind == "figure":
        lines += _render_figure(table)
    elif kind == "comparison":
        lines += _render_comparison(table)
    elif kind == "measures":
        lines += _render_measures(table)
    elif kind == "sweep":
        lines += _render_sweep(table)
    else:
        lines.append("(no rows)")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- inputs
def load_tables(folder: Path) -> dict[str, dict]:
    """Every table JSON under `folder` (figures/tables/), keyed by its path relative to it
    ("seeds_reduced.json", "variants/restarts_64/seeds_reduced.json"); a JSON that is not a
    table (no "rows") is skipped. Top-level tables first, then subfolders, each sorted; a seeds
    table's rows by seed (a run may measure them in any order)."""
    found = {}
    for path in sorted(Path(folder).rglob("*.json"), key=lambda p: (len(p.relative_to(folder).parts), str(p))):
        data = json.loads(path.read_text(encoding="utf-8"))
        if isinstance(data, dict) and isinstance(data.get("rows"), list):
            if all(isinstance(r, dict) and isinstance(r.get("seed"), int) for r in data["rows"]):
                data["rows"] = sorted(data["rows"], key=lambda r: r["seed"])
            found[path.relative_to(folder).as_posix()] = data
    return found


def load_times(path: Path) -> dict:
    """figures/notebook_times.json ({"seconds": {notebook: s}, "commit", ...}), or {}."""
    path = Path(path)
    return json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}


def notebook_titles(folder: Path) -> dict[str, str]:
    """{"00_overview": "Neural Constraint Satisfaction: an overview", ...}: each notebook's
    title, the first line of its first markdown cell without "# NN ·"."""
    titles = {}
    for path in sorted(Path(folder).glob("[0-9][0-9]_*.ipynb")):
        cells = json.loads(path.read_text(encoding="utf-8")).get("cells", [])
        first = next((c for c in cells if c.get("cell_type") == "markdown"), None)
        text = "".join(first["source"]) if first else ""
        line = text.strip().splitlines()[0] if text.strip() else path.stem
        titles[path.stem] = re.sub(r"^#+\s*\d+\s*[·:.-]?\s*", "", line).strip()
    return titles


# --------------------------------------------------------------------------- the README
def _top(tables: dict, prefix: str | tuple[str, ...]) -> list[tuple[str, dict]]:
    return [(p, t) for p, t in tables.items() if "/" not in p and (t.get("table") or Path(p).stem).startswith(prefix)]


def _headline_rows(tables: dict) -> list[tuple[str, str, dict, str]]:
    """(environment, label, {objects: cell}, command) of the headline numbers: each
    environment's success over training seeds (mean ± sd and the worst seed; a value that
    every seed shares, such as the oracle's, with its interval), or, for an environment
    without a seeds table yet, one training seed's table (`reproduce robogym`)."""
    seeded = {_env(t) for _, t in _top(tables, "seeds_")}
    sources = _top(tables, "seeds_") + [(p, t) for p, t in _top(tables, ENV_TABLE_PREFIXES) if _env(t) not in seeded]
    found: dict[tuple[str, str], tuple[dict, str]] = {}
    for path, table in sources:
        rows = table["rows"]
        for column, label, kind, better in _measure_columns(table):
            numbers = _column(column)[1]
            if kind != "rate" or not numbers or column.endswith("_constraints") or "_independent_" in column:
                continue          # the rows without the dependency rules: docs/results.md
            label = label.rsplit(",", 1)[0]           # "`ncs` on masks, 4 objects" -> "`ncs` on masks"
            learned = label.startswith("`ncs` on")   # a trained model's success; the others are references
            if learned:
                label += f", {len(rows)} training seeds" if len(rows) > 1 else ", one training seed"
            if len(rows) > 1 and (learned or not _constant(table, column)):
                cell = _seeds_cell(table, column, kind, better)
            else:
                cell = _cell(rows[0], column, kind)
            cells, _ = found.setdefault((_env(table), label), ({}, table_command(path, table)))
            cells[numbers[0]] = cell
    order = {e: i for i, e in enumerate(HEADLINE_ENVS)}
    keys = sorted(found, key=lambda key: order.get(key[0], len(order)))     # stable: table order within an env
    return [(env, label, *found[env, label]) for env, label in keys]


FIGURE_TABLES = ("fig9", "fig10", "fig11")      # Appendix D's, in the paper's order


def _claims_rows(tables: dict) -> list[list[str]]:
    """[figure, statement, our number, verdict] of the kit's NCS for every claim of the
    figure tables (the as-written row's claims stay in docs/results.md); a claim checked
    against several baselines (`ratio_claim` rows with a `denominator`) becomes one row."""
    rows = []
    for figure in FIGURE_TABLES:
        for path, table in _top(tables, figure + "_"):
            grouped: dict[str, list[dict]] = {}
            for claim in table.get("claims") or []:
                if "(ncs-paper)" in claim["statement"]:
                    continue
                key = claim["statement"]
                if "denominator" in claim:             # one row for "at least 50x each of them"
                    key = key.replace(claim["denominator"]["label"].split(" at ")[0], "X", 1)
                grouped.setdefault(key, []).append(claim)
            for key, group in grouped.items():
                name = f"Fig. {figure[3:]}"
                if len(group) == 1:
                    c = group[0]
                    rows.append([name, c["statement"], c.get("ours", ""), f"**{c['verdict']}**: {c['reason']}"])
                    continue
                statement = key.replace("baseline X", "baselines").replace(" X ", " each of them ")
                ours = "; ".join(f"{c['denominator']['label']}: {c.get('ours', '')}" for c in group)
                verdicts = "; ".join(f"{c['denominator']['label'].split(' at ')[0]} **{c['verdict']}**" for c in group)
                rows.append([name, statement, ours, verdicts])
    return rows


def render_results_block(tables: dict) -> str:
    """The README's `results` block: the headline table, the main comparison on each
    environment (complete goals) and one provenance sentence."""
    lines = []
    head = _headline_rows(tables)
    if head:
        counts = sorted({k for _, _, cells, _ in head for k in cells})
        horizon = BlockRearrangeConfig.horizon_multiplier      # the horizon every table's tasks use
        lines += [f"Share of seeded tasks solved (complete goals, horizon {horizon:g}x the fewest moves). Over "
                  "training seeds: mean ± sd (worst seed); otherwise the value with its 95 % Wilson interval.", ""]
        body = [[f"{env}: {label}", *(cells.get(k, "–") for k in counts), f"`{command}`"]
                for env, label, cells, command in head]
        lines += _markdown(["result", *(f"{k} objects" for k in counts), "written by"], body) + [""]
    for path, table in _top(tables, "baselines_"):
        if _env(table) not in README_COMPARISONS:
            lines += [f"**Main comparison, {_env(table)}**: [docs/results.md](docs/results.md) "
                      f"(`{table_command(path, table)}`).", ""]
            continue
        mpc = table.get("mpc_episodes")
        measured = any("constraints" in r for r in table["rows"])
        lines += [f"**Main comparison, {_env(table)}**, complete goals, {table.get('episodes')} tasks per cell"
                  + (f" (`mpc`: {mpc})" if mpc else "") + f": `{table_command(path, table)}` "
                  + ("(partial goals and the share of constraints satisfied: " if measured else "(partial goals: ")
                  + "[docs/results.md](docs/results.md)).", ""]
        lines += _render_comparison(table, goals=["complete"], notes=False, constraints=False) + [""]
    if lines:
        lines.append("Success with its 95 % Wilson interval; in brackets the share of random actions where it is "
                     "not 0, and the number of tasks where a method ran on fewer.")
        lines.append("")
    claims = _claims_rows(tables)
    if claims:
        lines += ["**Appendix D's claims** (robogym-rearrange, 4 objects, complete goals; each figure's panels in "
                  "[docs/results.md](docs/results.md), drawn by notebooks 08-10):", ""]
        lines += _markdown(["figure", "the paper says", "we measure", "verdict"], claims) + [""]
    used = _top(tables, "seeds_") + _top(tables, "baselines_") + [
        (p, t) for p, t in _top(tables, ENV_TABLE_PREFIXES) if _env(t) not in {_env(s) for _, s in _top(tables, "seeds_")}] + [
        (p, t) for figure in FIGURE_TABLES for p, t in _top(tables, figure + "_")]
    commits = {t.get("commit") for _, t in used}
    dirty = [f"`{Path(p).stem}`" for p, t in used if t.get("dirty")]
    if used:
        lines.append(f"Provenance: the {len(used)} " + ("tables above were" if len(used) > 1 else "table above was")
                     + " written by their commands at "
                     f"{len(commits)} commit{'s' if len(commits) > 1 else ''}"
                     + (f", from a dirty tree: {', '.join(dirty)}" if dirty else ", each from a clean tree")
                     + "; each table's commit, inputs and parameters are in [docs/results.md](docs/results.md).")
    else:
        lines.append("No tables yet: `python -m ncs_lite reproduce TABLE` writes them to `figures/tables/`.")
    return "\n".join(lines)


def _split_times(times: dict) -> dict[str, dict[str, float]]:
    """{notebook: {env: seconds}} from notebook_times.json's "<name>", "<name>_robogym" and
    "<name>_stacking" (`utils.split_notebook_run`)."""
    out: dict[str, dict[str, float]] = {}
    for key, seconds in (times.get("seconds") or {}).items():
        name, env = split_notebook_run(key)
        out.setdefault(name, {})[env] = float(seconds)
    return out


def _time_commits(times: dict) -> str:
    """The commit the notebook times were measured at ("commit abc1234"), or, when notebooks
    last ran at different commits (a partial rerun), each commit with the envs whose
    notebooks ran there ("commits abc1234 (block-rearrange, robogym-rearrange), def5678
    (block-stacking)"); "" when none is recorded. A notebook without its own commit
    ("commits", `record_notebook_time`) ran at the file's "commit"."""
    envs_at: dict[str, list[str]] = {}
    for key in times.get("seconds") or {}:
        commit = (times.get("commits") or {}).get(key, times.get("commit"))
        if commit:
            env = split_notebook_run(key)[1]
            if env not in envs_at.setdefault(commit, []):
                envs_at[commit].append(env)
    if len(envs_at) <= 1:
        return f"commit {next(iter(envs_at))}" if envs_at else ""
    return "commits " + ", ".join(f"{c} ({', '.join(e)})" for c, e in envs_at.items())


def _timed_envs(per: dict[str, dict[str, float]]) -> tuple[str, ...]:
    """The envs of the times' columns: block-rearrange and robogym-rearrange always, the others
    once some notebook has a time on them."""
    return tuple(e for e in NOTEBOOK_ENVS if e in BLOCK_ENVS or any(e in t for t in per.values()))


def render_times_block(times: dict) -> str:
    """The README's `times` block: what `make reproduce` took, from figures/notebook_times.json."""
    per = _split_times(times)
    if not per:
        return "`make reproduce` has not recorded its times yet (`figures/notebook_times.json`)."
    by_env = {env: sum(t.get(env, 0.0) for t in per.values()) for env in _timed_envs(per)}
    total = sum(by_env.values())
    preset = times.get("preset", DEFAULT_PRESET)
    commits = _time_commits(times)
    mixed = commits.startswith("commits ")
    text = (("The notebooks' last runs took " if mixed else "The last `make reproduce` ran the notebooks in ")
            + f"{format_seconds(total)} at `{preset}` "
            f"({format_seconds(by_env['block-rearrange'])} on block-rearrange, "
            f"{format_seconds(by_env['robogym-rearrange'])} for notebooks 04-07 on robogym-rearrange"
            + "".join(f", {format_seconds(by_env[env])} on {env}" for env in by_env if env not in BLOCK_ENVS)
            + "; one thread per process" + (f", {commits}" if mixed else "")
            + ", `figures/notebook_times.json`)")
    others = total - by_env["block-rearrange"]
    if preset == DEFAULT_PRESET and total > 60 * REPRODUCE_TARGET_MINUTES and others > 0:
        text += (f", over the {REPRODUCE_TARGET_MINUTES}-minute target: notebooks 04-07 run once more on each "
                 f"other environment, {format_seconds(others)} on top of block-rearrange's series")
    run = times.get("run")
    if not run:
        return text + "; creating `.venv` the first time comes on top."
    start = {(True, True): "a fresh clone (no `.venv`, no `.cache`)", (True, False): "no `.venv`",
             (False, True): "an empty `.cache`", (False, False): "`.venv` and `.cache` in place"}
    return (text + f"; the last whole run, from {start[run['venv_created'], run['cache_was_empty']]}, took "
            f"{format_seconds(run['seconds'])} of wall time on {run.get('cores', '?')} cores.")


def render_notebooks_block(times: dict, titles: dict) -> str:
    """The README's `notebooks` block: one line per notebook with its measured time."""
    per = _split_times(times)
    lines = []
    for name, title in titles.items():
        t = per.get(name, {})
        took = format_seconds(t["block-rearrange"]) if "block-rearrange" in t else "not measured yet"
        for env in NOTEBOOK_ENVS[1:]:
            if env in t:
                took += f"; on {env} {format_seconds(t[env])}"
        lines.append(f"- [`{name}`](notebooks/{name}.ipynb): {title} ({took})")
    return "\n".join(lines) if lines else "(no notebooks found)"


def readme_blocks(tables: dict, times: dict, titles: dict) -> dict[str, str]:
    """{block name: its content} for the README."""
    return {"results": render_results_block(tables), "times": render_times_block(times),
            "notebooks": render_notebooks_block(times, titles)}


def replace_block(text: str, name: str, content: str, where: str = "README.md") -> str:
    """`text` with the lines between `<!-- name:begin -->` and `<!-- name:end -->` replaced by
    `content`; ValueError naming the file and the markers when they are missing or repeated."""
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise ValueError(f"{where} must hold the marker lines {begin} and {end} once each, in that order "
                         "(the generated block goes between them)")
    i, j = text.index(begin) + len(begin), text.index(end)
    return text[:i] + "\n" + content.strip("\n") + "\n" + text[j:]


# --------------------------------------------------------------------------- docs/recipe.md
ABLATIONS = "ablations"        # figures/tables/ablations/<name>/: drop-one ablations of the recipe
# the headlines an ablation is judged by: NCS on masks at 4 and 7 objects, on slot states at 7,
# NCS on masks and fg-ARI at 7 with one slot-attention pass (the measures the recipe's targets name)
ABLATION_COLUMNS = ("ncs_4", "ncs_7", "ncs_slot_7", "ncs_7_r1", "fg_ari_7_r1")


def _recipe_fields(table: dict) -> dict[str, str]:
    """{field: value} of a seeds table's `--set` list (the last one of a field wins)."""
    return dict(str(o).split("=", 1) for o in table.get("overrides") or [])


def _undone(table: dict, reference: dict) -> list[str] | None:
    """The `--set` list that turns `reference`'s recipe into `table`'s, or None when `table`
    is not `reference` with more overrides (another preset, env or reading of the tasks, or a
    field `reference` sets that `table` leaves at the preset's value)."""
    same = ("env", "preset", "objects", "episodes", "ncs")
    if any(table.get(k) != reference.get(k) for k in same):
        return None
    mine, theirs = _recipe_fields(table), _recipe_fields(reference)
    if not set(theirs) <= set(mine):
        return None
    return [f"{f}={v}" for f, v in mine.items() if theirs.get(f) != v]


def _ablation_reference(path: str, table: dict, tables: dict) -> tuple[str, dict, list[str]] | None:
    """(path, table, undone) of the seeds table an ablation is measured against: of the other
    seeds tables (ablations/ included, for a reference trained segmentation-only), the one it
    extends by the fewest fields, a top-level table first on a tie."""
    found = []
    for other_path, other in tables.items():
        if other_path == path or not _is_seeds(other.get("table") or Path(other_path).stem):
            continue
        undone = _undone(table, other)
        if undone:
            found.append((len(undone), other_path.count("/"), other_path, other, undone))
    return min(found, key=lambda f: f[:3])[2:] if found else None


def _moved(table: dict, reference: dict) -> list[str] | None:
    """The headlines (ABLATION_COLUMNS) whose mean over seeds differs from the reference's by
    more than the larger of the two standard deviations: "`ncs` on masks, 7 objects 0.95 -> 0.60".
    A headline is compared only where both tables have a spread (two seeds or more); None when
    none is."""
    moved, compared = [], False
    for column in ABLATION_COLUMNS:
        a, b = _summary(table, column), _summary(reference, column)
        if not a or not b or min(a["n"], b["n"]) < 2:
            continue
        compared = True
        if abs(a["mean"] - b["mean"]) > max(float(a["sd"]), float(b["sd"])):
            _, _, template, groups, kind, _ = _column(column)
            label = _label(template, groups, _state(table))
            moved.append(f"{label} {format_value(b['mean'], kind)} -> {format_value(a['mean'], kind)}")
    return moved if compared else None


def _headline_cells(table: dict) -> list[str]:
    """The ABLATION_COLUMNS of a seeds table, each over its seeds ("–" where it has none)."""
    return [_seeds_cell(table, c, *_column(c)[4:]) if _summary(table, c) else "–" for c in ABLATION_COLUMNS]


def render_ablations_block(tables: dict) -> str:
    """docs/recipe.md's `ablations` block: each seeds table under figures/tables/ablations/
    beside the recipe it undoes departures of (`_ablation_reference`), its headlines over
    training seeds (mean ± sd, worst seed) and which of them move beyond the seeds' spread."""
    ablations = {p: t for p, t in tables.items() if p.startswith(ABLATIONS + "/") and _is_seeds(t.get("table") or "")}
    lines = ["Generated by `python -m ncs_lite.docs` from `figures/tables/ablations/` (each table's command: "
             "[results.md](results.md)). Each row is measured against the seeds table of the recipe it undoes "
             "departures of, with the same schedule and reading; a headline **moves** when the two means over "
             "seeds differ by more than the larger of their two standard deviations. Cells: mean ± sd "
             "(worst seed).", ""]
    header = ["undone (`--set`)", "seeds", "`ncs` on masks, 4", "`ncs` on masks, 7", "`ncs` on slot states, 7",
              "`ncs` on masks, 7, one pass", "fg-ARI 7, one start", "verdict"]
    body, shown = [], set()         # each reference's own row once, before its first ablation
    for path, table in ablations.items():
        found = _ablation_reference(path, table, tables)
        if found is None:
            body.append([f"`{path}`: no seeds table of a recipe it extends", str(len(table["rows"])),
                         *_headline_cells(table), "–"])
            continue
        ref_path, reference, undone = found
        if ref_path not in shown:
            shown.add(ref_path)
            body.append([f"the recipe: `{ref_path}`", str(len(reference["rows"])), *_headline_cells(reference), ""])
        moved = _moved(table, reference)
        if moved is None:
            verdict = "none yet: one seed, no spread"
        elif moved:
            verdict = "**moves**: " + "; ".join(moved)
        else:
            verdict = "within the seeds' spread"
        body.append([" ".join(f"`{u}`" for u in undone), str(len(table["rows"])), *_headline_cells(table), verdict])
    if not body:
        return "\n".join(lines[:1] + ["", "No ablation has been run yet."]) + "\n"
    return "\n".join(lines + _markdown(header, body)) + "\n"


# --------------------------------------------------------------------------- docs/results.md
def render_results_md(tables: dict, times: dict, titles: dict) -> str:
    """docs/results.md: the notebook times and every table under figures/tables/."""
    lines = ["# Results", "",
             "Generated by `python -m ncs_lite.docs` from `figures/tables/**/*.json` and "
             "`figures/notebook_times.json`: do not edit by hand. Each section names the command that "
             "regenerates its table, read from the table's own metadata; the dated measurements that no "
             "command of this commit regenerates are in [HISTORY.md](HISTORY.md).", "",
             "Tables in subfolders are kept beside the main ones: `shipped/` measures the shipped checkpoint "
             "alone, `variants/` a recipe or reading that was tried and not adopted (its overrides in its "
             "command), `ablations/` the recipe with one departure from Table 2 undone "
             "([recipe.md](recipe.md#drop-one-ablations)).", ""]
    lines += ["Contents: [notebook times](#notebook-times)"
              + "".join(f", [`{p}`](#{_anchor(p)})" for p in tables), ""]
    per = _split_times(times)
    lines += ["## Notebook times", ""]
    if per:
        commits = _time_commits(times)
        lines.append(f"`make reproduce` at `{times.get('preset', DEFAULT_PRESET)}`, one thread per process"
                     + (f", {commits}" if commits else "")
                     + (" (dirty tree)" if times.get("dirty") else "") + ":")
        lines.append("")
        envs = _timed_envs(per)
        body = [[f"`{name}`", *(format_seconds(t[e]) if e in t else "–" for e in envs)]
                for name, t in per.items()]
        body.append(["all", *(format_seconds(sum(t.get(e, 0.0) for t in per.values())) for e in envs)])
        lines += _markdown(["notebook", *envs], body)
    else:
        lines.append("Not recorded yet (`make reproduce` writes `figures/notebook_times.json`).")
    lines.append("")
    for path, table in tables.items():
        lines.append(render_table(path, table))
    return "\n".join(lines).rstrip("\n") + "\n"


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading `` `heading` ``: lower case, punctuation but - and _ dropped."""
    return re.sub(r"[^a-z0-9_\- ]", "", heading.lower()).replace(" ", "-")


# --------------------------------------------------------------------------- writing
def write_docs(check: bool = False, root: str | Path | None = None) -> list[str]:
    """Write the README's blocks and docs/results.md from the tables under `root` (default:
    the repo). With `check`, write nothing. Returns what differs from the committed text, one
    entry per file ("README.md (blocks: results, times)", "docs/results.md"): empty when
    everything is current."""
    root = Path(root) if root is not None else REPO_DIR
    tables = load_tables(root / "figures" / "tables")
    times = load_times(root / "figures" / "notebook_times.json")
    titles = notebook_titles(root / "notebooks")
    readme_path = root / "README.md"
    readme = readme_path.read_text(encoding="utf-8")
    new_readme, stale_blocks = readme, []
    for name, content in readme_blocks(tables, times, titles).items():
        replaced = replace_block(new_readme, name, content)
        if replaced != new_readme:
            stale_blocks.append(name)
        new_readme = replaced
    results_path = root / "docs" / "results.md"
    results = render_results_md(tables, times, titles)
    stale = []
    if stale_blocks:
        stale.append(f"README.md (blocks: {', '.join(stale_blocks)})")
    recipe_path = root / "docs" / "recipe.md"          # optional: a tree without it has no ablations block
    recipe = recipe_path.read_text(encoding="utf-8") if recipe_path.exists() else None
    new_recipe = recipe and replace_block(recipe, "ablations", render_ablations_block(tables), "docs/recipe.md")
    if new_recipe != recipe:
        stale.append("docs/recipe.md (block: ablations)")
    old_results = results_path.read_text(encoding="utf-8") if results_path.exists() else None
    if old_results != results:
        stale.append("docs/results.md")
    if not check:
        if stale_blocks:
            atomic_write_text(readme_path, new_readme)
        if old_results != results:
            atomic_write_text(results_path, results)
        if new_recipe != recipe:
            atomic_write_text(recipe_path, new_recipe)
    return stale


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ncs_lite.docs", description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="compare only; exit 1 naming each file whose generated text is out of date")
    args = parser.parse_args(argv)
    stale = write_docs(check=args.check)
    if args.check:
        for entry in stale:
            print(f"out of date: {entry} (run `python -m ncs_lite.docs`)")
        return 1 if stale else 0
    print("rewrote " + ", ".join(stale) if stale else "README.md and docs/results.md were current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
