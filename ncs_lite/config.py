"""dSLATE configuration as data: dataclasses and the named presets `ci`, `reduced`, `paper`.

`paper` is Table 2 of the appendix exactly. `reduced` trains on 2 CPU cores in at most
30 minutes and still separates objects (block-rearrange); `ci` runs in seconds and
exercises every code path. Everything a model or the trainer needs is a field here, so a
checkpoint stores its whole configuration as a plain dict (`to_dict`) and can be rebuilt
from it (`from_dict`).

Where Table 2 is silent, the decision is recorded in the field's comment. Why `reduced`
departs from Table 2 where it does: docs/recipe.md.
"""
from __future__ import annotations

import copy
import math
import typing
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from typing import Literal

__all__ = ["DVAEConfig", "SlotConfig", "DecoderConfig", "DynamicsConfig", "MixtureConfig",
           "TrainConfig", "DSlateConfig", "NCSConfig", "PRESETS", "get_preset", "from_dict", "to_dict",
           "table2_rows", "apply_overrides", "parse_override", "ncs_config", "ALIGN_RULES", "COLOR_AUGMENTS",
           "EDGE_ACTIONS", "ENTITY_STATES", "MIXTURE_ALPHAS", "MIXTURE_APPEARANCES", "MIXTURE_ERRORS",
           "MASK_READS", "SLOT_POSITIONS"]


# ------------------------------------------------------------------ the values a choice takes
# A field that picks one of a few behaviours has a `Literal` type; the tuple beside it is what
# `validate` checks and what the code acting on the choice imports (the models, data/augment.py,
# ncs/), so this module, which every stage reads, imports none of them.
MixtureAlpha = Literal["decoder", "attention"]    # MixtureConfig.alpha (models/mixture_decoder.py)
MixtureAppearance = Literal["slot", "type"]       # MixtureConfig.appearance
MixtureError = Literal["mixed", "per_slot"]       # how DSlate.mixture_error scores the paint
ColorAugment = Literal["none", "channels", "channels_gamma"]   # TrainConfig.color_augment (data/augment.py)
PhaseLoss = Literal["slate", "mixture"]           # TrainConfig.main_loss, polish_loss (training.train_step)
EntityState = Literal["mask", "slot"]             # NCSConfig.state: Table 3's columns (ncs.graph.METRICS_BY_STATE)
SlotPosition = Literal["attention", "assigned", "base"]   # NCSConfig.slot_position (ncs/perception.py)
MaskRead = Literal["attention", "pixel"]          # NCSConfig.masks (DSlate.infer)
SlotInit = Literal["random", "farthest"]          # SlotConfig.init, NCSConfig.slot_init (DSlate.infer)
AlignRule = Literal["hungarian", "mutual", "either", "near"]   # NCSConfig.align (ncs.policy.match)
EdgeAction = Literal["most_common", "nearest", "compose", "readout"]   # NCSConfig.edge_action (ncs/graph.py)
MIXTURE_ALPHAS = typing.get_args(MixtureAlpha)
MIXTURE_APPEARANCES = typing.get_args(MixtureAppearance)
MIXTURE_ERRORS = typing.get_args(MixtureError)
COLOR_AUGMENTS = typing.get_args(ColorAugment)
PHASE_LOSSES = typing.get_args(PhaseLoss)
ENTITY_STATES = typing.get_args(EntityState)
SLOT_POSITIONS = typing.get_args(SlotPosition)
MASK_READS = typing.get_args(MaskRead)
SLOT_INITS = typing.get_args(SlotInit)
ALIGN_RULES = typing.get_args(AlignRule)
EDGE_ACTIONS = typing.get_args(EdgeAction)


@dataclass
class DVAEConfig:
    """Discrete VAE: 64x64 image -> (image_size / downsample)^2 tokens over `vocab_size`."""
    vocab_size: int = 4096
    hidden: int = 64            # channels of the encoder/decoder (SLATE's dVAE uses 64)
    tau_start: float = 1.0      # gumbel-softmax temperature, cosine-annealed ...
    tau_end: float = 0.1        # ... to this value ...
    tau_steps: int = 30_000     # ... over this many optimizer steps
    lr: float = 3e-4            # constant, no warm-up
    foreground_weight: float = 1.0  # weight of pixels far from the image's median colour in
    #                             the reconstruction (1 = the paper's plain sum; DSlate.forward).
    #                             why: docs/recipe.md, `dvae.foreground_weight`


@dataclass
class SlotConfig:
    """Slot attention; a slot is [type z ; state s] of type_dim + state_dim features."""
    num_slots: int = 5
    iterations: int = 3         # in training
    eval_iterations: int = 7    # when building the graph / `infer` default
    heads: int = 1
    type_dim: int = 96
    state_dim: int = 96
    mlp_hidden: int = 192       # residual MLP of the slot update (SLATE: = slot size)
    encoder: str = "tokens"     # slot-attention input: "tokens" = dVAE token embeddings (SLATE,
    #                             the paper) or "cnn" = a CNN over pixels (STEVE), see pixel_encoder.py
    encoder_stride: int = 2     # "cnn" only: features and masks at image_size / stride
    position_state: bool = False  # the last 4 state features = centroid and spread of the
    #                             slot's attention (Invariant Slot Attention's slot position;
    #                             not in the paper): s then holds where its object is. With
    #                             state_dim 4 (`reduced`) that is all of s
    position_prior: float = 0.0  # with position_state: attention mass (in grid cells) added at
    #                             the image's centre with a uniform image's spread before the
    #                             centroid and spread are taken, so a slot attending to (almost)
    #                             nothing has the prior's state, not the centroid of its stray
    #                             attention, which jumps between frames; 0 = none. Acts from the
    #                             render phase on (that phase and every read after training,
    #                             DSlate.position_prior): a finished run extends by it

    implicit: bool = False      # differentiate only slot attention's last iteration, from the
    #                             detached slots of the others (implicit differentiation's
    #                             first-order form, Chang et al. 2022; not in the paper)
    init: SlotInit = "random"   # where a video's first slots start in training and in the
    #                             phases' reads: "random" (a draw from the learned Gaussian, the
    #                             paper's) or "farthest" (SlotAttention.farthest_point_slots,
    #                             seeded on the frame; not in the paper), so that training
    #                             shapes the fixed points that one pass from that start reaches
    #                             (`ncs.slot_init` sets how an agent's reads start)

    @property
    def slot_dim(self) -> int:
        return self.type_dim + self.state_dim


