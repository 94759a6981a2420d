"""What the two learned baselines (BC, IQL; Appendix B) share.

- `PixelEncoder`: a small CNN over the current image and the goal image stacked as 6
  channels. The baselines read pixels, not dSLATE slots: they then need no trained dSLATE,
  and a baseline that fails cannot blame a representation it did not learn.
- `ActionBox`: actions in "box units", u = (a - mid) / half in [-1, 1] per dimension, from
  the env's action Box. Networks predict u through a tanh, so an action is inside the Box
  by construction (no clipping), and every dimension weighs the same in an MSE.
- `HindsightGoals`: transitions of the buffer with goals relabelled from a later frame of
  the same episode. Draw t uniformly in 0..T-2, then the goal frame j uniformly in t+1..T-1.
  The draws of step n depend only on (seed, n), so a resumed run sees the same batches.
- `save_checkpoint` / `read_checkpoint`: one dict of tensors and plain values with a `kind`
  tag ("bc", "iql") and a digest of its tensors, loaded with `torch.load(weights_only=True)`
  and refused (naming the path) when it is another kind of file, corrupted or non-finite.

Shapes: B batch, E episodes, T frames per episode (5), H = W = 64 pixels.
"""
from __future__ import annotations

import csv
import io
from dataclasses import asdict, fields, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..data import load_buffer
from ..tensor_files import atomic_torch_save, check_weights, file_kind, load_tensor_file, tensor_digest
from ..utils import atomic_write_text, one_line, progress, seed_everything

CHECKPOINT_FORMAT = 1
KINDS = ("bc", "iql")                  # the kind tags of baseline checkpoints
DIGESTED = ("model", "optimizer")      # the tensors the stored content digest covers
BUFFER_KEYS = ("frames", "actions")


# ----------------------------------------------------------------------------- config helpers
def check_int(name: str, value, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")


def check_channels(channels, image_size: int = 64) -> None:
    if not isinstance(channels, (tuple, list)) or not channels:
        raise ValueError(f"channels must be a non-empty tuple of widths, got {channels!r}")
    for c in channels:
        check_int("every channel width", c, 1)
    if image_size % 2 ** len(channels):
        raise ValueError(f"{len(channels)} stride-2 convolutions need an image size divisible by "
                         f"{2 ** len(channels)}, got {image_size}")


def preset_config(presets: dict, preset: str, overrides: dict, what: str):
    """A fresh copy of `presets[preset]` with field overrides, validated (BC, IQL and MPC)."""
    if preset not in presets:
        raise ValueError(f"unknown {what} preset {preset!r}; expected one of {sorted(presets)}")
    cls = type(presets[preset])
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ValueError(f"unknown {cls.__name__} fields {unknown}; expected some of {names}")
    return replace(presets[preset], **overrides).validate()


def config_from_dict(cls, d: dict):
    """Rebuild a config dataclass from `asdict` output (lists back to tuples)."""
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} fields {unknown}; expected some of {sorted(names)}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}).validate()


