"""Sweeps (`sweeps.run_sweep`): the same rows in job order from the local pool and from
submitit; the claims of Figs. 10-11 (`stress`) on known numbers; bad settings refused."""
import math

import pytest

from ncs_lite.sweeps import EXECUTORS, MissingPackage, check_executor, run_sweep


# jobs run in new processes, which import a job's function by name: a builtin (`pow`) or the
# tables' own `evaluation.evaluate_job`, never a function of this test module
def random_jobs():
    """A cheap seeded sweep: `random` on robogym-rearrange's first tasks at two horizons."""
    from ncs_lite.evaluation import TaskSet

    def tasks(horizon, episodes):
        return TaskSet(env="robogym-rearrange", num_objects=4, horizon_multiplier=horizon, episodes=episodes, seed=0)
    return [("random", tasks(2.0, 2), {"cache": False}), ("random", tasks(1.0, 2), {"cache": False}),
            ("random", tasks(2.0, 1), {"cache": False, "seed": 3})]


def test_local_pool_keeps_job_order_whatever_the_start_order():
    jobs = [(i + 2, 3, 1000) for i in range(5)]
    expected = [pow(*job) for job in jobs]
    assert run_sweep(pow, jobs, workers=2, first=[4, 2, 0, 1, 3]) == expected
    assert run_sweep(pow, jobs, workers=1) == expected
    assert run_sweep(pow, []) == []


def test_submitit_gives_the_local_pool_rows_in_job_order(tmp_path):
    pytest.importorskip("submitit")
    from ncs_lite.evaluation import evaluate_job as evaluate_cell

    jobs = random_jobs()
    local = run_sweep(evaluate_cell, jobs, workers=2)
    assert [len(rows) for rows in local] == [2, 2, 1]
    assert [rows[0]["horizon_multiplier"] for rows in local] == [2.0, 1.0, 2.0]
    submitted = run_sweep(evaluate_cell, jobs, executor="submitit", folder=tmp_path / "%j", cluster="local",
                          workers=2, first=[2, 0, 1])
    assert submitted == local
    assert any(tmp_path.iterdir())                   # the jobs' pickles and logs are kept


def test_submitit_returns_jobs_in_order_with_more_jobs_than_workers(tmp_path):
    pytest.importorskip("submitit")
    jobs = [(i + 2, 3, 1000) for i in range(4)]
    assert run_sweep(pow, jobs, executor="submitit", folder=tmp_path / "%j", cluster="local",
                     workers=2, first=[3, 1, 2, 0]) == [8, 27, 64, 125]


@pytest.mark.parametrize("executor", ["slurm", "", None, "Local"])
def test_bad_executor_is_refused_in_one_line(executor):
    with pytest.raises(ValueError, match=r"unknown executor .*; expected one of 'local', 'submitit'") as info:
        run_sweep(pow, [(2, 3)], executor=executor)
    assert repr(executor) in str(info.value) and "\n" not in str(info.value)
    assert check_executor("submitit") == "submitit" and EXECUTORS == ("local", "submitit")


def test_reproduce_refuses_a_bad_executor_before_any_work():
    from ncs_lite.__main__ import build_parser
    from ncs_lite.experiments.reproduce import check_table_args

    args = build_parser().parse_args(["reproduce", "fig10", "--preset", "ci", "--executor", "dask"])
    with pytest.raises(ValueError, match=r"unknown executor 'dask'; expected one of 'local', 'submitit'"):
        check_table_args("fig10", args)
    args = build_parser().parse_args(["reproduce", "baselines", "--executor", "submitit"])
    with pytest.raises(ValueError, match="the baselines table does not read --executor"):
        check_table_args("baselines", args)
    args = build_parser().parse_args(["reproduce", "fig11", "--preset", "tiny"])
    with pytest.raises(ValueError, match="unknown preset 'tiny' for the fig11 table"):
        check_table_args("fig11", args)


