"""Neural Constraint Satisfaction (Section 4, Appendix A.2-A.3): the transition graph and
the agent that acts on it. Each step of the paper is one function:

| step                | function            | where                                              |
|---------------------|---------------------|----------------------------------------------------|
| type / state split  | `split`             | `ncs_lite/models/split.py` (a slot = [type z ; state s]) |
| isolate             | `isolate`           | `graph.py`: the entity a transition moved          |
| cluster             | `cluster`           | `graph.py`: K-means of isolated states into nodes  |
| bind                | `bind`              | `graph.py`: a state's nearest node                 |
| align               | `align`             | `policy.py`: goal entities to current ones, by type |
| select-constraint   | `select_constraint` | `policy.py`: the unsatisfied pair to act on        |

`graph.build_graph` runs isolate, cluster and bind over a buffer's transitions;
`graph.graph_from_buffer` reads the buffer first (the one path from a buffer to a graph);
`policy.NCSAgent.act` runs align and select-constraint, then acts along the edge. `kmeans`
holds the K-means both cluster and bind rest on (`kmeans`, `assign`).
"""
from ..models.split import split
from .graph import bind, build_graph, cluster, graph_from_buffer, isolate
from .kmeans import METRICS, KMeansResult, assign, kmeans, kmeans_plusplus, pairwise_distances
from .policy import align, select_constraint

__all__ = ["METRICS", "KMeansResult", "align", "assign", "bind", "build_graph", "cluster", "graph_from_buffer",
           "isolate", "kmeans", "kmeans_plusplus", "pairwise_distances", "select_constraint", "split"]
