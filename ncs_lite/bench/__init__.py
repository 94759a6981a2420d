"""Benchmarks (`python -m ncs_lite bench ...`); each module has `run() -> dict`."""