# ----------------------------------------------------------------------------- networks
def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers with ReLU between them (none after the last)."""
    layers = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class PixelEncoder(nn.Module):
    """(image, goal) uint8 (B, H, W, 3) each -> features (B, feature_dim).

    Stride-2 4x4 convolutions halve the side per layer: 64 -> 64 / 2^len(channels)."""

    def __init__(self, channels=(32, 64, 64, 64), feature_dim: int = 256, image_size: int = 64):
        super().__init__()
        check_channels(channels, image_size)
        convs, c_in = [], 6
        for c in channels:
            convs += [nn.Conv2d(c_in, c, 4, stride=2, padding=1), nn.ReLU()]
            c_in = c
        self.convs = nn.Sequential(*convs)
        side = image_size // 2 ** len(channels)
        self.project = nn.Sequential(nn.Flatten(), nn.Linear(c_in * side * side, feature_dim), nn.ReLU())
        self.image_size = image_size

    def forward(self, image: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        expected = (self.image_size, self.image_size, 3)
        for name, x in (("image", image), ("goal", goal)):
            if x.ndim != 4 or tuple(x.shape[1:]) != expected:
                raise ValueError(f"{name} must have shape (B, {', '.join(map(str, expected))}), "
                                 f"got {tuple(x.shape)}")
        x = torch.cat([image, goal], dim=-1).permute(0, 3, 1, 2).float() / 255.0  # (B, 6, H, W)
        return self.project(self.convs(x))                                         # (B, F)


class ActionBox(nn.Module):
    """The env's action Box as buffers (saved with the model): a <-> u = (a - mid) / half."""

    def __init__(self, low, high):
        super().__init__()
        low, high = (torch.as_tensor(np.asarray(v, np.float32)) for v in (low, high))
        if low.shape != (6,) or high.shape != (6,):
            raise ValueError(f"action bounds must have shape (6,), got {tuple(low.shape)} and {tuple(high.shape)}")
        if not bool((high > low).all()):
            raise ValueError(f"action bounds need high > low in every dimension, got low {low.tolist()} "
                             f"and high {high.tolist()}")
        self.register_buffer("low", low)
        self.register_buffer("high", high)

    @classmethod
    def from_space(cls, action_space) -> "ActionBox":
        return cls(action_space.low, action_space.high)

    def to_unit(self, a: torch.Tensor) -> torch.Tensor:
        return (a - (self.high + self.low) / 2) / ((self.high - self.low) / 2)

    def from_unit(self, u: torch.Tensor) -> torch.Tensor:
        return u * ((self.high - self.low) / 2) + (self.high + self.low) / 2


# ----------------------------------------------------------------------------- data
def check_buffer(buffer: dict, box: ActionBox | None = None) -> None:
    missing = [k for k in BUFFER_KEYS if k not in buffer]
    if missing:
        raise ValueError(f"buffer is missing {missing}; expected the dict of `ncs_lite.data.load_buffer`")
    frames, actions = np.asarray(buffer["frames"]), np.asarray(buffer["actions"])
    if frames.ndim != 5 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or frames.shape[1] < 2:
        raise ValueError("buffer['frames'] must be uint8 (E, T, H, W, 3) with T >= 2, got "
                         f"{frames.dtype} {frames.shape}")
    if actions.shape != (frames.shape[0], frames.shape[1] - 1, 6):
        raise ValueError(f"buffer['actions'] must have shape {(frames.shape[0], frames.shape[1] - 1, 6)}, "
                         f"got {actions.shape}")
    if box is not None:
        u = box.to_unit(torch.as_tensor(actions, dtype=torch.float32))
        if not bool((u.abs() <= 1).all()):
            raise ValueError("buffer actions leave the action Box "
                             f"(low {box.low.tolist()}, high {box.high.tolist()}): is it this env's buffer?")


