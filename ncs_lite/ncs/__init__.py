"""Neural Constraint Satisfaction (Section 4, Appendix A.2-A.3): the transition graph and
the agent that acts on it.

- `kmeans`: the **cluster** step (K-means under the metrics of Table 3) and **bind**
  (`assign`, nearest centroid).
"""
from .kmeans import METRICS, KMeansResult, assign, kmeans, kmeans_plusplus, pairwise_distances

__all__ = ["METRICS", "KMeansResult", "assign", "kmeans", "kmeans_plusplus", "pairwise_distances"]
