"""K-means (ncs_lite.ncs.kmeans): scipy agreement, brute force on tiny inputs, seeding,
empty-cluster re-seeding, error messages."""
import itertools
import warnings

import numpy as np
import pytest
import torch
from scipy.cluster.vq import kmeans2

from ncs_lite.ncs import METRICS, assign, kmeans, kmeans_plusplus, pairwise_distances


# ----------------------------------------------------------------------------- references
# Written from the definitions with explicit loops, independently of the library's
# matmul / cdist formulations.

def ref_distance(a: np.ndarray, c: np.ndarray, metric: str) -> float:
    a, c = a.astype(np.float64), c.astype(np.float64)
    if metric == "sqeuclidean":
        return float(sum((ai - ci) ** 2 for ai, ci in zip(a, c)))
    if metric == "cosine":
        return 1.0 - float(a @ c) / (np.sqrt(a @ a) * np.sqrt(c @ c))
    union = sum(max(ai, ci) for ai, ci in zip(a, c))
    inter = sum(min(ai, ci) for ai, ci in zip(a, c))
    return 0.0 if union == 0 else 1.0 - inter / union


def ref_centroid(members: np.ndarray, metric: str) -> np.ndarray:
    members = members.astype(np.float64)
    if metric == "cosine":  # spherical k-means: normalised mean of unit vectors
        m = (members / np.linalg.norm(members, axis=1, keepdims=True)).mean(0)
        return m / np.linalg.norm(m)
    return members.mean(0)  # sqeuclidean; iou by the documented choice


def ref_objective(x: np.ndarray, labels, k: int, metric: str) -> float:
    total = 0.0
    for j in range(k):
        members = x[np.asarray(labels) == j]
        c = ref_centroid(members, metric)
        total += sum(ref_distance(p, c, metric) for p in members)
    return total


def ref_nearest(x: np.ndarray, centroids: np.ndarray, metric: str):
    d = np.array([[ref_distance(p, c, metric) for c in centroids] for p in x])
    return d.argmin(1), d.min(1)


def blobs(sizes, centres, noise, seed):
    rng = np.random.default_rng(seed)
    parts = [np.asarray(c, dtype=np.float64) + noise * rng.standard_normal((n, len(c)))
             for n, c in zip(sizes, centres)]
    truth = np.concatenate([np.full(n, i) for i, n in enumerate(sizes)])
    return np.concatenate(parts), truth


def tiny_data(metric: str):
    """8 points in 3 loose groups: masks for IoU, directions for cosine."""
    if metric == "iou":
        centres = [[1, 1, 0, 0, 0, 0], [0, 0, 1, 1, 0, 0], [0, 0, 0.5, 0, 1, 1]]
        x, _ = blobs([3, 3, 2], centres, 0.15, seed=1)
        return np.abs(x)
    centres = [[1, 0, 0.2], [0, 1, 0.2], [0.6, 0.6, -1]]
    x, _ = blobs([3, 3, 2], centres, 0.3, seed=2)
    return x


def same_partition(a, b) -> bool:
    """True if labelings a and b group the points identically (up to renaming)."""
    a, b = np.asarray(a).tolist(), np.asarray(b).tolist()
    return len(set(zip(a, b))) == len(set(a)) == len(set(b))


# ----------------------------------------------------------------------------- scipy

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_matches_scipy_kmeans2_sqeuclidean(dtype):
    x, _ = blobs([500, 300, 400, 200, 350, 250], np.random.default_rng(0).normal(0, 2, (6, 5)),
                 1.0, seed=3)
    x = x.astype(dtype)
    init = x[np.random.default_rng(4).choice(len(x), 6, replace=False)].copy()
    iterations = 8
    ours = kmeans(x, 6, "sqeuclidean", init=init, max_iter=iterations, tol=0.0)
    # missing="raise": kmeans2 never hit an empty cluster, so both ran plain Lloyd steps.
    ref_c, ref_l = kmeans2(x, init, iter=iterations, minit="matrix", missing="raise")

    def inertia(c, lab):
        diff = x.astype(np.float64) - np.asarray(c, dtype=np.float64)[lab]
        return float((diff ** 2).sum())

    assert ours.centroids.dtype == (torch.float32 if dtype == np.float32 else torch.float64)
    ours_inertia = inertia(ours.centroids.numpy(), ours.labels.numpy())
    ref_inertia = inertia(ref_c, ref_l)
    assert abs(ours_inertia - ref_inertia) <= 0.01 * ref_inertia
    assert ours.inertia == pytest.approx(ours_inertia, rel=1e-4)  # reported == recomputed
    assert np.mean(ours.labels.numpy() == ref_l) > 0.99
    np.testing.assert_allclose(ours.centroids.numpy(), ref_c, atol=1e-3)


# ----------------------------------------------------------------------------- brute force

