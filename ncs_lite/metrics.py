"""Segmentation metrics: foreground adjusted Rand index (fg-ARI).

ARI compares two partitions of the same pixels and is 1 for identical partitions (up to
relabelling) and ~0 for chance. Foreground ARI (Greff et al. 2019; Locatello et al. 2020)
scores only pixels where the ground truth has an object, so how the background is split
does not count: the question is whether each object gets its own slot.

Shapes: predicted masks (B, K, H, W) (soft or hard; argmax over K), ground truth (B, k, H, W)
bool, one channel per object (pixels in no channel are background).
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = ["adjusted_rand_index", "foreground_ari", "absorbed_by_background"]


def adjusted_rand_index(labels_true: np.ndarray, labels_pred: np.ndarray) -> float:
    """ARI of two integer labelings of the same items (1-D arrays of equal length).

    Returns 1.0 when both put all items in one cluster (or there are < 2 items): the
    partitions agree and the formula's 0/0 is taken as perfect agreement.
    """
    labels_true, labels_pred = np.asarray(labels_true).ravel(), np.asarray(labels_pred).ravel()
    if labels_true.shape != labels_pred.shape:
        raise ValueError(f"label arrays must have the same length, got {labels_true.shape} "
                         f"and {labels_pred.shape}")
    n = labels_true.size
    if n < 2:
        return 1.0
    _, t = np.unique(labels_true, return_inverse=True)
    _, p = np.unique(labels_pred, return_inverse=True)
    table = np.zeros((t.max() + 1, p.max() + 1), dtype=np.int64)
    np.add.at(table, (t, p), 1)
    comb = lambda x: x * (x - 1) / 2.0  # noqa: E731 - pairs among x items
    sum_cells = comb(table).sum()
    sum_rows, sum_cols = comb(table.sum(1)).sum(), comb(table.sum(0)).sum()
    expected = sum_rows * sum_cols / comb(n)
    max_index = 0.5 * (sum_rows + sum_cols)
    if max_index == expected:
        return 1.0
    return float((sum_cells - expected) / (max_index - expected))


def foreground_ari(pred_masks, true_masks) -> np.ndarray:
    """fg-ARI per image: pred_masks (B, K, H, W), true_masks (B, k, H, W) bool -> (B,) float.

    Images without foreground pixels get NaN (average with np.nanmean).
    """
    pred = pred_masks.detach().cpu().numpy() if isinstance(pred_masks, torch.Tensor) else np.asarray(pred_masks)
    true = true_masks.detach().cpu().numpy() if isinstance(true_masks, torch.Tensor) else np.asarray(true_masks)
    if pred.ndim != 4 or true.ndim != 4:
        raise ValueError(f"masks must have shape (B, K, H, W), got predicted {pred.shape} and "
                         f"ground truth {true.shape}")
    if pred.shape[0] != true.shape[0] or pred.shape[2:] != true.shape[2:]:
        raise ValueError(f"predicted masks {pred.shape} and ground truth {true.shape} must agree "
                         "on batch size and image size (B, ., H, W)")
    if true.dtype != bool:
        raise ValueError(f"ground-truth masks must be bool, got {true.dtype}")
    pred_label = pred.argmax(axis=1)              # (B, H, W)
    true_label = true.argmax(axis=1)              # (B, H, W): object index where foreground
    fg = true.any(axis=1)                         # (B, H, W)
    out = np.full(pred.shape[0], np.nan)
    for b in range(pred.shape[0]):
        if fg[b].any():
            out[b] = adjusted_rand_index(true_label[b][fg[b]], pred_label[b][fg[b]])
    return out


def absorbed_by_background(pred_masks, true_masks) -> np.ndarray:
    """Which objects have no slot of their own, (B, k) bool.

    An object is absorbed when the slot winning most of its pixels (argmax over slots) is
    the slot winning most background pixels. fg-ARI hides this when it always happens to
    the same object: one cube merged with the floor costs only its own pixels' pairs, yet
    NCS can neither see nor move that cube (notebooks 03 and 06).
    """
    pred = pred_masks.detach().cpu().numpy() if isinstance(pred_masks, torch.Tensor) else np.asarray(pred_masks)
    true = np.asarray(true_masks.cpu() if isinstance(true_masks, torch.Tensor) else true_masks)
    if pred.ndim != 4 or true.ndim != 4 or pred.shape[0] != true.shape[0] or pred.shape[2:] != true.shape[2:]:
        raise ValueError(f"masks must have shapes (B, K, H, W) and (B, k, H, W) with equal B, H, W, "
                         f"got predicted {pred.shape} and ground truth {true.shape}")
    K = pred.shape[1]
    won = pred.argmax(axis=1)                                           # (B, H, W)
    out = np.zeros(true.shape[:2], bool)
    for b in range(len(won)):
        floor = ~true[b].any(0)
        background = np.bincount(won[b][floor], minlength=K).argmax() if floor.any() else -1
        for o in range(true.shape[1]):
            if true[b, o].any():
                out[b, o] = np.bincount(won[b][true[b, o]], minlength=K).argmax() == background
    return out


def evaluate_segmentation(model, directory, num_slots: int | None = None, iterations: int | None = None,
                          episodes: int | None = None, batch_size: int = 100, seed: int = 0) -> dict:
    """fg-ARI of a dSLATE's masks on every frame of a buffer (e.g. held-out episodes).

    num_slots defaults to the model's K; for scenes with more objects than it was trained on,
    pass one more than the number of objects (slot attention works for any K).
    Returns {"fg_ari": mean, "std": ..., "sem": ..., "images": n, "num_slots": K, "iterations": it}.
    """
    from .data import load_buffer

    buf = load_buffer(directory)
    frames = buf["frames"][:episodes].reshape(-1, *buf["frames"].shape[2:])     # (E*5, H, W, 3)
    masks = buf["masks"][:episodes].reshape(-1, *buf["masks"].shape[2:])        # (E*5, k, H, W)
    scores = []
    for i in range(0, len(frames), batch_size):
        out = model.infer(frames[i:i + batch_size], iterations=iterations, num_slots=num_slots, seed=seed)
        scores.append(foreground_ari(out.masks, masks[i:i + batch_size]))
    s = np.concatenate(scores)
    s = s[~np.isnan(s)]
    return {"fg_ari": float(s.mean()), "std": float(s.std()), "sem": float(s.std() / np.sqrt(len(s))),
            "images": int(len(s)), "num_slots": int(num_slots or model.cfg.slots.num_slots),
            "iterations": int(iterations or model.cfg.slots.eval_iterations)}
