"""Loading a trained dSLATE for everything downstream (NCS graph, baselines, notebooks).

    model = ncs_lite.load_dslate("ncs_lite/assets/dslate_block_rearrange_reduced.pt")
    out = model.infer(images)          # images (B, 64, 64, 3) uint8
    out.slots, out.types, out.states, out.masks   # (B,K,D) (B,K,Dz) (B,K,Ds) (B,K,64,64)
    next_slots = model.predict(out.slots, actions)  # actions (B, 6)

`infer` checks its input (ValueError naming the bad shape or dtype and what was expected).
How the shipped assets were made: the Makefile's asset targets (`make block-graphs`,
`make baseline-assets`, `make robogym-assets`, `make robogym-baseline-assets`) and
docs/HISTORY.md, "The shipped block-rearrange checkpoint: how it was made".
"""
from __future__ import annotations

from pathlib import Path

import torch

from .config import from_dict
from .models.dslate import DSlate
from .training import read_checkpoint, resolve_device
from .utils import PACKAGE_DIR, cache_dir

__all__ = ["load_dslate", "obtain_dslate", "shipped_asset", "SHIPPED_CHECKPOINT", "SHIPPED_GRAPH",
           "SHIPPED_SLOT_GRAPH"]

# The `reduced` block-rearrange checkpoint shipped with the kit (module docstring: how it was made).
SHIPPED_CHECKPOINT = PACKAGE_DIR / "assets" / "dslate_block_rearrange_reduced.pt"
# its NCS graph (`python -m ncs_lite graph ... --clusters 30`; `make block-graphs`)
SHIPPED_GRAPH = PACKAGE_DIR / "assets" / "graph_block_rearrange_reduced.pt"
# its graph on slot states (`graph ... --state slot`: Table 3's second column)
SHIPPED_SLOT_GRAPH = PACKAGE_DIR / "assets" / "graph_block_rearrange_reduced_slot.pt"
# the baselines' and the oracles' assets (`make baseline-assets`: the Makefile holds the commands)
ASSETS = PACKAGE_DIR / "assets"
SHIPPED_ORACLE_GRAPH = ASSETS / "graph_block_rearrange_oracle.pt"              # ncs-oracle, masks
SHIPPED_POSITION_GRAPH = ASSETS / "graph_block_rearrange_oracle_position.pt"   # ncs-oracle, positions
SHIPPED_NF_GRAPH = ASSETS / "nf_graph_block_rearrange_reduced.pt"             # nf, bound by SHIPPED_GRAPH
SHIPPED_NF_ORACLE_GRAPH = ASSETS / "nf_graph_block_rearrange_oracle.pt"       # nf-oracle
SHIPPED_POLICIES = {"bc": ASSETS / "bc_block_rearrange_reduced.pt", "iql": ASSETS / "iql_block_rearrange_reduced.pt"}
_SHIPPED_GRAPHS = {("ncs", "mask"): SHIPPED_GRAPH, ("ncs", "slot"): SHIPPED_SLOT_GRAPH,
                   ("ncs-oracle", "mask"): SHIPPED_ORACLE_GRAPH, ("ncs-oracle", "slot"): SHIPPED_POSITION_GRAPH,
                   ("nf", "mask"): SHIPPED_NF_GRAPH, ("nf-oracle", "mask"): SHIPPED_NF_ORACLE_GRAPH}
# robogym-rearrange: its `reduced` checkpoint, its graph on slot states (Table 3's
# second column, 45 nodes) and the position oracle's graph (`make robogym-assets`)
ROBOGYM_CHECKPOINT = ASSETS / "dslate_robogym_rearrange_reduced.pt"
ROBOGYM_SLOT_GRAPH = ASSETS / "graph_robogym_rearrange_reduced_slot.pt"
ROBOGYM_POSITION_GRAPH = ASSETS / "graph_robogym_rearrange_oracle_position.pt"
# ... and its baselines (`make robogym-baseline-assets`), NF bound by the two graphs above
ROBOGYM_POLICIES = {"bc": ASSETS / "bc_robogym_rearrange_reduced.pt", "iql": ASSETS / "iql_robogym_rearrange_reduced.pt"}
ROBOGYM_NF_GRAPH = ASSETS / "nf_graph_robogym_rearrange_reduced.pt"
ROBOGYM_NF_ORACLE_GRAPH = ASSETS / "nf_graph_robogym_rearrange_oracle.pt"
_SHIPPED = {
    "block-rearrange": {"model": SHIPPED_CHECKPOINT, "policy": SHIPPED_POLICIES, "graph": _SHIPPED_GRAPHS},
    "robogym-rearrange": {"model": ROBOGYM_CHECKPOINT, "policy": ROBOGYM_POLICIES,
                          "graph": {("ncs", "slot"): ROBOGYM_SLOT_GRAPH, ("ncs-oracle", "slot"): ROBOGYM_POSITION_GRAPH,
                                    ("nf", "slot"): ROBOGYM_NF_GRAPH, ("nf-oracle", "slot"): ROBOGYM_NF_ORACLE_GRAPH}},
}
SHIPPED_ENVS = tuple(_SHIPPED)
# 4-object training episodes per preset (`reduced`: as many as the shipped checkpoint's buffer)
TRAIN_EPISODES = {"ci": 16, "reduced": 5000, "paper": 5000}


