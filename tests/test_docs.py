"""The README's generated blocks and docs/results.md (`python -m ncs_lite.docs`): the committed
text is what the generator writes from the committed tables, and the rendering of tiny made-up
tables gives the numbers, intervals, worst seeds and commands expected."""
from __future__ import annotations

import copy
import json
import re

import pytest

from ncs_lite.docs import (format_mean_sd, format_value, render_results_block, render_table, replace_block,
                           table_command, write_docs)
from ncs_lite.utils import REPO_DIR

# a seeds table of the shape `reproduce seeds --env robogym-rearrange` writes, two seeds
SEEDS = {
    "table": "seeds_robogym_reduced", "env": "robogym-rearrange", "preset": "reduced", "seeds": [0, 1],
    "objects": [4, 5, 6, 7], "episodes": 100, "overrides": ["train.epochs=2"], "ncs_overrides": [],
    "ncs": {"state": "slot", "clusters": 45, "edge_action": "nearest", "restarts": None, "align": "near"},
    "commit": "abc1234", "dirty": False, "shipped_seed": 1, "shipped_rule": "the lowest held-out error",
    "rows": [
        {"seed": 0, "ncs_4": 0.9, "ncs_4_ci": "[0.83, 0.94]", "ncs_oracle_4": 0.98, "ncs_oracle_4_ci": "[0.93, 0.99]",
         "heldout_error": 0.05, "pairs_4_r1": "red+pink 3", "random_fraction_4": 0.02},
        {"seed": 1, "ncs_4": 0.7, "ncs_4_ci": "[0.61, 0.78]", "ncs_oracle_4": 0.98, "ncs_oracle_4_ci": "[0.93, 0.99]",
         "heldout_error": 0.04, "pairs_4_r1": "", "random_fraction_4": 0.30},
    ],
    # the table's own summary is what is printed (here deliberately not what the rows give)
    "summary": {"ncs_4": {"mean": 0.8, "sd": 0.25, "n": 2}, "ncs_oracle_4": {"mean": 0.98, "sd": 0.0, "n": 2}},
}
SINGLE = {"table": "robogym_reduced", "env": "robogym-rearrange", "episodes": 100, "objects": [4, 5, 6, 7],
          "checkpoint": "ncs_lite/assets/dslate.pt", "commit": "def5678", "dirty": False,
          "ncs": {"state": "slot"}, "rows": [{"ncs_4": 0.63, "ncs_4_ci": "[0.53, 0.72]"}]}
COMPARISON = {
    "table": "baselines_reduced", "env": "block-rearrange", "preset": "reduced", "episodes": 50, "mpc_episodes": 25,
    "commit": "0123abc", "dirty": True,
    "rows": [
        {"method": "ncs", "goal": "complete", "num_objects": 4, "episodes": 50, "success": 0.98,
         "ci_low": 0.895, "ci_high": 0.9965, "random_fraction": 0.07},
        {"method": "mpc", "goal": "complete", "num_objects": 4, "episodes": 25, "success": 0.56,
         "ci_low": 0.3704, "ci_high": 0.7330, "random_fraction": 0.0},
        {"method": "ncs", "goal": "partial", "num_objects": 4, "episodes": 50, "success": 1.0,
         "ci_low": 0.9287, "ci_high": 1.0, "random_fraction": 0.0},
    ],
}


def test_committed_readme_block_and_results_are_generated():
    stale = write_docs(check=True)
    assert stale == [], f"out of date: {stale}; run `python -m ncs_lite.docs` and commit the result"