@pytest.mark.parametrize("metric", ["iou", "cosine"])
def test_reaches_bruteforce_optimum_tiny(metric):
    x = tiny_data(metric)
    k = 3
    best = min(ref_objective(x, lab, k, metric)
               for lab in itertools.product(range(k), repeat=len(x)) if len(set(lab)) == k)
    results = [kmeans(x, k, metric, seed=s, tol=0.0) for s in range(6)]
    for r in results:
        # Every run ends at a verified fixed point of Lloyd's iteration: labels are the
        # brute-force nearest centroids, centroids are the metric's rule over the labels.
        assert r.converged
        labels = r.labels.numpy()
        ref_labels, ref_d = ref_nearest(x, r.centroids.numpy(), metric)
        np.testing.assert_array_equal(labels, ref_labels)
        for j in range(k):
            np.testing.assert_allclose(r.centroids[j].numpy(),
                                       ref_centroid(x[labels == j], metric), atol=1e-6)
        assert r.inertia == pytest.approx(ref_d.sum(), rel=1e-6, abs=1e-9)
        assert r.inertia >= best - 1e-9
    assert min(r.inertia for r in results) == pytest.approx(best, rel=1e-6)


@pytest.mark.parametrize("metric", METRICS)
def test_assign_matches_bruteforce_nearest(metric):
    rng = np.random.default_rng(5)
    x = rng.random((25, 7)) ** 2  # non-negative, so every metric applies
    centroids = rng.random((4, 7))
    if metric == "iou":
        x[3] = 0.0  # empty mask: IoU 0 with any non-empty centroid
    labels, dists = assign(torch.from_numpy(x), torch.from_numpy(centroids), metric, batch_size=6)
    ref_labels, ref_d = ref_nearest(x, centroids, metric)
    np.testing.assert_allclose(dists.numpy(), ref_d, atol=1e-9)
    # Same labels wherever the nearest centroid is not an exact tie (the empty mask is at
    # distance 1 from every centroid, so any label is nearest for it).
    full_ref = np.array([[ref_distance(p, c, metric) for c in centroids] for p in x])
    gap = np.sort(full_ref, axis=1)[:, 1] - ref_d
    assert (gap > 1e-6).sum() >= 24
    np.testing.assert_array_equal(labels.numpy()[gap > 1e-6], ref_labels[gap > 1e-6])
    np.testing.assert_allclose(full_ref[np.arange(len(x)), labels.numpy()], ref_d, atol=1e-9)
    full = pairwise_distances(x, centroids, metric).numpy()
    np.testing.assert_allclose(full, full_ref, atol=1e-9)


def test_iou_known_values():
    x = torch.tensor([[1.0, 0, 1, 0], [0.5, 0.5, 0, 0], [0, 0, 0, 0]])
    c = torch.tensor([[1.0, 1, 0, 0], [0, 0, 0, 0]])
    d = pairwise_distances(x, c, "iou")
    expected = torch.tensor([[1 - 1 / 3, 1.0], [1 - 1 / 2, 1.0], [1.0, 0.0]])
    torch.testing.assert_close(d, expected)


# ----------------------------------------------------------------------------- seeding

@pytest.mark.parametrize("metric", METRICS)
def test_kmeans_plusplus_spreads_over_blobs(metric):
    # One big tight blob and three small ones far away: uniform draws would mostly pick
    # the big blob; k-means++ (weights ~ distance) picks one centroid per blob.
    if metric == "iou":
        centres = np.repeat(np.eye(4), 3, axis=1)  # disjoint masks
    else:
        centres = 10 * np.eye(4) + (1.0 if metric == "cosine" else 0.0)
    x, truth = blobs([100, 5, 5, 5], centres, 0.001, seed=6)
    x = np.abs(x) if metric == "iou" else x
    for seed in range(5):
        init = kmeans_plusplus(x, 4, metric, seed=seed).numpy()
        nearest_point = [int(np.argmin([ref_distance(p, c, metric) for p in x])) for c in init]
        assert sorted(truth[nearest_point]) == [0, 1, 2, 3]


def test_deterministic_for_a_seed_and_batch_size_free():
    x, _ = blobs([60, 50, 40], [[0, 0, 0], [3, 0, 1], [0, 3, 2]], 1.0, seed=7)
    x = torch.from_numpy(x.astype(np.float32))
    torch.manual_seed(123)
    state = torch.get_rng_state()
    a = kmeans(x, 4, seed=11)
    b = kmeans(x, 4, seed=11)
    assert torch.equal(state, torch.get_rng_state())  # private generator only
    assert torch.equal(a.centroids, b.centroids) and torch.equal(a.labels, b.labels)
    assert a.inertia == b.inertia and a.n_iter == b.n_iter
    c = kmeans(x, 4, seed=11, batch_size=64)  # 150 rows: 64 + 64 + 22
    assert torch.equal(a.labels, c.labels)
    torch.testing.assert_close(a.centroids, c.centroids)
    assert not torch.equal(kmeans_plusplus(x, 4, seed=11), kmeans_plusplus(x, 4, seed=12))


