"""The type/state split's metrics (`ncs_lite.metrics.factorization_scores`, `ridge_probe`).

A model whose slots are built from the ground truth (type = the colour, state = the
position, dynamics = move the slot at the pick point) must score perfectly; one whose
states are noise and whose dynamics moves a random slot must score at chance."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from ncs_lite.data import cached_buffer, load_buffer
from ncs_lite.metrics import factorization_scores, ridge_probe
from ncs_lite.models.dslate import SlotInference


@pytest.fixture(scope="module")
def buffer():
    return load_buffer(cached_buffer(16, num_objects=3, seed=1000))


class GroundTruthModel:
    """A stand-in dSLATE whose slot k of a frame is object k (the floor last): z = the
    colour, s = the position (or noise), masks = the true masks; `predict` adds the action's
    move to the state nearest its pick point (or to a random slot)."""

    type_dim = 3
    can_render = False
    device = torch.device("cpu")

    def __init__(self, buffer, broken=False):
        self.buffer, self.broken = buffer, broken
        self.rng = np.random.default_rng(0)
        self.by_frame = {buffer["frames"][e, 0].tobytes(): e for e in range(len(buffer["frames"]))}

    def infer_video(self, videos, num_slots=None, restarts=1, seed=0, masks="attention"):
        b = self.buffer
        eps = [self.by_frame[np.asarray(v[0]).tobytes()] for v in videos]
        colours = torch.as_tensor(b["colors"][eps]).float()                   # (B, k, 3)
        pos = torch.as_tensor(b["positions"][eps][..., :2]).float()           # (B, T, k, 2)
        if self.broken:
            pos = torch.as_tensor(self.rng.normal(size=pos.shape)).float()
        B, T, k = pos.shape[:3]
        z = torch.cat([colours, torch.zeros(B, 1, 3)], 1)[:, None].expand(B, T, k + 1, 3)
        s = torch.cat([pos, torch.full((B, T, 1, 2), 9.0)], 2)                # the floor far off
        masks = torch.as_tensor(b["masks"][eps]).float()                      # (B, T, k, H, W)
        floor = 1 - masks.sum(2, keepdim=True).clamp(max=1)
        masks = torch.cat([masks, floor], 2)
        slots = torch.cat([z, s], -1)
        return SlotInference(slots, z, s, masks, masks.flatten(-2))

    def predict(self, slots, actions):
        nxt = slots.clone()
        for i in range(len(slots)):
            s = slots[i, :, 3:]
            j = (self.rng.integers(len(s)) if self.broken
                 else int((s - actions[i, :2]).norm(dim=1).argmin()))
            nxt[i, j, 3:] = s[j] + actions[i, 3:5]
        return nxt

    def reconstruct(self, images):
        return torch.as_tensor(np.asarray(images)).float() / 255.0             # a perfect round trip


def test_ground_truth_slots_score_perfectly(buffer):
    r = factorization_scores(GroundTruthModel(buffer), buffer)
    assert r["type_invariance"] == 0.0                         # z never moves
    assert r["identity_from_z"] == 1.0
    assert r["position_r2_from_s"] > 0.999
    assert r["position_r2_from_z"] < 0.2                       # colour says nothing of place
    assert r["own_slot_share"] == 1.0 and r["position_r2_own_slots"] > 0.999
    assert r["moved_slot_accuracy"] == 1.0 and r["moved_misses_objectless"] == 0.0
    assert r["predicted_position_r2"] > 0.99 > r["no_change_position_r2"]
    assert r["dvae_floor_max"] == 0.0
    assert "render_fg_error" not in r                          # the stand-in cannot render
    assert r["transitions"] == 16 * 4 and r["slots"] == 4


def test_noise_states_and_a_random_dynamics_score_at_chance(buffer):
    r = factorization_scores(GroundTruthModel(buffer, broken=True), buffer)
    assert r["position_r2_from_s"] < 0.2
    assert r["moved_slot_accuracy"] < 0.5                      # chance is 1/4
    assert 0.0 < r["moved_misses_objectless"] < 1.0            # some misses land on the floor's slot
    assert r["identity_from_z"] == 1.0                         # the types are still the colours


def test_objects_sharing_a_slot_leave_the_own_slot_score(buffer):
    class Merged(GroundTruthModel):
        """Objects 0 and 1 share slot 0 (slot 1 is empty): their state is a blend."""

        def infer_video(self, videos, num_slots=None, restarts=1, seed=0, masks="attention"):
            r = super().infer_video(videos, num_slots, restarts, seed)
            masks = r.masks.clone()
            masks[:, :, 0] += masks[:, :, 1]
            masks[:, :, 1] = 0
            s = r.states.clone()
            s[:, :, 0] = (s[:, :, 0] + s[:, :, 1]) / 2
            slots = torch.cat([r.types, s], -1)
            return SlotInference(slots, r.types, s, masks, masks.flatten(-2))

    r = factorization_scores(Merged(buffer), buffer)
    assert r["own_slot_share"] == pytest.approx(1 / 3)         # object 2 of 3
    assert sum(r["shared_slot_pairs"].values()) == r["objects_matched"] // 3   # one pair per frame
    assert r["position_r2_own_slots"] > 0.999 > r["position_r2_from_s"]


def test_shared_slot_pairs_name_the_colours_a_slot_merges():
    from ncs_lite.metrics import shared_slot_pairs

    names = ["red", "orange", "yellow"]
    colours = np.array([[1, 2, 0], [2, 1, 0]])                  # (E=2, k=3)
    owner = np.array([[[1, 1, 2], [1, 2, 3]],                   # episode 0: orange+yellow share slot 1 once
                      [[2, 2, 0], [-1, 3, 0]]])                 # episode 1: once, then red in the floor's slot 0
    background = np.array([[0, 0], [0, 0]])
    assert shared_slot_pairs(owner, background, colours, names) == {"orange+yellow": 2, "red+floor": 2}
    # an object without pixels (-1) shares nothing, even with another object without pixels
    assert shared_slot_pairs(np.full((1, 1, 2), -1), np.zeros((1, 1), int), colours[:1, :2], names) == {}


def test_shared_with_another_counts_cubes_in_one_slot_but_not_the_floor_or_the_absent():
    from ncs_lite.metrics import shared_with_another

    owner = np.array([[1, 1, 2, 0],            # two cubes in slot 1; one alone; one in the floor's slot 0
                      [0, 0, -1, -1]])         # two cubes in the floor's slot; two without pixels
    background = np.array([0, 0])
    np.testing.assert_array_equal(shared_with_another(owner, background),
                                  [[True, True, False, False], [False, False, False, False]])


def test_ridge_probe_reads_a_linear_map_and_not_noise():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 6))
    y = x[:, :2] @ np.array([[1.0, -2.0], [0.5, 3.0]]) + 0.01 * rng.normal(size=(400, 2))
    assert ridge_probe(x[:200], y[:200], x[200:], y[200:]) > 0.99
    assert ridge_probe(x[:200], rng.normal(size=(200, 2)), x[200:], rng.normal(size=(200, 2))) < 0.1
    with pytest.raises(ValueError, match="ridge_probe needs"):
        ridge_probe(x[:1], y[:1], x, y)


def test_segmentation_scores_count_cubes_that_share_a_slot_and_name_their_colours():
    from types import SimpleNamespace

    from ncs_lite.metrics import _colour_ids
    from ncs_lite.metrics import segmentation_scores

    data = load_buffer(cached_buffer(2, num_objects=3, seed=1000))    # what segmentation_scores reads
    frames = data["frames"].reshape(-1, *data["frames"].shape[2:])
    true = data["masks"].reshape(-1, *data["masks"].shape[2:]).astype(np.float32)
    by_frame = {f.tobytes(): i for i, f in enumerate(frames)}

    class MergesTheFirstTwo:               # true masks, but cubes 0 and 1 in one slot
        cfg = SimpleNamespace(slots=SimpleNamespace(num_slots=4, eval_iterations=7))

        def infer(self, images, iterations, num_slots, restarts, masks):
            m = torch.as_tensor(true[[by_frame[np.asarray(x).tobytes()] for x in images]])
            floor = 1 - m.sum(1, keepdim=True).clamp(max=1)
            masks = torch.cat([m[:, :1] + m[:, 1:2], torch.zeros_like(m[:, :1]), m[:, 2:], floor], 1)
            return SimpleNamespace(masks=masks)

    seg = segmentation_scores(MergesTheFirstTwo(), 3, images=10)
    assert seg["shared"] == pytest.approx(2 / 3) and seg["absorbed"] == 0
    assert np.asarray(seg["absorbed_cubes"]).shape == (10, 3) and not np.any(seg["absorbed_cubes"])
    assert seg["num_slots"] == 4 and seg["images"] == 10         # one slot per cube and the floor's
    colours, names = _colour_ids(data["colors"])
    pairs = ["+".join(sorted((names[colours[e, 0]], names[colours[e, 1]]))) for e in range(2)]
    frames_per_episode = data["frames"].shape[1]
    expected = {p: frames_per_episode * pairs.count(p) for p in set(pairs)}
    assert seg["pairs"] == [list(kv) for kv in sorted(expected.items(), key=lambda kv: (-kv[1], kv[0]))]
