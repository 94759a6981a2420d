"""One path from a buffer to an NCS graph: `graph_from_buffer`. Every command that builds a
graph (`graph`, and the tables seeds, clusters, baselines, fig9) hands it the NCSConfig of its
`--set ncs.*` overrides, so no override is read by one path and ignored by another."""
import sys

import pytest

import ncs_lite.experiments.comparison  # noqa: F401  (imported before the spy replaces the function in every module)
import ncs_lite.experiments.hyperparameters  # noqa: F401
import ncs_lite.experiments.reproduce  # noqa: F401
from ncs_lite.__main__ import main
from ncs_lite.data import collect
from ncs_lite.inference import SHIPPED_CHECKPOINT
from ncs_lite.ncs import graph as graph_module

OVERRIDES = ["ncs.graph_restarts=2", "ncs.iterations=3", "ncs.edge_action=nearest", "ncs.seed=5"]


class Built(Exception):
    """Raised by the spy: what the graph would be built with is known, nothing more need run."""


@pytest.fixture
def received(monkeypatch):
    """The NCSConfig of every call of `graph_from_buffer`, which raises `Built` instead of building."""
    seen = []
    original = graph_module.graph_from_buffer

    def spy(ncs, model, data, **kwargs):
        seen.append(ncs)
        raise Built

    for module in list(sys.modules.values()):
        if getattr(module, "graph_from_buffer", None) is original:
            monkeypatch.setattr(module, "graph_from_buffer", spy)
    return seen


def sets(overrides):
    return [arg for o in overrides for arg in ("--set", o)]


def overridden(ncs) -> bool:
    return (ncs.graph_restarts, ncs.iterations, ncs.edge_action, ncs.seed) == (2, 3, "nearest", 5)


@pytest.fixture(scope="module")
def small_buffer(tmp_path_factory):
    path = tmp_path_factory.mktemp("buf")
    collect(path, episodes=2, seed=0)
    return path


def test_graph_command(received, small_buffer, tmp_path):
    with pytest.raises(Built):
        main(["graph", "--checkpoint", str(SHIPPED_CHECKPOINT), "--data", str(small_buffer), "--clusters", "4", "--state", "slot", "--out", str(tmp_path / "g.pt"), *sets(OVERRIDES)])
    assert overridden(received[0]) and (received[0].clusters, received[0].state) == (4, "slot")


def test_seeds_table(received, tmp_path):
    with pytest.raises(Built):
        main(["reproduce", "seeds", "--preset", "ci", "--seeds", "0", "--runs", str(tmp_path / "runs"), "--episodes",
              "1", "--objects", "4", "--out-dir", str(tmp_path), *sets(OVERRIDES)])
    assert overridden(received[0]) and received[0].state == "mask"


def test_clusters_table(received, small_buffer, tmp_path):
    from ncs_lite.experiments.reproduce import clusters_table

    with pytest.raises(Built):         # the command reads the 5,000-episode buffer: here a small one
        clusters_table(clusters=(6,), data=small_buffer, overrides=OVERRIDES, out_dir=tmp_path)
    assert overridden(received[0]) and received[0].clusters == 6
    assert main(["reproduce", "clusters", "--set", "ncs.clusters=9"]) == 2           # the swept field


@pytest.mark.parametrize("table, env", [("baselines", "block-rearrange"), ("fig9", "robogym-rearrange")])
def test_tables_on_the_comparison_assets(received, tmp_path, table, env):
    with pytest.raises(Built):
        main(["reproduce", table, "--preset", "ci", "--out-dir", str(tmp_path), *sets(OVERRIDES)])
    ncs = received[0]
    assert overridden(ncs) and ncs.state == ("mask" if env == "block-rearrange" else "slot")


@pytest.mark.parametrize("table", ["baselines", "fig9"])
def test_the_shipped_graphs_refuse_a_build_override(table, tmp_path, capsys):
    """At `reduced` the comparison reads the shipped graphs: an override of how a graph is built
    cannot reach them, so it is refused rather than ignored; one of how NCS acts is not."""
    assert main(["reproduce", table, "--out-dir", str(tmp_path), "--set", "ncs.graph_restarts=2"]) == 2
    assert "at preset 'reduced' the graphs are the shipped ones" in capsys.readouterr().err
    assert main(["reproduce", table, "--out-dir", str(tmp_path), "--set", "train.lr=0.1"]) == 2
    assert "takes NCS fields only" in capsys.readouterr().err


def test_graph_like_rebuilds_with_the_settings_the_graph_was_built_with(small_buffer, tmp_path):
    from ncs_lite.experiments.hyperparameters import graph_like
    from ncs_lite.ncs.graph import TransitionGraph

    assert main(["graph", "--oracle", "--data", str(small_buffer), "--clusters", "6", "--out", str(tmp_path / "g.pt"),
                 "--set", "ncs.edge_action=nearest", "--set", "ncs.seed=5"]) == 0
    graph = TransitionGraph.load(tmp_path / "g.pt")
    fewer = graph_like(graph, clusters=4)
    assert (fewer.num_nodes, fewer.edge_action, fewer.info["seed"]) == (4, "nearest", 5)
    assert fewer.info["ncs"] == {**graph.info["ncs"], "clusters": 4}
