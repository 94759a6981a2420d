"""Benchmarks (`python -m ncs_lite bench NAME --out FILE.json`; `make bench` runs them all).

Each benchmark measures the kit against a reference measured in the same run, so its
figures are ratios that survive a change of machine. Timings live here, never in tests.
How to read each JSON: docs/benchmarks.md; dated results of earlier runs: docs/HISTORY.md.
"""
from __future__ import annotations

import importlib
import os
import platform
import time

from ..utils import atomic_write_json, git_commit, package_versions

# name -> module with a `run() -> dict`
BENCHMARKS = {
    "envs": "ncs_lite.bench.envs",
    "train": "ncs_lite.bench.train_step",
    "kmeans": "ncs_lite.bench.kmeans",
    "ncs": "ncs_lite.bench.ncs",
}


def run(name: str, out=None) -> dict:
    if name not in BENCHMARKS:
        raise ValueError(f"unknown benchmark {name!r}; expected one of {sorted(BENCHMARKS)}")
    load_before = os.getloadavg()[0]
    start = time.time()
    # local: only the benchmark asked for is imported (each loads what it measures: MuJoCo, pybullet, ...)
    result = importlib.import_module(BENCHMARKS[name]).run()
    # what a ratio needs beside it: the CPU (AMX or not), its cores and how busy they were
    result["meta"] = {"benchmark": name, "seconds": round(time.time() - start, 2),
                      "machine": platform.processor() or platform.machine(), "cpu": cpu_name(),
                      "cpus": os.cpu_count(), "load_average_1min_before": round(load_before, 2),
                      "versions": package_versions(), "commit": git_commit()}
    if out is not None:
        atomic_write_json(out, result)
    return result


def cpu_name() -> str:
    """The CPU's model name (from /proc/cpuinfo; the platform's processor string elsewhere)."""
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or "unknown"