class HindsightGoals:
    """Transitions (s_t, a_t, s_{t+1}) with a goal frame j > t of the same episode.

    `reached` is True when s_{t+1} is the goal: j == t + 1, or an identical image (a later
    frame can repeat an earlier one when a move undoes another)."""

    def __init__(self, buffer: dict, seed: int = 0):
        check_buffer(buffer)
        self.frames = torch.as_tensor(np.asarray(buffer["frames"]))     # (E, T, H, W, 3) uint8
        self.actions = torch.as_tensor(np.asarray(buffer["actions"]), dtype=torch.float32)  # (E, T-1, 6)
        self.episodes, self.frames_per_episode = self.frames.shape[:2]
        self.seed = int(seed)

    def indices(self, step: int, batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(episode, t, j) arrays (B,) of optimizer step `step`: a function of (seed, step)."""
        rng = np.random.default_rng([self.seed, int(step)])
        e = rng.integers(self.episodes, size=batch)
        t = rng.integers(self.frames_per_episode - 1, size=batch)
        j = t + 1 + np.floor(rng.random(batch) * (self.frames_per_episode - 1 - t)).astype(np.int64)
        return e, t, j

    def all_indices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every (episode, t, j) with t < j: E x T(T-1)/2 triples (for evaluation)."""
        pairs = [(t, j) for t in range(self.frames_per_episode - 1)
                 for j in range(t + 1, self.frames_per_episode)]
        e = np.repeat(np.arange(self.episodes), len(pairs))
        t, j = (np.tile(np.array(col), self.episodes) for col in zip(*pairs))
        return e, t, j

    def batch(self, e, t, j) -> dict[str, torch.Tensor]:
        """image, next_image, goal (B, H, W, 3) uint8; action (B, 6); reached (B,) bool."""
        e, t, j = (torch.as_tensor(v) for v in (e, t, j))
        image, nxt, goal = self.frames[e, t], self.frames[e, t + 1], self.frames[e, j]
        reached = (j == t + 1) | (nxt == goal).flatten(1).all(1)
        return {"image": image, "next_image": nxt, "goal": goal, "action": self.actions[e, t],
                "reached": reached}

    def sample(self, step: int, batch: int) -> dict[str, torch.Tensor]:
        return self.batch(*self.indices(step, batch))


def as_buffer(buffer) -> dict:
    """A loaded buffer dict, or a buffer directory to load."""
    if isinstance(buffer, (str, Path)):
        return load_buffer(buffer)
    if not isinstance(buffer, dict):
        raise ValueError(f"buffer must be a buffer directory or the dict of `load_buffer`, got {type(buffer).__name__}")
    return buffer


def observation_tensors(obs) -> tuple[torch.Tensor, torch.Tensor]:
    """An env observation -> (image, goal) uint8 tensors (1, H, W, 3)."""
    if not isinstance(obs, dict) or "image" not in obs or "goal" not in obs:
        raise ValueError(f"obs must be a dict with 'image' and 'goal', got {type(obs).__name__}")
    return tuple(torch.as_tensor(np.asarray(obs[k], np.uint8))[None] for k in ("image", "goal"))


# ----------------------------------------------------------------------------- checkpoints
def save_checkpoint(path, kind: str, model: nn.Module, cfg, *, step: int, log: list[dict],
                    optimizer=None, info: dict | None = None) -> Path:
    """Atomically write a baseline checkpoint (weights_only-loadable)."""
    ckpt = {"format": CHECKPOINT_FORMAT, "kind": kind, "config": asdict(cfg), "model": model.state_dict(),
            "optimizer": None if optimizer is None else optimizer.state_dict(),
            "step": int(step), "log": [dict(r) for r in log], "info": dict(info or {})}
    atomic_torch_save({**ckpt, "content_digest": tensor_digest(ckpt, DIGESTED)}, path)
    return Path(path)


def read_checkpoint(path, kind: str | None) -> dict:
    """Load a checkpoint written by `save_checkpoint`; ValueError naming `path` unless it is a
    `kind` one (any of KINDS when None) whose tensors match their digest and are finite."""
    path = Path(path)
    ckpt = load_tensor_file(path, f"{kind or 'baseline'} checkpoint",
                            "train one with `python -m ncs_lite train-baseline`")
    if ckpt.get("format") != CHECKPOINT_FORMAT or ckpt.get("kind") not in KINDS or "model" not in ckpt:
        raise ValueError(f"{path} is not an ncs-lite baseline checkpoint (format {CHECKPOINT_FORMAT}, kind "
                         f"{' or '.join(map(repr, KINDS))}); it holds {file_kind(ckpt)}")
    if kind is not None and ckpt["kind"] != kind:
        raise ValueError(f"{path} is a {ckpt['kind']!r} checkpoint, expected {kind!r}")
    missing = [k for k in ("config", "step", "log", "info") if k not in ckpt]
    if missing:
        raise ValueError(f"{path} is corrupted: it lacks {missing}, which every {ckpt['kind']} checkpoint holds")
    types = {"config": dict, "step": int, "log": list, "info": dict}
    wrong = [k for k, t in types.items() if not isinstance(ckpt[k], t) or isinstance(ckpt[k], bool)]
    if wrong:
        raise ValueError(f"{path} is corrupted: its {wrong[0]} is a {type(ckpt[wrong[0]]).__name__}, expected "
                         f"a {types[wrong[0]].__name__}")
    return check_weights(ckpt, path, DIGESTED)


def run_training(kind: str, model: nn.Module, optimizer, step_fn, cfg, *, out=None,
                 checkpoint_every: int | None = None, resume: bool = False, info: dict | None = None,
                 desc: str | None = None) -> list[dict]:
    """The loop BC and IQL share: `step_fn(step) -> {name: float}` for step = 0..cfg.steps-1.

    With `out`, an atomic checkpoint every `checkpoint_every` steps and at the end. With
    `resume`, continue from `out` (same config required): model, optimizer, step and log
    come back and the batches are those of the uninterrupted run (`HindsightGoals`), so the
    result is the same. Each checkpoint writes the log so far beside it as a CSV
    (`out` with suffix .csv). Returns the log, one dict per step."""
    log, start = [], 0
    if checkpoint_every is not None:
        check_int("checkpoint_every", checkpoint_every, 1)
    if resume:
        if out is None:
            raise ValueError("resume=True needs the checkpoint path `out`")
        ckpt = read_checkpoint(out, kind)
        if ckpt["config"] != asdict(cfg):
            diff = {k: (ckpt["config"].get(k), v) for k, v in asdict(cfg).items() if ckpt["config"].get(k) != v}
            raise ValueError(f"{out} was trained with another config (stored vs asked: {diff})")
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        log, start = list(ckpt["log"]), int(ckpt["step"])
    model.train()
    for step in progress(range(start, cfg.steps), desc=desc or f"train {kind}", initial=start, total=cfg.steps):
        row = {"step": step + 1, **step_fn(step)}
        log.append(row)
        if not all(np.isfinite(v) for v in row.values()):
            raise FloatingPointError(f"{kind} training diverged at step {step + 1}: {row}")
        if out is not None and checkpoint_every and (step + 1) % checkpoint_every == 0:
            _save_run(out, kind, model, cfg, step + 1, log, optimizer, info)
    if out is not None:
        _save_run(out, kind, model, cfg, cfg.steps, log, optimizer, info)
    model.eval()
    return log


def _save_run(out, kind, model, cfg, step, log, optimizer, info) -> None:
    """A checkpoint and, beside it, its loss log as a CSV (both atomic)."""
    save_checkpoint(out, kind, model, cfg, step=step, log=log, optimizer=optimizer, info=info)
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(log[0]) if log else ["step"])
    writer.writeheader()
    writer.writerows(log)
    atomic_write_text(Path(out).with_suffix(".csv"), text.getvalue())


