"""Figure helpers shared by the notebooks: one `save_fig`, filmstrips, presets.

`save_fig` writes figures/<notebook>/<name>.png and .pdf plus <name>.json with the
parameters, seed, package versions and commit that made it, so every figure in the
repo can be traced to the run that drew it.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import BoundaryNorm, ListedColormap

from .utils import (REPO_DIR, atomic_path, atomic_write_json, figures_dir, notebook_run, package_versions,
                    provenance, relative_to_repo)

PRESETS = ("ci", "reduced", "paper")


OWNER_PRESET = "reduced"   # the preset whose figures are committed in figures/
_PRESET: str | None = None  # the preset the running notebook resolved (None: not known)


def resolve_preset(preset: str) -> str:
    """The preset a notebook runs at: $NCS_LITE_PRESET (set by `make test`) wins over the
    `parameters` cell, so nbmake runs every notebook at `ci` without editing it. The answer is
    remembered: `figure_folder` sends figures of any preset but `reduced` away from figures/."""
    global _PRESET
    preset = os.environ.get("NCS_LITE_PRESET", preset)
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {PRESETS}, got {preset!r}")
    _PRESET = preset
    return preset


def figure_folder(notebook: str) -> Path:
    """figures/<notebook>/, with two exceptions that keep the committed figures/ what
    `make reproduce` drew:

    - the notebook resolved a preset other than `reduced` (e.g. `ci` in an interactive session)
      and $NCS_LITE_FIGURES is not set: build/figures/<preset>/<notebook>/;
    - the tree has uncommitted changes and the target is the committed `figures/` (unless
      NCS_LITE_ALLOW_DIRTY=1): build/figures-dirty/<notebook>/, so a committed figure always
      names the clean commit that drew it. `make reproduce` refuses a dirty tree up front; an
      interactive session writes beside it and says where."""
    if _PRESET is not None and _PRESET != OWNER_PRESET and not os.environ.get("NCS_LITE_FIGURES"):
        folder = REPO_DIR / "build" / "figures" / _PRESET / notebook
        if (_PRESET, notebook) not in _WARNED:
            _WARNED.add((_PRESET, notebook))
            print(f"(preset {_PRESET}: figures of {notebook} go to {relative_to_repo(folder)}; "
                  f"figures/ holds the `{OWNER_PRESET}` ones)")
        return folder
    folder = figures_dir() / notebook
    try:
        provenance(folder)
    except ValueError:
        scratch = REPO_DIR / "build" / "figures-dirty" / notebook
        if notebook not in _WARNED:
            _WARNED.add(notebook)
            print(f"(uncommitted changes in the kit: figures of {notebook} go to "
                  f"{relative_to_repo(scratch)}, not figures/, so figures/ keeps naming clean commits)")
        return scratch
    return folder


_WARNED: set = set()


def save_fig(fig, notebook: str, name: str, params: dict | None = None, model=None) -> Path:
    """Save `fig` as PNG + PDF + JSON under `figure_folder(notebook)`; return the PNG path.

    The JSON records the parameters, package versions, the commit (and whether the tree was
    dirty) and, given the `model` drawn, its checkpoint's commit, `--set` overrides and buffer.
    """
    folder = figure_folder(notebook)
    folder.mkdir(parents=True, exist_ok=True)
    for ext in ("png", "pdf"):
        with atomic_path(folder / f"{name}.{ext}") as tmp:
            fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight")
    record = {"notebook": notebook, "figure": name, "params": _repo_relative(params or {}),
              "versions": package_versions(), **provenance(folder, allow_dirty=True)}
    info = getattr(model, "checkpoint_info", None)
    if info:
        record["model"] = {"commit": (info.get("code_version") or {}).get("commit"),
                           "overrides": info.get("overrides") or [], "data": info.get("data"),
                           "step": info.get("step")}
    atomic_write_json(folder / f"{name}.json", record)
    return folder / f"{name}.png"


def _repo_relative(value):
    """`value` with every absolute path inside the repo (a str or Path, at any depth) made
    relative to it: a figure's record must not name the machine or checkout that drew it."""
    if isinstance(value, dict):
        return {k: _repo_relative(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_repo_relative(v) for v in value]
    if isinstance(value, (str, Path)) and os.path.isabs(value):
        return relative_to_repo(value)
    return value


def filmstrip(axes_row, frames, titles=None):
    """Draw frames (T, H, W, 3) uint8 along a row of matplotlib axes."""
    for t, ax in enumerate(axes_row):
        ax.axis("off")
        if t < len(frames):
            ax.imshow(np.asarray(frames[t]), interpolation="nearest")
            if titles is not None:
                ax.set_title(titles[t], fontsize=8)


# ---------------------------------------------------------------------- drawing helpers
# (figures that say what they show: arena positions drawn on the image)

def arena_to_pixel(env, xy, z: float = 0.0) -> np.ndarray:
    """Arena coordinates (..., 2) in metres -> image coordinates (..., 2) = (column, row) in
    pixels of a block-rearrange observation, through the env's own camera matrices, so a
    marker drawn at the result sits where the renderer put that point (points off the image
    come out outside 0..image_size). `z` is the height of the points (0 = the floor)."""
    xy = np.asarray(xy, np.float64)
    view = np.asarray(env._view, np.float64).reshape(4, 4).T     # PyBullet: column-major
    proj = np.asarray(env._proj, np.float64).reshape(4, 4).T
    pts = np.concatenate([xy, np.full(xy.shape[:-1] + (1,), z), np.ones(xy.shape[:-1] + (1,))], -1)
    clip = pts @ (proj @ view).T                                  # (..., 4)
    ndc = clip[..., :2] / clip[..., 3:]
    size = env.config.image_size
    return np.stack([(ndc[..., 0] + 1) / 2 * size - 0.5, (1 - ndc[..., 1]) / 2 * size - 0.5], -1)


def ground_truth_image(true_masks, colors, floor=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Ground-truth segmentation (k, H, W) bool + object colours (k, 3) in [0, 1] -> an RGB
    image (H, W, 3) in [0, 1]: each object's pixels in its colour, the rest `floor` (black,
    so the panel cannot be mistaken for the rendered image)."""
    true, colors = np.asarray(true_masks, bool), np.asarray(colors, np.float64)
    if true.ndim != 3 or colors.shape != (true.shape[0], 3):
        raise ValueError(f"need masks (k, H, W) and colours (k, 3), got {true.shape} and {colors.shape}")
    out = np.empty(true.shape[1:] + (3,))
    out[:] = floor
    for o in range(true.shape[0]):
        out[true[o]] = colors[o]
    return out


def slot_titles(owner, background, num_slots: int, names) -> list[str]:
    """Titles for one image's K slot masks from `metrics.slot_assignment` (one image's row):
    owner (k,) slot per object, background the floor's slot, names (k,) object names.
    A slot reads "floor", an object's name, several names joined by "+" (a slot sharing
    objects, or the floor holding one: "floor+green"), or "-" when it holds nothing."""
    owner = np.asarray(owner)
    titles = []
    for j in range(num_slots):
        parts = (["floor"] if int(background) == j else []) + [str(names[o]) for o in np.flatnonzero(owner == j)]
        titles.append("+".join(parts) if parts else "-")
    return titles


def token_colours(vocab_size: int, seed: int = 0):
    """(cmap, norm) that give every token id of a `vocab_size` vocabulary one fixed colour,
    the same in every image (pass both to `imshow`). Colours are shuffled so that
    neighbouring ids do not look alike."""
    base = colormaps["hsv"](np.linspace(0, 1, vocab_size, endpoint=False))[:, :3]
    shade = 0.55 + 0.45 * (np.arange(vocab_size) % 3) / 2        # vary lightness too
    colours = base * shade[:, None]
    colours = colours[np.random.default_rng(seed).permutation(vocab_size)]
    return ListedColormap(colours), BoundaryNorm(np.arange(vocab_size + 1) - 0.5, vocab_size)


def measured_time(notebook: str, env: str = "block-rearrange") -> str:
    """How long `notebook` took at `reduced` on `env`, from figures/notebook_times.json (written
    by `make reproduce`: {"seconds": {"NN_name": s, "NN_name_robogym": s, ...}, "commit": ...,
    "dirty": ...}, a run on another env under `utils.notebook_run`'s name; a flat
    {"NN_name": s, ...} is read too), as a sentence for the notebook's setup cell, or
    "not measured yet" when the file or the entry is missing."""
    notebook = notebook_run(notebook, env)
    path = REPO_DIR / "figures" / "notebook_times.json"
    try:
        times = json.loads(path.read_text())
        seconds = float(times.get("seconds", times)[notebook])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return f"time of {notebook} at `reduced`: not measured yet"
    amount = f"about {max(1, round(seconds))} s" if seconds < 90 else f"about {round(seconds / 60)} min"
    commit = str(times.get("commit") or "")[:7]
    where = f" at commit {commit}" + (" with uncommitted changes" if times.get("dirty") else "") if commit else ""
    return f"time of {notebook}: {amount} at `reduced` (measured by `make reproduce`{where})"
