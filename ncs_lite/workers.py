"""Independent, seeded jobs in worker processes: what a loop returns, bit for bit, sooner.

    rows = map_jobs(evaluate_cell, jobs, shared=assets, desc="comparison")

Each job the kit hands out is fixed by its own inputs (a comparison cell by its task set and
seed, a buffer shard by its episode numbers, a batch of videos by its slot-attention seed),
so it gives the same output in any process. Every worker runs on the caller's torch thread
count (another count changes the floating-point order: see `cache`), so `map_jobs` returns
the list the loop `[fn(shared, *job) for job in jobs]` returns.

Workers are spawned, not forked (a forked torch can hang in its thread pool): `fn` must be
defined at the top level of a module, and a script that calls `map_jobs` needs the
`if __name__ == "__main__":` guard. `shared` (e.g. a model) goes to each worker once. The
lines a job prints (which cache entry it loaded) come back and are printed in job order.
NCS_LITE_WORKERS sets the number of processes (1: run in this process).
"""
from __future__ import annotations

import contextlib
import io
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Sequence

import torch

from .utils import progress

__all__ = ["default_workers", "map_jobs"]

_shared: Any = None     # a worker's copy of `shared`


def default_workers(threads: int | None = None) -> int:
    """$NCS_LITE_WORKERS, else 1 on a GPU machine (the GPU runs a job's batch in parallel),
    else the cores this process may use divided by the threads a job keeps busy (`threads`,
    default torch's thread count, which each worker runs on; 1 for jobs that are mostly not
    torch, such as an env's episodes), at least 1."""
    value = os.environ.get("NCS_LITE_WORKERS")
    if value is not None:
        if not value.isdigit() or int(value) < 1:
            raise ValueError(f"NCS_LITE_WORKERS must be a positive integer, got {value!r}")
        return int(value)
    if torch.cuda.is_available():
        return 1
    return max(1, len(os.sched_getaffinity(0)) // (threads or torch.get_num_threads()))


def _start_worker(threads: int, shared) -> None:
    global _shared
    torch.set_num_threads(threads)
    os.environ["NCS_LITE_PROGRESS"] = "0"          # one bar, the caller's
    _shared = shared


def _run_job(fn: Callable, job: tuple) -> tuple[Any, str]:
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        result = fn(_shared, *job)
    return result, printed.getvalue()


def _is_empty(job: tuple) -> bool:
    """A job whose arguments are all empty sequences (a list of no shards) has nothing to do."""
    return bool(job) and all(isinstance(a, (list, tuple)) and not a for a in job)


def map_jobs(fn: Callable, jobs: Sequence[tuple], shared=None, workers: int | None = None,
             desc: str | None = None, first: Sequence[int] | None = None) -> list:
    """[fn(shared, *job) for job in jobs], run in `workers` processes (default
    `default_workers()`; in this process when that is 1 or there is one job). `first`: job
    indices in the order to start them (the costliest first keeps both cores busy to the end).
    Jobs that all hand over nothing (every argument an empty list, e.g. the shards left to
    collect of a buffer already on disk) run in this process without a progress bar, which
    would read "0 episodes 1/1".
    """
    workers = default_workers() if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    workers = min(workers, len(jobs))
    if all(_is_empty(job) for job in jobs):     # nothing to do (a buffer already on disk): no bar
        return [fn(shared, *job) for job in jobs]
    if workers <= 1:
        return [fn(shared, *job) for job in progress(jobs, desc=desc)]

    order = list(range(len(jobs))) if first is None else list(first)
    if sorted(order) != list(range(len(jobs))):
        raise ValueError(f"first must order the {len(jobs)} jobs' indices, got {order}")
    results = [None] * len(jobs)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_start_worker, initargs=(torch.get_num_threads(), shared)) as pool:
        futures = {pool.submit(_run_job, fn, jobs[i]): i for i in order}
        for future in progress(as_completed(futures), total=len(jobs), desc=f"{desc} ({workers} processes)"):
            results[futures[future]] = future.result()
    for _, printed in results:
        print(printed, end="")
    return [result for result, _ in results]
