"""The main comparison (`comparison.run_comparison`): cells run in worker processes return
what a serial run returns."""
import pytest

from ncs_lite.experiments.comparison import run_comparison


@pytest.fixture(scope="module")
def shipped():
    from ncs_lite.inference import SHIPPED_CHECKPOINT, SHIPPED_GRAPH, load_dslate
    from ncs_lite.ncs.graph import TransitionGraph

    if not (SHIPPED_CHECKPOINT.exists() and SHIPPED_GRAPH.exists()):
        pytest.skip("the shipped reduced dSLATE and graph are not present")
    # preset "ci" only sets MPC's CEM (a small one); the agents read the shipped files
    return {"model": load_dslate(SHIPPED_CHECKPOINT, device="cpu"), "graph": TransitionGraph.load(SHIPPED_GRAPH),
            "preset": "ci"}


def test_worker_processes_give_the_serial_rows(shipped):
    kw = dict(counts=(4, 5), goals=("complete", "partial"), episodes=2, methods=("ncs", "mpc", "random"),
              cache=False)
    serial = run_comparison(shipped, workers=1, **kw)
    assert len(serial) == 2 * 2 * 3 * 2
    assert run_comparison(shipped, workers=2, **kw) == serial


@pytest.mark.parametrize("workers", [0, -1, 1.5, True, "2"])
def test_bad_worker_counts_are_refused(shipped, workers):
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        run_comparison(shipped, methods=("random",), episodes=1, workers=workers)


def test_slot_inference_in_worker_processes_gives_the_serial_transitions(shipped, monkeypatch):
    import torch

    from ncs_lite.data import cached_buffer, load_buffer
    from ncs_lite.ncs.perception import DSlatePerception

    buffer = load_buffer(cached_buffer(6, seed=5))
    perception = DSlatePerception(shipped["model"], state="slot", batch_size=2, restarts=2)   # 3 batches
    done = {}
    for workers in ("1", "2"):
        monkeypatch.setenv("NCS_LITE_WORKERS", workers)
        done[workers] = perception.transitions(buffer)
    for serial, parallel in zip(done["1"], done["2"]):
        assert torch.equal(torch.as_tensor(serial), torch.as_tensor(parallel))


@pytest.mark.parametrize("value", ["0", "-2", "two", ""])
def test_bad_worker_variable_is_refused(monkeypatch, value):
    from ncs_lite.workers import default_workers

    monkeypatch.setenv("NCS_LITE_WORKERS", value)
    with pytest.raises(ValueError, match="NCS_LITE_WORKERS must be a positive integer"):
        default_workers()


def test_map_jobs_refuses_a_start_order_that_is_not_one():
    from ncs_lite.workers import map_jobs

    with pytest.raises(ValueError, match="first must order the 2 jobs' indices"):
        map_jobs(divmod, [(1,), (2,)], shared=7, workers=2, first=[0, 0])


def test_robogym_comparison_runs_every_method_from_the_shipped_assets():
    from ncs_lite.experiments.comparison import COMPARED, comparison_assets

    assets = comparison_assets("reduced", env="robogym-rearrange")
    assert assets["ncs"].state == "slot" and assets["ncs"].edge_action == "readout" and assets["ncs"].clusters == 45
    rows = run_comparison({**assets, "preset": "ci"}, counts=(4,), goals=("complete",), episodes=1, cache=False,
                          workers=1)                                   # ci: a small CEM for MPC
    assert sorted(r["method"] for r in rows) == sorted(COMPARED)
    assert {r["env"] for r in rows} == {"robogym-rearrange"}
    with pytest.raises(ValueError, match="env must be one of"):
        comparison_assets("reduced", env="no-such-env")
