"""Implicit Q-learning (IQL, Appendix B), goal-conditioned, on pixels.

Objectives (1)-(3) of Appendix B, with Q-hat the target network (twin heads, their min):

    L_V(psi)   = E[ L2^tau(min_i Qhat_i(s, a) - V(s)) ],  L2^tau(u) = |tau - 1(u < 0)| u^2   (1)
    L_Q(theta) = E[ (r + gamma (1 - done) V(s') - Q_i(s, a))^2 ]   for both heads i        (2)
    L_pi(phi)  = -E[ min(exp(beta (Qhat(s, a) - V(s))), 100) log pi(a | s) ]              (3)

(3) is written in the appendix without the minus sign; the policy *maximises* the weighted
log-likelihood, so the loss is its negative. The weight cap (100) and the defaults
(expectile 0.7, inverse temperature beta 3, discount 0.99, Polyak rate 0.005, Adam 3e-4)
are those of the IQL paper (Kostrikov et al., 2022).

Goal-conditioned by hindsight (`HindsightGoals`): a goal is a later frame of the same
episode; the reward is 1 and the episode ends (done) when the next frame is that goal,
else the reward is 0 (sparse success).

Decisions (the appendix is silent):
- One CNN encoder over (image, goal) feeds all heads. Only Q's loss trains it; V and the
  policy read its features detached, so (1) and (3) train their own heads only, as with
  separate networks. The target network is a Polyak copy of the encoder and both Q heads.
- One Adam over all parameters and one gradient step on L_V + L_Q + L_pi per batch: the
  three losses reach disjoint parameters, so this is the three updates of IQL on one batch,
  except that Q's TD target uses V before this step's V update.
- pi: a Gaussian in box units, mean tanh(head(features)), state-independent log std
  clamped to [-5, 2]; the agent acts with the mean (the IQL paper evaluates so).

    model, log = train_iql(buffer, env.action_space, iql_config("reduced"))
    agent = IQLAgent(model)
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import torch
from torch import nn

from .goal_conditioned import (preset_config, ActionBox, PixelEncoder, PolicyAgent,
                               check_channels, check_int, load_policy, mlp, run_training, save_policy,
                               training_setup)

KIND = "iql"
LOG_STD_RANGE = (-5.0, 2.0)


@dataclass
class IQLConfig:
    expectile: float = 0.7      # tau of (1), IQL paper
    beta: float = 3.0           # inverse temperature of (3), IQL paper
    discount: float = 0.99      # gamma of (2), IQL paper
    polyak: float = 0.005       # target <- (1 - polyak) target + polyak online, IQL paper
    max_weight: float = 100.0   # cap on exp(beta A), IQL paper
    channels: tuple[int, ...] = (32, 64, 64, 64)   # CNN widths, one stride-2 conv each
    feature_dim: int = 256
    hidden: int = 256           # width of every 2-layer head (IQL paper: 256)
    steps: int = 20_000
    batch_size: int = 256       # IQL paper
    lr: float = 3e-4            # IQL paper, for every network
    seed: int = 0

    def validate(self) -> "IQLConfig":
        check_channels(self.channels)
        for name, low in (("feature_dim", 1), ("hidden", 1), ("steps", 1), ("batch_size", 1), ("seed", 0)):
            check_int(f"iql.{name}", getattr(self, name), low)

        def number(name, ok, expected):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not ok(v):
                raise ValueError(f"iql.{name} must be {expected}, got {v!r}")

        number("expectile", lambda v: 0 < v < 1, "in (0, 1)")
        number("beta", lambda v: v >= 0, ">= 0")
        number("discount", lambda v: 0 <= v < 1, "in [0, 1)")
        number("polyak", lambda v: 0 < v <= 1, "in (0, 1]")
        number("max_weight", lambda v: v > 0, "> 0")
        number("lr", lambda v: v > 0, "> 0")
        return self


IQL_PRESETS = {
    "ci": IQLConfig(channels=(8, 16, 16), feature_dim=32, hidden=32, steps=10, batch_size=8),
    "reduced": IQLConfig(channels=(16, 32, 32, 32), feature_dim=128, hidden=128, steps=4000, batch_size=64),
    "paper": IQLConfig(),
}


def iql_config(preset: str = "reduced", **overrides) -> IQLConfig:
    """A fresh copy of a named preset, with field overrides. Only sizes differ between
    presets; the IQL hyperparameters are the IQL paper's in all three."""
    return preset_config(IQL_PRESETS, preset, overrides, "IQL")