@dataclass
class DecoderConfig:
    """SLATE's autoregressive transformer over the dVAE tokens, cross-attending to slots."""
    layers: int = 4
    heads: int = 4
    hidden: int = 192
    dropout: float = 0.1
    token_dropout: float = 0.0  # replace decoder *input* tokens by [MASK] with this probability
    #                             (word dropout; not in the paper): the decoder must read the slots
    slot_grad: float = 1.0      # scale of the gradient that the decoder's and the dynamics' losses
    #                             send into slot attention: 1 = the paper; 0 = slots learn only
    #                             from the mixture decoder (the decoder and dynamics still learn)


@dataclass
class DynamicsConfig:
    """Transformer over K slots + one action token; predicts each slot's next state."""
    layers: int = 4
    heads: int = 4
    hidden: int = 96
    dropout: float = 0.1        # Table 2's dropout, applied to both transformers
    latent_weight: float = 0.0  # weight of a latent loss (not in the paper): squared error of
    #                             the predicted next states against frame t+1's inferred states
    #                             (detached). 0 = the dynamics learns from ce_dyn alone (paper)


@dataclass
class MixtureConfig:
    """Auxiliary mixture decoder (not in the paper; see models/mixture_decoder.py): each slot
    paints a patch per grid position; mixing weights that sum to 1 over slots combine them."""
    weight: float = 0.0         # loss weight; 0 = off (the paper)
    hidden: int = 128           # MLP width
    alpha: MixtureAlpha = "decoder"  # mixing weights: "decoder" = painted alpha logits on the token
    #                             grid; "attention" = slot attention's masks on its own grid
    foreground_weight: float = 1.0  # weight of pixels far from the image's median colour in
    #                             the reconstruction (1 = plain sum), see DSlate.mixture_error
    appearance: MixtureAppearance = "slot"  # what a slot paints: "slot" = from the whole slot and the
    #                             position; "type" = one look from z alone (mixture_decoder.py)
    error: MixtureError = "mixed"  # the reconstruction error: "mixed" = of the mixed image (Locatello
    #                             et al.); "per_slot" = of each slot's own patches, weighted by
    #                             its mixing weight (a mixture likelihood, as in MONet): two
    #                             slots cannot blend their looks into a third colour, so a slot
    #                             holding two cubes of different colours pays for one of them
    state_mask_weight: float = 0.0  # weight of the state-mask loss: each slot's mask drawn from
    #                             its state s alone against slot attention's (state_decoder.py);
    #                             0 = off. Makes s hold where the object is
    render_hidden: int = 0      # width of the renderer's MLP (state_decoder.py): each slot's mask
    #                             drawn from its state s for `DSlate.render`, fitted to the
    #                             frames in the render phase (TrainConfig.render_steps); 0 = none
    #                             (render then draws the state-mask decoder's masks)


@dataclass
class TrainConfig:
    epochs: int = 200
    episodes_per_epoch: int = 5_000
    num_objects: int = 4        # objects in each video of the training buffer that
    #                             `reproduce seeds` and `obtain_dslate` collect (A.1: "each video
    #                             in the experience buffer contains four objects"); `train
    #                             --data` trains on the buffer it is given
    window: int = 5             # frames per training video (Table 2: episode length 5)
    batch_size: int = 32
    lr: float = 2e-4            # peak lr of slot attention, decoder and dynamics
    warmup_steps: int = 30_000  # linear warm-up of `lr`
    lr_decay: str = "none"      # after warm-up: "none" (paper is silent) or "cosine" to 0.1 lr
    dvae_warmup_steps: int = 0  # first steps train the dVAE alone (cheap); the paper trains
    #                             jointly from step 0 (= 0). The other lr schedule starts after.
    # segmentation starts (kit, not in the paper): after the dVAE warm-up, slot attention, its
    # encoder, the mixture decoder and the state-mask head train on the mixture loss alone
    # (DSlate.mixture_loss) from `segmentation_starts` initialisations in turn,
    # `segmentation_start_steps` steps each on the same batches; the schedule continues from
    # the start whose mixture error over its last quarter was lowest (training.select_start).
    # Slot attention is a local search in training too, as NCS's restarts are at reading time
    # (why: docs/recipe.md, `train.segmentation_starts`). 0 steps = none
    segmentation_starts: int = 1
    segmentation_start_steps: int = 0
    # what the main schedule minimises: "slate" DSlate.forward's sum (Table 2: every part
    # trains jointly); "mixture" DSlate.mixture_loss alone, so that only slot attention, its
    # encoder, the mixture decoder and the state-mask head train (the SLATE decoder and the
    # dynamics stay at their initialisation, the dVAE where its warm-up left it). With
    # decoder.slot_grad 0 slot attention learns from the mixture loss alone in either case,
    # so "mixture" is a segmentation-only schedule at about a third of a step's cost: for
    # ablations of what concerns segmentation (docs/recipe.md, "Ablations of segmentation
    # alone"); the seeds table leaves out the columns that read the untrained parts
    # (experiments.reproduce.SEGMENTATION_ONLY)
    main_loss: PhaseLoss = "slate"
    grad_clip: float = 1.0      # clip_grad_norm_ max norm, with norm type below
    grad_clip_norm: str = "inf"  # SLATE reference clips the inf-norm (max |grad|) at 1.0
    precision: str = "auto"     # "auto" | "bf16" | "fp32"; auto = bf16 autocast where supported
    checkpoint_every: int = 500  # optimizer steps between checkpoints
    seed: int = 0
    # polish (kit, not in the paper; see `reduced`): steps after the schedule at a constant
    # lr with the dVAE frozen and the mixture loss's foreground weight raised.
    # why: docs/recipe.md, `train.polish_steps` and `train.polish_mixture_error`
    polish_steps: int = 0
    polish_lr: float = 2e-4
    polish_foreground_weight: float = 20.0
    polish_mixture_error: MixtureError = "mixed"  # the mixture error of the polish steps (see
    #                             MixtureConfig.error): "per_slot" there splits slots that
    #                             blend two similar colours, once the cubes have slots
    polish_loss: PhaseLoss = "slate"  # what the polish minimises: "slate" DSlate.forward's sum
    #                             (every part but the dVAE trains on it), "mixture" the mixture
    #                             decoder's and the state-mask head's losses alone
    #                             (DSlate.mixture_loss: a third of the step's cost; the SLATE
    #                             decoder and the dynamics wait for the later phases)
    # dynamics phase (kit, not in the paper; see `reduced`): steps after the polish that train
    # the dynamics alone, on the latent loss against frame t+1's states, with every other
    # part frozen and the slots read as NCS reads them (eval_iterations). Jointly, ce_dyn's
    # gradient drowns the latent loss (why: docs/recipe.md, `train.dynamics_steps`)
    dynamics_steps: int = 0
    dynamics_lr: float = 1e-3
    # render phase (kit, not in the paper; see `reduced`): steps after the dynamics phase that
    # fit the renderer (MixtureConfig.render_hidden) to the frames through the frozen mixture
    # decoder, a pixel loss on slots read as NCS reads them; nothing else moves. The state-mask
    # decoder's masks, fitted to slot attention's, render nearly empty floor (why:
    # docs/recipe.md, `train.render_steps`)
    render_steps: int = 0
    render_lr: float = 1e-3
    render_mask_steps: int = 0  # the render phase's first steps fit the renderer's masks to slot
    #                             attention's (cross-entropy) before the pixel loss takes over
    # refit phase (kit, not in the paper; see `reduced`): steps after the render phase that
    # train the dynamics alone again, as the dynamics phase does (dynamics_lr), on states read
    # with slots.position_prior, which acts from the render phase on: the dynamics phase read
    # states without it, and a model that plans with the dynamics (MPC) reads them with it
    # (why: docs/recipe.md, `train.refit_steps`)
    refit_steps: int = 0
    dynamics_prior: bool = False  # the dynamics phase reads states with slots.position_prior too,
    #                             as every read after it does; the refit phase, which trains the
    #                             dynamics again on such states, then repeats it (refit_steps 0)
    # colour augmentation of the segmentation path (kit, not in the paper; data/augment.py):
    # "none"; "channels" = the mixture loss reads each video with its RGB channels in a
    # random order; "channels_gamma" = and each channel raised to a random power. The
    # decoder, dynamics and dVAE read the true colours (why: docs/recipe.md, `train.color_augment`)
    color_augment: ColorAugment = "none"

    def main_steps(self) -> int:
        """Optimizer steps of the schedule: epochs x episodes per epoch / batch size."""
        return max(1, math.ceil(self.epochs * self.episodes_per_epoch / self.batch_size))

    def total_steps(self) -> int:
        """Optimizer steps of a full run: the segmentation starts', the schedule's, then the
        polish, dynamics, render and refit steps (the run as a list of phases: training.phases)."""
        return (self.segmentation_starts * self.segmentation_start_steps + self.main_steps() + self.polish_steps
                + self.dynamics_steps + self.render_steps + self.refit_steps)


