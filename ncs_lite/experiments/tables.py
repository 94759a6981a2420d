"""The results tables on disk: `figures/tables/<name>.csv` (one row per seed, point or
method) and `<name>.json` (the rows, the summary and the provenance), one writer for every
table (`reproduce`, `stress`, `hyperparameters`). Writing a committed table regenerates the
README's blocks and docs/results.md (`docs.write_docs`), so the prose never lags the numbers.

A table records torch's thread count (`threads`): float32 sums split over threads round in
another order, and a few near-ties (an argmax, a k-means assignment) can land elsewhere, so a
table is bit for bit the same only when recomputed on as many threads; the command the docs
rebuild names them (`OMP_NUM_THREADS=N`).
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import torch

from ..docs import write_docs
from ..utils import atomic_write_json, atomic_write_text, figures_dir, provenance

__all__ = ["table_dir", "write_table"]


def table_dir(out_dir) -> Path:
    """`out_dir`, or figures/tables/ (the committed tables) when it is None."""
    return Path(out_dir) if out_dir else figures_dir() / "tables"


def write_table(name: str, rows: list[dict], meta: dict, out_dir=None, allow_dirty=False) -> Path:
    """figures/tables/<name>.csv + .json, refusing a dirty tree for the committed folder."""
    folder = table_dir(out_dir)
    made = provenance(folder / f"{name}.json", allow_dirty)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(folder / f"{name}.csv", buf.getvalue())
    atomic_write_json(folder / f"{name}.json", {"table": name, "rows": rows, **meta, **made,
                                                    "threads": torch.get_num_threads()})
    if out_dir is None:                 # the committed tables: the README's blocks follow them
        write_docs()
    return folder / f"{name}.csv"