def test_seeds_table_gives_each_seed_mean_sd_and_the_worst_seed():
    text = render_table("seeds_robogym_reduced.json", SEEDS)
    ncs = next(line for line in text.splitlines() if line.startswith("| `ncs` on slot states, 4 objects"))
    assert ncs.split(" | ")[1:] == ["0.90 [0.83, 0.94]", "0.70 [0.61, 0.78]", "0.80 ± 0.25", "0.70 (seed 1) |"]
    # lower is better for the held-out error: its worst seed is the highest; no summary: computed (sd n - 1)
    held = next(line for line in text.splitlines() if line.startswith("| held-out reconstruction error"))
    assert held.split(" | ")[1:] == ["0.05", "0.04", "0.045 ± 0.00707", "0.05 (seed 0) |"]
    # the same for every seed (the oracle): no worst seed
    oracle = next(line for line in text.splitlines() if line.startswith("| `ncs-oracle`"))
    assert oracle.endswith("| 0.98 ± 0.00 |  |")
    assert "| 2.0 % | 30 % |" in text                   # shares of actions as percentages
    assert "red+pink" not in text                     # only the columns of interest
    assert "**shipped**" in text.splitlines()[-1].split(" | ")[2]     # seed 1's column
    assert "written at commit abc1234 (clean tree)" in text


def test_comparison_table_gives_intervals_random_share_and_smaller_n():
    text = render_table("baselines_reduced.json", COMPARISON)
    assert "| `ncs` | 0.98 [0.90, 1.00] (7.0 % random) |" in text
    assert "| `mpc` | 0.56 [0.37, 0.73] (n = 25) |" in text
    assert "*partial goals*" in text and "| `ncs` | 1.00 [0.93, 1.00] |" in text
    assert "from a tree with uncommitted changes" in text


def test_the_share_of_constraints_satisfied_is_shown_where_a_table_has_it():
    # a comparison table with `constraints`: a second table per goal kind, in docs/results.md only
    rows = [{**r, "constraints": c, "constraints_ci_low": c - 0.05, "constraints_ci_high": min(1.0, c + 0.05)}
            for r, c in zip(COMPARISON["rows"], (0.99, 0.8, 1.0))]
    table = {**COMPARISON, "rows": rows}
    text = render_table("baselines_reduced.json", table)
    assert "*complete goals, share of constraints satisfied*" in text
    assert "| `mpc` | 0.80 [0.75, 0.85] |" in text and "| `ncs` | 1.00 [0.95, 1.00] |" in text
    assert "| `ncs` | 0.98 [0.90, 1.00] (7.0 % random) |" in text          # success as before
    readme = render_results_block({"baselines_reduced.json": table})
    assert "share of constraints satisfied: [docs/results.md]" in readme and "0.80 [0.75" not in readme
    # an old table without them renders as before
    assert "constraints" not in render_table("baselines_reduced.json", COMPARISON)
    assert "constraints" not in render_results_block({"baselines_reduced.json": COMPARISON})
    # a seeds table: its own rows with their interval, not in the headline (the share of tasks solved)
    seeds = copy.deepcopy(SEEDS)
    for row, c in zip(seeds["rows"], (0.95, 0.85)):
        row.update(ncs_4_constraints=c, ncs_4_constraints_ci=f"[{c - 0.03:.2f}, {c + 0.03:.2f}]")
    text = render_table("seeds_robogym_reduced.json", seeds)
    line = next(x for x in text.splitlines() if x.startswith("| `ncs` on slot states, share of constraints"))
    assert line.split(" | ")[1:] == ["0.95 [0.92, 0.98]", "0.85 [0.82, 0.88]", "0.90 ± 0.07", "0.85 (seed 1) |"]
    assert "share of constraints" not in render_results_block({"seeds_robogym_reduced.json": seeds})