# ----------------------------------------------------------------------------- the pieces
def expectile_loss(diff: torch.Tensor, expectile: float) -> torch.Tensor:
    """Mean of L2^tau(u) = |tau - 1(u < 0)| u^2 over u = Qhat - V: (1)'s loss. At tau = 0.5
    it is half the MSE; tau > 0.5 weighs V below Q more, so V tends to an upper expectile."""
    weight = torch.where(diff < 0, 1.0 - expectile, expectile)
    return (weight * diff.square()).mean()


def advantage_weights(advantage: torch.Tensor, beta: float, max_weight: float = 100.0) -> torch.Tensor:
    """(3)'s weights min(exp(beta A), max_weight). An overflow to inf is clamped to the cap
    too, and the weights carry no gradient (A is a target for the policy, not trained here)."""
    return torch.exp(beta * advantage.detach()).clamp(max=max_weight)


@torch.no_grad()
def polyak_update(target: nn.Module, online: nn.Module, rate: float) -> None:
    """target <- (1 - rate) target + rate online, parameter by parameter (in place)."""
    t_params, o_params = list(target.parameters()), list(online.parameters())
    if len(t_params) != len(o_params):
        raise ValueError(f"target and online networks differ: {len(t_params)} vs {len(o_params)} tensors")
    for t, o in zip(t_params, o_params):
        t.mul_(1.0 - rate).add_(o, alpha=rate)


class QHeads(nn.Module):
    """Twin Q heads: (features (B, F), action in box units (B, 6)) -> (B,), (B,)."""

    def __init__(self, feature_dim: int, hidden: int):
        super().__init__()
        self.q1 = mlp([feature_dim + 6, hidden, hidden, 1])
        self.q2 = mlp([feature_dim + 6, hidden, hidden, 1])

    def forward(self, features: torch.Tensor, action: torch.Tensor):
        x = torch.cat([features, action], dim=-1)
        return self.q1(x).squeeze(-1), self.q2(x).squeeze(-1)


