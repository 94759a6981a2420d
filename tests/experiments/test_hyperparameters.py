"""Fig. 9's axes: a graph rebuilt with other nodes or less data, and a fixed slot count."""
import pytest

from ncs_lite.config import NCSConfig, get_preset
from ncs_lite.data import collect, load_buffer
from ncs_lite.evaluation import learned_perception
from ncs_lite.experiments.hyperparameters import graph_like
from ncs_lite.models import DSlate
from ncs_lite.ncs.graph import TransitionGraph, build_graph
from ncs_lite.ncs.perception import OraclePerception


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from ncs_lite.__main__ import main

    folder = tmp_path_factory.mktemp("fig9")
    collect(folder / "buf", episodes=40, seed=0)
    assert main(["graph", "--oracle", "--data", str(folder / "buf"), "--clusters", "12",
                 "--out", str(folder / "g.pt")]) == 0
    return TransitionGraph.load(folder / "g.pt"), load_buffer(folder / "buf")


def test_graph_like_rebuilds_the_graph_with_other_nodes_or_fewer_episodes(built):
    graph, buffer = built
    same = graph_like(graph)
    assert same.num_nodes == graph.num_nodes and same.edges == graph.edges
    fewer = graph_like(graph, clusters=8)
    assert fewer.num_nodes == 8 and fewer.info["ncs"]["clusters"] == 8
    prefix = graph_like(graph, episodes=10)
    per_episode = buffer["actions"].shape[1]
    assert prefix.info["transitions"] == 10 * per_episode and prefix.info["episodes"] == 10
    # the first 10 episodes' transitions, built directly, give the same graph
    st, st1, actions, moved = OraclePerception().transitions(buffer)
    keep = 10 * per_episode
    direct = build_graph(st[:keep], st1[:keep], actions[:keep], clusters=12, true_entity=moved[:keep])
    assert prefix.edges == direct.edges
    with pytest.raises(ValueError, match=r"episodes must be an integer in \[1, 40\].*got 41"):
        graph_like(graph, episodes=41)


def test_a_fixed_slot_count_ignores_the_object_count():
    model = DSlate(get_preset("ci")).eval()
    assert learned_perception(model, 4, NCSConfig(slots=3)).num_slots == 3
    assert learned_perception(model, 7, NCSConfig(slots=3)).num_slots == 3
    assert learned_perception(model, 4, NCSConfig()).num_slots == max(model.cfg.slots.num_slots, 5)
    with pytest.raises(ValueError, match="ncs.slots must be an integer >= 1, got 0"):
        NCSConfig(slots=0).validate()


def _rows(clusters, data, slots, episodes=100):
    rows = []
    for varied, points in (("clusters", clusters), ("data", data), ("slots", slots)):
        for x, successes in points.items():
            rows.append({"varied": varied, "x": x, "method": "ncs", "successes": successes, "episodes": episodes,
                         "success": successes / episodes})
    return rows


def test_fig9_claims_read_the_gaps_between_points():
    from ncs_lite.experiments.hyperparameters import fig9_claims

    rows = _rows({16: 40, 45: 90, 50: 60}, {2500: 30, 20000: 90}, {3: 10, 5: 100, 10: 99})
    verdicts = {c["statement"]: c["verdict"] for c in fig9_claims(rows)}
    assert list(verdicts.values()) == ["held", "held", "held", "held"]
    # a peak at an end of the cluster range, no gain from data, a large loss with double slots
    rows = _rows({16: 90, 45: 60, 50: 40}, {2500: 60, 20000: 60}, {3: 10, 5: 90, 10: 40})
    claims = fig9_claims(rows)
    assert [c["verdict"] for c in claims] == ["not held", "not testable", "held", "not held"]
    assert "at an end" in claims[0]["ours"]
    # an axis without the counts a claim compares
    claims = fig9_claims(_rows({16: 40, 45: 90, 50: 60}, {2500: 30, 20000: 90}, {6: 80, 8: 80}))
    assert [c["verdict"] for c in claims[2:]] == ["not testable", "not testable"]
