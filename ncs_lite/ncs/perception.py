"""Entities from observations: what NCS sees of a scene.

An entity is a pair (type z, state s). The learned perception reads them off dSLATE's slots
(state = the slot-attention mask, block-rearrange, or the state half s of the slot,
robogym-rearrange: Table 3's two columns); the oracle reads them off the environment's
ground truth (type = colour, state = the object's segmentation mask, or its position as the
stand-in for s), so the same graph and policy code runs on both and the gap between them is
the cost of the learned representation.

Mask states are average-pooled to 16x16 = the dVAE token grid (64 / 4), so oracle and
learned mask states share one feature space of D = 256 (slot states: D = the model's state
dim; oracle positions: D = 3). `Entities.masks` keeps the full-resolution masks of the
entities (for the learned perception: those of the restart it kept; for mask states, the
masks the states were pooled from), so a figure draws exactly what the agent acted on.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from ..cache import buffer_digest, cached, code_digest, digest
from ..config import (EXTRA_SLOTS, MASK_READS, RESTARTS, RESTARTS_BY_ENV, SLOT_INITS, SLOT_POSITIONS, NCSConfig,
                      ncs_env_default)
from ..data import load_buffer
from ..workers import map_jobs

STATE_GRID = 16
# slot positions read from the cells each slot wins (DSlate.assigned_states, DSlate.base_states)
WON_CELL_READS = ("assigned", "base")


def acting_restarts(ncs, model) -> int:
    """The restarts an agent reads a scene with: `ncs.restarts`, or when it is None those of
    the env the model was trained on (RESTARTS_BY_ENV; RESTARTS for a model that names none)."""
    if ncs.restarts is not None:
        return ncs.restarts
    return ncs_env_default("restarts", model_env(model))


def acting_slot_init(ncs, model) -> str:
    """Where an agent's first slot-attention start begins: `ncs.slot_init`, or when it is None
    that of the env the model was trained on (SLOT_INIT_BY_ENV; SLOT_INIT otherwise)."""
    return ncs.slot_init or ncs_env_default("slot_init", model_env(model))


def acting_extra_slots(ncs, model) -> int:
    """The slots an agent reads a scene with beyond one per object: `ncs.extra_slots`, or when
    it is None those of the env the model was trained on (EXTRA_SLOTS_BY_ENV; EXTRA_SLOTS, the
    floor's, otherwise)."""
    if ncs.extra_slots is not None:
        return ncs.extra_slots
    return ncs_env_default("extra_slots", model_env(model))


def acting_masks(ncs, model) -> str:
    """The masks an agent reads a model's slots with: `ncs.masks`, or when it is None those of
    the env the model was trained on (`default_masks`)."""
    return ncs.masks or default_masks(model)


def default_masks(model) -> str:
    """The masks of the env the model was trained on (MASKS_BY_ENV), when the model paints
    what pixel masks need (slot attention's otherwise)."""
    if getattr(model, "mixture", None) is None:
        return "attention"
    return ncs_env_default("masks", model_env(model))


def acting_slot_position(ncs, model) -> str:
    """How an agent reads slot states' positions: `ncs.slot_position`, or when it is None the
    default of the env the model was trained on (`default_slot_position`)."""
    return ncs.slot_position or default_slot_position(model)


def scene_slots(model, num_objects: int, ncs=None) -> int:
    """The slots a scene of `num_objects` objects is read with: `ncs.slots` when set (a fixed
    count: the reader is not told how many objects there are), else one per object plus
    `acting_extra_slots` (the floor's and any spare), at least the model's trained K; slot
    states read from the cells each slot wins (`slot_position` "assigned") get no more than
    that, since a spare slot would win a few cells of a cube (SLOT_POSITION_BY_ENV). `ncs`
    None: the measures' reading, one slot per object and the floor's, at least K, on every
    env. Used by NCS, NF and MPC (`evaluation.learned_perception`), by graphs, and by every
    measure that reads held-out scenes."""
    ncs = ncs or NCSConfig(extra_slots=EXTRA_SLOTS)
    if ncs.slots is not None:
        return ncs.slots
    slots = num_objects + acting_extra_slots(ncs, model)
    if ncs.state == "slot" and acting_slot_position(ncs, model) in WON_CELL_READS:
        return slots
    trained = getattr(getattr(model, "cfg", None), "slots", None)     # stand-in models in tests declare no K
    return max(trained.num_slots if trained is not None else 0, slots)


def model_env(model) -> str | None:
    """The env a loaded model was trained on (None for a model that names none)."""
    return (getattr(model, "checkpoint_info", None) or {}).get("env")


def default_slot_position(model) -> str:
    """The slot-state read of the env the model was trained on (SLOT_POSITION_BY_ENV), when
    the model has position features to read ("attention" otherwise)."""
    if not model.cfg.slots.position_state:
        return "attention"
    return ncs_env_default("slot_position", model_env(model))


class Entities(NamedTuple):
    """K entities of one image: types (K, Dz), states (K, D) and, when the perception has
    them, the masks (K, H, W) of the entities (float, summing to 1 over K for the learned
    perception; 0/1 per object for the oracle). With mask states, `states` are these masks
    pooled; with slot or position states, the masks only show where the entities are."""
    types: torch.Tensor
    states: torch.Tensor
    masks: torch.Tensor | None = None


def pool_masks(masks, grid: int = STATE_GRID) -> torch.Tensor:
    """(..., H, W) masks -> (..., grid * grid) float states (area averages)."""
    m = torch.as_tensor(np.asarray(masks)).float()
    lead, (h, w) = m.shape[:-2], m.shape[-2:]
    if h % grid or w % grid:
        raise ValueError(f"mask size {(h, w)} must be a multiple of the state grid {grid}")
    pooled = torch.nn.functional.avg_pool2d(m.reshape(-1, 1, h, w), h // grid)
    return pooled.reshape(*lead, grid * grid)


def visible_states(states: torch.Tensor) -> torch.Tensor:
    """Pooled ground-truth masks (..., D) with an object that shows no pixel (a cube hidden
    under and behind stacks in block-stacking) given the uniform state: the cosine metrics are
    undefined for a zero vector, and the uniform state lies far from every place, so
    `ncs.dependencies` counts the object as off the graph. Visible objects are unchanged."""
    hidden = states.sum(-1, keepdim=True) == 0
    return torch.where(hidden, torch.full_like(states, 1.0 / states.shape[-1]), states)


# The oracle's ground-truth stand-in for each kind of learned state (NCSConfig.state): the
# segmentation mask for the attention mask, the object's position for the slot's state half
ORACLE_STATES = {"mask": "mask", "slot": "position"}


class OraclePerception:
    """Ground-truth entities (for the `ncs-oracle` agent only: it reads `info`).

    type = what the object is (`info["types"]`: a cube's colour; colour and shape in
    robogym-rearrange); state = its segmentation mask pooled to the state grid
    ("mask", D = 256) or its position ("position", D = 3), the ground truth that the slot's
    state half s stands for. A graph of positions is built with the slot metrics (Table 3's
    second column, `graph_state` "slot").

    The position is the full (x, y, z) of `info["positions"]` (k, 3) / buffer["positions"]
    (E, T, k, 3), z being the cubes' fixed resting height. isolate and select-constraint
    measure cosine distance, which sees only directions: with (x, y) alone a cube moved
    along a line through the grid's centre, e.g. (0.05, 0.05) -> (0.15, 0.15), would look
    unmoved: isolate would lose its transition and select-constraint would never pick its
    unsatisfied goal. The constant nonzero z makes the cosine distance 0 only for equal positions;
    squared Euclidean (cluster, bind) ignores it.
    """

    reads_ground_truth = True

    def __init__(self, state: str = "mask"):
        if state not in ORACLE_STATES.values():
            raise ValueError(f"oracle state must be one of {sorted(ORACLE_STATES.values())}, got {state!r}")
        self.state = state

    @property
    def graph_state(self) -> str:
        """The Table 3 column (METRICS_BY_STATE key) of these states: "mask" or "slot"."""
        return {v: k for k, v in ORACLE_STATES.items()}[self.state]

    def _states(self, masks: torch.Tensor, positions) -> torch.Tensor:
        if self.state == "mask":
            return visible_states(pool_masks(masks))
        return torch.as_tensor(np.asarray(positions)).float()

    def current(self, obs, info) -> Entities:
        masks = torch.as_tensor(np.asarray(info["masks"])).float()
        return Entities(torch.as_tensor(info["types"]).float(), self._states(masks, info["positions"]), masks)

    def goal(self, obs, info) -> Entities:
        keep = np.asarray(info["constrained"])
        masks = torch.as_tensor(np.asarray(info["goal_masks"])[keep]).float()
        return Entities(torch.as_tensor(info["types"][keep]).float(),
                        self._states(masks, np.asarray(info["goal_positions"])[keep]), masks)

    def transitions(self, buffer: dict):
        """Buffer -> (states_t, states_t1 (M, k, D), actions (M, 6), true moved entity (M,))."""
        if self.state == "mask":
            states = visible_states(pool_masks(buffer["masks"]))      # (E, T, k, 256)
        else:
            states = torch.as_tensor(np.asarray(buffer["positions"])).float()   # (E, T, k, 3)
        return (states[:, :-1].flatten(0, 1), states[:, 1:].flatten(0, 1),
                buffer["actions"].reshape(-1, 6), buffer["moved"].reshape(-1))

    def describe(self) -> dict:
        """What this perception's output depends on (a cache key, `buffer_transitions`)."""
        return {"perception": "oracle", "state": self.state, "grid": STATE_GRID}


class DSlatePerception:
    """Learned entities from a trained dSLATE (`ncs_lite.load_dslate`).

    type = z (the action-invariant half of the slot); state = the slot-attention mask pooled
    to the 16x16 state grid like the oracle's (block-rearrange, Table 3) or the state half s
    of the slot ("slot"), its position features read as `slot_position` says (SLOT_POSITIONS;
    None: `default_slot_position`); every mask, and the "base" read, from the `masks` it
    names (MASK_READS; None: `default_masks`).
    `num_slots` may exceed the trained K: slot attention runs with any number of slots, and
    a scene needs at least one slot per object plus one for the background. `restarts`
    initial slot samples per image, the best reconstructed kept (`DSlate.infer`), the first
    of them begun where `slot_init` says (SLOT_INITS); the entities, masks included, are
    those of the kept restart. Inference is seeded, so the
    same image always gives the same entities.
    """

    reads_ground_truth = False

    def __init__(self, model, iterations: int = 7, num_slots: int | None = None,
                 state: str = "mask", batch_size: int = 64, restarts: int = RESTARTS,
                 slot_position: str | None = None, masks: str | None = None, slot_init: str = "random"):
        if state not in ("mask", "slot"):
            raise ValueError(f"state must be 'mask' or 'slot', got {state!r}")
        if slot_init not in SLOT_INITS:
            raise ValueError(f"slot_init must be one of {', '.join(map(repr, SLOT_INITS))}, got {slot_init!r}")
        masks = masks or default_masks(model)
        if masks not in MASK_READS:
            raise ValueError(f"masks must be one of {', '.join(map(repr, MASK_READS))}, got {masks!r}")
        if masks == "pixel" and model.mixture is None:
            raise ValueError("masks 'pixel' read what the mixture decoder paints; this model has none (use 'attention')")
        slot_position = slot_position or default_slot_position(model)
        if slot_position not in SLOT_POSITIONS:
            raise ValueError(f"slot_position must be one of {', '.join(map(repr, SLOT_POSITIONS))}, "
                             f"got {slot_position!r}")
        if slot_position in WON_CELL_READS and state == "slot" and not model.cfg.slots.position_state:
            raise ValueError(f"slot_position {slot_position!r} reads slots.position_state's features; "
                             "this model has none (use 'attention')")
        self.model, self.iterations, self.num_slots = model, iterations, num_slots
        self.restarts, self.slot_position, self.masks = restarts, slot_position, masks
        self.state, self.batch_size, self.slot_init = state, batch_size, slot_init

    @property
    def graph_state(self) -> str:
        """The Table 3 column (METRICS_BY_STATE key) of these states: "mask" or "slot"."""
        return self.state

    def _entities(self, image) -> Entities:
        r = self.model.infer(np.asarray(image)[None], iterations=self.iterations, num_slots=self.num_slots,
                             restarts=self.restarts, masks=self.masks, slot_init=self.slot_init)
        masks = r.masks[0].cpu().float()                               # (K, H, W), the kept restart
        states = pool_masks(masks) if self.state == "mask" else _slot_states(self.model, r, self.slot_position)[0]
        return Entities(r.types[0].cpu().float(), states, masks)

    def current(self, obs, info=None) -> Entities:
        return self._entities(obs["image"])

    def goal(self, obs, info=None) -> Entities:
        return self._entities(obs["goal"])

    def transitions(self, buffer: dict):
        """Buffer -> (states_t, states_t1 (M, K, D), actions (M, 6), true moved slot (M,)).

        Slots follow objects through each video (frame t+1 starts from frame t's slots).
        The true moved slot (for coverage only) is the slot whose mask overlaps the moved
        object's ground-truth mask most at frame t. Videos are read `batch_size` at a time
        (the restarts' initial samples depend on the batch, so the result does too).
        M = E * (T - 1) in episode order: transition t of episode e is row e * (T - 1) + t.
        """
        frames = buffer["frames"]
        batches = [(frames[i:i + self.batch_size],) for i in range(0, len(frames), self.batch_size)]
        # each batch is seeded alone: worker processes give the loop's result
        done = map_jobs(_infer_videos, batches, desc="slot inference",
                        shared=(self.model, self.iterations, self.num_slots, self.restarts, self.state,
                                self.slot_position, self.masks, self.slot_init))
        masks = torch.cat([m for m, _ in done])                          # (E, T, K, N)
        states = torch.cat([s for _, s in done])                         # (E, T, K, D)
        gt = pool_masks(buffer["masks"])                               # (E, T, k, N)
        moved = torch.as_tensor(buffer["moved"])                       # (E, T-1)
        gt_moved = torch.gather(gt[:, :-1], 2, moved[..., None, None].expand(-1, -1, 1, gt.shape[-1]))
        overlap = (masks[:, :-1] * gt_moved).sum(-1)                   # (E, T-1, K)
        true_slot = overlap.argmax(-1)
        return (states[:, :-1].flatten(0, 1), states[:, 1:].flatten(0, 1),
                buffer["actions"].reshape(-1, 6), true_slot.reshape(-1).numpy())

    def describe(self) -> dict:
        """What this perception's output depends on (a cache key, `buffer_transitions`)."""
        return {"perception": "dslate", "model": digest(self.model), "iterations": self.iterations,
                "num_slots": self.num_slots, "state": self.state, "restarts": self.restarts,
                "slot_position": self.slot_position if self.state == "slot" else None,   # unread for mask states
                "masks": self.masks, "slot_init": self.slot_init,
                "batch_size": self.batch_size, "grid": STATE_GRID}


def graph_perception(ncs, model=None, num_slots: int | None = None):
    """How a graph reads its buffer's frames (`graph.graph_from_buffer`): `model`'s entities
    with `ncs.graph_restarts` restarts, its iterations, state and slot position and
    `num_slots` slots (None: the model's K), or, with no model, ground truth (the oracle's
    stand-in for `ncs.state`, ORACLE_STATES)."""
    if model is None:
        return OraclePerception(ORACLE_STATES[ncs.state])
    return DSlatePerception(model, iterations=ncs.iterations, num_slots=num_slots, restarts=ncs.graph_restarts,
                            state=ncs.state, slot_position=ncs.slot_position, masks=ncs.masks,
                            slot_init=acting_slot_init(ncs, model))


def slot_read(perception) -> dict:
    """What a graph built from `perception` records of how it read slots, so an agent that
    reads them another way is refused (`evaluation.check_graph_reading`): the masks, and for
    slot states the slot position; {} for ground truth."""
    if getattr(perception, "reads_ground_truth", True):
        return {}
    read = {"masks": perception.masks}
    if perception.state == "slot":
        read["slot_position"] = perception.slot_position
    return read


def built_slot_position(info: dict) -> str | None:
    """How the graph whose `info` this is read slot states (`slot_read`): a graph the `graph`
    command wrote before reads were recorded read the model's s ("attention"); None when the
    graph does not say (ground truth, mask states, or built outside the commands)."""
    if "slot_position" in info:
        return info["slot_position"]
    learned_slots = info.get("perception_state") == "slot" and not info.get("oracle")
    return "attention" if learned_slots else None


def _infer_videos(spec: tuple, videos) -> tuple[torch.Tensor, torch.Tensor]:
    """Pooled masks and states of a batch of videos (a job of `DSlatePerception.transitions`)."""
    model, iterations, num_slots, restarts, state, slot_position, masks, slot_init = spec
    r = model.infer_video(videos, iterations=iterations, num_slots=num_slots, restarts=restarts, masks=masks,
                          slot_init=slot_init)
    pooled = pool_masks(r.masks).cpu().float()
    return pooled, (pooled if state == "mask" else _slot_states(model, r, slot_position))


def _slot_states(model, r, slot_position: str) -> torch.Tensor:
    """The slot states (..., K, Ds) of a `SlotInference`, read as `slot_position` says: the
    model's s, or its position read from the attention cells ("assigned") or from the masks
    ("base") each slot wins."""
    if slot_position == "assigned":
        states = model.assigned_states(r.states, r.attention)
    elif slot_position == "base":
        states = model.base_states(r.states, r.masks)
    else:
        states = r.states
    return states.cpu().float()


# code the transitions of a buffer depend on (besides the buffer and the perception's settings)
TRANSITIONS_CODE = ("models", "ncs/perception.py")


def buffer_transitions(perception, directory: str | Path, buffer: dict | None = None):
    """`perception.transitions` of the buffer at `directory`, computed once and cached
    (`ncs_lite.cache`) under the buffer's content, the perception's settings and weights and
    the code that computes it; a second call, in this or a later session, loads it.

    The learned perception's pass over a buffer is the kit's most expensive step after
    training (slot inference with restarts on every frame). `buffer`: the loaded buffer, if
    the caller already has it (it must be the one at `directory`).
    """
    def compute():
        data = buffer if buffer is not None else load_buffer(directory)
        return tuple(perception.transitions(data))

    return cached("transitions", compute, buffer=buffer_digest(directory), **perception.describe(),
                  code=code_digest(*TRANSITIONS_CODE))
