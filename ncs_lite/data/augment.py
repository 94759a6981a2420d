"""Colour augmentation for the segmentation path (`TrainConfig.color_augment`; not in the paper).

Why: with the pixel CNN and the mixture decoder (`reduced`), slot attention learns a soft
k-means over colours, and that search locks in. Each training run ends with one of the
buffer's 8 colours always in the floor's slot (the floor's look drifts toward it, and its
attention there saturates at exactly 1, so no gradient moves it out): blue in the shipped
seed-0 checkpoint, green in a rerun of the same recipe. Training the segmentation on
videos whose RGB channels are permuted (one random order per video, the identity among the
six) shows it 8 x 6 colours in which no fixed colour can be merged with the grey floor; with
a sixth slot (one spare) no colour was absorbed in the runs that chose this (notebook 04).
A channel permutation keeps every cube's shape, position and contrast with the floor.

Shapes: videos (B, T, H, W, 3) uint8 -> the same, channels permuted per video.
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = ["COLOR_AUGMENTS", "permute_channels"]

COLOR_AUGMENTS = ("none", "channels")


def permute_channels(videos: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """videos (B, T, H, W, C) with the C channels of each video in an order drawn from `rng`
    (all C! orders equally likely, the identity included); the same order for every frame."""
    if videos.ndim != 5:
        raise ValueError(f"videos must have shape (B, T, H, W, C), got {tuple(videos.shape)}")
    B, C = videos.shape[0], videos.shape[-1]
    order = torch.from_numpy(np.stack([rng.permutation(C) for _ in range(B)]))    # (B, C)
    return torch.gather(videos, 4, order[:, None, None, None, :].to(videos.device).expand_as(videos))
