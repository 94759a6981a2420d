"""Segmentation metrics (fg-ARI, absorbed objects) and the type/state split's metrics.

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

from .data import cached_buffer, load_buffer
from .envs.block_rearrange import COLOR_NAMES, PALETTE
from .envs.objects import COLOUR_NAMES, COLOURS
from .models.split import split
from .ncs.perception import default_masks, scene_slots

__all__ = ["HELDOUT_SEED", "adjusted_rand_index", "foreground_ari", "absorbed_by_background", "slot_assignment",
           "in_floor_slot", "shared_with_another", "lost_in_reconstruction", "heldout_images", "segmentation_scores",
           "ridge_probe", "matched_slots", "factorization_scores"]

HELDOUT_SEED = 1000          # held-out buffers: the training buffer's seed + 1000


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
    return in_floor_slot(*slot_assignment(pred_masks, true_masks))


def in_floor_slot(owner: np.ndarray, background: np.ndarray) -> np.ndarray:
    """`absorbed_by_background` from `slot_assignment`'s owner (B, k) and background (B,)."""
    owner, background = np.asarray(owner), np.asarray(background)
    return (owner >= 0) & (owner == background[:, None])


def shared_with_another(owner: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Which objects share their slot with another object, (B, k) bool, from
    `slot_assignment`'s owner (B, k) and background (B,): two cubes in one slot are one
    entity to NCS, with one type between theirs and one state between their cells. An object
    absorbed into the floor's slot, or without pixels, is not counted here."""
    owner, background = np.asarray(owner), np.asarray(background)
    present = owner >= 0
    holders = ((owner[:, :, None] == owner[:, None, :]) & present[:, None, :]).sum(-1)
    return present & ~in_floor_slot(owner, background) & (holders > 1)


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


def heldout_images(num_objects: int, images: int = 200, seed: int = 0, env: str = "block-rearrange") -> dict:
    """The first `images` frames of the held-out buffer of `num_objects` objects (buffer seed
    `seed` + HELDOUT_SEED, episodes never trained on): frames (n, H, W, 3), masks (n, k, H, W),
    colors (n, k, 3) each frame's object colours, episode_colors (E, k, 3) the buffer's and
    frames_per_episode (T)."""
    data = load_buffer(cached_buffer(max(images // 5, 2), env=env, num_objects=num_objects,
                                     seed=seed + HELDOUT_SEED))
    per_episode = data["frames"].shape[1]
    return {"frames": data["frames"].reshape(-1, *data["frames"].shape[2:])[:images],
            "masks": data["masks"].reshape(-1, *data["masks"].shape[2:])[:images],
            "colors": np.repeat(data["colors"], per_episode, axis=0)[:images], "episode_colors": data["colors"],
            "frames_per_episode": per_episode}


def segmentation_scores(model, num_objects: int, images: int = 200, restarts: int = 1,
                        seed: int = 0, env: str = "block-rearrange", masks: str | None = None) -> dict:
    """Held-out fg-ARI, the share of cubes absorbed into the floor's slot and the share that
    share a slot with another cube (`shared`; `pairs`: [colour pair, frames] of the pairs found
    sharing one, most first), on `heldout_images`, read with 7 iterations, `scene_slots` slots
    (one per object plus one, at least the model's K) and `restarts` starts per image, its
    `masks` (None: the model's env's, `default_masks`, as NCS reads them); with
    `absorbed_cubes` (n, k), which cubes of each image are in the floor's slot
    (`absorbed_by_background`). The segmentation measure of notebook 03 and the seeds table."""
    held = heldout_images(num_objects, images, seed, env)
    frames, truth = held["frames"], held["masks"]
    colours, names = _colour_ids(held["episode_colors"])                        # (E, k) per episode
    colours = np.repeat(colours, held["frames_per_episode"], axis=0)[:images]    # ... per frame
    slots = scene_slots(model, num_objects)
    masks = masks or default_masks(model)
    aris, owners, backgrounds = [], [], []
    for i in range(0, len(frames), 50):
        r = model.infer(frames[i:i + 50], iterations=7, num_slots=slots, restarts=restarts, masks=masks)
        aris.append(foreground_ari(r.masks, truth[i:i + 50]))
        owner, background = slot_assignment(r.masks, truth[i:i + 50])
        owners.append(owner)
        backgrounds.append(background)
    owner, background = np.concatenate(owners), np.concatenate(backgrounds)
    shared = shared_with_another(owner, background)
    absorbed = in_floor_slot(owner, background)
    pairs = shared_slot_pairs(owner[:, None], background[:, None], colours, names)
    return {"fg_ari": float(np.nanmean(np.concatenate(aris))),
            "absorbed": float(absorbed.mean()), "shared": float(shared[owner >= 0].mean()),
            "pairs": [[p, n] for p, n in pairs.items() if not p.endswith("+floor")],   # a list: JSON keeps its order
            "images": int(len(frames)), "num_slots": int(slots), "restarts": int(restarts),
            "absorbed_cubes": absorbed.tolist()}


# ---------------------------------------------------------------------- the type/state split
def ridge_probe(train_x, train_y, test_x, test_y, alpha: float = 1.0) -> float:
    """R^2 on (test_x, test_y) of a ridge regression fitted on (train_x, train_y).

    x (n, d) features, y (n, c) targets; features standardised with the training half's
    mean and spread. R^2 = 1 - SSE / SST summed over the c targets (SST around the test
    targets' own mean), so 0 = predicting the mean, 1 = perfect, < 0 = worse than the mean.
    """
    tx, ty, vx, vy = (np.asarray(a, np.float64) for a in (train_x, train_y, test_x, test_y))
    if tx.ndim != 2 or ty.ndim != 2 or len(tx) != len(ty) or len(vx) != len(vy) or len(tx) < 2:
        raise ValueError(f"ridge_probe needs x (n, d) and y (n, c) with n >= 2, got {tx.shape}, "
                         f"{ty.shape}, {vx.shape}, {vy.shape}")
    mu, sd = tx.mean(0), tx.std(0) + 1e-8
    tx, vx = (tx - mu) / sd, (vx - mu) / sd
    ym = ty.mean(0)
    w = np.linalg.solve(tx.T @ tx + alpha * np.eye(tx.shape[1]), tx.T @ (ty - ym))
    pred = vx @ w + ym
    return float(1.0 - ((vy - pred) ** 2).sum() / ((vy - vy.mean(0)) ** 2).sum())


def _ridge_fit(x, y, alpha: float = 1.0):
    """The ridge map of `ridge_probe` as a function (to read predicted states)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mu, sd, ym = x.mean(0), x.std(0) + 1e-8, y.mean(0)
    xs = (x - mu) / sd
    w = np.linalg.solve(xs.T @ xs + alpha * np.eye(x.shape[1]), xs.T @ (y - ym))
    return lambda v: ((np.asarray(v, np.float64) - mu) / sd) @ w + ym


def _r2(pred, target) -> float:
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    return float(1.0 - ((target - pred) ** 2).sum() / ((target - target.mean(0)) ** 2).sum())


def _colour_ids(colors: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(E, k, 3) object colours -> (E, k) integer ids of the distinct colours, and a name per
    id (the colour's name in block-rearrange's or robogym-rearrange's palette, if it is one)."""
    palette, palette_names = np.concatenate([PALETTE, COLOURS]), (*COLOR_NAMES, *COLOUR_NAMES)
    flat = np.round(np.asarray(colors, np.float64).reshape(-1, 3), 4)
    distinct, ids = np.unique(flat, axis=0, return_inverse=True)
    names = []
    for i, c in enumerate(distinct):
        d = np.linalg.norm(palette - c, axis=1)
        names.append(palette_names[d.argmin()] if d.min() < 1e-3 else f"colour {i}")
    return ids.reshape(colors.shape[:2]), names


def _floor_pixels(decoded, images, true_masks) -> np.ndarray:
    """(B, k) fraction of object o's pixels that `decoded` paints nearer the floor's colour
    (the image's mean outside every object) than the pixel's true colour; NaN without pixels.
    A perfect round trip scores 0 (shaded sides and anti-aliased edges included)."""
    out = np.full(true_masks.shape[:2], np.nan)
    for b in range(len(images)):
        floor = ~true_masks[b].any(0)
        background = images[b][floor].mean(0)
        for o in range(true_masks.shape[1]):
            m = true_masks[b, o]
            if m.any():
                px, colour = decoded[b][m], images[b][m]
                out[b, o] = float((np.linalg.norm(px - background, axis=-1)
                                   < np.linalg.norm(px - colour, axis=-1)).mean())
    return out


@torch.no_grad()
def matched_slots(model, buffer: dict, restarts: int = 1, seed: int = 0, batch_size: int = 50) -> dict:
    """Slots of every frame of a buffer's videos, and which slot holds which object.

    Slots are inferred through each video (`infer_video`: slot k follows one object) with
    one slot per object plus one for the floor, at least the model's trained K (`scene_slots`,
    as NCS's perception and `segmentation_scores` read a scene) and the model's env's masks
    (`default_masks`); object o's slot in a frame is the slot
    winning most of its true pixels (`slot_assignment`). Returns arrays:
      slots (E, T, K, D), masks (E, T, K, H, W), owner (E, T, k) (-1: no pixels), z, s;
      per matched (episode, frame, object) row: episode, frame, object, types (n, Dz),
      states (n, Ds), positions (n, 2) true (x, y), colours (n,) colour ids, own_slot (n,)
      bool (the slot is neither the floor's nor shared with another object); and
      all_positions (E, T, k, 2), all_colours (E, k), colour_names (one per id),
      background (E, T) the floor's slot.
    """

    frames, true = buffer["frames"], np.asarray(buffer["masks"]).astype(bool)
    E, T, k = true.shape[:3]
    num_slots = scene_slots(model, k)
    slots, masks = [], []
    for i in range(0, E, batch_size):
        r = model.infer_video(frames[i:i + batch_size], num_slots=num_slots, restarts=restarts, seed=seed,
                              masks=default_masks(model))
        slots.append(r.slots.cpu().float())
        masks.append(r.masks.cpu().float())
    slots, masks = torch.cat(slots), torch.cat(masks)                 # (E, T, K, D), (E, T, K, H, W)
    owner, background = slot_assignment(masks.flatten(0, 1), true.reshape(E * T, *true.shape[2:]))
    owner, background = owner.reshape(E, T, k), background.reshape(E, T)
    z, s = (half.numpy() for half in split(slots, model.type_dim))
    pos = np.asarray(buffer["positions"])[..., :2]                     # (E, T, k, 2)
    colour, names = _colour_ids(buffer["colors"])                      # (E, k)
    e_idx, t_idx, o_idx = np.nonzero(owner >= 0)
    slot_of = owner[e_idx, t_idx, o_idx]
    flat, floor = owner.reshape(E * T, k), background.reshape(E * T)
    own = (~in_floor_slot(flat, floor) & ~shared_with_another(flat, floor)).reshape(E, T, k)[e_idx, t_idx, o_idx]
    return {"slots": slots, "masks": masks, "owner": owner, "z": z, "s": s,
            "episode": e_idx, "frame": t_idx, "object": o_idx, "own_slot": own, "background": background,
            "types": z[e_idx, t_idx, slot_of], "states": s[e_idx, t_idx, slot_of],
            "positions": pos[e_idx, t_idx, o_idx], "colours": colour[e_idx, o_idx],
            "all_positions": pos, "all_colours": colour, "colour_names": names}


def shared_slot_pairs(owner: np.ndarray, background: np.ndarray, colours: np.ndarray, names) -> dict:
    """owner (E, T, k) slot of each object (-1: no pixels), background (E, T) the floor's slot,
    colours (E, k) colour ids named by `names` -> {"a+b" or "a+floor": frames}, most first."""
    counts: dict[str, int] = {}
    k = owner.shape[2]
    present = owner >= 0
    for a in range(k):
        partners = [(b, present[..., a] & (owner[..., a] == owner[..., b])) for b in range(a + 1, k)]
        partners.append((None, present[..., a] & (owner[..., a] == background)))
        for b, hit in partners:
            for e, t in zip(*np.nonzero(hit)):
                name = names[colours[e, a]]
                key = f"{name}+floor" if b is None else "+".join(sorted((name, names[colours[e, b]])))
                counts[key] = counts.get(key, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


@torch.no_grad()
def factorization_scores(model, buffer: dict, restarts: int = 1, seed: int = 0,
                         batch_size: int = 50, matched: dict | None = None) -> dict:
    """How well a dSLATE splits slots into type z and state s, on held-out transitions.

    `buffer`: a loaded buffer (`ncs_lite.data.load_buffer`) the model was not trained on.
    Slots are inferred through each video (slot k follows one object), with one slot per
    object plus one for the floor, at least the model's K (`matched_slots`). Ground truth is used only to match slots to objects
    (the slot winning most of an object's pixels, `slot_assignment`) and as the probes'
    targets. Probes are fitted on the first half of the episodes, scored on the second.

      type_invariance      mean |z_t - z_t+1| of an object's slot across a transition over
                           mean |z_i - z_j| between two objects' slots in one image (0 = z
                           never moves; 1 = it moves as far as another object's z is)
      identity_from_z      nearest-centroid accuracy of the object's colour from z (chance:
                           1 / colours)
      position_r2_from_s / _from_z   ridge R^2 of the object's (x, y) from s / from z
      own_slot_share       share of the matched objects whose slot is their own (neither the
                           floor's nor shared): what the segmentation leaves to the split
      own_slot_by_colour   {colour name: own_slot_share over that colour's objects}
      shared_slot_pairs    {"a+b": frames in which an object of colour a and one of colour b
                           share a slot; "a+floor": frames in which an a object is in the
                           floor's slot}, most frequent first: which cubes the segmentation merges
      position_r2_own_slots   position_r2_from_s over those objects only (fitted and scored on
                           them): the split's own quality, segmentation failures aside
      moved_slot_accuracy  how often the dynamics' largest predicted state change (L2) is on
                           the slot of the object the action moved (chance: 1 / slots; over
                           the transitions that moved an object)
      moved_misses_objectless   of the transitions it misses, the share whose largest change
                           is on a slot holding no object (the floor's or a spare; 0 if none missed)
      predicted_position_r2   R^2 of the moved object's next (x, y) read by the s-probe from
                           the *predicted* s; `no_change_position_r2` reads it from the
                           current s (the trivial baseline: predict no change)
      render_fg_error, floor_fg_error   mean absolute pixel error on the objects' pixels of
                           the image drawn from the slots alone (`DSlate.render`) and of an
                           image of the empty floor (only for models that can render)
      predicted_render_error, no_change_error   on the moved object's pixels (at t and t+1):
                           the frame drawn from the predicted slots and the current frame,
                           each against the true next frame
      dvae_floor_by_colour {colour name: fraction of its pixels the dVAE round trip paints
                           nearer the floor than the colour}; dvae_floor_max its maximum
    Plus the counts they rest on. `matched`: `matched_slots(model, buffer, restarts, seed)`
    if the caller already has it (a notebook draws it too).
    """
    true = np.asarray(buffer["masks"]).astype(bool)
    f = matched if matched is not None else matched_slots(model, buffer, restarts, seed, batch_size)
    E = true.shape[0]
    feats_z, feats_s, target, own_slot, labels = f["types"], f["states"], f["positions"], f["own_slot"], f["colours"]
    train = f["episode"] < E // 2
    test = ~train
    out = {
        "type_invariance": _type_invariance(f["z"], f["owner"]),
        **_identity_from_z(feats_z, labels, train, test),
        "position_r2_from_s": ridge_probe(feats_s[train], target[train], feats_s[test], target[test]),
        "position_r2_from_z": ridge_probe(feats_z[train], target[train], feats_z[test], target[test]),
        "own_slot_share": float(own_slot.mean()),
        "own_slot_by_colour": {f["colour_names"][c]: float(own_slot[labels == c].mean())
                               for c in np.unique(labels)},
        "shared_slot_pairs": shared_slot_pairs(f["owner"], f["background"], f["all_colours"], f["colour_names"]),
        # NaN when either half holds fewer than 2 objects with a slot of their own (a tiny model)
        "position_r2_own_slots": (ridge_probe(feats_s[train & own_slot], target[train & own_slot],
                                              feats_s[test & own_slot], target[test & own_slot])
                                  if min((train & own_slot).sum(), (test & own_slot).sum()) >= 2 else float("nan")),
    }
    transitions = _predicted_transitions(model, buffer, f)
    out.update(_dynamics_scores(transitions, f, train, model.type_dim))
    out.update({"episodes": int(E), "objects_matched": int(len(f["episode"])),
                "transitions": int((transitions["moved_slot"] >= 0).sum()),
                "restarts": int(restarts), "slots": int(f["slots"].shape[2])})
    frames = buffer["frames"]
    images = frames.reshape(-1, *frames.shape[2:]).astype(np.float64) / 255.0     # (E*T, H, W, 3)
    if model.can_render:
        out.update(_render_scores(model, frames, images, true, f["slots"], transitions))
    out.update(_dvae_floor_scores(model, frames, images, true, f["all_colours"], f["colour_names"]))
    return out


def _type_invariance(z: np.ndarray, owner: np.ndarray) -> float:
    """Mean |z| change of an object's slot across a transition over the mean |z| distance
    between two objects' slots in one image (`factorization_scores`' type_invariance)."""
    E, T = owner.shape[:2]
    moves, apart = [], []
    for e in range(E):
        for t in range(T):
            own = [j for j in owner[e, t] if j >= 0]
            for a in range(len(own)):
                for b in range(a + 1, len(own)):
                    if own[a] != own[b]:
                        apart.append(np.linalg.norm(z[e, t, own[a]] - z[e, t, own[b]]))
            if t + 1 < T:
                for j in own:
                    moves.append(np.linalg.norm(z[e, t, j] - z[e, t + 1, j]))
    return float(np.mean(moves) / np.mean(apart))


def _identity_from_z(feats_z, labels, train, test) -> dict:
    """Nearest colour-centroid accuracy of an object's colour from z, fitted on `train`,
    scored on `test`, with its chance level."""
    classes = np.unique(labels[train])
    centroids = np.stack([feats_z[train][labels[train] == c].mean(0) for c in classes])
    guess = classes[np.linalg.norm(feats_z[test][:, None] - centroids[None], axis=-1).argmin(1)]
    return {"identity_from_z": float((guess == labels[test]).mean()),
            "identity_chance": float(1.0 / len(classes))}


def _predicted_transitions(model, buffer: dict, f: dict) -> dict:
    """The dynamics' prediction at every transition t -> t+1 of the matched videos: the
    current and predicted slots (M, K, D), the episode and step of each, the object the
    action moved (-1: a no-op) and that object's slot."""
    E, T = f["owner"].shape[:2]
    actions = torch.as_tensor(np.asarray(buffer["actions"]), dtype=torch.float32)   # (E, T-1, 6)
    now = f["slots"][:, :-1].flatten(0, 1)                             # (M, K, D)
    pred = torch.cat([model.predict(now[i:i + 500].to(model.device),
                                    actions.flatten(0, 1)[i:i + 500].to(model.device)).cpu().float()
                      for i in range(0, len(now), 500)])
    moved = np.asarray(buffer["moved"]).reshape(-1)                    # (M,) object index
    ep, tt = np.repeat(np.arange(E), T - 1), np.tile(np.arange(T - 1), E)
    moved_slot = np.where(moved >= 0, f["owner"][ep, tt, np.maximum(moved, 0)], -1)   # -1: a no-op
    return {"now": now, "pred": pred, "ep": ep, "tt": tt, "moved": moved, "moved_slot": moved_slot}


def _dynamics_scores(tr: dict, f: dict, train, type_dim: int) -> dict:
    """Does the predicted state change fall on the moved object's slot, and does the
    s-probe read the moved object's next position from the predicted s (against reading it
    from the current s: predict no change)?"""
    Dz, E = type_dim, f["owner"].shape[0]
    now, pred, ep, tt, moved, moved_slot = (tr[n] for n in ("now", "pred", "ep", "tt", "moved", "moved_slot"))
    change = (pred[..., Dz:] - now[..., Dz:]).norm(dim=-1).numpy()     # (M, K)
    ok = moved_slot >= 0
    largest = change.argmax(1)[ok]                                     # the slot it moves most
    hits = largest == moved_slot[ok]
    misses_objectless = ~(f["owner"][ep, tt][ok] == largest[:, None]).any(1)[~hits]   # no object's slot
    read_pos = _ridge_fit(f["states"][train], f["positions"][train])
    m_test = ok & (ep >= E // 2)
    next_pos = f["all_positions"][ep, tt + 1, moved][m_test]
    pred_s = pred[..., Dz:].numpy()[m_test, moved_slot[m_test]]
    cur_s = now[..., Dz:].numpy()[m_test, moved_slot[m_test]]
    return {"moved_slot_accuracy": float(hits.mean()),
            "moved_slot_chance": float(1.0 / f["slots"].shape[2]),
            "moved_misses_objectless": float(misses_objectless.mean()) if len(misses_objectless) else 0.0,
            "predicted_position_r2": _r2(read_pos(pred_s), next_pos),
            "no_change_position_r2": _r2(read_pos(cur_s), next_pos)}


def _render_scores(model, frames, images, true, slots, tr: dict) -> dict:
    """Pixel errors of the images drawn from the slots alone (`DSlate.render`): on the
    objects' pixels against the empty floor's, and the frame drawn from the predicted slots
    on the moved object's pixels against the current frame (no change)."""
    E, T, k = true.shape[:3]
    drawn = np.concatenate([model.render(slots.flatten(0, 1)[i:i + 200].to(model.device)).cpu().numpy()
                            for i in range(0, E * T, 200)]).astype(np.float64)
    fg = true.reshape(E * T, k, *true.shape[3:]).any(1)                # (E*T, H, W)
    floor = np.median(images.reshape(E * T, -1, 3), axis=1)[:, None, None]
    pred, ep, tt, moved = tr["pred"], tr["ep"], tr["tt"], tr["moved"]
    nxt = np.concatenate([model.render(pred[i:i + 200].to(model.device)).cpu().numpy()
                          for i in range(0, len(pred), 200)]).astype(np.float64)
    cur_img = frames[:, :-1].reshape(-1, *frames.shape[2:]).astype(np.float64) / 255.0
    next_img = frames[:, 1:].reshape(-1, *frames.shape[2:]).astype(np.float64) / 255.0
    region = true[ep, tt, moved] | true[ep, tt + 1, moved]             # (M, H, W)
    return {"render_fg_error": float(np.abs(drawn - images).mean(-1)[fg].mean()),
            "floor_fg_error": float(np.abs(floor - images).mean(-1)[fg].mean()),
            "predicted_render_error": float(np.abs(nxt - next_img).mean(-1)[region].mean()),
            "no_change_error": float(np.abs(cur_img - next_img).mean(-1)[region].mean())}


def _dvae_floor_scores(model, frames, images, true, colour, colour_names) -> dict:
    """Per colour, the share of its pixels the dVAE round trip paints nearer the floor than
    the colour, and the largest share."""
    E, T, k = true.shape[:3]
    recon = np.concatenate([model.reconstruct(frames.reshape(E * T, *frames.shape[2:])[i:i + 200]).cpu().numpy()
                            for i in range(0, E * T, 200)]).astype(np.float64)
    lost = _floor_pixels(recon, images, true.reshape(E * T, k, *true.shape[3:]))   # (E*T, k)
    ids = np.repeat(colour, T, axis=0)                                 # (E*T, k)
    by_colour = {colour_names[c]: float(np.nanmean(lost[ids == c])) for c in np.unique(ids)}
    return {"dvae_floor_by_colour": by_colour, "dvae_floor_max": max(by_colour.values())}