@dataclass
class DSlateConfig:
    name: str = "paper"
    image_size: int = 64
    downsample: int = 4         # tokens = (image_size / downsample)^2 = 16 x 16
    action_dim: int = 6
    dvae: DVAEConfig = field(default_factory=DVAEConfig)
    slots: SlotConfig = field(default_factory=SlotConfig)
    decoder: DecoderConfig = field(default_factory=DecoderConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    mixture: MixtureConfig = field(default_factory=MixtureConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    @property
    def grid(self) -> int:
        return self.image_size // self.downsample

    @property
    def num_tokens(self) -> int:
        return self.grid ** 2

    @property
    def mask_grid(self) -> int:
        """Side of the slot-attention input grid, i.e. of the attention masks."""
        return self.image_size // self.slots.encoder_stride if self.slots.encoder == "cnn" else self.grid

    def validate(self) -> "DSlateConfig":
        """Refuse, in one line naming the field, a value this code cannot build or train:
        types, sizes and ranges (`_AT_LEAST`, `_IN_RANGE`), choices (`_CHOICES`), shapes that
        must divide, and parts that need another part (`_check_needs`)."""
        _check_field_types(self)
        for name, low in _AT_LEAST.items():         # sizes a model can be built and trained with
            value = _field(self, name)
            if value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        for name, (low, high, expected) in _IN_RANGE.items():
            value = _field(self, name)
            if not (low < value if high is None else low <= value < high):
                raise ValueError(f"{name} must be {expected}, got {value!r}")
        for name, options in _CHOICES.items():
            if _field(self, name) not in options:
                raise ValueError(f"{name} must be {_options_text(options)}, got {_field(self, name)!r}")
        if self.action_dim != 6:
            raise ValueError(f"action_dim must be 6 (the envs' action (w, dw)), got {self.action_dim}")
        try:
            norm = float(self.train.grad_clip_norm)
        except ValueError:
            norm = float("nan")
        if not norm > 0:
            raise ValueError("train.grad_clip_norm must be the order of a norm, a number > 0 or 'inf' "
                             f"(clip_grad_norm_'s norm_type), got {self.train.grad_clip_norm!r}")
        if not 2 <= self.train.window <= 5:
            raise ValueError(f"train.window must be in 2..5 (frames per video), got {self.train.window}")
        for size, divisor in (("image_size", "downsample"), ("image_size", "slots.encoder_stride"),
                              ("slots.slot_dim", "slots.heads"), ("decoder.hidden", "decoder.heads"),
                              ("dynamics.hidden", "dynamics.heads")):
            if _field(self, size) % _field(self, divisor):
                raise ValueError(f"{size} ({_field(self, size)}) must be divisible by {divisor} "
                                 f"({_field(self, divisor)})")
        if self.train.dvae_warmup_steps > self.train.main_steps():
            raise ValueError(f"train.dvae_warmup_steps ({self.train.dvae_warmup_steps}) are the schedule's first "
                             f"steps and cannot exceed its {self.train.main_steps()} (train.main_steps())")
        if self.train.render_mask_steps > self.train.render_steps:
            raise ValueError(f"train.render_mask_steps ({self.train.render_mask_steps}) are the render phase's "
                             f"first steps and cannot exceed train.render_steps ({self.train.render_steps})")
        _check_needs(self)
        return self


def _options_text(options) -> str:
    """'a' or 'b' / 'a', 'b' or 'c': the choices of a field, for its error."""
    quoted = [repr(o) for o in options]
    return quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"


def _check_needs(cfg: "DSlateConfig") -> None:
    """Refuse a part switched on without the part it needs (a phase without the loss or
    decoder it trains, a mask head without attention masks, ...), naming both."""
    mixture = cfg.mixture.weight > 0
    attention = mixture and cfg.mixture.alpha == "attention"
    needs = (
        (cfg.slots.position_state and cfg.slots.state_dim < 4,
         "slots.position_state fills 4 state features with where the slot attends "
         f"and needs slots.state_dim >= 4, got {cfg.slots.state_dim}"),
        (cfg.mixture.appearance == "type" and cfg.mixture.alpha != "attention",
         "mixture.appearance 'type' paints without a position and needs "
         f"mixture.alpha 'attention', got {cfg.mixture.alpha!r}"),
        (cfg.mixture.state_mask_weight > 0 and not attention,
         "mixture.state_mask_weight > 0 learns slot attention's masks from s and "
         "needs the mixture decoder (mixture.weight > 0) with mixture.alpha 'attention'"),
        (cfg.mixture.render_hidden and not attention,
         "mixture.render_hidden > 0 draws masks for the mixture decoder to paint and "
         "needs it (mixture.weight > 0) with mixture.alpha 'attention'"),
        (cfg.train.render_steps and not cfg.mixture.render_hidden,
         "train.render_steps > 0 fits the renderer, but mixture.render_hidden is 0 (no renderer)"),
        (cfg.train.color_augment != "none" and not mixture,
         "train.color_augment augments the mixture decoder's input, but mixture.weight "
         "is 0 (no mixture decoder)"),
        (cfg.train.segmentation_start_steps and not mixture,
         "train.segmentation_start_steps > 0 trains slot attention on the mixture decoder's loss, "
         "but mixture.weight is 0 (no mixture decoder)"),
        (cfg.train.main_loss == "mixture" and not mixture,
         "train.main_loss 'mixture' trains slot attention on the mixture decoder's loss, "
         "but mixture.weight is 0 (no mixture decoder)"),
        (cfg.train.polish_steps and not mixture,
         "train.polish_steps > 0 polishes the mixture decoder's slots, but "
         "mixture.weight is 0 (no mixture decoder)"),
        (cfg.train.dynamics_steps and cfg.dynamics.latent_weight == 0,
         "train.dynamics_steps > 0 trains the dynamics on the latent loss, but "
         "dynamics.latent_weight is 0 (no latent loss)"),
    )
    for broken, message in needs:
        if broken:
            raise ValueError(message)


# Smallest values of the integer fields that size a model or a run (validate)
_AT_LEAST = {
    "image_size": 1, "downsample": 1, "dvae.vocab_size": 1, "dvae.hidden": 1, "dvae.tau_steps": 0,
    "slots.num_slots": 1, "slots.iterations": 1, "slots.eval_iterations": 1, "slots.heads": 1,
    "slots.type_dim": 1, "slots.state_dim": 1, "slots.mlp_hidden": 1, "slots.encoder_stride": 1,
    "decoder.layers": 1, "decoder.heads": 1, "decoder.hidden": 1, "dynamics.layers": 1,
    "dynamics.heads": 1, "dynamics.hidden": 1, "mixture.hidden": 1, "train.epochs": 1,
    "train.episodes_per_epoch": 1, "train.batch_size": 1, "train.warmup_steps": 0,
    "train.dvae_warmup_steps": 0, "train.checkpoint_every": 1, "train.seed": 0, "train.dynamics_steps": 0,
    "train.render_steps": 0, "train.render_mask_steps": 0, "mixture.render_hidden": 0,
    "train.refit_steps": 0, "train.polish_steps": 0, "train.segmentation_starts": 1,
    "train.segmentation_start_steps": 0, "train.num_objects": 1,
}
# float fields: (low, high, what is expected): low < value when high is None, else low <= value < high
_IN_RANGE = {
    "dvae.tau_start": (0.0, None, "> 0"), "dvae.tau_end": (0.0, None, "> 0"), "dvae.lr": (0.0, None, "> 0"),
    "train.lr": (0.0, None, "> 0"), "train.grad_clip": (0.0, None, "> 0"), "train.dynamics_lr": (0.0, None, "> 0"),
    "train.render_lr": (0.0, None, "> 0"), "slots.position_prior": (0.0, math.inf, ">= 0"),
    "decoder.dropout": (0.0, 1.0, "in [0, 1)"), "decoder.token_dropout": (0.0, 1.0, "in [0, 1)"),
    "dynamics.dropout": (0.0, 1.0, "in [0, 1)"), "decoder.slot_grad": (0.0, math.inf, ">= 0"),
    "mixture.weight": (0.0, math.inf, ">= 0"),
    "mixture.foreground_weight": (1.0, math.inf, ">= 1"), "dvae.foreground_weight": (1.0, math.inf, ">= 1"),
    "train.polish_foreground_weight": (1.0, math.inf, ">= 1"),
    "mixture.state_mask_weight": (0.0, math.inf, ">= 0"), "dynamics.latent_weight": (0.0, math.inf, ">= 0"),
    "train.polish_lr": (0.0, None, "> 0"),
}
# fields that take one of a few words
_CHOICES = {
    "slots.encoder": ("tokens", "cnn"), "mixture.error": MIXTURE_ERRORS,
    "train.polish_mixture_error": MIXTURE_ERRORS, "train.polish_loss": PHASE_LOSSES,
    "train.main_loss": PHASE_LOSSES,
    "mixture.alpha": MIXTURE_ALPHAS,
    "mixture.appearance": MIXTURE_APPEARANCES, "train.precision": ("auto", "bf16", "fp32"),
    "train.color_augment": COLOR_AUGMENTS, "train.lr_decay": ("none", "cosine"),
    "slots.init": SLOT_INITS,
}


def _field(cfg, dotted: str):
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


def _check_field_types(cfg, where: str = "") -> None:
    """ValueError naming the field unless every field of the dataclass `cfg` (nested ones
    too) has its annotated type: an int (not a bool), a finite float (an int is one), a str,
    a bool. A config read from a file is otherwise used as it comes (`from_dict`)."""
    hints = typing.get_type_hints(type(cfg))
    for f in fields(cfg):
        value, name = getattr(cfg, f.name), where + f.name
        if is_dataclass(value):
            _check_field_types(value, name + ".")
            continue
        kind = hints.get(f.name)
        if typing.get_origin(kind) is Literal:          # a choice: its values' type here, which one in validate
            kind = type(typing.get_args(kind)[0])
        if kind is bool:
            ok, expected = isinstance(value, bool), "a bool"
        elif kind is int:
            ok, expected = isinstance(value, int) and not isinstance(value, bool), "an integer"
        elif kind is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            expected = "a finite number"
        elif kind is str:
            ok, expected = isinstance(value, str), "a string"
        else:
            continue
        if not ok:
            raise ValueError(f"{name} must be {expected}, got {value!r}")


@dataclass
class NCSConfig:
    """How NCS reads a model and builds its graph (`graph`, `evaluate`; Tables 3-4)."""
    clusters: int = 30          # graph nodes, Table 4 (block-rearrange 30)
    restarts: int | None = None  # slot-attention restarts per image when an agent reads a scene
    #                             (DSlatePerception); None = the model's env's (ncs.perception.
    #                             RESTARTS_BY_ENV). why: docs/recipe.md, "How NCS reads a model"
    graph_restarts: int = 8     # ... per frame when `graph` and `graph-nf` read the buffer's videos
    slot_init: SlotInit | None = None  # where an agent's first start begins: "random" (a draw from
    #                             the learned Gaussian, the paper's) or "farthest" (seeded on the
    #                             scene: SlotAttention.farthest_point_slots); the other restarts are
    #                             random; None = the model's env's (SLOT_INIT_BY_ENV)
    iterations: int = 7         # slot-attention iterations when reading entities (Table 2)
    extra_slots: int | None = None  # slots = objects + this (1: the floor's), at least the trained K;
    #                             None = the model's env's (EXTRA_SLOTS_BY_ENV)
    slots: int | None = None    # slots an agent reads every scene with, whatever its object count
    #                             (Fig. 9's slot axis); None = objects + extra_slots as above
    seed: int = 0               # k-means seed
    state: EntityState = "mask"  # an entity's state s, a column of Table 3: "mask" = the slot-attention
    #                             mask (block-rearrange), "slot" = the state half s of the slot
    #                             (robogym-rearrange); picks the isolate, cluster and bind metrics
    slot_position: SlotPosition | None = None  # with slot states, where a slot is: "attention" (the model's
    #                             s), "assigned" (the cells it wins, one slot per object plus
    #                             the floor's) or "base" (the lowest row and mean column of the
    #                             pixels it wins, as many slots); None = the model's env's
    #                             (SLOT_POSITION_BY_ENV: "assigned" block-rearrange, "base" block-stacking)
    masks: MaskRead | None = None  # a slot's mask: "attention" (slot attention's, upsampled from its
    #                             grid) or "pixel" (each pixel given to the slot whose attention and
    #                             painted colour explain it best: DSlate.pixel_masks); None = the
    #                             model's env's (MASKS_BY_ENV: "pixel" block-stacking)
    align: AlignRule = "near"   # which pairs of align's matching are constraints (ncs.policy.align):
    #                             "near" = those whose types are closer than a quarter of the
    #                             scene's median type distance (the kit's; a partial goal's
    #                             unconstrained cubes are no constraints), "hungarian" = all of
    #                             them (the paper's plain matching), "either" / "mutual" = one /
    #                             both entities the other's nearest type (the rules: ncs/policy.py)
    edge_action: EdgeAction | None = None  # how an edge becomes an action (ncs.graph): "most_common"
    #                             (grid cells), or from the states of the graph's transitions,
    #                             "nearest", "compose" or "readout" (continuous positions); None =
    #                             the graph's when acting, the env's when building
    #                             (ncs.graph.EDGE_ACTION_BY_ENV)
    nearest_variance: float = 0.95  # "nearest" compares slot states along the directions holding
    #                             this share of the buffer's moves (1 = whole states; ncs.graph)
    dependencies: bool | None = None  # objects that depend on each other (the kit's extension of
    #                             Appendix F, ncs.dependencies): the graph learns which nodes
    #                             support which and the agent acts only on satisfiable constraints,
    #                             clears blockers and follows shortest paths; None = the env's
    #                             (DEPENDENCIES_BY_ENV: block-stacking)

    def validate(self) -> "NCSConfig":
        for name, low in (("clusters", 1), ("restarts", 1), ("graph_restarts", 1), ("iterations", 1),
                          ("extra_slots", 0), ("slots", 1), ("seed", 0)):
            value = getattr(self, name)
            if name in ("restarts", "slots", "extra_slots") and value is None:   # the env's; objects + extra
                continue
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"ncs.{name} must be an integer >= {low}, got {value!r}")
        if self.state not in ENTITY_STATES:
            raise ValueError(f"ncs.state must be one of {', '.join(map(repr, ENTITY_STATES))}, got {self.state!r}")
        if self.slot_position is not None and self.slot_position not in SLOT_POSITIONS:
            raise ValueError(f"ncs.slot_position must be one of {', '.join(map(repr, SLOT_POSITIONS))} "
                             f"or None (the env's), got {self.slot_position!r}")
        if self.slot_init is not None and self.slot_init not in SLOT_INITS:
            raise ValueError(f"ncs.slot_init must be one of {', '.join(map(repr, SLOT_INITS))} "
                             f"or None (the env's), got {self.slot_init!r}")
        if self.masks is not None and self.masks not in MASK_READS:
            raise ValueError(f"ncs.masks must be one of {', '.join(map(repr, MASK_READS))} "
                             f"or None (the env's), got {self.masks!r}")

        if self.align not in ALIGN_RULES:
            raise ValueError(f"ncs.align must be one of {', '.join(map(repr, ALIGN_RULES))}, got {self.align!r}")

        if not (isinstance(self.nearest_variance, (int, float)) and not isinstance(self.nearest_variance, bool)
                and 0.0 < self.nearest_variance <= 1.0):
            raise ValueError(f"ncs.nearest_variance must be a number in (0, 1], got {self.nearest_variance!r}")
        if self.dependencies not in (None, True, False):
            raise ValueError(f"ncs.dependencies must be true, false or None (the env's), got {self.dependencies!r}")
        if self.edge_action is not None and self.edge_action not in EDGE_ACTIONS:
            raise ValueError(f"ncs.edge_action must be one of {', '.join(map(repr, EDGE_ACTIONS))}, "
                             f"got {self.edge_action!r}")
        return self


def _paper() -> DSlateConfig:
    return DSlateConfig(name="paper")


def _reduced() -> DSlateConfig:
    """`paper` cut to 2 CPU cores and 30 minutes of training on block-rearrange, with an
    object bias and an explicit type/state split.

    The fields it changes, each with its reason in a clause; the full reasons and the measured
    effect of each: docs/recipe.md (one row per field); the training time: docs/results.md.
    * CPU budget: `train.epochs` 7, `train.window` 2 (one transition per video),
      `train.batch_size` 16, `train.lr` 1e-3 with `train.warmup_steps` 100 and
      `train.lr_decay` "cosine" (a 30,000-step warm-up would never end), `train.precision`
      "fp32" (bf16 autocast gains nothing at these widths);
    * widths: `dvae.vocab_size` 64 (fewer codes merged colours), `decoder.layers` / `hidden`
      2 / 64, `dynamics.layers` / `hidden` 2 / 64, `slots.type_dim` 32, `slots.mlp_hidden` 128,
      `mixture.hidden` 64; `decoder.dropout` and `dynamics.dropout` 0 (short training on a
      simple scene);
    * the dVAE first: `train.dvae_warmup_steps` 600, `dvae.tau_steps` 600, `dvae.lr` 3e-3
      (the tokens settle, and tau cools, before the rest reads them);
    * `decoder.token_dropout` 0.5: the decoder must read the slots, not only its own context;
    * object bias: `slots.encoder` "cnn" (stride 2: 32x32 masks, as in STEVE); the mixture
      decoder (`mixture.weight` 1) mixing with slot attention's masks (`mixture.alpha`
      "attention"), which slots learn from alone (`decoder.slot_grad` 0); foreground pixels
      weighted 5x (`mixture.foreground_weight`, `dvae.foreground_weight`: else the colour
      nearest the floor's ends up as floor);
    * type/state split: `slots.state_dim` 4 and `slots.position_state` (s = where the slot
      attends, as in Invariant Slot Attention); `mixture.appearance` "type" (one look per slot,
      from z); `mixture.state_mask_weight` 1 (a detached head draws each mask from s);
      `dynamics.latent_weight` 1 (the dynamics learns where the moved object's s goes);
    * no colour always in the floor's slot: `slots.num_slots` 6 (one spare) with
      `train.color_augment` "channels" (the mixture loss on colour-permuted videos);
    * slot attention that separates cubes on every training seed: `slots.implicit` (only the
      last iteration carries the gradient, Chang et al. 2022) with `slots.iterations` 5, and
      `train.segmentation_starts` 4 of `segmentation_start_steps` 800 (slot attention trained
      from four initialisations on the mixture loss, the schedule going on from the best);
    * phases after the schedule: the polish (`train.polish_steps` 1,200 at `polish_lr` 2e-4,
      dVAE frozen, `polish_foreground_weight` 20, `polish_mixture_error` "per_slot",
      `polish_loss` "mixture": no cube left in the floor's slot, no slot holding two cubes of
      near colours); then two that train one part each: the dynamics phase
      (`train.dynamics_steps` 4,000, reading states with the position prior,
      `train.dynamics_prior`: trained jointly, the next frame's token loss drowns the latent
      loss); the render phase (`train.render_steps` 2,000, the first `render_mask_steps` 1,000
      on slot attention's masks, `mixture.render_hidden` 64: so that `DSlate.render` draws the
      cubes);
    * `slots.position_prior` 2, from the dynamics phase on: a slot holding nothing keeps still.
    `train.checkpoint_every` 250 only sets how often a run saves. The dVAE, the SLATE decoder,
    the dynamics' architecture and the paper's losses are kept. Each departure is one field, so
    its ablation is an override of this preset (`reproduce seeds --set train.polish_steps=0`);
    the runs that led to them are dated in docs/HISTORY.md.
    """
    return DSlateConfig(
        name="reduced",
        dvae=DVAEConfig(vocab_size=64, hidden=64, tau_steps=600, lr=3e-3, foreground_weight=5.0),
        slots=SlotConfig(num_slots=6, iterations=5, eval_iterations=7, heads=1,
                         type_dim=32, state_dim=4, mlp_hidden=128, encoder="cnn", encoder_stride=2,
                         position_state=True, position_prior=2.0, implicit=True),
        decoder=DecoderConfig(layers=2, heads=4, hidden=64, dropout=0.0, token_dropout=0.5,
                              slot_grad=0.0),
        dynamics=DynamicsConfig(layers=2, heads=4, hidden=64, dropout=0.0, latent_weight=1.0),
        mixture=MixtureConfig(weight=1.0, hidden=64, alpha="attention", foreground_weight=5.0,
                              appearance="type", state_mask_weight=1.0, render_hidden=64),
        train=TrainConfig(epochs=7, episodes_per_epoch=5_000, window=2, batch_size=16, lr=1e-3,
                          warmup_steps=100, lr_decay="cosine", dvae_warmup_steps=600,
                          segmentation_starts=4, segmentation_start_steps=800,
                          precision="fp32", checkpoint_every=250, polish_steps=1200, polish_lr=2e-4,
                          polish_foreground_weight=20.0, polish_mixture_error="per_slot",
                          polish_loss="mixture", dynamics_steps=4000, dynamics_lr=1e-3,
                          dynamics_prior=True, render_steps=2000, render_lr=1e-3,
                          render_mask_steps=1000, color_augment="channels"),
    )


def _ci() -> DSlateConfig:
    """The `reduced` model's structure at toy widths: seconds per run. It keeps the refit
    phase, which `reduced` no longer runs, and leaves out the segmentation starts, implicit
    differentiation and the polish on segmentation alone, which the tests of those fields set
    (tests/test_training.py, tests/models/test_models.py)."""
    return DSlateConfig(
        name="ci",
        dvae=DVAEConfig(vocab_size=16, hidden=16, tau_steps=20, lr=1e-3, foreground_weight=5.0),
        slots=SlotConfig(num_slots=3, iterations=2, eval_iterations=3, heads=1,
                         type_dim=8, state_dim=8, mlp_hidden=16, encoder="cnn", encoder_stride=2,
                         position_state=True, position_prior=2.0),
        decoder=DecoderConfig(layers=1, heads=2, hidden=16, dropout=0.1, token_dropout=0.25,
                              slot_grad=0.0),
        dynamics=DynamicsConfig(layers=1, heads=2, hidden=16, dropout=0.1, latent_weight=1.0),
        mixture=MixtureConfig(weight=1.0, hidden=16, alpha="attention", foreground_weight=5.0,
                              appearance="type", state_mask_weight=0.1, render_hidden=8),
        train=TrainConfig(epochs=1, episodes_per_epoch=16, window=2, batch_size=4, lr=1e-3,
                          warmup_steps=2, dvae_warmup_steps=1, precision="fp32",
                          checkpoint_every=2, polish_steps=2, polish_mixture_error="per_slot",
                          dynamics_steps=2, render_steps=2, render_mask_steps=1, refit_steps=2,
                          color_augment="channels"),
    )


PRESETS = {"ci": _ci, "reduced": _reduced, "paper": _paper}
# Seeded tasks per point of Figs. 10 and 11 at each preset (`stress.TASKS`; `reproduce fig10
# --episodes`, `--mpc-episodes`; docs.py names them when it rebuilds a table's command). MPC
# plans with 2,500 dynamics rollouts a step (x its planning horizon) and runs every episode to
# its horizon, so `reduced` runs it on the first `mpc` tasks of each set, sized for about 10
# minutes of fig10's MPC cells in two one-thread processes (1, 2, 4, 8x: 60 steps a task at
# each of 3 planning horizons; 0.11 / 0.17 / 0.23 s a step on the shipped model, 2 cores); the
# other methods read the whole set
STRESS_TASKS = {"ci": {"tasks": 2, "mpc": 2}, "reduced": {"tasks": 100, "mpc": 40},
                "paper": {"tasks": 100, "mpc": 100}}
# What a preset changes on an environment other than block-rearrange, each with its reason
# (`get_preset(name, env)`; the same as `--set` overrides, recorded in the checkpoint's config).
ENV_OVERRIDES = {
    "robogym-rearrange": {
        # robogym's 13 colours on a brown table: at 5x the dVAE round trip painted whole
        # colours as the table. why 20x: docs/recipe.md, `dvae.foreground_weight`; the runs:
        # docs/HISTORY.md, "robogym-rearrange: the dVAE's foreground weight"
        "reduced": ("dvae.foreground_weight=20",),
    },
    "block-stacking": {
        # the recipe before implicit slot attention and the segmentation starts, which the shipped
        # checkpoint was trained with: the adopted recipe merged stacked cubes of near colours and
        # solved a tenth as many 4-cube towers (docs/recipe.md, "block-stacking's recipe")
        "reduced": ("slots.implicit=false", "slots.iterations=3", "train.segmentation_starts=1",
                    "train.segmentation_start_steps=0", "train.epochs=8", "train.polish_loss=slate",
                    "train.dynamics_prior=false", "train.dynamics_steps=2000", "train.render_steps=4000",
                    "train.refit_steps=2000"),
    },
}

# How NCS reads each environment where the envs differ: every per-env default of the kit
# (the dSLATE recipe's are ENV_OVERRIDES above). Why each value: docs/recipe.md, "How NCS
# reads a model"; Table 3 gives the state kinds, Table 4 the clusters.
CLUSTERS_BY_ENV = {"block-rearrange": 30, "robogym-rearrange": 45, "block-stacking": 47}   # Table 4
# Table 3's columns; block-stacking reads slot states too: a cube's visible mask changes with
# what stands on it and in front of it, so masks of one place bind to different nodes (the runs:
# docs/HISTORY.md, "block-stacking: the camera, the starts and the entity state")
STATE_BY_ENV = {"block-rearrange": "mask", "robogym-rearrange": "slot", "block-stacking": "slot"}
EDGE_ACTION_BY_ENV = {"block-rearrange": "most_common", "robogym-rearrange": "readout",
                      "block-stacking": "nearest"}
# envs whose objects depend on each other (NCSConfig.dependencies; ncs.dependencies)
DEPENDENCIES_BY_ENV = {"block-stacking": True}
# slot-attention restarts: RESTARTS per video of the buffer when a graph is built
# (NCSConfig.graph_restarts), RESTARTS_BY_ENV per image an agent acts on (NCSConfig.restarts)
RESTARTS = 8
RESTARTS_BY_ENV = {"block-rearrange": 32, "robogym-rearrange": 8, "block-stacking": 32}
# where an agent's first start begins (NCSConfig.slot_init): on block-rearrange seeded on the
# scene, so that one pass of slot attention separates seven cubes; the other envs' tables were
# measured with the learned Gaussian's draw (docs/recipe.md, "How NCS reads a model")
SLOT_INIT = "random"
SLOT_INIT_BY_ENV = {"block-rearrange": "farthest"}
# spare slots beyond one per object when an agent reads a scene (NCSConfig.extra_slots): 1 is the
# floor's; on block-rearrange one more, where a slot that merges two cubes has a free slot to
# hand one to (docs/recipe.md, "How NCS reads a model"). The measures that read held-out scenes
# (fg-ARI, the shipping rule's error) keep one per object and the floor's (`scene_slots`)
EXTRA_SLOTS = 1
EXTRA_SLOTS_BY_ENV = {"block-rearrange": 2}
# where a slot state's position comes from (NCSConfig.slot_position): the slot's soft attention
# ("attention"), the cells it wins ("assigned"; measured on block-rearrange only) or the base of
# the pixels it wins ("base": block-stacking, where a cube's level must be told from the row
# behind it and the visible part of a covered cube moves; docs/recipe.md)
SLOT_POSITION = "attention"
SLOT_POSITION_BY_ENV = {"block-rearrange": "assigned", "block-stacking": "base"}
# the masks a model's slots are read with (NCSConfig.masks): slot attention's, upsampled from
# its grid ("attention"), or refined to pixels by the mixture decoder's paint ("pixel":
# block-stacking, whose places lie 3-3.5 pixels apart, under two of slot attention's cells;
# docs/recipe.md, "Pixel masks")
MASKS = "attention"
MASKS_BY_ENV = {"block-stacking": "pixel"}
# NCSConfig fields whose None means "the default of the env the model was trained on":
# (that default by env, the default of every other env and of a model that names none)
NCS_ENV_DEFAULTS = {"restarts": (RESTARTS_BY_ENV, RESTARTS), "slot_init": (SLOT_INIT_BY_ENV, SLOT_INIT),
                    "extra_slots": (EXTRA_SLOTS_BY_ENV, EXTRA_SLOTS), "masks": (MASKS_BY_ENV, MASKS),
                    "slot_position": (SLOT_POSITION_BY_ENV, SLOT_POSITION)}
# the task sets of an env's comparison (`reproduce baselines`) where they differ from
# comparison.run_comparison's defaults (4-7 objects, complete and partial goals): block-stacking's
# towers from 3 to 6 cubes, complete goals
TASKS_BY_ENV = {"block-stacking": {"counts": (3, 4, 5, 6), "goals": ("complete",)}}
# the episodes of the 4-object buffer a graph reads (comparison.graph_episodes_of): continuous
# positions need more exemplars per node than grid cells
GRAPH_EPISODES_BY_ENV = {"robogym-rearrange": 20000}


def ncs_env_default(field: str, env: str | None):
    """The value an NCSConfig `field` left at None takes for a model trained on `env`
    (NCS_ENV_DEFAULTS; `env` None: a model that names no env)."""
    by_env, elsewhere = NCS_ENV_DEFAULTS[field]
    return by_env.get(env, elsewhere)


def get_preset(name: str, env: str = "block-rearrange") -> DSlateConfig:
    """A fresh copy of the named preset ('ci', 'reduced' or 'paper') for `env`: the preset
    with that env's `ENV_OVERRIDES` applied."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}")
    return apply_overrides(PRESETS[name]().validate(), ENV_OVERRIDES.get(env, {}).get(name, ()))


def to_dict(cfg: DSlateConfig) -> dict:
    """A plain nested dict of primitives (safe for `torch.load(weights_only=True)`)."""
    return asdict(cfg)


def from_dict(d: dict) -> DSlateConfig:
    """Rebuild a config from `to_dict`; unknown keys raise ValueError.

    A missing key takes its field's default: fields added since a file was written default
    to the behaviour the code had before them (every new departure is off by default)."""
    def build(cls, data, where):
        if not isinstance(data, dict):
            raise ValueError(f"config {where or 'root'} must be a dict, got {type(data).__name__}")
        names = {f.name: f for f in fields(cls)}
        extra = set(data) - set(names)
        if extra:
            raise ValueError(f"config {where or 'root'} does not match this code's {cls.__name__}: "
                             f"unknown keys {sorted(extra)}")
        kwargs = {}
        for n, f in names.items():
            default = f.default_factory() if callable(f.default_factory) else None  # type: ignore[misc]
            if is_dataclass(default):
                kwargs[n] = build(type(default), data.get(n, to_dict(default)), f"{where}.{n}".strip("."))
            elif n in data:
                kwargs[n] = data[n]
        return cls(**kwargs)

    return build(DSlateConfig, copy.deepcopy(d), "").validate()


def config_diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Human-readable differences between two config dicts: ['train.lr: 0.001 != 0.0002']."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += config_diff(va, vb, f"{prefix}{k}.")
        elif va != vb:
            out.append(f"{prefix}{k}: {va!r} != {vb!r}")
    return out


def saved_config_diff(saved: dict, cfg: DSlateConfig) -> list[str]:
    """`config_diff` of a saved config (a checkpoint's) against `cfg`, the saved one read as
    `from_dict` reads it: a field added since it was written counts as its default, not as a
    difference."""
    return config_diff(to_dict(from_dict(saved)), to_dict(cfg))


def table2_rows(cfg: DSlateConfig | None = None) -> list[tuple[str, object]]:
    """Table 2 of the appendix, rendered from a config (default: the `paper` preset).

    Rows are (name, value) in the paper's order and wording, for a notebook table.
    """
    cfg = cfg or get_preset("paper")
    t, d, s, dec, dyn = cfg.train, cfg.dvae, cfg.slots, cfg.decoder, cfg.dynamics
    return [
        ("Number of epochs", t.epochs),
        ("Episodes per epoch", t.episodes_per_epoch),
        ("Episode length", t.window),
        ("Batch size", t.batch_size),
        ("Peak LR", t.lr),
        ("LR warmup steps", t.warmup_steps),
        ("Dropout", dec.dropout),
        ("dVAE: Vocabulary size", d.vocab_size),
        ("dVAE: Temp. cooldown", f"{d.tau_start:g} to {d.tau_end:g}"),
        ("dVAE: Temp. cooldown steps", d.tau_steps),
        ("dVAE: LR (no warmup)", d.lr),
        ("dVAE: Image size", cfg.image_size),
        ("dVAE: Image tokens", f"Image size / {cfg.downsample} = {cfg.grid}"),
        ("Transformer decoder: Layers", dec.layers),
        ("Transformer decoder: Heads", dec.heads),
        ("Transformer decoder: Hidden dim.", dec.hidden),
        ("Slot attention: Slots", s.num_slots),
        ("Slot attention: Iterations", s.iterations),
        ("Slot attention: Slot heads", s.heads),
        ("Slot attention: Slot dim. (h)", s.slot_dim),
        ("Slot attention: Type dim. (z)", s.type_dim),
        ("Slot attention: State dim. (s)", s.state_dim),
        ("Transformer dynamics: Layers", dyn.layers),
        ("Transformer dynamics: Heads", dyn.heads),
        ("Transformer dynamics: Hidden dim.", dyn.hidden),
    ]


# ---------------------------------------------------------------------- command-line overrides
def parse_override(text: str) -> tuple[str, str]:
    """'section.field=value' -> ('section.field', 'value'), or ValueError naming the text."""
    key, sep, value = str(text).partition("=")
    if not sep or not key.strip():
        raise ValueError(f"--set takes section.field=value (e.g. train.lr=1e-3), got {text!r}")
    return key.strip(), value.strip()


def _convert(raw: str, kind, where: str):
    """The text of an override as the field's type (int, float, str, bool); an optional
    field (`int | None`) also takes "none"."""
    kind = {"int": int, "float": float, "str": str, "bool": bool}.get(kind, kind)
    if type(None) in typing.get_args(kind):                    # `X | None`
        if raw.lower() == "none":
            return None
        kind = next(a for a in typing.get_args(kind) if a is not type(None))
    try:
        if kind is bool:
            if raw.lower() not in ("true", "false", "1", "0"):
                raise ValueError
            return raw.lower() in ("true", "1")
        if kind is int:
            return int(raw)
        if kind is float:
            value = float(raw)
            if not math.isfinite(value):
                raise ValueError
            return value
        return str(raw)
    except ValueError:
        raise ValueError(f"--set {where}={raw}: expected a finite {kind.__name__}, got {raw!r}") from None


def apply_overrides(cfg, overrides) -> object:
    """A copy of the dataclass `cfg` with `overrides` (['train.lr=1e-3', ...]) applied and
    validated; ValueError names an unknown field with the allowed ones, or a bad value.

    Dotted keys walk nested dataclasses (`train.lr` on a DSlateConfig, `clusters` on an
    NCSConfig). Properties (`slots.slot_dim`) cannot be set: set their parts instead.
    """
    cfg = copy.deepcopy(cfg)
    for text in overrides or ():
        key, raw = parse_override(text)
        *parents, leaf = key.split(".")
        node, path = cfg, []
        for part in parents:
            sub = {f.name: f for f in fields(node)}
            if part not in sub or not is_dataclass(getattr(node, part)):
                sections = sorted(n for n in sub if is_dataclass(getattr(node, n)))
                raise ValueError(f"--set {key}: unknown config section {'.'.join(path + [part])!r}; "
                                 f"sections: {', '.join(sections) or 'none'}")
            node, path = getattr(node, part), path + [part]
        names = {f.name: f for f in fields(node) if not is_dataclass(getattr(node, f.name))}
        if leaf not in names:
            where = ".".join(path) or type(node).__name__
            raise ValueError(f"--set {key}: unknown field {leaf!r} of {where}; allowed fields: "
                             f"{', '.join(sorted(names))}")
        hints = typing.get_type_hints(type(node))
        setattr(node, leaf, _convert(raw, hints.get(leaf, type(getattr(node, leaf))), key))
    return cfg.validate()


def section_config(cfg, section: str, overrides=()) -> object:
    """`cfg` (a dataclass with `validate`) with the `SECTION.FIELD=VALUE` overrides applied;
    an override of another section is refused, naming the fields this command takes."""
    for text in overrides or ():
        key, _ = parse_override(text)
        if not key.startswith(f"{section}."):
            allowed = ", ".join(f"{section}.{f.name}" for f in fields(cfg))
            raise ValueError(f"--set {key}: this command takes {section.upper()} fields only; allowed fields: {allowed}")
    return apply_overrides(cfg, [str(o)[len(section) + 1:] for o in overrides or ()])


def split_overrides(overrides, sections) -> dict[str, list[str]]:
    """Overrides grouped by their section (`ncs.clusters=16` -> "ncs"); a section outside
    `sections` is refused, naming the ones this command takes."""
    out = {name: [] for name in sections}
    for text in overrides or ():
        key, _ = parse_override(text)
        section = key.split(".", 1)[0]
        if section not in out or "." not in key:
            raise ValueError(f"--set {key}: this command takes fields of {', '.join(s + '.' for s in sections)} "
                             "only (e.g. ncs.clusters=16)")
        out[section].append(text)
    return out


def ncs_config(overrides=(), **fields_) -> NCSConfig:
    """An NCSConfig from keyword fields and `ncs.FIELD=VALUE` overrides (`graph`, `evaluate`)."""
    return section_config(NCSConfig(**{k: v for k, v in fields_.items() if v is not None}), "ncs", overrides)
