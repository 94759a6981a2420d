"""Colour augmentation for the segmentation path (`TrainConfig.color_augment`; not in the paper).

Why: with the pixel CNN and the mixture decoder (`reduced`), slot attention learns a soft
k-means over colours, and that search locks in: without augmentation a training run can end
with one of the buffer's 8 colours always in the floor's slot (the floor's look drifts toward
it, and its attention there saturates at exactly 1, so no gradient moves it out). Training
the segmentation on videos whose RGB channels are permuted (one random order per video, the
identity among the six) shows it 8 x 6 colours in which no fixed colour can be merged with
the grey floor; `reduced` pairs it with a spare slot (why: docs/recipe.md, `slots.num_slots`
and `train.color_augment`). A channel permutation keeps every cube's shape, position and
contrast with the floor.

A permutation is an isometry of RGB space, though: it never changes how close two colours
are, so it cannot teach slot attention to split two near ones (orange and yellow differ by
0.31, mostly in green). `"channels_gamma"` also raises each channel of a video to a random
power g (log-uniform in [1/2.5, 2.5]), which stretches some distances and shrinks others,
so no fixed colour distance holds across the training videos (a variant run and not adopted:
docs/results.md, `variants/channels_gamma`).

Shapes: videos (B, T, H, W, 3) uint8 -> the same, channels permuted per video.
"""
from __future__ import annotations

import numpy as np
import torch

from ..config import COLOR_AUGMENTS

__all__ = ["COLOR_AUGMENTS", "augment_colors", "permute_channels", "permute_channels_and_gamma"]

GAMMA_RANGE = 2.5          # g in [1 / GAMMA_RANGE, GAMMA_RANGE], log-uniform


def permute_channels(videos: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """videos (B, T, H, W, C) with the C channels of each video in an order drawn from `rng`
    (all C! orders equally likely, the identity included); the same order for every frame."""
    if videos.ndim != 5:
        raise ValueError(f"videos must have shape (B, T, H, W, C), got {tuple(videos.shape)}")
    B, C = videos.shape[0], videos.shape[-1]
    order = torch.from_numpy(np.stack([rng.permutation(C) for _ in range(B)]))    # (B, C)
    return torch.gather(videos, 4, order[:, None, None, None, :].to(videos.device).expand_as(videos))


def permute_channels_and_gamma(videos: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """`permute_channels`, then each channel of each video raised to its own power g drawn
    log-uniform in [1/GAMMA_RANGE, GAMMA_RANGE] (from `rng`, after the orders), on [0, 1]."""
    permuted = permute_channels(videos, rng).float() / 255.0
    B, C = videos.shape[0], videos.shape[-1]
    g = torch.from_numpy(np.exp(rng.uniform(-np.log(GAMMA_RANGE), np.log(GAMMA_RANGE), size=(B, C)))).float()
    out = permuted ** g[:, None, None, None, :].to(videos.device)
    return (out * 255.0).round().to(videos.dtype)


AUGMENTS = {"channels": permute_channels, "channels_gamma": permute_channels_and_gamma}   # = COLOR_AUGMENTS[1:]


def augment_colors(kind: str, videos: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """The colour augmentation `kind` (a key of AUGMENTS) of `videos`."""
    if kind not in AUGMENTS:
        raise ValueError(f"colour augmentation must be one of {', '.join(map(repr, AUGMENTS))}, got {kind!r}")
    return AUGMENTS[kind](videos, rng)