def test_command_is_rebuilt_from_the_tables_metadata():
    assert table_command("variants/short/seeds_robogym_reduced.json", SEEDS) == (
        "python -m ncs_lite reproduce seeds --seeds 0 1 --env robogym-rearrange --set train.epochs=2 "
        "--runs .cache/seeds-short --out-dir figures/tables/variants/short")
    # a table written before `ncs_overrides` was recorded: the override read from its `ncs` section
    old = {**copy.deepcopy(SEEDS), "overrides": [], "env": "block-rearrange", "objects": [4, 7]}
    del old["ncs_overrides"]
    old["ncs"]["restarts"] = 8
    assert table_command("seeds_reduced.json", old) == \
        "python -m ncs_lite reproduce seeds --seeds 0 1 --set ncs.restarts=8"
    # the shipped seed measured on tasks no other table uses
    assert table_command("shipped/seeds_reduced.json", {**old, "seeds": [2], "task_seed": 1}) == (
        "python -m ncs_lite reproduce seeds --seeds 2 --task-seed 1 --set ncs.restarts=8 "
        "--out-dir figures/tables/shipped")
    assert table_command("baselines_reduced.json", COMPARISON) == \
        "python -m ncs_lite reproduce baselines --episodes 50 --mpc-episodes 25"
    assert table_command("robogym_reduced.json", SINGLE) == "python -m ncs_lite reproduce robogym"
    assert table_command("robogym_reduced.json", {**SINGLE, "objects": [4], "checkpoint": "other.pt"}) == \
        "python -m ncs_lite reproduce robogym --checkpoint other.pt --objects 4"
    # a table that recorded its thread count: the command sets it (the condition for the same digits)
    assert table_command("robogym_reduced.json", {**SINGLE, "threads": 1}) == \
        "OMP_NUM_THREADS=1 python -m ncs_lite reproduce robogym"


def test_headline_prefers_a_seeds_table_and_skips_absent_ones():
    with_seeds = render_results_block({"seeds_robogym_reduced.json": SEEDS, "robogym_reduced.json": SINGLE})
    assert "robogym-rearrange: `ncs` on slot states, 2 training seeds | 0.80 ± 0.25 (0.70) |" in with_seeds
    assert "robogym-rearrange: `ncs-oracle` (ground truth) | 0.98 [0.93, 0.99] |" in with_seeds
    assert "reproduce robogym" not in with_seeds and "def5678" not in with_seeds
    without = render_results_block({"robogym_reduced.json": SINGLE})
    assert "robogym-rearrange: `ncs` on slot states, one training seed | 0.63 [0.53, 0.72] |" in without
    assert "`python -m ncs_lite reproduce robogym`" in without
    assert "Main comparison" not in without                # no baselines table: no comparison


def test_formats():
    assert format_value(0.987, "rate") == "0.99" and format_value(0.0125, "num3") == "0.013"
    assert format_value(0.041, "pct") == "4.1 %" and format_value(0.5, "pct") == "50 %"
    assert format_value(1323, "int") == "1,323" and format_value(float("nan")) == "n/a"
    assert format_mean_sd(28.4, 1.08, "min") == "28.4 ± 1.1 min"


def test_replace_block_names_missing_markers():
    text = "a\n<!-- results:begin -->\nold\n<!-- results:end -->\nb\n"
    assert replace_block(text, "results", "new") == "a\n<!-- results:begin -->\nnew\n<!-- results:end -->\nb\n"
    with pytest.raises(ValueError, match=r"README.md must hold the marker lines <!-- times:begin -->"):
        replace_block(text, "times", "new")


def test_write_docs_on_a_tree_with_and_without_an_optional_table(tmp_path):
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "notebooks" / "00_overview.ipynb").write_text(json.dumps(
        {"cells": [{"cell_type": "markdown", "source": ["# 00 · An overview\n", "text"]}]}))
    tables = tmp_path / "figures" / "tables"
    tables.mkdir(parents=True)
    (tables / "seeds_robogym_reduced.json").write_text(json.dumps(SEEDS))
    (tmp_path / "figures" / "notebook_times.json").write_text(json.dumps({"seconds": {"00_overview": 75.0}}))
    blocks = "".join(f"<!-- {b}:begin -->\n<!-- {b}:end -->\n" for b in ("results", "times", "notebooks"))
    (tmp_path / "README.md").write_text("# kit\n" + blocks)
    assert write_docs(check=True, root=tmp_path) == ["README.md (blocks: results, times, notebooks)",
                                                     "docs/results.md"]
    assert not (tmp_path / "docs").exists()                 # check writes nothing
    write_docs(root=tmp_path)
    assert write_docs(check=True, root=tmp_path) == []
    readme = (tmp_path / "README.md").read_text()
    assert "- [`00_overview`](notebooks/00_overview.ipynb): An overview (1.2 min)" in readme
    assert "0.80 ± 0.25 (0.70)" in readme
    (tables / "seeds_robogym_reduced.json").unlink()          # an optional table not written yet
    assert write_docs(check=True, root=tmp_path) == ["README.md (blocks: results)", "docs/results.md"]
    write_docs(root=tmp_path)
    assert "0.80 ± 0.25" not in (tmp_path / "README.md").read_text()