def test_max_iter_zero_returns_init_and_its_assignment():
    x = torch.randn(30, 2, generator=torch.Generator().manual_seed(0))
    init = x[:3].clone()
    r = kmeans(x, 3, init=init, max_iter=0)
    assert r.n_iter == 0 and not r.converged
    assert torch.equal(r.centroids, init)
    assert torch.equal(r.labels, assign(x, init, "sqeuclidean")[0])


# ----------------------------------------------------------------------------- empty clusters

def test_empty_cluster_takes_the_farthest_point():
    x = torch.tensor([[0.0], [0.1], [-0.1], [10.0], [10.2], [9.8], [30.0]])
    init = torch.tensor([[0.0], [10.0], [1000.0]])  # centroid 2 gets no point
    r = kmeans(x, 3, init=init, max_iter=1)
    # The point farthest from its centroid (30, at 20 from 10) moves to cluster 2 and
    # leaves cluster 1's mean (kmeans2 would give 15 for cluster 1 and keep 1000).
    torch.testing.assert_close(r.centroids, torch.tensor([[0.0], [10.0], [30.0]]))
    assert r.labels.tolist() == [0, 0, 0, 1, 1, 1, 2]


@pytest.mark.parametrize("metric", METRICS)
def test_duplicate_init_is_reseeded(metric):
    if metric == "iou":
        centres = np.repeat(np.eye(3), 2, axis=1)
    else:
        centres = 5 * np.eye(3) + (1.0 if metric == "cosine" else 0.0)
    x, truth = blobs([20, 20, 20], centres, 0.05, seed=8)
    x = np.abs(x) if metric == "iou" else x
    init = x[[0, 0, 20]]  # two identical centroids: ties go to the first, the second empties
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "empty cluster" warning at the end
        r = kmeans(x, 3, metric, init=init, tol=0.0)
    assert r.converged
    assert torch.bincount(r.labels, minlength=3).min() > 0
    assert same_partition(r.labels.numpy(), truth)


def test_warns_when_fewer_distinct_points_than_k():
    x = torch.tensor([[0.0, 0.0]] * 5 + [[1.0, 1.0]] * 5)
    with pytest.warns(RuntimeWarning, match="empty cluster"):
        r = kmeans(x, 3, max_iter=5)
    assert r.inertia == 0.0


# ----------------------------------------------------------------------------- errors

def test_error_messages():
    x = torch.rand(5, 3)
    with pytest.raises(ValueError, match=r"k must be <= the number of points N=5, got k=6"):
        kmeans(x, 6)
    with pytest.raises(ValueError, match=r"k must be an integer >= 1, got 0"):
        kmeans(x, 0)
    with pytest.raises(ValueError, match=r"unknown metric 'l1'; "
                                         r"expected one of 'cosine', 'iou', 'sqeuclidean'"):
        kmeans(x, 2, "l1")
    with pytest.raises(ValueError, match=r"unknown metric 'euclidean'"):
        assign(x, x[:2], "euclidean")
    with pytest.raises(ValueError, match=r"x must have shape \(N, D\), got \(5,\)"):
        kmeans(torch.rand(5), 2)
    with pytest.raises(ValueError, match=r"x must have shape \(N, D\), got \(2, 5, 3\)"):
        assign(torch.rand(2, 5, 3), x, "cosine")
    bad = x.clone()
    bad[2, 1] = float("nan")
    with pytest.raises(ValueError, match=r"x must be finite, got NaN or inf in row 2"):
        kmeans(bad, 2, batch_size=2)
    bad[2, 1] = float("inf")
    with pytest.raises(ValueError, match=r"finite"):
        assign(bad, x[:2], "sqeuclidean")
    with pytest.raises(ValueError, match=r"'iou' needs non-negative masks.*row 1"):
        kmeans(torch.tensor([[0.0, 1], [-0.5, 1], [1, 1]]), 2, "iou")
    with pytest.raises(ValueError, match=r"'cosine' is undefined for zero vectors: "
                                         r"row 0 of centroids has norm 0"):
        assign(x, torch.zeros(2, 3), "cosine")
    with pytest.raises(ValueError, match=r"centroids must have shape \(K, 3\) to match x of "
                                         r"shape \(5, 3\), got \(2, 4\)"):
        assign(x, torch.rand(2, 4), "sqeuclidean")
    with pytest.raises(ValueError,
                       match=r"init must have shape \(k, D\) = \(2, 3\), got \(3, 3\)"):
        kmeans(x, 2, init=x[:3])
    with pytest.raises(ValueError, match=r"init must be 'k-means\+\+'"):
        kmeans(x, 2, init="random")
    with pytest.raises(ValueError, match=r"tol must be a finite number >= 0, got -1"):
        kmeans(x, 2, tol=-1)
    with pytest.raises(ValueError, match=r"max_iter must be an integer >= 0, got -1"):
        kmeans(x, 2, max_iter=-1)
    with pytest.raises(ValueError, match=r"batch_size must be an integer >= 1, got 0"):
        assign(x, x[:2], "sqeuclidean", batch_size=0)
    with pytest.raises(ValueError, match=r"seed must be an integer >= 0, got -3"):
        kmeans(x, 2, seed=-3)
