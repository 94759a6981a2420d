"""The kit's files of tensors (dSLATE, BC and IQL checkpoints; NCS and NF graphs): written
atomically, read with `torch.load(weights_only=True)`, tagged with their kind and checked
against a digest of their tensors.

    atomic_torch_save(sd, path)                       # readers see the old file or the new one
    sd = load_tensor_file(path, "transition graph")   # ValueError naming the file, not a pickle error
    check_weights(sd, path, ("model",))               # a flipped byte or a NaN is refused

Here rather than in `utils` because these need torch and `cache.digest`, while `utils` is
imported by every command, torch-free ones too (`python -m ncs_lite.docs`).
"""
from __future__ import annotations

import os
from pathlib import Path

import torch

from .cache import digest
from .utils import atomic_path, one_line

__all__ = ["FILE_KINDS", "atomic_torch_save", "check_weights", "file_kind", "load_tensor_file", "tensor_digest"]


def atomic_torch_save(obj, path: str | os.PathLike) -> None:
    """`torch.save(obj, path)` through `utils.atomic_path`: never a half-written file."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def load_tensor_file(path: str | os.PathLike, what: str, hint: str = "", map_location="cpu") -> dict:
    """`torch.load(path, weights_only=True)` of a file that must hold a dict; FileNotFoundError
    or ValueError naming the file and `what` it should be (truncated, not a torch file, a
    pickle that is not plain tensors, a directory) instead of the unpickler's own error."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no {what} at {path}{'; ' + hint if hint else ''}")
    if path.is_dir():
        raise ValueError(f"{path} is a directory, expected a {what} file")
    if not path.is_file():                  # a FIFO or a device: reading it could block for ever
        raise ValueError(f"{path} is not a regular file, expected a {what} file")
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is an empty file, expected a {what} file")
    try:
        obj = torch.load(path, weights_only=True, map_location=map_location)
    except Exception as e:  # noqa: BLE001 - truncated zips, foreign pickles, ... come in many types
        raise ValueError(f"{path} is not a readable {what} ({one_line(e)})") from None
    if not isinstance(obj, dict):
        raise ValueError(f"{path} is not a {what} (it holds a {type(obj).__name__}, expected a dict)")
    return obj


# The kind tag of each file type the kit writes, and what it is called in an error about a
# file passed in the wrong place (`TransitionGraph.load` given a checkpoint, ...).
FILE_KINDS = {"dslate": "a dSLATE checkpoint", "bc": "a BC checkpoint", "iql": "an IQL checkpoint",
              "ncs-graph": "an NCS transition graph", "nf-graph": "an NF graph"}


def file_kind(sd: dict) -> str:
    """What a loaded file is, from its kind tag or, for files written before the tags, its keys."""
    if "kind" in sd:
        return FILE_KINDS.get(sd["kind"], f"a file of kind {sd['kind']!r}")
    if "model_version" in sd:
        return "a dSLATE checkpoint"
    if "centroids" in sd:
        return "an NF graph" if "sets" in sd else "an NCS transition graph"
    return f"a dict with keys {sorted(map(str, sd))[:6]}"


def tensor_digest(sd: dict, keys: tuple[str, ...]) -> str:
    """Digest of a checkpoint's tensors under `keys` (model, optimizer, ...): stored when it
    is saved, compared when it is loaded (`check_weights`)."""
    return digest(*[sd.get(k) for k in keys])


def check_weights(sd: dict, path, keys: tuple[str, ...]) -> dict:
    """ValueError naming `path` when a checkpoint's tensors do not match the content digest
    stored with them (files from before the digest have none) or its weights (`sd["model"]`)
    are not all finite: a flipped byte or a NaN would otherwise load without complaint."""
    model = sd.get("model")
    if not (isinstance(model, dict) and all(isinstance(t, torch.Tensor) for t in model.values())):
        raise ValueError(f"{path} is corrupted: its 'model' must be a dict of tensors, got "
                         f"{type(model).__name__}")
    if "content_digest" in sd and tensor_digest(sd, keys) != sd["content_digest"]:
        raise ValueError(f"{path} is corrupted: its weights do not match the digest stored when it was saved")
    bad = [k for k, t in sd["model"].items()
           if isinstance(t, torch.Tensor) and t.is_floating_point() and not bool(torch.isfinite(t).all())]
    if bad:
        raise ValueError(f"{path} holds non-finite weights ({len(bad)} of {len(sd['model'])} tensors, "
                         f"e.g. {bad[0]}); expected finite ones: retrain it")
    return sd