def test_links_in_readme_and_docs_point_to_files_that_exist():
    missing = []
    for page in [REPO_DIR / "README.md", *sorted((REPO_DIR / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://", "#", "mailto:")):
                continue
            if not (page.parent / target.split("#")[0]).exists():
                missing.append(f"{page.relative_to(REPO_DIR)}: {target}")
    assert missing == []


def test_the_readme_lists_appendix_d_claims_one_row_per_statement():
    from ncs_lite.docs import _claims_rows, render_results_block

    def ratio(num, den, verdict):
        return {"statement": f"NCS ({num}) at a 1x horizon reaches at least 50x the success of the model-based "
                             f"baseline {den} at 8x", "numerator": {"label": f"{num} at 1x"},
                "denominator": {"label": f"{den} at 8x"}, "ours": f"ratio for {den}", "verdict": verdict,
                "reason": "r"}

    claims = [ratio("ncs", "mpc", "not testable"), ratio("ncs", "nf", "held"), ratio("ncs-paper", "mpc", "not held"),
              {"statement": "NF performs similar to the random baseline", "ours": "gap 0.00", "verdict": "held",
               "reason": "the gap's interval lies within +-0.1"}]
    rows = _claims_rows({"fig10_reduced.json": {"table": "fig10_reduced", "claims": claims, "rows": []}})
    assert [r[0] for r in rows] == ["Fig. 10", "Fig. 10"]
    assert rows[0][1].endswith("the model-based baselines at 8x") and "ncs-paper" not in " ".join(rows[0])
    assert rows[0][3] == "mpc **not testable**; nf **held**"
    assert rows[1][3].startswith("**held**")
    block = render_results_block({"fig10_reduced.json": {"table": "fig10_reduced", "claims": claims, "rows": [],
                                                          "commit": "abc1234"}})
    assert "Appendix D's claims" in block and "the 1 table above was written by their commands at 1 commit" in block
    assert "abc1234" not in block                   # the README names no commit: docs/results.md does


def test_the_times_block_quotes_the_whole_run_and_where_it_started():
    from ncs_lite.docs import render_times_block

    times = {"preset": "reduced", "seconds": {"00_overview": 60.0, "04_dslate_training_robogym": 120.0}}
    assert "comes on top" in render_times_block(times)             # no whole run recorded yet
    times["run"] = {"seconds": 600.0, "venv_created": True, "cache_was_empty": True, "cores": 2}
    text = render_times_block(times)
    assert "from a fresh clone (no `.venv`, no `.cache`), took 10.0 min of wall time on 2 cores" in text
    times["run"].update(venv_created=False, cache_was_empty=False)
    assert "`.venv` and `.cache` in place" in render_times_block(times)


def test_the_times_block_says_where_the_time_goes_over_the_target():
    from ncs_lite.docs import REPRODUCE_TARGET_MINUTES, render_times_block

    within = {"preset": "reduced", "seconds": {"04_dslate_training": 600.0, "04_dslate_training_robogym": 300.0}}
    assert "target" not in render_times_block(within)
    over = {"preset": "reduced", "seconds": {"04_dslate_training": 1500.0, "04_dslate_training_robogym": 400.0,
                                              "04_dslate_training_stacking": 200.0}}
    assert 60 * REPRODUCE_TARGET_MINUTES < 2100
    assert (f"over the {REPRODUCE_TARGET_MINUTES}-minute target: notebooks 04-07 run once more on each other "
            "environment, 10.0 min on top of block-rearrange's series") in render_times_block(over)
    assert "target" not in render_times_block({**over, "preset": "ci"})


def test_notebook_times_of_each_env_go_to_its_column():
    """make reproduce records notebooks 04-07's runs on the other envs as <name>_robogym and
    <name>_stacking: each lands in its env's column, and block-stacking's column appears only
    once it has a time (the committed README, without one, stays as it is)."""
    from ncs_lite.docs import render_notebooks_block, render_results_md, render_times_block

    times = {"preset": "reduced", "seconds": {"04_dslate_training": 60.0, "04_dslate_training_robogym": 120.0}}
    titles = {"04_dslate_training": "dSLATE"}
    text = render_times_block(times)
    assert "(1.0 min on block-rearrange, 2.0 min for notebooks 04-07 on robogym-rearrange; one thread" in text
    assert "block-stacking" not in text + render_notebooks_block(times, titles) + render_results_md({}, times, titles)
    times["seconds"]["04_dslate_training_stacking"] = 180.0
    assert "in 6.0 min at `reduced` (1.0 min on block-rearrange, 2.0 min for notebooks 04-07 on robogym-rearrange, " \
           "3.0 min on block-stacking; one thread" in render_times_block(times)
    assert render_notebooks_block(times, titles) == ("- [`04_dslate_training`](notebooks/04_dslate_training.ipynb): "
                                                     "dSLATE (1.0 min; on robogym-rearrange 2.0 min; on block-stacking 3.0 min)")
    results = render_results_md({}, times, titles)
    assert "| notebook | block-rearrange | robogym-rearrange | block-stacking |" in results
    assert "| `04_dslate_training` | 1.0 min | 2.0 min | 3.0 min |" in results


def test_a_notebooks_run_on_each_env_has_one_name():
    from ncs_lite.utils import notebook_run, split_notebook_run

    for env, name in (("block-rearrange", "06_action_selection"), ("robogym-rearrange", "06_action_selection_robogym"),
                      ("block-stacking", "06_action_selection_stacking")):
        assert notebook_run("06_action_selection", env) == name
        assert split_notebook_run(name) == ("06_action_selection", env)
    with pytest.raises(ValueError, match="env must be one of block-rearrange, robogym-rearrange, block-stacking, "
                                         "got 'stacking'"):
        notebook_run("06_action_selection", "stacking")


def test_times_of_a_partial_rerun_name_each_commit(tmp_path, monkeypatch):
    """A notebook rerun alone keeps its own commit, the times recorded before keep the file's,
    and the README and docs/results.md then name each commit with its envs, not one."""
    import json
    from ncs_lite.docs import render_results_md, render_times_block
    from ncs_lite.experiments import reproduce

    path = tmp_path / "notebook_times.json"
    path.write_text(json.dumps({"preset": "reduced", "commit": "aaaaaaa", "seconds": {"04_dslate_training": 60.0}}))
    monkeypatch.setattr(reproduce, "figures_dir", lambda: tmp_path)
    monkeypatch.setattr(reproduce, "git_commit", lambda: "bbbbbbb")
    reproduce.record_notebook_time("04_dslate_training_stacking", 180.0)
    times = dict(json.loads(path.read_text()), dirty=False)
    assert times["commits"] == {"04_dslate_training": "aaaaaaa", "04_dslate_training_stacking": "bbbbbbb"}
    text = render_times_block(times)
    assert text.startswith("The notebooks' last runs took 4.0 min") and \
        "commits aaaaaaa (block-rearrange), bbbbbbb (block-stacking)" in text
    assert "commits aaaaaaa (block-rearrange), bbbbbbb (block-stacking):" in render_results_md({}, times, {})
    times["commits"]["04_dslate_training"] = "bbbbbbb"                 # a whole run: one commit
    assert render_times_block(times).startswith("The last `make reproduce` ran the notebooks in 4.0 min")
    assert "one thread per process, commit bbbbbbb:" in render_results_md({}, times, {})


def test_the_recipe_names_every_departure_of_reduced_from_table_2():
    """docs/recipe.md's table of departures names every field in which `reduced` differs from
    `paper` (Table 2), and each field its first column names exists; a field a recipe change
    adds or moves must reach the table."""
    from ncs_lite.config import config_diff, get_preset, to_dict

    text = (REPO_DIR / "docs" / "recipe.md").read_text()
    table = text.split("| field |", 1)[1].split("\n\n", 1)[0]
    named = set(re.findall(r"`([a-z_]+\.[a-z_]+)`", table))
    paper, reduced = to_dict(get_preset("paper")), to_dict(get_preset("reduced"))
    differ = {d.split(":")[0] for d in config_diff(paper, reduced)} - {"name", "train.checkpoint_every"}
    assert differ <= named, sorted(differ - named)
    rows = [line.split("|")[1] for line in table.splitlines()[2:]]
    for field in {f for row in rows for f in re.findall(r"`([a-z_]+\.[a-z_]+)`", row)}:
        section, leaf = field.split(".")
        assert leaf in paper[section], field
    assert "`train.checkpoint_every`" in text                  # the one difference that changes no result


def test_an_ablation_is_measured_against_the_recipe_it_extends():
    """docs/recipe.md's ablations block: each table under ablations/ beside the seeds table of
    the recipe it undoes departures of (the closest one, a segmentation-only reference for a
    segmentation-only ablation), with the headlines that move beyond the seeds' spread."""
    from ncs_lite.docs import render_ablations_block

    def seeds(overrides, ncs_7):
        return {"table": "seeds_reduced", "env": "block-rearrange", "preset": "reduced", "objects": [4, 7],
                "episodes": 100, "ncs": {"state": "mask"}, "overrides": overrides, "seeds": [0, 1, 2],
                "rows": [{"seed": s, "ncs_4": 1.0, "ncs_7": v} for s, v in enumerate(ncs_7)]}

    seg = ["train.main_loss=mixture", "train.render_steps=0"]
    tables = {"seeds_reduced.json": seeds([], [0.9, 0.92, 0.94]),
              "ablations/no_prior/seeds_reduced.json": seeds(["slots.position_prior=0"], [0.5, 0.6, 0.7]),
              "ablations/segmentation_only/seeds_reduced.json": seeds(seg, [0.9, 0.9, 0.94]),
              "ablations/no_polish/seeds_reduced.json": seeds([*seg, "train.polish_steps=0"], [0.88, 0.9, 0.92]),
              "ablations/other_env/seeds_reduced.json": {**seeds(["train.epochs=2"], [0.9]), "env": "robogym-rearrange"},
              "ablations/one_seed/seeds_reduced.json": seeds(["train.epochs=2"], [0.5])}
    block = render_ablations_block(tables)
    rows = {line.split(" | ")[0].lstrip("| "): line for line in block.splitlines() if line.startswith("| ")}
    assert "0.92 ± 0.02 (0.90)" in rows["the recipe: `seeds_reduced.json`"]
    assert rows["`slots.position_prior=0`"].endswith("**moves**: `ncs` on masks, 7 objects 0.92 -> 0.60 |")
    # against the recipe trained segmentation-only, not the full one
    assert "the recipe: `ablations/segmentation_only/seeds_reduced.json`" in rows
    assert rows["`train.polish_steps=0`"].endswith("within the seeds' spread |")
    assert rows["`ablations/other_env/seeds_reduced.json`: no seeds table of a recipe it extends"]
    assert rows["`train.epochs=2`"].endswith("none yet: one seed, no spread |")       # one seed: no verdict
    header = next(line for line in block.splitlines() if line.startswith("| undone"))
    assert header.count("|") == rows["`train.epochs=2`"].count("|")              # a heading per column
    assert "No ablation has been run yet." in render_ablations_block({"seeds_reduced.json": tables["seeds_reduced.json"]})