def load_dslate(path: str | Path = SHIPPED_CHECKPOINT, device=None) -> DSlate:
    """Rebuild a dSLATE from a checkpoint written by `train` (weights_only loading), in eval
    mode on `device` (default: CUDA when available, else CPU). ValueError when the file is
    not a dSLATE checkpoint or does not match this code."""
    device = resolve_device(device)
    ckpt = read_checkpoint(path, map_location=device)
    try:
        cfg = from_dict(ckpt["config"])
    except (ValueError, TypeError) as e:
        raise ValueError(f"checkpoint {path} holds a config this code cannot use: {e}") from e
    try:
        model = DSlate(cfg)
    except (ValueError, RuntimeError) as e:
        raise ValueError(f"checkpoint {path} holds a config this code cannot build a dSLATE from: {e}") from None
    try:
        model.load_state_dict(ckpt["model"])
    except RuntimeError as e:
        raise ValueError(f"checkpoint {path} does not match this code's dSLATE "
                         f"(preset {cfg.name!r}): {e}") from e
    model.checkpoint_info = {k: ckpt.get(k) for k in ("step", "env", "data", "precision", "seconds",
                                                      "last", "code_version", "overrides")}
    return model.to(device).eval()


def obtain_dslate(preset: str = "reduced", train_from_scratch: bool = False, seed: int = 0,
                  env: str = "block-rearrange", device=None) -> tuple[DSlate, Path]:
    """The notebooks' "load the checkpoint if present, else train": returns (model, path).

    * `reduced` without `train_from_scratch`: `env`'s shipped checkpoint, when present.
    * otherwise: train at `preset` (train.seed = `seed`) on the cached 4-object buffer
      `data.cached_buffer(TRAIN_EPISODES[preset], seed=seed)`, writing
      `<cache>/checkpoints/dslate-<env>-<preset>-s<seed>.pt`. A finished checkpoint there is
      reused (unless `train_from_scratch`), an interrupted one is resumed, and one made with
      another config, env, buffer or training code is retrained; each decision is printed.
    With preset="reduced", seed=0 this is the command that made the shipped checkpoint.
    """
    from .cache import load_or_train
    from .config import get_preset
    from .data import cached_buffer
    from .training import train

    shipped = _SHIPPED.get(env, {}).get("model")
    if preset == "reduced" and not train_from_scratch and shipped is not None and shipped.exists():
        return load_dslate(shipped, device), shipped
    cfg = get_preset(preset, env)
    cfg.train.seed = int(seed)
    path = cache_dir() / "checkpoints" / f"dslate-{env}-{preset}-s{seed}.pt"
    data = cached_buffer(TRAIN_EPISODES[preset], env=env, num_objects=4, seed=int(seed))

    def unfinished(ckpt: Path) -> str | None:
        step, total = int(read_checkpoint(ckpt)["step"]), cfg.train.total_steps()
        return None if step >= total else f"at step {step} of {total}"

    model = load_or_train(path, unfit=lambda ckpt: _unfit(ckpt, cfg, env, data), unfinished=unfinished,
                          train=lambda resume, force: train(cfg, data, path, resume=resume, force=force,
                                                            device=device, env=env),
                          load=lambda ckpt: load_dslate(ckpt, device), who="obtain_dslate",
                          from_scratch=train_from_scratch)
    return model, path


def _unfit(path: Path, cfg, env: str, data: Path) -> str | None:
    """Why the cached checkpoint at `path` cannot be reused or resumed, or None."""
    from .config import saved_config_diff
    from .data import manifest_hash
    from .training import training_code_version

    try:
        ckpt = read_checkpoint(path)
    except ValueError as e:
        return f"it cannot be read ({e})"
    diff = saved_config_diff(ckpt["config"], cfg)
    if diff:
        return f"it was trained with another config ({'; '.join(diff[:3])})"
    if ckpt.get("env") != env:
        return f"it was trained on {ckpt.get('env')!r}, not {env!r}"
    if (ckpt.get("data") or {}).get("manifest_sha256") != manifest_hash(data):
        return "it was trained on another buffer (manifest hash differs)"
    if (ckpt.get("code_version") or {}).get("training_code") != training_code_version():
        return "the training code changed since it was trained"
    return None


def shipped_asset(env: str, method: str, need: str, state: str = "mask") -> Path:
    """The shipped `reduced` file a method runs from when no path is given: `need` is
    "model" (the dSLATE checkpoint), "graph" or "policy" (see `evaluation.NEEDS`).
    ValueError when the kit ships none for that env, method and state."""
    flag = {"model": "--checkpoint", "graph": "--graph", "policy": "--policy"}.get(need)
    if flag is None:
        raise ValueError(f"need must be 'model', 'graph' or 'policy', got {need!r}")
    path = None
    if env in _SHIPPED:
        shipped = _SHIPPED[env]
        path = {"model": shipped["model"], "policy": shipped["policy"].get(method),
                "graph": shipped["graph"].get((method, state))}[need]
    if path is None:
        raise ValueError(f"the kit ships no {need} for {method!r} on {env!r} with {state!r} states; pass {flag}")
    if not path.exists():
        raise FileNotFoundError(f"the shipped {need} {path} is missing; `make baseline-assets` rebuilds it, "
                                f"or pass {flag}")
    return path
