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

__all__ = ["adjusted_rand_index", "foreground_ari", "absorbed_by_background", "slot_assignment",
           "lost_in_reconstruction"]


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


def _as_numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def slot_assignment(pred_masks, true_masks) -> tuple[np.ndarray, np.ndarray]:
    """Which slot holds each object, and which slot holds the floor.

    pred_masks (B, K, H, W) soft or hard, true_masks (B, k, H, W) bool. Every pixel goes to
    the slot that wins it (argmax over K). Returns
      owner (B, k) int: the slot winning most of object o's pixels (-1: o has no pixels);
      background (B,) int: the slot winning most pixels outside every object (-1: none).
    A figure titles slot j with the objects whose owner is j (and "floor" when background
    is j); `absorbed_by_background` is owner == background.
    """
    pred, true = _as_numpy(pred_masks), _as_numpy(true_masks)
    if pred.ndim != 4 or true.ndim != 4 or pred.shape[0] != true.shape[0] or pred.shape[2:] != true.shape[2:]:
        raise ValueError(f"masks must have shapes (B, K, H, W) and (B, k, H, W) with equal B, H, W, "
                         f"got predicted {pred.shape} and ground truth {true.shape}")
    true = true.astype(bool)
    K = pred.shape[1]
    won = pred.argmax(axis=1)                                           # (B, H, W)
    owner = np.full(true.shape[:2], -1, np.int64)                       # (B, k)
    background = np.full(true.shape[0], -1, np.int64)                   # (B,)
    for b in range(len(won)):
        floor = ~true[b].any(0)
        if floor.any():
            background[b] = np.bincount(won[b][floor], minlength=K).argmax()
        for o in range(true.shape[1]):
            if true[b, o].any():
                owner[b, o] = np.bincount(won[b][true[b, o]], minlength=K).argmax()
    return owner, background


def absorbed_by_background(pred_masks, true_masks) -> np.ndarray:
    """Which objects have no slot of their own, (B, k) bool.

    An object is absorbed when the slot winning most of its pixels (argmax over slots) is
    the slot winning most background pixels. fg-ARI hides this when it always happens to
    the same object: one cube merged with the floor costs only its own pixels' pairs, yet
    NCS can neither see nor move that cube (notebooks 03 and 06).
    """
    owner, background = slot_assignment(pred_masks, true_masks)
    return (owner >= 0) & (owner == background[:, None])


def lost_in_reconstruction(reconstructions, images, true_masks) -> np.ndarray:
    """Which objects a reconstruction paints as background, (B, k) bool.

    reconstructions and images (B, H, W, 3), uint8 in 0..255 or float in [0, 1] (each
    judged on its own: uint8 is divided by 255); true_masks (B, k, H, W) bool. Object o is
    lost when the reconstruction's mean colour over o's pixels is closer to the image's
    background colour (the mean of the true image outside every object) than to o's own
    mean colour in the true image. A per-pixel error cannot say this: a small cube painted
    as floor costs few pixels (notebook 02: the dVAE paints green cubes as floor).
    Objects without pixels are never lost.
    """
    def unit(x):
        x = _as_numpy(x)
        return x.astype(np.float64) / 255.0 if x.dtype == np.uint8 else x.astype(np.float64)

    rec, img, true = unit(reconstructions), unit(images), _as_numpy(true_masks)
    if rec.shape != img.shape or rec.ndim != 4 or rec.shape[-1] != 3:
        raise ValueError(f"reconstructions and images must both have shape (B, H, W, 3), got "
                         f"{rec.shape} and {img.shape}")
    if true.ndim != 4 or true.shape[0] != img.shape[0] or true.shape[2:] != img.shape[1:3]:
        raise ValueError(f"true_masks must have shape (B={img.shape[0]}, k, {img.shape[1]}, "
                         f"{img.shape[2]}), got {true.shape}")
    true = true.astype(bool)
    out = np.zeros(true.shape[:2], bool)
    for b in range(len(img)):
        floor = ~true[b].any(0)
        if not floor.any():
            continue
        background = img[b][floor].mean(0)                             # (3,)
        for o in range(true.shape[1]):
            m = true[b, o]
            if m.any():
                painted, colour = rec[b][m].mean(0), img[b][m].mean(0)
                out[b, o] = np.linalg.norm(painted - background) < np.linalg.norm(painted - colour)
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