def test_missing_submitit_names_the_package_and_the_install(monkeypatch):
    import builtins

    real = builtins.__import__

    def no_submitit(name, *args, **kwargs):
        if name == "submitit":
            raise ModuleNotFoundError("No module named 'submitit'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_submitit)
    with pytest.raises(MissingPackage, match=r"needs the package submitit.*pip install 'submitit==1\.5\.4'") as info:
        run_sweep(pow, [(2, 3)], executor="submitit")
    assert isinstance(info.value, ImportError) and isinstance(info.value, ValueError)   # one line on the CLI
    assert "\n" not in str(info.value)


def test_first_must_order_the_jobs():
    with pytest.raises(ValueError, match="first must order the 2 jobs' indices"):
        run_sweep(pow, [(2, 3), (3, 4)], first=[1, 1])


# ---------------------------------------------------------------------- the claims
def cell(label, successes, episodes):
    return {"label": label, "successes": successes, "episodes": episodes}


def test_newcombe_interval_known_values():
    from ncs_lite.experiments.stress import newcombe_interval

    # Newcombe (1998), Table II, example (a): 56/70 - 48/80 -> 0.2 [0.0524, 0.3339]
    d, lo, hi = newcombe_interval(56, 70, 48, 80)
    assert d == pytest.approx(0.2) and lo == pytest.approx(0.0524, abs=5e-4) and hi == pytest.approx(0.3339, abs=5e-4)
    d, lo, hi = newcombe_interval(0, 10, 0, 10)         # both 0: the interval still has a width
    assert d == 0 and lo < 0 < hi


def test_ratio_claim_with_a_denominator_above_zero():
    from ncs_lite.experiments.stress import katz_ratio_interval, ratio_claim

    ratio, lo, hi = katz_ratio_interval(80, 100, 1, 100)
    se = math.sqrt(1 / 80 - 1 / 100 + 1 / 1 - 1 / 100)
    assert ratio == pytest.approx(80.0) and lo == pytest.approx(80 * math.exp(-1.96 * se))
    assert hi == pytest.approx(80 * math.exp(1.96 * se))
    claim = ratio_claim("50x", cell("ncs at 1x", 80, 100), cell("mpc at 8x", 1, 100), 50.0)
    assert claim["ratio"] == 80.0 and claim["verdict"] == "not testable"     # [11.3, 567] contains 50
    assert "contains 50" in claim["reason"]
    assert ratio_claim("2x", cell("a", 90, 100), cell("b", 20, 100), 2.0)["verdict"] == "held"
    assert ratio_claim("50x", cell("a", 30, 100), cell("b", 20, 100), 50.0)["verdict"] == "not held"


def test_ratio_claim_with_a_zero_denominator_reports_the_gap():
    from ncs_lite.experiments.stress import newcombe_interval, ratio_claim

    claim = ratio_claim("50x", cell("ncs at 1x", 35, 50), cell("mpc at 8x", 0, 20), 50.0)
    d, lo, hi = newcombe_interval(35, 50, 0, 20)
    assert claim["ratio"] is None and claim["ratio_ci"] is None
    assert claim["gap"] == pytest.approx(0.7) and claim["gap_ci"] == [round(lo, 4), round(hi, 4)]
    assert 0 < lo < 0.7 < hi
    assert claim["ours"].startswith("ratio undefined (mpc at 8x solved 0 of 20); gap 0.70")
    assert claim["verdict"] == "not testable" and "ratio undefined" in claim["reason"]
    # with enough tasks a zero denominator can still show the ratio: 50 x 0.0038 < 0.74
    assert ratio_claim("50x", cell("a", 80, 100), cell("b", 0, 1000), 50.0)["verdict"] == "held"


def test_gap_claims_and_their_combination():
    from ncs_lite.experiments.stress import all_of, gap_claim

    above = gap_claim("a > b", cell("a", 30, 40), cell("b", 5, 40), "greater")
    assert above["verdict"] == "held"
    assert gap_claim("a < b", cell("a", 30, 40), cell("b", 5, 40), "less")["verdict"] == "not held"
    unsure = gap_claim("a > b", cell("a", 2, 10), cell("b", 1, 10), "greater")
    assert unsure["verdict"] == "not testable"
    assert gap_claim("a ~ b", cell("a", 2, 10), cell("b", 1, 10), "similar")["verdict"] == "not testable"
    assert gap_claim("a ~ b", cell("a", 1, 100), cell("b", 0, 100), "similar")["verdict"] == "held"
    assert gap_claim("a ~ b", cell("a", 30, 40), cell("b", 5, 40), "similar")["verdict"] == "not held"
    assert all_of("both", [above, above])["verdict"] == "held"
    assert all_of("both", [above, unsure])["verdict"] == "not testable"
    with pytest.raises(ValueError, match="expect must be"):
        gap_claim("?", cell("a", 1, 2), cell("b", 1, 2), "bigger")


def test_fig10_claims_read_the_table_rows():
    from ncs_lite.experiments.stress import _claims

    def row(method, x, success, n):
        return {"method": method, "varied": "horizon_multiplier", "x": x, "episodes": n, "success": success}

    rows = [row("ncs", 1.0, 0.7, 100), row("mpc", 8.0, 0.0, 20), row("nf", 8.0, 0.01, 100),
            row("random", 8.0, 0.0, 100)]
    claims = _claims("fig10", rows)
    fifty = [c for c in claims if "50x" in c["statement"]]
    assert [c["denominator"]["label"] for c in fifty] == ["mpc at 8x", "nf at 8x"]
    assert fifty[0]["ratio"] is None and fifty[0]["verdict"] == "not testable"
    assert fifty[1]["ratio"] == pytest.approx(70.0) and fifty[1]["verdict"] == "not testable"
    assert any("NF performs similar" in c["statement"] and c["verdict"] == "held" for c in claims)
    assert any("MPC performs worse" in c["statement"] and c["verdict"] == "not testable" for c in claims)
    assert len(claims) == 4


def test_stress_cells_share_fig10s_cells_and_name_the_paper_reading():
    from ncs_lite.config import NCSConfig
    from ncs_lite.experiments.stress import PAPER_NCS, cell_jobs

    assets = {"ncs": NCSConfig(state="slot", clusters=45, edge_action="readout"), "model": object(),
              "graph": "g", "oracle_graph": "o", "nf_graph": "n", "bc": "bc", "iql": "iql"}
    sizes = {"tasks": 3, "mpc": 2}
    p10, j10 = cell_jobs("fig10", assets, "ci", sizes)
    p11, j11 = cell_jobs("fig11", assets, "ci", sizes)
    key = lambda job: (job[2]["label"], job[1])                     # noqa: E731
    horizon11 = [key(j11[i]) for v, _, _, i in p11 if v == "horizon_multiplier"]
    assert set(horizon11) <= {key(j) for j in j10}                   # Fig. 11 right = Fig. 10's cells
    assert len(j11) == len({key(j) for j in j11})                    # each cell once (4x, no noise is shared)
    paper = next(j for j in j10 if j[2]["label"] == "ncs-paper")
    assert {k: getattr(paper[2]["ncs"], k) for k in PAPER_NCS} == PAPER_NCS == {
        "restarts": 1, "slot_init": "random", "extra_slots": 1, "align": "hungarian", "edge_action": "most_common",
        "dependencies": False}
    mpcs = {j[2]["label"]: (j[2]["mpc"].horizon, j[1].episodes) for j in j10 if j[0] == "mpc"}
    assert mpcs == {"mpc": (1, 2), "mpc-h2": (2, 2), "mpc-h3": (3, 2)}
    noisy = {j[1].action_noise for j in j11}
    assert noisy == {0.0, 0.01, 0.02, 0.03, 0.05, 0.08}
    assert all(j[1].horizon_multiplier == 4.0 for j in j11 if j[1].action_noise > 0)


def test_tasks_per_point_and_unknown_methods():
    from ncs_lite.experiments.stress import TASKS, available, tasks_per_point

    assert tasks_per_point("ci") == {"tasks": 2, "mpc": 2}
    assert tasks_per_point("reduced")["tasks"] == 100 and tasks_per_point("paper") == {"tasks": 100, "mpc": 100}
    assert tasks_per_point("reduced", episodes=5, mpc_episodes=50) == {"tasks": 5, "mpc": 5}
    assert set(TASKS) == {"ci", "reduced", "paper"}
    with pytest.raises(ValueError, match="unknown methods"):
        available(["ncs", "mcts"])
    from ncs_lite.evaluation import METHODS

    assert ("random-object" in available(["random-object"])) == ("random-object" in METHODS)
    with pytest.raises(ValueError, match="unknown preset"):
        tasks_per_point("huge")
