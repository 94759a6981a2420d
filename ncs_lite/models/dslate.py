"""dSLATE: SLATE (dVAE + slot attention + transformer decoder) over videos, plus dynamics.

Each slot is split as [type z ; state s] (Table 2: 96 + 96). Frame 0's slots start from
the learned Gaussian; frame t+1's slots start from frame t's, so slot k follows the same
object through a video. The dynamics predicts s_{t+1} from all slots and the action and
copies z, which makes the type action-invariant and the state the part that moves. With
cfg.slots.position_state (not in the paper; `reduced`), the last POSITION_FEATURES state
features are where the slot attends (`_with_position`), so s holds where its object is.
Why `reduced` adds the mixture, mask and latent losses and the later phases: docs/recipe.md.

Training loss for a video of T frames (per-image sums, averaged over images):
    mse      dVAE reconstruction of every frame (sum over pixels; pixels far from the image's
             median colour weighted by cfg.dvae.foreground_weight, 1 in `paper`)
    ce       SLATE token cross-entropy of every frame decoded from its slots (sum over tokens)
    ce_dyn   token cross-entropy of frame t+1 decoded from the *predicted* slots
    mix      auxiliary mixture-decoder reconstruction of every frame from its slots (sum
             over pixels), weighted by cfg.mixture.weight: 0 in `paper`, see mixture_decoder.py;
             on colour-augmented copies of the frames when the trainer passes them
             (`mixture_videos`, TrainConfig.color_augment)
    mask     cross-entropy of slot attention's masks (detached) under the masks drawn from
             the states s alone (detached too: it trains the drawing head only; sum over
             positions), weighted by cfg.mixture.state_mask_weight (0 in `paper`, see
             state_decoder.py)
    latent   squared error of the predicted states of frame t+1 against its inferred states
             (detached; sum over slots and features), weighted by cfg.dynamics.latent_weight
             (0 in `paper`)
    loss     = mse + ce + ce_dyn + weights * (mix, mask, latent)
ce and ce_dyn reach slot attention with their gradient scaled by cfg.decoder.slot_grad
(1 in `paper`; `reduced` lets the slots learn from the mixture decoder alone). An optional
last phase trains the dynamics alone on the latent loss (`dynamics_loss`).
As in SLATE, the transformer's targets are the dVAE's *sampled* hard tokens, detached,
so the dVAE learns only from its reconstruction and the rest only from the tokens.

Shapes: videos (B, T, H, W, 3) uint8; actions (B, T-1, A); slots (B, T, K, D);
tokens (B, N) over a vocabulary of V; masks (B, K, H, W).
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .decoder import TransformerDecoder
from .dvae import DVAE, patchify, unpatchify
from .dynamics import Dynamics
from ..config import MASK_READS, MIXTURE_ERRORS, SLOT_INITS
from .mixture_decoder import MixtureDecoder
from .pixel_encoder import PixelEncoder
from .positional import sinusoid_2d
from .slot_attention import SlotAttention
from .split import split
from .state_decoder import SlotRenderer, StateMaskDecoder, coordinate_grid

__all__ = ["DSlate", "SlotInference", "MODEL_VERSION"]

# Bump when a change makes old checkpoints load into a different function.
MODEL_VERSION = "dslate-2"
# state features that slots.position_state fills with where the slot attends (`_with_position`)
POSITION_FEATURES = 4
LOSSES = ("loss", "mse", "ce", "ce_dyn", "mix", "mask", "latent")
# RGB distance from the median colour above which a pixel counts as foreground in the
# weighted losses: well below a cube's distance to the floor (anti-aliased edges are lower)
FOREGROUND_DISTANCE = 0.1
# the spread (RGB in [0, 1]) of a pixel's colour around what its slot paints there, in
# `pixel_masks`: below the distance between two cubes' colours and between a cube's faces and
# the floor, above the painting's error (block-stacking, fg-ARI at 4 cubes with one start:
# 0.87 at 0.05, 0.89 at 0.1, 0.90 at 0.2, 0.86 at 0.4; docs/HISTORY.md, "block-stacking: pixel masks")
PIXEL_MASK_SIGMA = 0.1


def foreground(x: torch.Tensor) -> torch.Tensor:
    """(B, H, W, 1) bool: pixels of images x (B, H, W, 3) in [0, 1] whose colour is farther
    than FOREGROUND_DISTANCE from the image's median colour. The median is the floor's in
    these scenes (most pixels); no ground truth is read."""
    background = x.flatten(1, 2).median(dim=1).values[:, None, None]   # (B, 1, 1, 3)
    return (x - background).norm(dim=-1, keepdim=True) > FOREGROUND_DISTANCE


def foreground_weights(x: torch.Tensor, weight: float, p: int, dtype: torch.dtype) -> torch.Tensor:
    """(B, N, p*p*3) per-pixel weights of images x (B, H, W, 3) in patches of p: 1, and `weight`
    for `foreground` pixels (the weighted errors of the mixture decoder and the renderer)."""
    far = foreground(x).expand_as(x).to(dtype)                          # (B, H, W, 3)
    return patchify(1.0 + (weight - 1.0) * far, p)


def mask_cross_entropy(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of drawn masks (logits (B, K, N), softmax over K) against slot attention's
    (target (B, K, N)), summed over slots and cells, mean over images."""
    return -(target.float() * logits.float().log_softmax(1)).sum((1, 2)).mean()


