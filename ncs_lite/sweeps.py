"""Sweeps that scale out: an indexed list of independent, seeded jobs, run here or on a cluster.

    results = run_sweep(fn, jobs)                                   # this machine's worker processes
    results = run_sweep(fn, jobs, executor="submitit")              # submitit: Slurm when there is
                                                                    # one, else local processes
    # either way: results == [fn(*job) for job in jobs], in job order, bit for bit

A job is fixed by its own inputs (a task set and its seed, a method's settings and assets), so
it gives the same output in any process on any machine that runs the same code on the same
torch thread count (`workers`: another count changes the floating-point order). Both
executors run every job on the caller's thread count.

* "local": the kit's process pool (`workers.map_jobs`), `workers` processes at once.
* "submitit": `submitit.AutoExecutor(folder, cluster)`; `cluster` None lets submitit pick
  (Slurm when `srun` is found, else "local"). On a cluster the jobs go as one job array
  (`map_array`, at most `workers` running when given). submitit's "local" cluster has no
  array throttle (it starts every job of an array at once), so there the jobs are submitted
  `workers` at a time, each when one finishes. Each job pickles its own arguments; its
  pickles and logs stay in `folder` (default <cache>/submitit/<job id>).

submitit is an optional extra (`pip install -e '.[sweeps]'`; `make setup` installs it).
"""
from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Sequence

import torch

from .utils import REPO_DIR, cache_dir, progress
from .workers import default_workers, map_jobs

__all__ = ["EXECUTORS", "SUBMITIT_VERSION", "MissingPackage", "check_executor", "require_submitit", "run_sweep"]

EXECUTORS = ("local", "submitit")
SUBMITIT_VERSION = "1.5.4"          # = pyproject.toml's `sweeps` extra and the Makefile's pin
TIMEOUT_MIN = 24 * 60               # a job's wall-clock limit (submitit's local default is 2 minutes)


class MissingPackage(ImportError, ValueError):
    """An optional package is not installed (a ValueError too: the command line prints one line)."""


def check_executor(executor) -> str:
    """`executor` if it is one of EXECUTORS, else a ValueError naming it and the choices."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; expected one of {', '.join(map(repr, EXECUTORS))}")
    return executor


def require_submitit():
    """The submitit module, or a one-line MissingPackage saying how to install it."""
    try:
        import submitit  # local: an optional extra (`.[sweeps]`), imported only for --executor submitit
    except ImportError:
        raise MissingPackage(f"--executor submitit needs the package submitit, which is not installed: "
                             f"pip install 'submitit=={SUBMITIT_VERSION}' (or pip install -e '.[sweeps]'; "
                             "make setup installs it)", name="submitit") from None
    return submitit


def _call(_, fn: Callable, job: tuple):
    """A `map_jobs` job: fn(*job) (map_jobs passes its `shared` first)."""
    return fn(*job)


def _submitit_job(package: str, threads: int, fn: Callable, job: tuple):
    """One submitit job: fn(*job) on the caller's torch thread count, refusing to run another
    copy of the kit than the caller's (an installed one found first would give other rows)."""
    here = str(Path(__file__).resolve().parent)
    if here != package:
        raise ValueError(f"this job imported ncs_lite from {here}, the sweep was started from {package}: "
                         "put the caller's checkout first on the jobs' PYTHONPATH")
    torch.set_num_threads(threads)
    os.environ["NCS_LITE_PROGRESS"] = "0"          # the caller's bar only
    return fn(*job)


@contextmanager
def _kit_on_pythonpath():
    """The jobs (new processes, or Slurm jobs that inherit this environment) import this
    checkout of ncs_lite, wherever the caller's working directory is."""
    before = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(REPO_DIR), *([before] if before else [])])
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = before


def _result(index: int, job):
    try:
        return job.result()
    except Exception as exc:
        raise RuntimeError(f"sweep job {index} failed (submitit job {job.job_id}; logs: {job.paths.stderr})") from exc


def _run_submitit(fn: Callable, jobs: list[tuple], folder, cluster: str | None, workers: int | None,
                  order: list[int], timeout_min: float, desc: str | None, parameters: dict | None) -> list:
    submitit = require_submitit()
    folder = Path(folder) if folder is not None else cache_dir() / "submitit" / "%j"
    executor = submitit.AutoExecutor(folder=folder, cluster=cluster)
    executor.update_parameters(timeout_min=timeout_min, cpus_per_task=torch.get_num_threads(),
                               name=desc or "ncs-lite-sweep")
    if parameters:
        executor.update_parameters(**parameters)
    package = str(Path(__file__).resolve().parent)
    args = {i: (package, torch.get_num_threads(), fn, jobs[i]) for i in order}
    results: list = [None] * len(jobs)
    with _kit_on_pythonpath():
        if executor.cluster != "local":             # one job array; the scheduler runs them
            if workers is not None and executor.cluster == "slurm":
                executor.update_parameters(slurm_array_parallelism=workers)
            submitted = executor.map_array(_submitit_job, *zip(*(args[i] for i in order)))
            for i, job in progress(list(zip(order, submitted)), desc=desc):
                results[i] = _result(i, job)
            return results
        limit = min(workers or default_workers(), len(jobs))
        waiting, running = list(order), {}
        bar = progress(total=len(jobs), desc=f"{desc} ({limit} submitit jobs)")
        while waiting or running:
            while waiting and len(running) < limit:
                i = waiting.pop(0)
                running[i] = executor.submit(_submitit_job, *args[i])
            done = [i for i, job in running.items() if job.done()]
            for i in done:
                results[i] = _result(i, running.pop(i))
                bar.update(1)
            if not done:
                time.sleep(0.2)
        bar.close()
    return results


def run_sweep(fn: Callable, jobs: Sequence[Sequence[Any]], executor: str = "local", folder=None,
              cluster: str | None = None, workers: int | None = None, first: Sequence[int] | None = None,
              desc: str | None = None, timeout_min: float = TIMEOUT_MIN, parameters: dict | None = None) -> list:
    """[fn(*job) for job in jobs], in job order, run by `executor` (EXECUTORS; see the module
    docstring). `fn` must be defined at the top level of a module (jobs run in new processes).
    `workers`: jobs at once (default `workers.default_workers()` here; the scheduler's on a
    cluster); `first`: the order to start them (costliest first keeps every core busy to the
    end); `folder`, `cluster`, `timeout_min` (minutes per job) and `parameters` (more of
    `AutoExecutor.update_parameters`, e.g. {"slurm_partition": "cpu"}): submitit's."""
    check_executor(executor)
    jobs = [tuple(job) for job in jobs]
    order = list(range(len(jobs))) if first is None else list(first)
    if sorted(order) != list(range(len(jobs))):
        raise ValueError(f"first must order the {len(jobs)} jobs' indices, got {order}")
    if not jobs:
        return []
    if executor == "local":
        return map_jobs(_call, [(fn, job) for job in jobs], workers=workers, first=first, desc=desc)
    return _run_submitit(fn, jobs, folder, cluster, workers, order, timeout_min, desc, parameters)
