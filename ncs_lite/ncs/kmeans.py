"""K-means with the three distance metrics NCS uses (Appendix A.2, Table 3).

NCS turns the isolated entity states of the experience buffer into graph nodes by
clustering them (**cluster**), and later maps a new state to its node by nearest centroid
(**bind**). Table 3 picks the metric per state representation:

| state s                                | cluster         | bind            |
|----------------------------------------|-----------------|-----------------|
| attention mask alpha (block-rearrange) | `"iou"`         | `"cosine"`      |
| slot state part (robogym-rearrange)    | `"sqeuclidean"` | `"sqeuclidean"` |

The paper adapted overshiki/kmeans_pytorch; this file is the kit's own implementation.

Shapes: `x` is `(N, D)` (N states, D features: a flattened mask or a state vector),
`centroids` is `(K, D)`, `labels` is `(N,)` int64, `distances` is `(N,)`.

Decisions (the paper is silent on them):

- **Metrics.** `sqeuclidean`: ||x - c||^2, computed as ||x||^2 - 2 x.c + ||c||^2 with one
  matmul per batch (float32 rounding is ~1e-7 ||x||^2 per entry: fine unless the data sit
  far from the origin relative to their spread; centre them first if they do).
  `cosine`: 1 - x.c / (||x|| ||c||), in [0, 2]; zero vectors are rejected (undefined).
  `iou`: soft IoU of non-negative masks, IoU = sum(min(x, c)) / sum(max(x, c)), distance
  1 - IoU in [0, 1] (two all-zero masks are identical: distance 0). With
  min = (a + b - |a - b|) / 2 and max = (a + b + |a - b|) / 2 this is
  2 L1 / (sum x + sum c + L1), so one L1 distance matrix (`torch.cdist(p=1)`) gives it.
- **Centroid update.** `sqeuclidean`: the mean of the members (the exact minimiser, so
  Lloyd's iterations never increase the inertia). `cosine`: the normalised mean of the
  normalised members ("spherical k-means"; also the exact minimiser of sum(1 - cos)), so
  cosine centroids are unit vectors. `iou`: the plain mean of the member masks. It is not
  the minimiser of sum(1 - IoU) (that has no closed form), but it is a soft mask again,
  cheap, and what a Lloyd's loop with a pluggable distance (the structure of the code
  the paper adapted) computes; the price is that the inertia is not guaranteed to fall
  at every iteration, which the tolerance and `max_iter` bound.
- **k-means++ initialisation** with the same metric: the first centroid is a uniformly
  drawn point, each next one a point drawn with probability proportional to its distance
  to the nearest centroid chosen so far (for `sqeuclidean` that distance is already
  squared, so this is the classic D^2 weighting). All randomness comes from one
  `torch.Generator` seeded with `seed`: same seed, same data -> same result.
- **Stopping.** One iteration = update the centroids from the current labels, then
  reassign. Stop after `max_iter` iterations, or when the labels did not change (a fixed
  point), or when the relative inertia change |I_prev - I| / I_prev <= `tol`. `tol=0`
  stops only when nothing changes any more. Counting this way, `max_iter=n` does the same
  work as `scipy.cluster.vq.kmeans2(iter=n)`: n updates and n + 1 assignments.
- **Empty clusters** are re-seeded before the update: each empty cluster takes the point
  farthest from its current centroid (among clusters with more than one member, so no
  other cluster is emptied), and that point leaves its old cluster's sums.
- **Batching.** Every pass over the data works on `batch_size` rows at a time and never
  copies `x`, so memory is O(batch_size * max(D, K)) on top of the data: 100k masks of
  4096 features (1.6 GB as float32) cluster in under 0.1 GB more (measured peak RSS).
- **Speed.** One pass per iteration: a matmul for the distances (sqeuclidean, cosine)
  or an L1 `cdist` (iou), a row-wise min, and a one-hot matmul for the cluster sums.
  `python -m ncs_lite bench kmeans` compares it with `scipy.cluster.vq.kmeans2`.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..utils import progress, progress_enabled

METRICS = ("cosine", "iou", "sqeuclidean")


class EmptyClusterWarning(RuntimeWarning):
    """k-means ended with empty clusters. Hidden by default: `kmeans` prints one explained
    line instead (e.g. the oracle's ground-truth masks take fewer distinct values than k)."""


warnings.filterwarnings("ignore", category=EmptyClusterWarning)

# Default batch: about this many elements per (batch_size, max(D, K)) block (32 MB in float32).
_BATCH_ELEMENTS = 2**23


@dataclass(frozen=True)
class KMeansResult:
    """What `kmeans` returns.

    centroids: (K, D), same dtype as the data (float32 unless the data were float64).
    labels:    (N,) int64, the nearest centroid of every point (consistent with `centroids`).
    inertia:   sum over points of the distance to their centroid (float, summed in float64).
    n_iter:    centroid updates done (0 <= n_iter <= max_iter).
    converged: True if stopped by the fixed point or the tolerance, False if by max_iter.
    """

    centroids: torch.Tensor
    labels: torch.Tensor
    inertia: float
    n_iter: int
    converged: bool


# ----------------------------------------------------------------------------- validation

def _check_metric(metric) -> str:
    if metric not in METRICS:
        valid = ", ".join(map(repr, METRICS))
        raise ValueError(f"unknown metric {metric!r}; expected one of {valid}")
    return metric


def _as_matrix(x, name: str) -> torch.Tensor:
    """A 2-D floating tensor view of `x` (NumPy arrays are shared, not copied)."""
    t = torch.as_tensor(x)
    if t.ndim != 2:
        raise ValueError(f"{name} must have shape (N, D), got {tuple(t.shape)}")
    if t.dtype not in (torch.float32, torch.float64):
        t = t.to(torch.float32)  # ints, bools, half precision
    return t


def _check_int(value, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _batch_size(batch_size, d: int, k: int) -> int:
    if batch_size is None:
        return max(256, _BATCH_ELEMENTS // max(d, k, 1))
    return _check_int(batch_size, "batch_size", 1)


def _check_values(x: torch.Tensor, metric: str, name: str, batch_size: int) -> None:
    """Finite everywhere; non-negative for IoU; no zero rows for cosine. Batched.

    Fast path: a batch whose total is finite holds no NaN or inf (either would propagate
    into the sum), so the elementwise test runs only to locate a bad row (or when the sum
    merely overflowed, which is not an error)."""
    for start in range(0, x.shape[0], batch_size):
        xb = x[start:start + batch_size]
        if not bool(torch.isfinite(xb.sum())):
            finite = torch.isfinite(xb).all(dim=1)
            if not bool(finite.all()):
                row = start + int((~finite).nonzero()[0, 0])
                raise ValueError(f"{name} must be finite, got NaN or inf in row {row}")
        if metric == "iou" and bool(xb.amin() < 0):
            row = start + int((xb < 0).any(dim=1).nonzero()[0, 0])
            raise ValueError(f"metric 'iou' needs non-negative masks, got a negative value "
                             f"in row {row} of {name} (min {float(xb[row - start].min()):.3g})")
        if metric == "cosine":
            zero = torch.linalg.vector_norm(xb, dim=1) == 0
            if bool(zero.any()):
                row = start + int(zero.nonzero()[0, 0])
                raise ValueError(f"metric 'cosine' is undefined for zero vectors: row {row} of "
                                 f"{name} has norm 0")


# ----------------------------------------------------------------------------- distances

def _prepare(centroids: torch.Tensor, metric: str) -> tuple:
    """Per-centroid quantities each batch reuses (computed once per pass)."""
    if metric == "sqeuclidean":
        return centroids.T.contiguous(), centroids.square().sum(dim=1)  # (D, K), (K,)
    if metric == "cosine":
        unit = centroids / torch.linalg.vector_norm(centroids, dim=1, keepdim=True)
        return (unit.T.contiguous(),)  # (D, K)
    return centroids, centroids.sum(dim=1)  # iou: (K, D), (K,)


def _row_stats(xb: torch.Tensor, metric: str) -> torch.Tensor:
    """The per-point quantity each metric needs, (B,): ||x||^2, ||x|| or sum(x).

    `kmeans` computes it once for all N points and reuses it at every iteration."""
    if metric == "sqeuclidean":
        return torch.linalg.vector_norm(xb, dim=1).square_()
    if metric == "cosine":
        return torch.linalg.vector_norm(xb, dim=1)
    return xb.sum(dim=1)


def _batch_distances(xb: torch.Tensor, rb: torch.Tensor, prepared: tuple,
                     metric: str) -> torch.Tensor:
    """Distances (B, K) from a batch of points (B, D), with row stats rb (B,), to every centroid."""
    if metric == "sqeuclidean":
        ct, c_sq = prepared
        d = torch.addmm(c_sq, xb, ct, alpha=-2)  # ||c||^2 - 2 x.c, (B, K)
        return d.add_(rb.unsqueeze(1)).clamp_min_(0)
    if metric == "cosine":
        (unit_t,) = prepared
        return (1 - (xb @ unit_t) / rb.unsqueeze(1)).clamp_(0, 2)
    c, c_sum = prepared
    l1 = torch.cdist(xb, c, p=1)  # (B, K)
    denom = rb.unsqueeze(1) + c_sum + l1  # = 2 sum(max(x, c))
    return torch.where(denom > 0, 2 * l1 / denom.clamp_min(torch.finfo(denom.dtype).tiny),
                       torch.zeros_like(l1))


def _batch_nearest(xb: torch.Tensor, rb: torch.Tensor, prepared: tuple, metric: str,
                   out: tuple) -> None:
    """Nearest centroid of each point of a batch, written into out = (distances (B,),
    labels (B,)) (slices of the pass's result tensors: no extra copy)."""
    dist, labels = out
    if metric == "sqeuclidean":
        # argmin does not need ||x||^2: add it to the (B,) minimum only.
        ct, c_sq = prepared
        torch.min(torch.addmm(c_sq, xb, ct, alpha=-2), dim=1, out=out)  # (B, K) -> (B,)
        dist.add_(rb).clamp_min_(0)
    elif metric == "cosine":
        # Scaling a row by 1/||x|| does not move its argmax: normalise the (B,) maximum only.
        (unit_t,) = prepared
        torch.max(xb @ unit_t, dim=1, out=out)  # best cosine similarity x 1/||x||
        torch.addcdiv(torch.ones_like(dist), dist, rb, value=-1, out=dist).clamp_(0, 2)
    else:
        torch.min(_batch_distances(xb, rb, prepared, metric), dim=1, out=out)


def _features(xb: torch.Tensor, rb: torch.Tensor, metric: str) -> torch.Tensor:
    """What a centroid averages: unit vectors for cosine, the points themselves otherwise."""
    return xb / rb.unsqueeze(1) if metric == "cosine" else xb


def _all_row_stats(x: torch.Tensor, metric: str, batch_size: int) -> torch.Tensor:
    return torch.cat([_row_stats(x[s:s + batch_size], metric)
                      for s in range(0, x.shape[0], batch_size)])


def _pass(x, row_stats, centroids, metric, batch_size, accumulate=True):
    """One sweep over the data: nearest centroid of every point, and (optionally) the
    per-cluster sums (K, D) float64 and counts (K,) that the next update needs.

    row_stats: (N,) from `_row_stats`, or None to compute them batch by batch."""
    n, k = x.shape[0], centroids.shape[0]
    prepared = _prepare(centroids, metric)
    labels = torch.empty(n, dtype=torch.int64, device=x.device)
    dists = torch.empty(n, dtype=x.dtype, device=x.device)
    sums = torch.zeros(k, x.shape[1], dtype=torch.float64, device=x.device) if accumulate else None
    counts = torch.zeros(k, dtype=torch.int64, device=x.device) if accumulate else None
    for start in range(0, n, batch_size):
        rows = slice(start, start + batch_size)
        xb = x[rows]
        rb = _row_stats(xb, metric) if row_stats is None else row_stats[rows]
        _batch_nearest(xb, rb, prepared, metric, out=(dists[rows], labels[rows]))
        if accumulate:
            # Per-cluster sums as one matmul with the batch's one-hot labels (K, B). Summing
            # with index_add_ is faster on one thread, but with more torch threads it goes
            # through a parallel sort of the labels, ~15x slower here (100k x 64, 2 threads).
            # Each batch is summed in the data's dtype, the (K, D) partials in float64.
            onehot = torch.zeros(k, xb.shape[0], dtype=x.dtype, device=x.device)
            onehot.scatter_(0, labels[rows].unsqueeze(0), 1.0)
            sums += onehot @ _features(xb, rb, metric)
            counts += onehot.sum(dim=1).long()  # exact: B < 2^24
    return labels, dists, sums, counts


def _check_pair(x: torch.Tensor, c: torch.Tensor) -> None:
    if c.shape[0] < 1:
        raise ValueError(f"centroids must hold at least one row, got shape {tuple(c.shape)}")
    if c.shape[1] != x.shape[1]:
        raise ValueError(f"centroids must have shape (K, {x.shape[1]}) to match x of shape "
                         f"{tuple(x.shape)}, got {tuple(c.shape)}")


def pairwise_distances(x, centroids, metric: str) -> torch.Tensor:
    """Full distance matrix (N, K) between points (N, D) and centroids (K, D).

    Meant for small inputs (notebooks, tests, ranking a handful of entities); `assign`
    is the batched nearest-centroid search for large ones.
    """
    metric = _check_metric(metric)
    x, c = _as_matrix(x, "x"), _as_matrix(centroids, "centroids")
    _check_pair(x, c)
    c = c.to(x.dtype)
    _check_values(x, metric, "x", max(1, x.shape[0]))
    _check_values(c, metric, "centroids", max(1, c.shape[0]))
    return _batch_distances(x, _row_stats(x, metric), _prepare(c, metric), metric)


def assign(x, centroids, metric: str, *, batch_size: int | None = None):
    """Nearest centroid of every point: NCS's **bind** (Table 3: cosine for masks,
    squared Euclidean for slot states).

    x: (N, D) points; centroids: (K, D). Returns (labels (N,) int64, distances (N,)) with
    distances in x's floating dtype. Exact ties go to the lowest centroid index.
    """
    metric = _check_metric(metric)
    x, c = _as_matrix(x, "x"), _as_matrix(centroids, "centroids")
    _check_pair(x, c)
    c = c.to(device=x.device, dtype=x.dtype)
    batch_size = _batch_size(batch_size, x.shape[1], c.shape[0])
    _check_values(x, metric, "x", batch_size)
    _check_values(c, metric, "centroids", batch_size)
    labels, dists, _, _ = _pass(x, None, c, metric, batch_size, accumulate=False)
    return labels, dists


# ----------------------------------------------------------------------------- k-means

def kmeans_plusplus(x, k: int, metric: str = "sqeuclidean", *, seed: int = 0,
                    batch_size: int | None = None) -> torch.Tensor:
    """k-means++ initial centroids (k, D): rows of x drawn with the same metric's distance."""
    metric = _check_metric(metric)
    x = _as_matrix(x, "x")
    k = _check_k(k, x.shape[0])
    seed = _check_int(seed, "seed", 0)
    batch_size = _batch_size(batch_size, x.shape[1], k)
    _check_values(x, metric, "x", batch_size)
    return _kmeans_plusplus(x, _all_row_stats(x, metric, batch_size), k, metric,
                            _generator(seed, x.device), batch_size)


def _generator(seed: int, device) -> torch.Generator:
    return torch.Generator(device=device).manual_seed(seed)


def _check_k(k, n: int) -> int:
    k = _check_int(k, "k", 1)
    if k > n:
        raise ValueError(f"k must be <= the number of points N={n}, got k={k}")
    return k


def _kmeans_plusplus(x, row_stats, k, metric, gen, batch_size) -> torch.Tensor:
    n = x.shape[0]
    chosen = [int(torch.randint(n, (1,), generator=gen, device=x.device))]
    # closest[i]: distance of point i to its nearest chosen centroid, (N,) float64.
    closest = _pass(x, row_stats, x[chosen], metric, batch_size, accumulate=False)[1].double()
    for _ in range(1, k):
        weights = closest.clamp_min(0)
        total = float(weights.sum())
        if total > 0:
            cumulative = torch.cumsum(weights, dim=0)
            u = torch.rand((), generator=gen, dtype=torch.float64, device=x.device) * total
            i = int(torch.searchsorted(cumulative, u.reshape(1), right=True).clamp_max(n - 1))
        else:  # every point coincides with a chosen centroid: draw among the unchosen
            free = torch.ones(n, dtype=torch.bool, device=x.device)
            free[chosen] = False
            candidates = free.nonzero().squeeze(1)
            i = int(candidates[torch.randint(len(candidates), (1,), generator=gen,
                                             device=x.device)])
        chosen.append(i)
        d_new = _pass(x, row_stats, x[i:i + 1], metric, batch_size, accumulate=False)[1]
        d_new = d_new.double()
        torch.minimum(closest, d_new, out=closest)
    centroids = x[chosen].clone()
    return _features(centroids, row_stats[chosen], metric)


def _reseed_empty(x, row_stats, labels, dists, sums, counts, metric) -> int:
    """Give each empty cluster the point farthest from its centroid (in place).

    Only points of clusters with >= 2 members are candidates, so no cluster is emptied in
    turn. Returns how many empty clusters could not be re-seeded (all candidates sit on
    their centroid: the data hold fewer distinct points than k).
    """
    empty = (counts == 0).nonzero().squeeze(1).tolist()
    if not empty:
        return 0
    far = dists.double().clone()
    far[counts[labels] < 2] = -math.inf
    left = 0
    for e in empty:
        i = int(far.argmax())
        if not far[i] > 0:
            left += 1
            continue
        donor = int(labels[i])
        f = _features(x[i:i + 1], row_stats[i:i + 1], metric)[0].double()
        sums[donor] -= f
        counts[donor] -= 1
        sums[e] = f
        counts[e] = 1
        labels[i] = e
        far[i] = -math.inf
        if counts[donor] < 2:
            far[labels == donor] = -math.inf
    return left


def _update(sums, counts, previous, metric) -> torch.Tensor:
    """New centroids (K, D) from per-cluster sums; empty clusters keep their centroid."""
    filled = counts > 0
    means = sums / counts.clamp_min(1).unsqueeze(1).to(sums.dtype)
    if metric == "cosine":
        norms = torch.linalg.vector_norm(means, dim=1, keepdim=True)
        filled &= norms.squeeze(1) > 0  # members cancelling out exactly: keep the old one
        means = means / norms.clamp_min(torch.finfo(means.dtype).tiny)
    return torch.where(filled.unsqueeze(1), means.to(previous.dtype), previous)


def kmeans(x, k: int, metric: str = "sqeuclidean", *, seed: int = 0, max_iter: int = 100,
           tol: float = 1e-4, batch_size: int | None = None, init="k-means++",
           verbose: bool = False) -> KMeansResult:
    """Cluster the rows of x (N, D) into k clusters under `metric` (one of METRICS).

    NCS's **cluster** step (Table 3: IoU for attention masks, squared Euclidean for slot
    states; k from Table 4). Lloyd's iterations from a k-means++ start; see the module
    docstring for the centroid rule of each metric, the stopping rule and the re-seeding
    of empty clusters.

    x:          (N, D) array or tensor (float64 stays float64, anything else becomes float32).
    k:          number of clusters, 1 <= k <= N.
    seed:       seeds the k-means++ draw (a private torch.Generator; global RNGs untouched).
    max_iter:   cap on centroid updates (0 returns the initial centroids).
    tol:        stop when |I_prev - I| <= tol * I_prev (inertia I); 0 = only at a fixed point.
    batch_size: rows per batch in every pass (default: ~8M elements per batch).
    init:       "k-means++" or explicit initial centroids (k, D).
    verbose:    show a progress bar (still silenced by NCS_LITE_PROGRESS=0).
    """
    metric = _check_metric(metric)
    x = _as_matrix(x, "x")
    n, d = x.shape
    k = _check_k(k, n)
    seed = _check_int(seed, "seed", 0)
    max_iter = _check_int(max_iter, "max_iter", 0)
    if not (isinstance(tol, (int, float, np.floating)) and math.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be a finite number >= 0, got {tol!r}")
    batch_size = _batch_size(batch_size, d, k)
    _check_values(x, metric, "x", batch_size)
    row_stats = _all_row_stats(x, metric, batch_size)  # (N,), reused by every pass

    centroids = _initial_centroids(x, row_stats, init, k, metric, seed, batch_size)
    labels, dists, sums, counts = _pass(x, row_stats, centroids, metric, batch_size)
    inertia = float(dists.sum(dtype=torch.float64))
    n_iter, converged = 0, False
    bar = progress(total=max_iter, desc=f"k-means ({metric}, k={k})",
                   disable=not (verbose and progress_enabled())) if verbose else None
    while n_iter < max_iter and not converged:
        _reseed_empty(x, row_stats, labels, dists, sums, counts, metric)
        centroids = _update(sums, counts, centroids, metric)
        new_labels, dists, sums, counts = _pass(x, row_stats, centroids, metric, batch_size)
        new_inertia = float(dists.sum(dtype=torch.float64))
        n_iter += 1
        converged = (torch.equal(new_labels, labels)
                     or abs(inertia - new_inertia) <= tol * abs(inertia))
        labels, inertia = new_labels, new_inertia
        if bar is not None:
            bar.update(1)
            bar.set_postfix(inertia=f"{inertia:.4g}")
    if bar is not None:
        bar.close()
    if bool((counts == 0).any()):
        _report_empty(x, counts, k)
    return KMeansResult(centroids=centroids, labels=labels, inertia=inertia, n_iter=n_iter,
                        converged=converged)


def _initial_centroids(x: torch.Tensor, row_stats, init, k: int, metric: str, seed: int,
                       batch_size: int) -> torch.Tensor:
    """`kmeans`' start: a k-means++ draw (`init` "k-means++") or the given (k, D) centroids,
    checked."""
    d = x.shape[1]
    if isinstance(init, str):
        if init != "k-means++":
            raise ValueError(f"init must be 'k-means++' or centroids of shape ({k}, {d}), "
                             f"got {init!r}")
        return _kmeans_plusplus(x, row_stats, k, metric, _generator(seed, x.device), batch_size)
    centroids = _as_matrix(init, "init").to(device=x.device, dtype=x.dtype)
    if tuple(centroids.shape) != (k, d):
        raise ValueError(f"init must have shape (k, D) = ({k}, {d}), "
                         f"got {tuple(centroids.shape)}")
    _check_values(centroids, metric, "init", batch_size)
    return centroids.clone()


def _report_empty(x: torch.Tensor, counts: torch.Tensor, k: int) -> None:
    """Say, in one plain line and as an EmptyClusterWarning, how many clusters `kmeans`
    left empty and why."""
    empty, distinct = int((counts == 0).sum()), int(torch.unique(x, dim=0).shape[0])
    why = (f"the data hold only {distinct} distinct points" if distinct < k
           else "the last update emptied a cluster (raise max_iter)")
    # one plain line a reader can act on, not a warning with a source path; the warning
    # (EmptyClusterWarning, a RuntimeWarning) is still raised for code that catches it
    print(f"k-means: {empty} of k={k} clusters ended empty, because {why}; "
          "no point of the data is assigned to them")
    warnings.warn(EmptyClusterWarning(
        f"k-means ended with {empty} empty cluster(s) of k={k}: {why}"), stacklevel=3)
