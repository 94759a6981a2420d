"""Behaviour cloning (BC, Appendix B): imitate the buffer's actions with an MSE loss.

The policy is goal-conditioned: (current image, goal image) -> action. The buffer holds no
goals, so each transition (s_t, a_t) gets one in hindsight, a later frame s_j (j > t) of the
same episode (`HindsightGoals`). The loss is the MSE in box units (`ActionBox`: every
action dimension scaled to [-1, 1] by the env's Box), so x, y and the move weigh alike.

    model, log = train_bc(buffer, env.action_space, bc_config("reduced"))
    agent = BCAgent(model)          # reset(obs, info) / act(obs, info) -> (action, False)

Appendix B gives no sizes for BC; the presets are the kit's: `ci` (seconds), `reduced`
(minutes on 2 CPU cores), `paper` (the full-size setting; not numbers from the paper).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .goal_conditioned import (preset_config, ActionBox, HindsightGoals, PixelEncoder, PolicyAgent, as_buffer,
                               check_channels, check_int, load_policy, mlp, run_training, save_policy,
                               training_setup)

KIND = "bc"


@dataclass
class BCConfig:
    channels: tuple[int, ...] = (32, 64, 64, 64)   # CNN widths, one stride-2 conv each
    feature_dim: int = 256      # encoder output
    hidden: int = 256           # width of the 2-layer action head
    steps: int = 20_000         # optimizer steps
    batch_size: int = 64
    lr: float = 3e-4            # Adam
    seed: int = 0               # initialisation and hindsight draws

    def validate(self) -> "BCConfig":
        check_channels(self.channels)
        for name, low in (("feature_dim", 1), ("hidden", 1), ("steps", 1), ("batch_size", 1), ("seed", 0)):
            check_int(f"bc.{name}", getattr(self, name), low)
        if not (isinstance(self.lr, (int, float)) and np.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"bc.lr must be a finite number > 0, got {self.lr!r}")
        return self


BC_PRESETS = {
    "ci": BCConfig(channels=(8, 16, 16), feature_dim=32, hidden=32, steps=20, batch_size=8),
    "reduced": BCConfig(channels=(16, 32, 32, 32), feature_dim=128, hidden=128, steps=4000, batch_size=32,
                        lr=1e-3),   # the kit's choice for a short run (docs/HISTORY.md, "Moved from the docstrings")
    "paper": BCConfig(),
}


def bc_config(preset: str = "reduced", **overrides) -> BCConfig:
    """A fresh copy of a named preset, with field overrides."""
    return preset_config(BC_PRESETS, preset, overrides, "BC")


class BCPolicy(nn.Module):
    """(image, goal) uint8 (B, H, W, 3) -> action in box units (B, 6), tanh-bounded."""

    def __init__(self, cfg: BCConfig, box: ActionBox):
        super().__init__()
        self.cfg = cfg.validate()
        self.encoder = PixelEncoder(cfg.channels, cfg.feature_dim)
        self.head = mlp([cfg.feature_dim, cfg.hidden, 6])
        self.box = box

    def forward(self, image: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.head(self.encoder(image, goal)))         # (B, 6) in [-1, 1]

    @torch.no_grad()
    def act(self, image: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Actions in env units (B, 6), inside the Box."""
        return self.box.from_unit(self(image, goal))


def train_bc(buffer, action_space, cfg: BCConfig | None = None, *, out=None,
             checkpoint_every: int | None = None, resume: bool = False,
             info: dict | None = None) -> tuple[BCPolicy, list[dict]]:
    """Train BC on a buffer (dict of `load_buffer`, or its directory).

    Returns (model in eval mode, log: one {"step", "loss"} per step; loss = batch MSE in box
    units). `out`, `checkpoint_every`, `resume`: see `goal_conditioned.run_training`; `info` is
    stored in the checkpoint."""
    cfg = (cfg or BCConfig()).validate()
    model, box, goals = training_setup(buffer, action_space, cfg, BCPolicy)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)

    def step_fn(step: int) -> dict:
        b = goals.sample(step, cfg.batch_size)
        loss = (model(b["image"], b["goal"]) - box.to_unit(b["action"])).square().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        return {"loss": loss.item()}

    log = run_training(KIND, model, optimizer, step_fn, cfg, out=out, checkpoint_every=checkpoint_every,
                       resume=resume, info={"episodes": goals.episodes, **(info or {})})
    return model, log


@torch.no_grad()
def bc_mse(model: BCPolicy, buffer, batch_size: int = 256) -> float:
    """MSE in box units over every hindsight pair (t < j) of the buffer."""
    goals = HindsightGoals(as_buffer(buffer))
    e, t, j = goals.all_indices()
    total = 0.0
    for i in range(0, len(e), batch_size):
        b = goals.batch(e[i:i + batch_size], t[i:i + batch_size], j[i:i + batch_size])
        total += float((model(b["image"], b["goal"]) - model.box.to_unit(b["action"])).square().sum())
    return total / (len(e) * 6)


def mean_action_mse(buffer, action_space) -> float:
    """MSE in box units of predicting the mean action, over the same pairs as `bc_mse`:
    the score of a policy that ignores both images."""
    goals = HindsightGoals(as_buffer(buffer))
    e, t, _ = goals.all_indices()
    u = ActionBox.from_space(action_space).to_unit(goals.actions[torch.as_tensor(e), torch.as_tensor(t)])
    return float((u - u.mean(0)).square().mean())


def save_bc(path, model: BCPolicy, log: list[dict] | None = None):
    """A finished model (no optimizer state) as a `bc` checkpoint."""
    return save_policy(path, KIND, model, log)


def load_bc(path) -> BCPolicy:
    """A BC model from a `bc` checkpoint (weights_only), in eval mode."""
    return load_policy(path, KIND, BCConfig, BCPolicy)


class BCAgent(PolicyAgent):
    """The harness's interface around a trained `BCPolicy`: its mean action, never random."""


__all__ = ["BCAgent", "BCConfig", "BCPolicy", "BC_PRESETS", "bc_config", "bc_mse", "load_bc",
           "mean_action_mse", "save_bc", "train_bc"]
