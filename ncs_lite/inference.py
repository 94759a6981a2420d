"""Loading a trained dSLATE for everything downstream (NCS graph, baselines, notebooks).

    model = ncs_lite.load_dslate("ncs_lite/assets/dslate_block_rearrange_reduced.pt")
    out = model.infer(images)          # images (B, 64, 64, 3) uint8
    out.slots, out.types, out.states, out.masks   # (B,K,D) (B,K,Dz) (B,K,Ds) (B,K,64,64)
    next_slots = model.predict(out.slots, actions)  # actions (B, 6)

`infer` checks its input (ValueError naming the bad shape or dtype and what was expected).
The checkpoint format lives here with its reader (`read_checkpoint`), so that everything
downstream reads models without importing the trainer; the notebooks' "load the checkpoint if
present, else train" is `training.obtain_dslate`.
How the shipped assets were made: the Makefile's asset targets (`make block-graphs`,
`make baseline-assets`, `make robogym-assets`, `make robogym-baseline-assets`) and
docs/HISTORY.md, "The shipped block-rearrange checkpoint: how it was made".
"""
from __future__ import annotations

from pathlib import Path

import torch

from .config import from_dict
from .models.dslate import MODEL_VERSION, DSlate
from .tensor_files import check_weights, file_kind, load_tensor_file
from .utils import PACKAGE_DIR

__all__ = ["load_dslate", "read_checkpoint", "resolve_device", "shipped_asset", "CHECKPOINT_FORMAT",
           "SHIPPED_CHECKPOINT", "SHIPPED_GRAPH", "SHIPPED_SLOT_GRAPH", "TRAIN_EPISODES"]

# The dSLATE checkpoint file: `training.train` writes it, `read_checkpoint` reads and checks it
CHECKPOINT_FORMAT = 1
CHECKPOINT_KIND = "dslate"                   # files from before the tag have none
DIGESTED = ("model", "optimizer", "rng")     # the tensors the stored content digest covers

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


def slot_env_assets(env: str) -> dict:
    """The shipped `reduced` files of an env read on slot states (robogym-rearrange:
    `make robogym-assets` and `robogym-baseline-assets`; block-stacking: `make stacking-assets`),
    named the same way: its dSLATE, its graph on slot states (Table 3's second column), the
    position oracle's graph, BC and IQL, and NF bound by each of the two graphs."""
    name = env.replace("-", "_")
    return {"model": ASSETS / f"dslate_{name}_reduced.pt",
            "policy": {m: ASSETS / f"{m}_{name}_reduced.pt" for m in ("bc", "iql")},
            "graph": {("ncs", "slot"): ASSETS / f"graph_{name}_reduced_slot.pt",
                      ("ncs-oracle", "slot"): ASSETS / f"graph_{name}_oracle_position.pt",
                      ("nf", "slot"): ASSETS / f"nf_graph_{name}_reduced.pt",
                      ("nf-oracle", "slot"): ASSETS / f"nf_graph_{name}_oracle.pt"}}


_SHIPPED = {"block-rearrange": {"model": SHIPPED_CHECKPOINT, "policy": SHIPPED_POLICIES, "graph": _SHIPPED_GRAPHS},
            **{env: slot_env_assets(env) for env in ("robogym-rearrange", "block-stacking")}}
ROBOGYM_POSITION_GRAPH = _SHIPPED["robogym-rearrange"]["graph"][("ncs-oracle", "slot")]
SHIPPED_ENVS = tuple(_SHIPPED)
SHIPPED_MODELS = {env: shipped["model"] for env, shipped in _SHIPPED.items()}
# 4-object training episodes per preset (`reduced`: as many as the shipped checkpoint's buffer)
TRAIN_EPISODES = {"ci": 16, "reduced": 5000, "paper": 5000}


def resolve_device(device=None) -> torch.device:
    """The given device, else CUDA when available, else CPU."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"unknown device {device!r}; expected 'cpu' or 'cuda' (or 'cuda:N')") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {str(device)!r} asked for, but this torch build sees no CUDA GPU; use 'cpu'")
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device {str(device)!r} is not supported; expected 'cpu' or 'cuda'")
    return device


def read_checkpoint(path: str | Path, map_location="cpu") -> dict:
    """Load and check a dSLATE checkpoint (weights_only=True). ValueError naming `path` when
    it is not one (naming what it is), was written by an incompatible version of the code,
    does not match its content digest, or holds non-finite weights."""
    path = Path(path)
    ckpt = load_tensor_file(path, "dSLATE checkpoint", "train one with `python -m ncs_lite train`",
                            map_location=map_location)
    if ckpt.get("kind", CHECKPOINT_KIND) != CHECKPOINT_KIND or "model" not in ckpt or "config" not in ckpt:
        raise ValueError(f"{path} is not a dSLATE checkpoint (kind {CHECKPOINT_KIND!r} with 'model' and "
                         f"'config'); it holds {file_kind(ckpt)}")
    if ckpt.get("format") != CHECKPOINT_FORMAT or ckpt.get("model_version") != MODEL_VERSION:
        raise ValueError(f"{path} was written by another version of the code: checkpoint format "
                         f"{ckpt.get('format')!r} / model {ckpt.get('model_version')!r}, this code "
                         f"expects format {CHECKPOINT_FORMAT} / model {MODEL_VERSION!r}; retrain it")
    step = ckpt.get("step", 0)
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise ValueError(f"{path} is corrupted: its step must be an integer >= 0, got {step!r}")
    return check_weights(ckpt, path, DIGESTED)


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
