"""The main comparison (`comparison.run_comparison`): cells run in worker processes return
what a serial run returns."""
import pytest

from ncs_lite.comparison import run_comparison


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
