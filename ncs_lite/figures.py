"""Figure helpers shared by the notebooks: one `save_fig`, filmstrips, presets.

`save_fig` writes figures/<notebook>/<name>.png and .pdf plus <name>.json with the
parameters, seed, package versions and commit that made it, so every figure in the
repo can be traced to the run that drew it.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .utils import atomic_path, atomic_write_json, figures_dir, git_commit, package_versions

PRESETS = ("ci", "reduced", "paper")


def resolve_preset(preset: str) -> str:
    """The preset a notebook runs at: $NCS_LITE_PRESET (set by `make test`) wins over the
    `parameters` cell, so nbmake runs every notebook at `ci` without editing it."""
    preset = os.environ.get("NCS_LITE_PRESET", preset)
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {PRESETS}, got {preset!r}")
    return preset


def save_fig(fig, notebook: str, name: str, params: dict | None = None) -> Path:
    """Save `fig` as PNG + PDF + JSON under figures/<notebook>/; return the PNG path."""
    folder = figures_dir() / notebook
    folder.mkdir(parents=True, exist_ok=True)
    for ext in ("png", "pdf"):
        with atomic_path(folder / f"{name}.{ext}") as tmp:
            fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight")
    atomic_write_json(folder / f"{name}.json", {
        "notebook": notebook, "figure": name, "params": params or {},
        "versions": package_versions(), "commit": git_commit()})
    return folder / f"{name}.png"


def filmstrip(axes_row, frames, titles=None):
    """Draw frames (T, H, W, 3) uint8 along a row of matplotlib axes."""
    for t, ax in enumerate(axes_row):
        ax.axis("off")
        if t < len(frames):
            ax.imshow(np.asarray(frames[t]), interpolation="nearest")
            if titles is not None:
                ax.set_title(titles[t], fontsize=8)