class IQLNetworks(nn.Module):
    """Encoder, twin Q, V and the policy, plus the target copy of encoder and Q heads."""

    def __init__(self, cfg: IQLConfig, box: ActionBox):
        super().__init__()
        self.cfg = cfg.validate()
        self.encoder = PixelEncoder(cfg.channels, cfg.feature_dim)
        self.q = QHeads(cfg.feature_dim, cfg.hidden)
        self.v = mlp([cfg.feature_dim, cfg.hidden, cfg.hidden, 1])
        self.policy_mean = mlp([cfg.feature_dim, cfg.hidden, cfg.hidden, 6])
        self.policy_log_std = nn.Parameter(torch.zeros(6))
        self.target = nn.ModuleDict({"encoder": copy.deepcopy(self.encoder), "q": copy.deepcopy(self.q)})
        self.target.requires_grad_(False)
        self.box = box

    def online_parameters(self):
        return [p for name, p in self.named_parameters() if not name.startswith("target.")]

    def target_q(self, image, goal, action_unit) -> torch.Tensor:
        """min of the target's twin heads, (B,), no gradient."""
        with torch.no_grad():
            q1, q2 = self.target["q"](self.target["encoder"](image, goal), action_unit)
            return torch.minimum(q1, q2)

    def policy(self, features: torch.Tensor) -> torch.distributions.Normal:
        mean = torch.tanh(self.policy_mean(features))                     # (B, 6) box units
        std = self.policy_log_std.clamp(*LOG_STD_RANGE).exp().expand_as(mean)
        return torch.distributions.Normal(mean, std)

    @torch.no_grad()
    def act(self, image: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The policy's mean action in env units (B, 6), inside the Box."""
        return self.box.from_unit(torch.tanh(self.policy_mean(self.encoder(image, goal))))


def iql_losses(model: IQLNetworks, batch: dict, cfg: IQLConfig) -> dict[str, torch.Tensor]:
    """Losses (1)-(3) on one batch of `HindsightGoals`, and the statistics the log keeps."""
    a = model.box.to_unit(batch["action"])                               # (B, 6)
    reward = batch["reached"].float()                                     # sparse success
    not_done = 1.0 - reward                                               # the episode ends at the goal
    features = model.encoder(batch["image"], batch["goal"])              # (B, F)
    with torch.no_grad():
        v_next = model.v(model.encoder(batch["next_image"], batch["goal"])).squeeze(-1)
        td_target = reward + cfg.discount * not_done * v_next
    q_hat = model.target_q(batch["image"], batch["goal"], a)             # (B,)
    v = model.v(features.detach()).squeeze(-1)
    v_loss = expectile_loss(q_hat - v, cfg.expectile)                     # (1)
    q1, q2 = model.q(features, a)
    q_loss = (td_target - q1).square().mean() + (td_target - q2).square().mean()   # (2)
    weights = advantage_weights(q_hat - v.detach(), cfg.beta, cfg.max_weight)
    log_prob = model.policy(features.detach()).log_prob(a).sum(-1)
    policy_loss = -(weights * log_prob).mean()                            # (3)
    return {"v_loss": v_loss, "q_loss": q_loss, "policy_loss": policy_loss,
            "mean_weight": weights.mean(), "mean_q": q1.mean(), "mean_v": v.mean(),
            "reward_rate": reward.mean()}


def train_iql(buffer, action_space, cfg: IQLConfig | None = None, *, out=None,
              checkpoint_every: int | None = None, resume: bool = False,
              info: dict | None = None) -> tuple[IQLNetworks, list[dict]]:
    """Train IQL on a buffer (dict of `load_buffer`, or its directory).

    Returns (model in eval mode, log: one dict per step with the three losses, the mean
    advantage weight, mean Q and V, and the batch's reward rate). `out`,
    `checkpoint_every`, `resume`: see `goal_conditioned.run_training`; `info` is
    stored in the checkpoint."""
    cfg = (cfg or IQLConfig()).validate()
    model, box, goals = training_setup(buffer, action_space, cfg, IQLNetworks)
    optimizer = torch.optim.Adam(model.online_parameters(), lr=cfg.lr)

    def step_fn(step: int) -> dict:
        losses = iql_losses(model, goals.sample(step, cfg.batch_size), cfg)
        optimizer.zero_grad(set_to_none=True)
        (losses["v_loss"] + losses["q_loss"] + losses["policy_loss"]).backward()
        optimizer.step()
        polyak_update(model.target["encoder"], model.encoder, cfg.polyak)
        polyak_update(model.target["q"], model.q, cfg.polyak)
        return {k: v.item() for k, v in losses.items()}

    log = run_training(KIND, model, optimizer, step_fn, cfg, out=out, checkpoint_every=checkpoint_every,
                       resume=resume, info={"episodes": goals.episodes, **(info or {})})
    return model, log


def save_iql(path, model: IQLNetworks, log: list[dict] | None = None):
    """A finished model (no optimizer state) as a `iql` checkpoint."""
    return save_policy(path, KIND, model, log)


def load_iql(path) -> IQLNetworks:
    """A IQL model from a `iql` checkpoint (weights_only), in eval mode."""
    return load_policy(path, KIND, IQLConfig, IQLNetworks)


class IQLAgent(PolicyAgent):
    """The harness's interface around a trained `IQLNetworks`: its mean action, never random."""


__all__ = ["IQLAgent", "IQLConfig", "IQLNetworks", "IQL_PRESETS", "advantage_weights", "expectile_loss",
           "iql_config", "iql_losses", "load_iql", "polyak_update", "save_iql", "train_iql"]