def scale_grad(x: torch.Tensor, scale: float) -> torch.Tensor:
    """x in the forward pass; its gradient times `scale` in the backward pass."""
    if scale == 1.0:
        return x
    return x.detach() if scale == 0.0 else x.detach() + scale * (x - x.detach())


class SlotInference(NamedTuple):
    """Result of `DSlate.infer`: slots (B,K,D), types (B,K,Dz), states (B,K,Ds),
    masks (B,K,H,W) summing to 1 over K, attention (B,K,N') on the slot-attention
    input grid (N' = cfg.mask_grid ** 2: the token grid, or the pixel CNN's)."""
    slots: torch.Tensor
    types: torch.Tensor
    states: torch.Tensor
    masks: torch.Tensor
    attention: torch.Tensor


class DSlate(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        self.cfg = cfg
        V, N, d = cfg.dvae.vocab_size, cfg.num_tokens, cfg.decoder.hidden
        sc = cfg.slots
        self.type_dim, self.state_dim, self.slot_dim = sc.type_dim, sc.state_dim, sc.slot_dim
        self.dvae = DVAE(V, cfg.dvae.hidden, cfg.downsample, cfg.image_size)
        self.token_emb = nn.Embedding(V, d)
        # learned positions (SLATE), initialised with 2-D sinusoids so that where a token is
        # is informative from the first step (a from-scratch table is slow to learn on a CPU)
        self.pos_emb = nn.Parameter(sinusoid_2d(cfg.grid, d))
        self.mask_emb = nn.Parameter(torch.zeros(1, 1, d))             # [MASK] for token dropout
        # slot-attention inputs: the token embeddings (SLATE) or a pixel CNN (STEVE)
        self.pixel_encoder = (PixelEncoder(d, sc.encoder_stride, cfg.image_size)
                              if sc.encoder == "cnn" else None)
        # SLATE's encoder MLP between those features and slot attention
        self.sa_in = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, d), nn.ReLU(), nn.Linear(d, d))
        self.slot_attn = SlotAttention(d, sc.slot_dim, sc.num_slots, sc.iterations, sc.heads,
                                       sc.mlp_hidden, implicit=sc.implicit)
        dc = cfg.decoder
        self.decoder = TransformerDecoder(V, N, sc.slot_dim, d, dc.layers, dc.heads, dc.dropout)
        dy = cfg.dynamics
        self.dynamics = Dynamics(sc.type_dim, sc.state_dim, cfg.action_dim, dy.hidden, dy.layers,
                                 dy.heads, dy.dropout)
        mx = cfg.mixture
        mix_grid = cfg.mask_grid if mx.alpha == "attention" else cfg.grid
        self.mixture = (MixtureDecoder(sc.slot_dim, mix_grid, cfg.image_size // mix_grid, mx.hidden,
                                       mx.alpha, mx.appearance, sc.type_dim)
                        if mx.weight > 0 else None)
        self.state_masks = (StateMaskDecoder(sc.state_dim, cfg.mask_grid)
                            if mx.state_mask_weight > 0 else None)
        # made last and outside the global random stream: a run with a renderer trains every
        # other part bit for bit as a run without one, which a finished run may be extended by
        with torch.random.fork_rng(devices=[]):
            self.renderer = (SlotRenderer(sc.type_dim, sc.state_dim, cfg.mask_grid, mx.render_hidden)
                             if mx.render_hidden > 0 else None)
        self.register_buffer("grid_coords", coordinate_grid(cfg.mask_grid), persistent=False)
        # the prior on where a slot is (slots.position_prior); training switches it off before
        # the render phase, so the phases before it train as without one
        self.position_prior = sc.position_prior

    # ------------------------------------------------------------------ input checks
    def _check_images(self, images, ndim: int, what: str) -> torch.Tensor:
        S = self.cfg.image_size
        if isinstance(images, np.ndarray):
            images = torch.from_numpy(images)
        if not isinstance(images, torch.Tensor):
            raise ValueError(f"{what} must be a uint8 tensor or array, got {type(images).__name__}")
        want = "(B, H, W, 3)" if ndim == 4 else "(B, T, H, W, 3)"
        if images.dtype != torch.uint8:
            raise ValueError(f"{what} must have dtype uint8 (pixel values 0..255), got {images.dtype}")
        if images.ndim != ndim or tuple(images.shape[-3:]) != (S, S, 3):
            raise ValueError(f"{what} must have shape {want} with H = W = {S}, "
                             f"got {tuple(images.shape)}")
        return images.to(self.pos_emb.device)

    @property
    def device(self) -> torch.device:
        return self.pos_emb.device

    # ------------------------------------------------------------------ pieces
    def _embed(self, ids: torch.Tensor) -> torch.Tensor:
        """token ids (B, N) -> embeddings with positions (B, N, d)."""
        return self.token_emb(ids) + self.pos_emb

    def _drop_tokens(self, ids: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        """Decoder inputs with token dropout (training only): each input token is replaced by
        a learned [MASK] embedding (its position kept) with probability decoder.token_dropout.
        Like word dropout in text VAEs (Bowman et al., 2016), it stops the autoregressive
        decoder from predicting a scene from its own context and ignoring the slots."""
        p = self.cfg.decoder.token_dropout
        if not self.training or p <= 0:
            return emb
        drop = torch.rand(ids.shape, device=ids.device) < p                    # (B*T, N)
        masked = (self.mask_emb + self.pos_emb).to(emb.dtype).expand_as(emb)
        return torch.where(drop[..., None], masked, emb)

    def _slot_inputs(self, x: torch.Tensor, emb: torch.Tensor | None = None) -> torch.Tensor:
        """Slot-attention inputs (B, N', d) from images x (B, H, W, 3) in [0, 1]: the pixel
        CNN's features, or the token embeddings (pass `emb` if already computed)."""
        if self.pixel_encoder is not None:
            return self.sa_in(self.pixel_encoder(x))
        return self.sa_in(self._embed(self.dvae.tokenize(x)) if emb is None else emb)

    def _inputs_to_slots(self, inp, T, init_slots=None, iterations=None, num_slots=None,
                         generator=None):
        """inp (B*T, N', d) -> slots (B, T, K, D), attention (B, T, K, N'); frame t+1 starts
        from frame t's slots, frame 0 from `init_slots` or as `slots.init` says."""
        BT, N, d = inp.shape
        B = BT // T
        inp = inp.reshape(B, T, N, d)
        if init_slots is None and self.cfg.slots.init == "farthest":
            init_slots = self.slot_attn.farthest_point_slots(inp[:, 0], num_slots)
        slots, attns, prev = [], [], init_slots
        for t in range(T):
            prev, attn = self.slot_attn(inp[:, t], init_slots=prev, iterations=iterations,
                                        num_slots=num_slots, generator=generator)
            if self.cfg.slots.position_state:
                prev = self._with_position(prev, attn)
            slots.append(prev)
            attns.append(attn)
        return torch.stack(slots, 1), torch.stack(attns, 1)

    def _with_position(self, slots: torch.Tensor, attn: torch.Tensor) -> torch.Tensor:
        """slots (B, K, D) with their last POSITION_FEATURES state features replaced by where
        each slot attends: the centroid (row, col) and spread (std per axis) of its attention
        (B, K, N') over the grid, in [-1, 1]. As in Invariant Slot Attention (Biza et al.,
        2023), where a slot is becomes part of the slot; here, of its state s."""
        a, prior = attn.float(), self.position_prior
        coords = self.grid_coords.to(a.dtype)                            # (N', 2)
        if prior > 0:   # `prior` cells of attention at (0, 0) with the spread of a uniform image
            mass = a.sum(-1, keepdim=True) + prior                       # (B, K, 1)
            centre = (a @ coords) / mass                                 # (B, K, 2)
            spread = ((a @ coords.pow(2) + prior / 3.0) / mass - centre.pow(2)).clamp(min=1e-6).sqrt()
        else:           # the computation from before the prior, bit for bit (shipped checkpoints)
            w = a / (a.sum(-1, keepdim=True) + 1e-8)                     # (B, K, N')
            centre = w @ coords                                          # (B, K, 2)
            spread = (w @ coords.pow(2) - centre.pow(2)).clamp(min=1e-6).sqrt()
        where = torch.cat([centre, spread], -1).to(slots.dtype)
        return torch.cat([slots[..., :slots.shape[-1] - POSITION_FEATURES], where], -1)

    def assigned_states(self, states: torch.Tensor, attention: torch.Tensor) -> torch.Tensor:
        """states (..., K, Ds) with their position features read from the cells each slot wins
        (its attention is the largest of the K there) instead of from its soft attention
        (..., K, N'), with the same prior. With soft attention a cube's centroid leans toward
        the other cubes its slot attends to a little, more so the more cubes a scene holds;
        NCS can read slot states this way (`ncs.slot_position`, ncs/perception.py)."""
        if not self.cfg.slots.position_state:
            raise ValueError("assigned_states reads the position features of slots.position_state, "
                             "which this model does not have")
        return self._with_position(states, self._won_cells(attention))

    def base_states(self, states: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
        """states (..., K, Ds) with their position features replaced by where each slot's
        object stands in the image: the lowest row and the mean column of the pixels it wins
        in its masks (..., K, H, W) (`SlotInference.masks`: the masks NCS acts on), then two
        zeros where the spread was (a slot that wins no pixel reads (0, 0, 0, 0), the prior's
        centre). A camera that looks down at a slant draws an object's base where it touches
        what it stands on, and that edge stays put when another object covers the object's
        top, which moves the centroid of the visible part: block-stacking's places (cell,
        level) are told apart by it (`ncs.slot_position` "base"; docs/recipe.md)."""
        if not self.cfg.slots.position_state:
            raise ValueError("base_states reads the position features of slots.position_state, "
                             "which this model does not have")
        lead, (K, H, W) = masks.shape[:-3], masks.shape[-3:]
        won = self._won_cells(masks.reshape(-1, K, H * W)).reshape(*lead, K, H * W)
        coords = coordinate_grid(H).to(won)                                # (H*W, 2) (row, col)
        cells = won.sum(-1)                                                # (..., K)
        bottom = torch.where(won > 0, coords[:, 0], torch.full_like(won, -2.0)).amax(-1)
        bottom = torch.where(cells > 0, bottom, torch.zeros_like(bottom))
        column = (won @ coords[:, 1]) / cells.clamp(min=1.0)
        where = torch.stack([bottom, column, torch.zeros_like(bottom), torch.zeros_like(bottom)], -1)
        return torch.cat([states[..., :states.shape[-1] - POSITION_FEATURES], where.to(states.dtype)], -1)

    @staticmethod
    def _won_cells(attention: torch.Tensor) -> torch.Tensor:
        """(..., K, N') one-hot: 1 where the slot's attention is the largest of the K."""
        return F.one_hot(attention.argmax(-2), attention.shape[-2]).movedim(-1, -2).to(attention.dtype)

    # ------------------------------------------------------------------ training
    def forward(self, videos: torch.Tensor, actions: torch.Tensor, tau: float,
                dvae_only: bool = False, foreground_weight: float | None = None,
                mixture_videos: torch.Tensor | None = None, mixture_error: str | None = None) -> dict:
        """videos (B, T, H, W, 3) uint8, actions (B, T-1, A) -> dict of scalar losses.

        dvae_only: compute the dVAE reconstruction alone (ce = ce_dyn = 0), for a warm-up
        phase that gives the transformer stable tokens (see TrainConfig.dvae_warmup_steps).
        foreground_weight, mixture_error: override `mixture.foreground_weight` and
        `mixture.error` (the polish phase's, see TrainConfig.polish_steps).
        mixture_videos: videos (B, T, H, W, 3) uint8 for the mixture loss alone, e.g. `videos`
        colour-augmented (TrainConfig.color_augment): slot attention then learns its masks
        from them, and the decoder and dynamics read slots of `videos` (without gradient
        into slot attention when decoder.slot_grad is 0)."""
        videos = self._check_images(videos, 5, "videos")
        B, T = videos.shape[:2]
        if actions.shape != (B, T - 1, self.cfg.action_dim):
            raise ValueError(f"actions must have shape {(B, T - 1, self.cfg.action_dim)}, "
                             f"got {tuple(actions.shape)}")
        x = videos.flatten(0, 1).float() / 255.0                       # (B*T, H, W, 3)
        mse, ids = self._dvae_loss(x, tau)
        out = dict.fromkeys(LOSSES, mse.new_zeros(()))
        if dvae_only:
            return {**out, "loss": mse, "mse": mse}

        emb = self._embed(ids)                                         # (B*T, N, d)
        if mixture_videos is not None:
            mixture_videos = self._check_images(mixture_videos, 5, "mixture_videos")
            if mixture_videos.shape != videos.shape:
                raise ValueError(f"mixture_videos must have the shape of videos {tuple(videos.shape)}, "
                                 f"got {tuple(mixture_videos.shape)}")
        own = mixture_videos is None or self.cfg.decoder.slot_grad != 0.0   # slots learn from these frames
        with torch.set_grad_enabled(own and torch.is_grad_enabled()):
            slots, attn = self._inputs_to_slots(self._slot_inputs(x, emb), T)  # (B, T, K, D), (B, T, K, N')
        read = scale_grad(slots, self.cfg.decoder.slot_grad)           # what decoder/dynamics see
        ce, ce_dyn, pred = self._slate_losses(ids, emb, read, actions.to(videos.device))
        out.update(mse=mse, ce=ce, ce_dyn=ce_dyn)
        loss = mse + ce + ce_dyn
        if self.mixture is not None:
            xm, mslots, mattn = x, slots, attn
            if mixture_videos is not None:
                xm = mixture_videos.flatten(0, 1).float() / 255.0
                mslots, mattn = self._inputs_to_slots(self._slot_inputs(xm), T)
            out["mix"] = self.mixture_error(xm, mslots.flatten(0, 1), mattn.flatten(0, 1),
                                            foreground_weight, mixture_error).mean()
            loss = loss + self.cfg.mixture.weight * out["mix"]
        if self.state_masks is not None:
            out["mask"] = self._state_mask_loss(slots, attn)
            loss = loss + self.cfg.mixture.state_mask_weight * out["mask"]
        if self.cfg.dynamics.latent_weight > 0:
            target = split(slots[:, 1:], self.type_dim)[1].detach()
            out["latent"] = (split(pred, self.type_dim)[1] - target).float().pow(2).sum((2, 3)).mean()
            loss = loss + self.cfg.dynamics.latent_weight * out["latent"]
        out["loss"] = loss
        return out

    def _dvae_loss(self, x: torch.Tensor, tau: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The dVAE's loss on frames x (M, H, W, 3) in [0, 1]: the squared error of its
        reconstruction from relaxed one-hot tokens at temperature tau, summed per image
        (foreground pixels weighted by `dvae.foreground_weight`) and averaged; with the
        sampled token ids (M, N) the transformer learns to predict."""
        code_logits = self.dvae.logits(x)                              # (M, N, V)
        soft, ids = self.dvae.sample(code_logits, tau)                 # (M, N, V), (M, N)
        recon = self.dvae.decode(soft.to(code_logits.dtype))           # (M, H, W, 3)
        err = (recon.float() - x).pow(2)                               # (M, H, W, 3)
        w = self.cfg.dvae.foreground_weight
        if w != 1.0:
            err = err * (1.0 + (w - 1.0) * foreground(x))
        return err.sum(dim=(1, 2, 3)).mean(), ids

    def _slate_losses(self, ids: torch.Tensor, emb: torch.Tensor, slots: torch.Tensor,
                      actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SLATE's and the dynamics' cross-entropies: the decoder predicts each frame's tokens
        ids (B*T, N) from its slots (B, T, K, D), and frame t+1's from the slots the dynamics
        predict from frame t's and action t (B, T-1, A); per image, averaged. Also returns
        the predicted slots (B, T-1, K, D)."""
        B, T = slots.shape[:2]
        dec_in = self._drop_tokens(ids, emb)                           # (B*T, N, d)
        logits = self.decoder(dec_in, slots.flatten(0, 1))             # (B*T, N, V)
        ce = F.cross_entropy(logits.flatten(0, 1).float(), ids.flatten(), reduction="sum") / (B * T)
        pred = self.dynamics(slots[:, :-1], actions)                   # (B, T-1, K, D)
        emb_next = dec_in.reshape(B, T, *emb.shape[1:])[:, 1:].flatten(0, 1)
        logits_dyn = self.decoder(emb_next, pred.flatten(0, 1))        # (B*(T-1), N, V)
        ce_dyn = F.cross_entropy(logits_dyn.flatten(0, 1).float(), ids.reshape(B, T, -1)[:, 1:].flatten(),
                                 reduction="sum") / (B * (T - 1))
        return ce, ce_dyn, pred

    @torch.no_grad()
    def _read_videos(self, videos: torch.Tensor):
        """Videos (B, T, H, W, 3) uint8 -> images x (B*T, H, W, 3) in [0, 1], slots (B, T, K, D)
        and attention (B, T, K, N'), inferred without gradient with `eval_iterations`, as NCS
        and MPC read them: the input of the phases that train one part alone."""
        x = videos.flatten(0, 1).float() / 255.0
        slots, attn = self._inputs_to_slots(self._slot_inputs(x), videos.shape[1],
                                            iterations=self.cfg.slots.eval_iterations)
        return x, slots, attn

    def _state_mask_loss(self, slots: torch.Tensor, attn: torch.Tensor) -> torch.Tensor:
        """The state-mask head's cross-entropy against slot attention's masks, slots (..., K, D)
        and attention (..., K, N'). A read-out: its gradient stops at s (through slot attention
        it collapsed the masks into one slot that a bump can draw: docs/HISTORY.md, "The
        type/state split")."""
        logits = self.state_masks(split(slots, self.type_dim)[1].flatten(0, -3).detach())   # (M, K, N')
        return mask_cross_entropy(logits, attn.flatten(0, -3).detach())

    def mixture_loss(self, videos: torch.Tensor, foreground_weight: float | None = None,
                     mixture_videos: torch.Tensor | None = None, mixture_error: str | None = None) -> dict:
        """A polish of segmentation alone (TrainConfig.polish_loss "mixture"): the mixture
        decoder's error (weighted by `mixture.weight`) on slots read from `mixture_videos`
        (default `videos`) and, with a state-mask head, its cross-entropy. Slot attention, its
        encoder, the mixture decoder and the head receive gradients; the dVAE, the SLATE
        decoder and the dynamics are not run. The other LOSSES are 0."""
        if self.mixture is None:
            raise ValueError("mixture_loss trains the mixture decoder, but this model has none (mixture.weight = 0)")
        videos = self._check_images(videos if mixture_videos is None else mixture_videos, 5,
                                    "videos" if mixture_videos is None else "mixture_videos")
        x = videos.flatten(0, 1).float() / 255.0                       # (B*T, H, W, 3)
        slots, attn = self._inputs_to_slots(self._slot_inputs(x), videos.shape[1])
        mix = self.mixture_error(x, slots.flatten(0, 1), attn.flatten(0, 1), foreground_weight, mixture_error).mean()
        out = {**dict.fromkeys(LOSSES, mix.new_zeros(())), "mix": mix}
        loss = self.cfg.mixture.weight * mix
        if self.state_masks is not None:
            out["mask"] = self._state_mask_loss(slots, attn)
            loss = loss + self.cfg.mixture.state_mask_weight * out["mask"]
        out["loss"] = loss
        return out

    def dynamics_loss(self, videos: torch.Tensor, actions: torch.Tensor) -> dict:
        """The dynamics phase's loss (TrainConfig.dynamics_steps): the latent loss alone, on
        slots inferred through each video without gradient, with `eval_iterations` as NCS
        and MPC read them. Only the dynamics receives a gradient. The other LOSSES are 0."""
        videos = self._check_images(videos, 5, "videos")
        _, slots, _ = self._read_videos(videos)
        pred = self.dynamics(slots[:, :-1], actions.to(videos.device))
        latent = (split(pred, self.type_dim)[1] - split(slots[:, 1:], self.type_dim)[1]).float().pow(2).sum((2, 3)).mean()
        return {**dict.fromkeys(LOSSES, latent.new_zeros(())), "loss": latent, "latent": latent}

    def render_loss(self, videos: torch.Tensor, masks: bool = False) -> dict:
        """The render phase's loss (TrainConfig.render_steps): the mean absolute error of
        `render`'s image against each frame, pixels far from the floor's colour weighted by
        `mixture.foreground_weight`, on slots inferred without gradient with `eval_iterations`
        (as NCS reads them); with `masks` (the phase's first `render_mask_steps`), the
        cross-entropy of the renderer's masks against slot attention's instead, as the
        state-mask decoder learns. Only the renderer receives a gradient: the mixture decoder
        paints frozen. The other LOSSES are 0 (the log's "loss" column holds the error)."""
        if self.renderer is None:
            raise ValueError("render_loss fits the renderer, but this model has none (mixture.render_hidden = 0)")
        x, slots, attn = self._read_videos(self._check_images(videos, 5, "videos"))
        slots = slots.flatten(0, 1)
        if masks:
            error = mask_cross_entropy(self.renderer(slots), attn.flatten(0, 1))
            return {**dict.fromkeys(LOSSES, error.new_zeros(())), "loss": error}
        for p in self.mixture.parameters():                            # painting, not learning
            p.requires_grad_(False)
        try:
            patches, _ = self.mixture(slots, self._render_alpha(slots))
        finally:
            for p in self.mixture.parameters():
                p.requires_grad_(True)
        p = self.cfg.image_size // self.mixture.grid
        weight = foreground_weights(x, self.cfg.mixture.foreground_weight, p, torch.float32)
        error = ((patches.float() - patchify(x, p)).abs() * weight).mean()
        return {**dict.fromkeys(LOSSES, error.new_zeros(())), "loss": error}

    def mixture_error(self, x: torch.Tensor, slots: torch.Tensor, attention: torch.Tensor,
                      foreground_weight: float | None = None, error: str | None = None) -> torch.Tensor:
        """The mixture decoder's reconstruction error per image (B,): x (B, H, W, 3) in [0, 1],
        slots (B, K, D), attention (B, K, N'); `foreground_weight` and `error` default to the
        config's (`mixture.foreground_weight`, `mixture.error`).

        A summed squared error, with pixels whose colour is far (> FOREGROUND_DISTANCE in RGB)
        from the image's median colour weighted by `mixture.foreground_weight`: a cube merged
        into the floor's slot costs only its squared colour distance to the floor, so with a
        plain sum the floor's slot keeps the cube nearest its colour (why: docs/recipe.md,
        `mixture.foreground_weight`). The median colour is the floor's in these scenes (most
        pixels); no ground truth is read.
        With error "per_slot" each pixel's error is that of every slot's own patch, weighted
        by the slot's mixing weight, instead of the mixed patch's: two slots can then no
        longer share two cubes by blending their looks into both colours.
        """
        error = self.cfg.mixture.error if error is None else error
        if error not in MIXTURE_ERRORS:
            raise ValueError(f"error must be one of {MIXTURE_ERRORS}, got {error!r}")
        p = self.cfg.image_size // self.mixture.grid
        target = patchify(x, p)                                        # (B, N, p*p*3)
        if error == "per_slot":
            patches, alpha = self.mixture.paint(slots, attention)      # (B, K, N|1, c), (B, K, N)
            err = (alpha[..., None] * (patches - target[:, None]).pow(2)).sum(1)   # (B, N, c)
        else:
            patches, _ = self.mixture(slots, attention)                # (B, N, p*p*3)
            err = (patches - target).pow(2)                            # (B, N, p*p*3)
        w = self.cfg.mixture.foreground_weight if foreground_weight is None else foreground_weight
        if w != 1.0:
            err = err * foreground_weights(x, w, p, err.dtype)
        return err.sum(dim=(1, 2))

    # ------------------------------------------------------------------ inference API
    @torch.no_grad()
    def tokens(self, images) -> torch.Tensor:
        """images (B, H, W, 3) uint8 -> deterministic dVAE token ids (B, N)."""
        images = self._check_images(images, 4, "images")
        return self.dvae.tokenize(images.float() / 255.0)

    @torch.no_grad()
    def features(self, images) -> torch.Tensor:
        """images (B, H, W, 3) uint8 -> slot-attention inputs (B, N', d), N' = cfg.mask_grid ** 2."""
        images = self._check_images(images, 4, "images")
        return self._slot_inputs(images.float() / 255.0)

    @contextmanager
    def _eval_mode(self):
        """Eval mode for the block, then the mode the model was in. Switches only a training
        model: `train()` walks every submodule, a cost MPC would pay at every call."""
        if not self.training:
            yield
            return
        self.eval()
        try:
            yield
        finally:
            self.train()

    @torch.no_grad()
    def infer(self, images, iterations: int | None = None, num_slots: int | None = None,
              init_slots: torch.Tensor | None = None, seed: int = 0, restarts: int = 1,
              masks: str = "attention", slot_init: str = "random") -> SlotInference:
        """Slots and masks of single images.

        images (B, H, W, 3) uint8; iterations defaults to the config's eval_iterations;
        num_slots overrides K (e.g. 8 slots for 7 objects: slot attention works for any K);
        init_slots (B, K, D) continues from a previous frame; `seed` fixes the initial
        slot sample so inference is reproducible.

        restarts > 1 runs slot attention from that many initial samples and keeps, per image,
        the one the model itself reconstructs best (`reconstruction_error`: no ground truth).
        Slot attention is a local search: now and then two slots share a cube and another
        cube falls into the background slot, and a fresh start usually avoids it (why:
        docs/recipe.md, "How NCS reads a model"; the restarts NCS acts with:
        `ncs.perception.RESTARTS_BY_ENV`).

        masks: "attention" = slot attention's, upsampled from its grid (`upsample_masks`);
        "pixel" = refined to single pixels by what each slot paints (`pixel_masks`).

        slot_init: where the first restart begins without `init_slots`: "random" (a draw from
        the learned Gaussian) or "farthest" (`SlotAttention.farthest_point_slots`, seeded on
        the image); the other restarts are drawn.
        """
        if not isinstance(restarts, int) or restarts < 1:
            raise ValueError(f"restarts must be a positive integer, got {restarts!r}")
        if masks not in MASK_READS:
            raise ValueError(f"masks must be one of {', '.join(map(repr, MASK_READS))}, got {masks!r}")
        if slot_init not in SLOT_INITS:
            raise ValueError(f"slot_init must be one of {', '.join(map(repr, SLOT_INITS))}, got {slot_init!r}")
        if init_slots is not None and restarts > 1:
            raise ValueError("restarts > 1 draws fresh initial slots; it cannot be combined with init_slots")
        with self._eval_mode():
            images = self._check_images(images, 4, "images")
            x = images.float() / 255.0                                  # (B, H, W, 3)
            inp = self._slot_inputs(x)                                  # (B, N', d)
            B = inp.shape[0]
            gen = torch.Generator(device=self.device).manual_seed(int(seed))
            if init_slots is not None and tuple(init_slots.shape[::2]) != (B, self.slot_dim):
                raise ValueError(f"init_slots must have shape (B={B}, K, D={self.slot_dim}), "
                                 f"got {tuple(init_slots.shape)}")
            if init_slots is None:         # drawn here: slots.init sets how training starts, not this
                farthest = slot_init == "farthest"
                init_slots = self.slot_attn.initial_slots(B * (restarts - farthest), num_slots, gen)
                if farthest:
                    init_slots = torch.cat([self.slot_attn.farthest_point_slots(inp, num_slots), init_slots])
            # all restarts in one batch: row r * B + b is restart r of image b
            slots, attn = self._inputs_to_slots(
                inp.repeat(restarts, 1, 1), 1, init_slots=init_slots,
                iterations=iterations or self.cfg.slots.eval_iterations,
                num_slots=num_slots, generator=gen)
            slots, attn = slots[:, 0].float(), attn[:, 0].float()      # (R*B, K, D), (R*B, K, N')
            if restarts > 1:
                err = self.reconstruction_error(x.repeat(restarts, 1, 1, 1), slots, attn)
                best = err.reshape(restarts, B).argmin(0) * B + torch.arange(B, device=self.device)
                slots, attn = slots[best], attn[best]
            read = self.upsample_masks(attn) if masks == "attention" else self.pixel_masks(x, slots, attn)
            return SlotInference(slots, *split(slots, self.type_dim), read, attn)

    @torch.no_grad()
    def reconstruction_error(self, x: torch.Tensor, slots: torch.Tensor,
                             attention: torch.Tensor) -> torch.Tensor:
        """How badly slots explain their images, per image (B,): lower is better.

        x (B, H, W, 3) in [0, 1], slots (B, K, D), attention (B, K, N'). With a mixture
        decoder: its summed squared pixel error (the `mix` loss, scored as the polish steps
        score it when there are any); without one (the paper's model): the decoder's token
        cross-entropy of the dVAE's tokens, teacher-forced (the `ce` loss). Ranks restarts in
        `infer`."""
        if self.mixture is not None:       # the error the slots were trained on last
            t = self.cfg.train
            return self.mixture_error(x, slots, attention,
                                      error=t.polish_mixture_error if t.polish_steps else None)
        ids = self.dvae.tokenize(x)                                     # (B, N)
        logits = self.decoder(self._embed(ids), slots.to(self.pos_emb.dtype))  # (B, N, V)
        return F.cross_entropy(logits.float().transpose(1, 2), ids, reduction="none").sum(1)

    @torch.no_grad()
    def infer_video(self, videos, iterations: int | None = None, num_slots: int | None = None,
                    seed: int = 0, restarts: int = 1, masks: str = "attention",
                    slot_init: str = "random") -> SlotInference:
        """Like `infer` for videos (B, T, H, W, 3): each frame starts from the previous frame's
        slots, so slot k tracks one object (`restarts` and `slot_init` apply to the first frame).
        Outputs gain a T axis: slots (B, T, K, D), ..."""
        videos = self._check_images(videos, 5, "videos")
        B, T = videos.shape[:2]
        out, prev = [], None
        for t in range(T):
            r = self.infer(videos[:, t], iterations, num_slots, init_slots=prev, seed=seed,
                           restarts=restarts if prev is None else 1, masks=masks, slot_init=slot_init)
            out.append(r)
            prev = r.slots
        return SlotInference(*(torch.stack(x, 1) for x in zip(*out)))

    def upsample_masks(self, attn: torch.Tensor) -> torch.Tensor:
        """attention (B, K, N) -> masks (B, K, H, W). Bilinear weights sum to one, so the
        masks still sum to one over K at every pixel."""
        B, K, _ = attn.shape
        g, S = self.cfg.mask_grid, self.cfg.image_size
        return F.interpolate(attn.reshape(B, K, g, g), size=(S, S), mode="bilinear",
                             align_corners=False)

    @torch.no_grad()
    def pixel_masks(self, x: torch.Tensor, slots: torch.Tensor, attention: torch.Tensor) -> torch.Tensor:
        """Masks (B, K, H, W) at the image's resolution, summing to 1 over K: each pixel of
        x (B, H, W, 3) in [0, 1] shared among the slots (B, K, D) in proportion to their
        upsampled attention (B, K, N') times how well the colour each paints there (the
        mixture decoder, before mixing) explains the pixel's, a Gaussian of spread
        PIXEL_MASK_SIGMA. This is the mixture's posterior of which slot drew each pixel, an
        E-step on slot attention's masks, which are the prior: a slot-attention cell covers
        several pixels, and an object's edge moves to the pixel where its colour ends. Reads
        the image and the model only, no ground truth."""
        if self.mixture is None:
            raise ValueError("pixel masks read what the mixture decoder paints; this model has none "
                             "(mixture.weight = 0): use masks 'attention'")
        patches, _ = self.mixture.paint(slots.to(self.pos_emb.dtype), attention)   # (B, K, N|1, p*p*3)
        B, K = slots.shape[:2]
        g, S = self.mixture.grid, self.cfg.image_size
        paint = unpatchify(patches.expand(B, K, g * g, -1).reshape(B * K, g * g, -1).float(), S // g, g)
        distance = (paint.reshape(B, K, S, S, 3) - x[:, None].float()).pow(2).sum(-1)    # (B, K, H, W)
        prior = self.upsample_masks(attention.float()).clamp(min=1e-6).log()
        return torch.softmax(prior - distance / (2 * PIXEL_MASK_SIGMA ** 2), dim=1)

    @torch.no_grad()
    def predict(self, slots: torch.Tensor, actions) -> torch.Tensor:
        """Dynamics: slots (B, K, D), actions (B, A) -> next slots (B, K, D); the type part
        slots[..., :Dz] is returned unchanged."""
        if slots.ndim != 3 or slots.shape[-1] != self.slot_dim:
            raise ValueError(f"slots must have shape (B, K, {self.slot_dim}), got {tuple(slots.shape)}")
        actions = torch.as_tensor(actions, dtype=torch.float32, device=slots.device)
        if actions.shape != (slots.shape[0], self.cfg.action_dim):
            raise ValueError(f"actions must have shape ({slots.shape[0]}, {self.cfg.action_dim}), "
                             f"got {tuple(actions.shape)}")
        with self._eval_mode():
            return self.dynamics(slots.to(self.pos_emb.dtype), actions)

    @property
    def can_render(self) -> bool:
        """Whether `render` works: the model has the mixture decoder and the renderer or the
        state-mask decoder."""
        return self.mixture is not None and (self.renderer is not None or self.state_masks is not None)

    @torch.no_grad()
    def state_masks_of(self, slots: torch.Tensor) -> torch.Tensor:
        """The masks (B, K, H, W) that the states of slots (B, K, D) alone draw, summing to 1
        over K (state_decoder.py); compare `infer(...).masks`, slot attention's own."""
        if self.state_masks is None:
            raise ValueError("this model has no state-mask decoder (mixture.state_mask_weight = 0)")
        return self.upsample_masks(self._state_alpha(slots))

    def _state_alpha(self, slots: torch.Tensor) -> torch.Tensor:
        """Masks (B, K, N') on slot attention's grid drawn from the states of slots (B, K, D)."""
        logits = self.state_masks(split(slots, self.type_dim)[1].to(self.pos_emb.dtype))
        return logits.float().softmax(1)

    def _render_alpha(self, slots: torch.Tensor) -> torch.Tensor:
        """The masks (B, K, N') `render` paints with: the renderer's, else the state-mask decoder's."""
        if self.renderer is None:
            return self._state_alpha(slots)
        return self.renderer(slots.to(self.pos_emb.dtype)).float().softmax(1)

    @torch.no_grad()
    def render(self, slots: torch.Tensor) -> torch.Tensor:
        """The image the slots alone describe: each slot's look (mixture decoder, from z)
        where its state s says it is (the renderer, fitted to the frames in the render phase;
        without one, the state-mask decoder). slots (B, K, D), inferred or predicted by
        `predict` -> images (B, H, W, 3) float in [0, 1]. Needs `can_render`; the paper's
        model decodes through its transformer instead (`decode`)."""
        if not self.can_render:
            raise ValueError("render needs the mixture decoder and the renderer or the state-mask "
                             "decoder (mixture.weight > 0 and mixture.render_hidden > 0 or "
                             "mixture.state_mask_weight > 0); use decode() for the SLATE decoder")
        if slots.ndim != 3 or slots.shape[-1] != self.slot_dim:
            raise ValueError(f"slots must have shape (B, K, {self.slot_dim}), got {tuple(slots.shape)}")
        slots = slots.to(self.pos_emb.dtype)
        patches, _ = self.mixture(slots, self._render_alpha(slots))    # (B, N', p*p*3)
        g = self.mixture.grid
        return unpatchify(patches, self.cfg.image_size // g, g).clamp(0, 1)

    @torch.no_grad()
    def decode_tokens(self, slots: torch.Tensor, temperature: float = 0.0,
                      seed: int = 0) -> torch.Tensor:
        """Autoregressively generate token ids (B, N) from slots (B, K, D); greedy when
        temperature == 0, else sampled. N sequential decoder passes: for notebooks."""
        with self._eval_mode():
            B, N = slots.shape[0], self.cfg.num_tokens
            gen = torch.Generator(device=self.device).manual_seed(int(seed))
            ids = torch.zeros(B, N, dtype=torch.long, device=self.device)
            for n in range(N):
                logits = self.decoder(self._embed(ids)[:, :n + 1], slots)[:, n]   # (B, V)
                if temperature > 0:
                    probs = torch.softmax(logits.float() / temperature, -1)
                    ids[:, n] = torch.multinomial(probs, 1, generator=gen)[:, 0]
                else:
                    ids[:, n] = logits.argmax(-1)
            return ids

    @torch.no_grad()
    def decode(self, slots: torch.Tensor, temperature: float = 0.0, seed: int = 0) -> torch.Tensor:
        """slots (B, K, D) -> images (B, H, W, 3) float in [0, 1] via tokens and the dVAE."""
        if slots.ndim != 3 or slots.shape[-1] != self.slot_dim:
            raise ValueError(f"slots must have shape (B, K, {self.slot_dim}), got {tuple(slots.shape)}")
        ids = self.decode_tokens(slots.to(self.pos_emb.dtype), temperature, seed)
        return self.dvae.decode_ids(ids).clamp(0, 1)

    @torch.no_grad()
    def reconstruct(self, images) -> torch.Tensor:
        """dVAE round trip: images (B, H, W, 3) uint8 -> (B, H, W, 3) float in [0, 1]."""
        return self.dvae.decode_ids(self.tokens(images)).clamp(0, 1)