__all__ = ["ActionBox", "HindsightGoals", "PixelEncoder", "as_buffer", "check_buffer", "mlp",
           "observation_tensors", "read_checkpoint", "run_training", "save_checkpoint"]


def save_policy(path, kind: str, model: nn.Module, log: list[dict] | None = None):
    """A finished model (no optimizer state) as a `kind` checkpoint."""
    return save_checkpoint(path, kind, model, model.cfg, step=model.cfg.steps, log=log or [])


def load_policy(path, kind: str, config_cls, model_cls) -> nn.Module:
    """A `model_cls(cfg, ActionBox)` from a `kind` checkpoint (weights_only), in eval mode."""
    ckpt = read_checkpoint(path, kind)
    sd = ckpt["model"]
    try:
        cfg = config_from_dict(config_cls, ckpt["config"])
        if "box.low" not in sd or "box.high" not in sd:
            raise ValueError("its model lacks the action bounds box.low and box.high")
        model = model_cls(cfg, ActionBox(sd["box.low"], sd["box.high"]))
        model.load_state_dict(sd)
    except (ValueError, TypeError, RuntimeError) as e:      # load_state_dict: RuntimeError
        raise ValueError(f"{path} holds a {kind} checkpoint this code cannot use: {one_line(e)}") from None
    model.log, model.info, model.step = ckpt["log"], ckpt["info"], ckpt["step"]
    return model.eval()


class PolicyAgent:
    """The harness's interface around a trained goal-conditioned policy (`model.act(image,
    goal)`): its action every step, never a random one."""

    def __init__(self, model: nn.Module):
        self.model = model.eval()

    def reset(self, obs, info, seed: int | None = None) -> None:
        pass   # the goal image comes with every observation; the policy draws nothing

    def act(self, obs, info):
        image, goal = observation_tensors(obs)
        return self.model.act(image, goal)[0].numpy().astype(np.float32), False


def training_setup(buffer, action_space, cfg, build):
    """What BC and IQL training share: the checked buffer, `build(cfg, box)`'s model (after
    seeding) and the hindsight goal sampler. Returns (model, box, goals)."""
    buffer = as_buffer(buffer)
    box = ActionBox.from_space(action_space)
    check_buffer(buffer, box)
    seed_everything(cfg.seed)
    return build(cfg, box), box, HindsightGoals(buffer, cfg.seed)
