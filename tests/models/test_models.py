"""Unit tests of dSLATE's parts on tiny configs (CPU, a few seconds)."""
import math
import re

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ncs_lite.config import (DSlateConfig, config_diff, from_dict, get_preset, saved_config_diff,
                             table2_rows, to_dict)
from ncs_lite.metrics import absorbed_by_background, adjusted_rand_index, foreground_ari
from ncs_lite.models import DSlate, Dynamics, SlotAttention, TransformerDecoder, tau_schedule
from ncs_lite.models.dvae import DVAE, patchify, unpatchify
from ncs_lite.models.mixture_decoder import MixtureDecoder


def tiny_cfg(**train) -> DSlateConfig:
    cfg = get_preset("ci")
    for k, v in train.items():
        setattr(cfg.train, k, v)
    return cfg


def videos(B=2, T=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randint(0, 256, (B, T, 64, 64, 3), dtype=torch.uint8, generator=g),
            torch.randn(B, T - 1, 6, generator=g))


# ---------------------------------------------------------------- config
def test_presets_and_unknown_name():
    for name in ("ci", "reduced", "paper"):
        assert get_preset(name).name == name
    with pytest.raises(ValueError, match="unknown preset 'tiny'.*ci, reduced, paper"):
        get_preset("tiny")


def test_paper_preset_is_table2():
    rows = dict(table2_rows(get_preset("paper")))
    assert rows["Number of epochs"] == 200 and rows["Episodes per epoch"] == 5000
    assert rows["Episode length"] == 5 and rows["Batch size"] == 32
    assert rows["Peak LR"] == 2e-4 and rows["LR warmup steps"] == 30000 and rows["Dropout"] == 0.1
    assert rows["dVAE: Vocabulary size"] == 4096 and rows["dVAE: LR (no warmup)"] == 3e-4
    assert rows["dVAE: Temp. cooldown"] == "1 to 0.1" and rows["dVAE: Temp. cooldown steps"] == 30000
    assert rows["dVAE: Image size"] == 64 and rows["dVAE: Image tokens"].endswith("= 16")
    assert (rows["Transformer decoder: Layers"], rows["Transformer decoder: Heads"],
            rows["Transformer decoder: Hidden dim."]) == (4, 4, 192)
    assert (rows["Slot attention: Slots"], rows["Slot attention: Iterations"],
            rows["Slot attention: Slot heads"]) == (5, 3, 1)
    assert (rows["Slot attention: Slot dim. (h)"], rows["Slot attention: Type dim. (z)"],
            rows["Slot attention: State dim. (s)"]) == (192, 96, 96)
    assert (rows["Transformer dynamics: Layers"], rows["Transformer dynamics: Heads"],
            rows["Transformer dynamics: Hidden dim."]) == (4, 4, 96)
    assert get_preset("paper").slots.eval_iterations == 7


def test_config_round_trip_and_diff():
    cfg = get_preset("reduced")
    assert to_dict(from_dict(to_dict(cfg))) == to_dict(cfg)
    diff = config_diff(to_dict(cfg), to_dict(get_preset("paper")))
    assert "dvae.vocab_size: 64 != 4096" in diff and "slots.encoder: 'cnn' != 'tokens'" in diff
    bad = to_dict(cfg)
    bad["slots"]["colour"] = 3
    with pytest.raises(ValueError, match="unknown keys \\['colour'\\]"):
        from_dict(bad)


# ---------------------------------------------------------------- dVAE
def test_tau_schedule_values():
    c = get_preset("paper").dvae
    assert tau_schedule(0, c) == 1.0
    assert tau_schedule(15_000, c) == pytest.approx(0.55)
    assert tau_schedule(7_500, c) == pytest.approx(0.1 + 0.45 * (1 + math.cos(math.pi / 4)))
    assert tau_schedule(30_000, c) == pytest.approx(0.1)
    assert tau_schedule(90_000, c) == pytest.approx(0.1)
    taus = [tau_schedule(s, c) for s in range(0, 30_001, 1000)]
    assert all(a > b for a, b in zip(taus, taus[1:]))


def test_dvae_shapes_and_patchify_inverse():
    x = torch.rand(3, 64, 64, 3)
    assert torch.equal(unpatchify(patchify(x, 4), 4, 16), x)
    d = DVAE(vocab_size=8, hidden=16)
    logp = d.encode(x)
    assert logp.shape == (3, 256, 8)
    soft, ids = d.sample(logp, tau=0.5)
    assert soft.shape == (3, 256, 8) and ids.shape == (3, 256) and ids.dtype == torch.long
    assert torch.allclose(soft.sum(-1), torch.ones(3, 256))
    assert torch.equal(soft.argmax(-1), ids)              # the hard token is the soft sample's mode
    assert d.decode(soft).shape == (3, 64, 64, 3)
    torch.manual_seed(1)
    soft_logits, ids_logits = d.sample(d.logits(x), tau=0.5)     # unnormalised: same sample
    torch.manual_seed(1)
    soft_logp, ids_logp = d.sample(logp, tau=0.5)
    assert torch.equal(ids_logits, ids_logp) and torch.allclose(soft_logits, soft_logp, atol=1e-5)


# ---------------------------------------------------------------- slot attention
def test_slot_attention_permutation_equivariance_and_masks():
    torch.manual_seed(0)
    sa = SlotAttention(input_dim=16, slot_dim=12, num_slots=4, iterations=3, heads=2)
    x = torch.randn(2, 30, 16)
    init = torch.randn(2, 4, 12)
    perm = torch.tensor([2, 0, 3, 1])
    slots, attn = sa(x, init_slots=init)
    slots_p, attn_p = sa(x, init_slots=init[:, perm])
    assert slots.shape == (2, 4, 12) and attn.shape == (2, 4, 30)
    assert torch.allclose(slots_p, slots[:, perm], atol=1e-5)
    assert torch.allclose(attn_p, attn[:, perm], atol=1e-6)
    assert torch.allclose(attn.sum(1), torch.ones(2, 30), atol=1e-5)
    assert not torch.allclose(slots[:, 0], slots[:, 1])     # slots differ: the test can fail


def test_slot_attention_learned_init_gets_gradients_and_any_k():
    torch.manual_seed(0)
    sa = SlotAttention(input_dim=8, slot_dim=8, num_slots=3, iterations=2)
    slots, attn = sa(torch.randn(2, 10, 8), num_slots=7)
    assert slots.shape == (2, 7, 8) and attn.shape == (2, 7, 10)
    slots.square().sum().backward()
    assert sa.mu.grad is not None and sa.mu.grad.abs().sum() > 0
    assert sa.log_sigma.grad is not None and sa.log_sigma.grad.abs().sum() > 0


def test_implicit_slot_attention_reads_the_same_and_differentiates_one_step():
    """`implicit` changes the gradient, not the read: the same slots and attention, and the
    gradient equals that of one iteration started from the unrolled slots, detached."""
    torch.manual_seed(0)
    plain = SlotAttention(input_dim=8, slot_dim=8, num_slots=3, iterations=3, heads=2)
    implicit = SlotAttention(input_dim=8, slot_dim=8, num_slots=3, iterations=3, heads=2, implicit=True)
    implicit.load_state_dict(plain.state_dict())
    x, init = torch.randn(2, 10, 8), torch.randn(2, 3, 8)
    slots, attn = implicit(x, init_slots=init)
    ref_slots, ref_attn = plain(x, init_slots=init)
    assert torch.equal(slots, ref_slots) and torch.equal(attn, ref_attn)

    slots.square().sum().backward()
    with torch.no_grad():
        before, _ = plain(x, init_slots=init, iterations=2)
    one, _ = plain(x, init_slots=before, iterations=1)
    one.square().sum().backward()
    for (name, p), q in zip(implicit.named_parameters(), plain.parameters()):
        if name in ("mu", "log_sigma"):
            assert p.grad is None                           # the initial Gaussian gets none
        else:
            assert p.grad is not None and torch.allclose(p.grad, q.grad, atol=1e-6), name
    full = SlotAttention(input_dim=8, slot_dim=8, num_slots=3, iterations=3, heads=2)
    full.load_state_dict(plain.state_dict())
    full(x, init_slots=init)[0].square().sum().backward()
    assert not torch.allclose(full.to_q.weight.grad, implicit.to_q.weight.grad)  # it differs from unrolling


def test_farthest_point_slots_seed_one_slot_on_each_part_of_the_scene():
    """Three well-separated groups of inputs, three slots: one seed per group (the farthest
    points), and each slot is one update from mu with its group's mean value; the read is
    deterministic and does not depend on the inputs' order."""
    torch.manual_seed(0)
    sa = SlotAttention(input_dim=8, slot_dim=6, num_slots=3, iterations=2)
    centres = torch.randn(3, 8) * 5
    groups = torch.tensor([0] * 10 + [1] * 5 + [2] * 15)
    x = (centres[groups] + 0.01 * torch.randn(30, 8))[None]                  # (1, 30, 8)
    slots = sa.farthest_point_slots(x)
    assert slots.shape == (1, 3, 6) and torch.equal(slots, sa.farthest_point_slots(x))
    order = torch.randperm(30)
    assert torch.allclose(sa.farthest_point_slots(x[:, order]).sort(1).values, slots.sort(1).values, atol=1e-6)
    with torch.no_grad():
        _, v = sa.to_kv(sa.norm_inputs(x[0])).chunk(2, dim=-1)
        means = torch.stack([v[groups == g].mean(0) for g in range(3)])
        new = sa.gru(means, sa.mu.reshape(1, -1).expand(3, -1))
        expected = new + sa.mlp(new)                                          # one slot per group
    assert all(any(torch.allclose(s, e, atol=1e-5) for s in slots[0]) for e in expected)
    assert not torch.allclose(slots[0, 0], slots[0, 1])


# ---------------------------------------------------------------- decoder, dynamics
def test_decoder_is_causal():
    torch.manual_seed(0)
    dec = TransformerDecoder(vocab_size=10, num_tokens=12, slot_dim=6, dim=16, layers=2, heads=2).eval()
    emb, slots = torch.randn(1, 12, 16), torch.randn(1, 3, 6)
    out = dec(emb, slots)
    emb2 = emb.clone()
    emb2[:, 5] += torch.randn(16)                            # change token 5
    out2 = dec(emb2, slots)
    assert out.shape == (1, 12, 10)
    assert torch.allclose(out[:, :6], out2[:, :6], atol=1e-6)  # positions <= 5 cannot see token 5
    assert not torch.allclose(out[:, 6:], out2[:, 6:])        # later positions do
    assert not torch.allclose(dec(emb, slots + 1.0), out)     # and the slots matter


def test_dynamics_carries_type_exactly_and_is_equivariant():
    torch.manual_seed(0)
    dyn = Dynamics(type_dim=4, state_dim=6, action_dim=6, hidden=16, layers=2, heads=2).eval()
    torch.nn.init.normal_(dyn.head.weight)                   # leave the identity initialisation
    slots, actions = torch.randn(3, 5, 10), torch.randn(3, 6)
    nxt = dyn(slots, actions)
    assert nxt.shape == (3, 5, 10)
    assert torch.equal(nxt[..., :4], slots[..., :4])          # type z_{t+1} = z_t exactly
    assert not torch.allclose(nxt[..., 4:], slots[..., 4:])   # the state moves
    assert not torch.allclose(dyn(slots, actions + 1)[..., 4:], nxt[..., 4:])  # with the action
    perm = torch.tensor([4, 2, 0, 1, 3])
    assert torch.allclose(dyn(slots[:, perm], actions), nxt[:, perm], atol=1e-5)
    assert dyn(slots[None].expand(2, -1, -1, -1), actions[None].expand(2, -1, -1)).shape == (2, 3, 5, 10)


# ---------------------------------------------------------------- dSLATE
@pytest.mark.parametrize("token_dropout, encoder, mixture, alpha, slot_grad, split", [
    (0.0, "tokens", 0.0, "decoder", 1.0, False),            # the paper's model
    (0.5, "tokens", 0.5, "decoder", 1.0, False),
    (0.5, "tokens", 0.5, "attention", 1.0, False),
    (0.5, "cnn", 0.5, "attention", 0.0, False),
    (0.5, "cnn", 0.5, "attention", 0.0, True),              # the `reduced` preset's choices
])
def test_dslate_forward_and_inference_api(token_dropout, encoder, mixture, alpha, slot_grad, split):
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.decoder.token_dropout, cfg.decoder.slot_grad = token_dropout, slot_grad
    cfg.slots.encoder, cfg.mixture.weight, cfg.mixture.alpha = encoder, mixture, alpha
    # the split's departures (look from z, masks from s, latent dynamics, dVAE weight) or none
    cfg.mixture.appearance, cfg.mixture.state_mask_weight = ("type", 0.3) if split else ("slot", 0.0)
    cfg.dynamics.latent_weight, cfg.dvae.foreground_weight = (2.0, 5.0) if split else (0.0, 1.0)
    cfg.slots.position_state = split
    cfg.mixture.render_hidden = 8 if split else 0
    m = DSlate(cfg)
    v, a = videos(B=2, T=3)
    out = m(v, a, tau=1.0)
    assert set(out) == {"loss", "mse", "ce", "ce_dyn", "mix", "mask", "latent"}
    assert all(x.ndim == 0 and torch.isfinite(x) for x in out.values())
    assert (out["mix"] > 0) == (mixture > 0)
    assert (out["mask"] > 0) == (out["latent"] > 0) == split
    assert torch.allclose(out["loss"], out["mse"] + out["ce"] + out["ce_dyn"] + mixture * out["mix"]
                          + cfg.mixture.state_mask_weight * out["mask"]
                          + cfg.dynamics.latent_weight * out["latent"])
    assert m.can_render == split
    K, Dz, Ds = cfg.slots.num_slots, cfg.slots.type_dim, cfg.slots.state_dim
    r = m.infer(v[:, 0])
    assert r.slots.shape == (2, K, Dz + Ds) and r.types.shape == (2, K, Dz)
    assert r.states.shape == (2, K, Ds) and r.masks.shape == (2, K, 64, 64)
    assert r.attention.shape == (2, K, cfg.mask_grid ** 2)
    assert cfg.mask_grid == (32 if encoder == "cnn" else 16)
    assert torch.allclose(r.masks.sum(1), torch.ones(2, 64, 64), atol=1e-5)
    assert torch.equal(torch.cat([r.types, r.states], -1), r.slots)
    assert torch.equal(m.infer(v[:, 0]).slots, r.slots)       # seeded: reproducible
    r8 = m.infer(v[:, 0].numpy(), iterations=2, num_slots=8)  # numpy input, more slots at inference
    assert r8.masks.shape == (2, 8, 64, 64)
    nxt = m.predict(r.slots, torch.randn(2, 6))
    assert torch.equal(nxt[..., :Dz], r.types)
    vid = m.infer_video(v)
    assert vid.slots.shape == (2, 3, K, Dz + Ds) and vid.masks.shape == (2, 3, K, 64, 64)
    if split:   # the last 4 state features are where each slot attends: centroid, spread
        from ncs_lite.models.state_decoder import coordinate_grid
        w = r.attention / (r.attention.sum(-1, keepdim=True) + cfg.slots.position_prior)
        assert torch.allclose(r.states[..., -4:-2], w @ coordinate_grid(cfg.mask_grid), atol=1e-5)
        assert (r.states[..., -2:] > 0).all()
        img = m.render(nxt)
        assert img.shape == (2, 64, 64, 3) and 0 <= img.min() and img.max() <= 1
        drawn = m.state_masks_of(r.slots)
        assert drawn.shape == (2, K, 64, 64)
        assert torch.allclose(drawn.sum(1), torch.ones(2, 64, 64), atol=1e-5)
        # the drawn masks read s alone: changing z changes nothing
        other = torch.cat([torch.randn_like(r.types), r.states], -1)
        assert torch.allclose(m.state_masks_of(other), drawn)
        # the render phase's loss reaches the renderer alone (the mixture decoder paints frozen)
        m.train()
        for masks in (False, True):
            m.zero_grad(set_to_none=True)
            m.render_loss(v, masks=masks)["loss"].backward()
            reached = {n for n, p in m.named_parameters() if p.grad is not None}
            assert reached and all(n.startswith("renderer.") for n in reached)
        assert all(p.requires_grad for p in m.parameters())
    else:
        with pytest.raises(ValueError, match="render needs"):
            m.render(r.slots)


@pytest.mark.parametrize("mixture", [0.0, 1.0])
def test_restarts_keep_the_best_reconstruction_per_image(mixture):
    """restarts=R: per image, the restart with the lowest reconstruction error (mixture
    decoder, or token cross-entropy without one), and never worse than restart 0 alone."""
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.mixture.weight = mixture
    m = DSlate(cfg).eval()
    images = videos(B=3, T=1)[0][:, 0]
    x = images.float() / 255
    best = m.infer(images, restarts=4, seed=5)
    err_best = m.reconstruction_error(x, best.slots, best.attention)
    # every restart, one image batch at a time: the same initial draws as the batched call
    per_restart = m.infer(images.repeat(4, 1, 1, 1), seed=5)
    err_all = m.reconstruction_error(x.repeat(4, 1, 1, 1), per_restart.slots,
                                     per_restart.attention).reshape(4, 3)
    assert torch.allclose(err_best, err_all.min(0).values, rtol=1e-5)
    assert (err_best <= err_all[0] + 1e-4).all()
    assert torch.allclose(best.masks.sum(1), torch.ones(3, 64, 64), atol=1e-5)
    assert best.slots.shape == (3, cfg.slots.num_slots, cfg.slots.slot_dim)
    assert m.infer_video(videos(B=2, T=3)[0], restarts=2).slots.shape[:2] == (2, 3)
    with pytest.raises(ValueError, match="restarts must be a positive integer, got 0"):
        m.infer(images, restarts=0)
    with pytest.raises(ValueError, match="cannot be combined with init_slots"):
        m.infer(images, restarts=2, init_slots=best.slots)


def test_farthest_slot_init_is_the_first_restart_and_needs_no_seed():
    """slot_init "farthest": one restart reads the same slots whatever the seed, differs from
    a draw, and with more restarts the kept read is never worse than the farthest start."""
    torch.manual_seed(0)
    m = DSlate(tiny_cfg()).eval()
    images = videos(B=3, T=1)[0][:, 0]
    x = images.float() / 255
    one = m.infer(images, slot_init="farthest", seed=0)
    assert torch.equal(one.slots, m.infer(images, slot_init="farthest", seed=7).slots)
    assert not torch.allclose(one.slots, m.infer(images, seed=0).slots)
    best = m.infer(images, slot_init="farthest", restarts=4, seed=3)
    err_one = m.reconstruction_error(x, one.slots, one.attention)
    assert (m.reconstruction_error(x, best.slots, best.attention) <= err_one + 1e-4).all()
    assert m.infer_video(videos(B=2, T=2)[0], slot_init="farthest").slots.shape[:2] == (2, 2)
    with pytest.raises(ValueError, match="slot_init must be one of 'random', 'farthest', got 'kmeans'"):
        m.infer(images, slot_init="kmeans")


def test_slots_init_farthest_starts_training_reads_on_the_frame_and_leaves_agents_reads_random():
    """slots.init "farthest": a training step's first frame starts from the farthest-point
    slots, so two forward passes agree whatever the global seed; `infer` keeps its restarts
    drawn (a random read differs with its seed) unless `slot_init` asks otherwise."""
    cfg = tiny_cfg()
    cfg.slots.init = "farthest"
    torch.manual_seed(0)
    m = DSlate(cfg)
    v, _ = videos(B=2, T=2)
    inp = m._slot_inputs(v.flatten(0, 1).float() / 255.0)
    first = [m._inputs_to_slots(inp, 2)[0] for _ in range(2)]
    assert torch.equal(first[0], first[1])
    m.eval()
    images = v[:, 0]
    assert not torch.allclose(m.infer(images, seed=0).slots, m.infer(images, seed=1).slots)
    assert torch.equal(m.infer(images, restarts=3, seed=2).slots, m.infer(images, restarts=3, seed=2).slots)
    cfg.slots.init = "grid"
    with pytest.raises(ValueError, match="slots.init must be .*'random'.*'farthest'.*got 'grid'"):
        cfg.validate()


def test_pixel_masks_move_an_edge_to_the_pixel_where_its_colour_ends():
    """masks "pixel": each pixel goes to the slot whose attention and painted colour explain it
    (the mixture's posterior, `DSlate.pixel_masks`). A red square whose edges fall inside
    slot attention's 2-pixel cells is given back pixel for pixel where the attention's
    upsampled masks blur it; where two slots paint the same colour, the attention decides.
    A model without the mixture decoder, or an unknown read, is refused."""
    torch.manual_seed(0)
    m = DSlate(tiny_cfg()).eval()
    g, S = m.cfg.mask_grid, m.cfg.image_size
    grey, red = torch.tensor([0.3, 0.3, 0.3]), torch.tensor([0.8, 0.1, 0.1])
    x = grey.expand(1, S, S, 3).clone()
    x[0, 9:21, 5:17] = red                                    # rows 9-20, columns 5-16: odd edges
    attn = torch.full((1, 2, g, g), 1e-3)
    attn[0, 0] = 1.0
    attn[0, 0, 4:11, 2:9], attn[0, 1, 4:11, 2:9] = 1e-3, 1.0  # cells cover pixels 8-21, 4-17
    attn = attn.flatten(2) / attn.flatten(2).sum(1, keepdim=True)
    look = torch.stack([grey, red]).repeat(1, (S // g) ** 2)  # each slot paints one colour
    m.mixture.paint = lambda slots, attention: (look[None, :, None], attention)
    slots = torch.zeros(1, 2, m.slot_dim)
    masks = m.pixel_masks(x, slots, attn)
    assert masks.shape == (1, 2, S, S)
    torch.testing.assert_close(masks.sum(1), torch.ones(1, S, S))
    truth = (x[0] - red).abs().sum(-1) < 1e-6
    assert torch.equal(masks[0].argmax(0) == 1, truth)
    assert not torch.equal(m.upsample_masks(attn)[0].argmax(0) == 1, truth)
    look[1] = look[0]                                          # the same paint: the prior alone
    torch.testing.assert_close(m.pixel_masks(x, slots, attn), m.upsample_masks(attn))
    with pytest.raises(ValueError, match="masks must be one of 'attention', 'pixel', got 'edges'"):
        m.infer(videos(B=1, T=1)[0][:, 0], masks="edges")
    plain = tiny_cfg()
    plain.mixture.weight = 0.0
    with pytest.raises(ValueError, match="this model has none"):
        DSlate(plain).pixel_masks(x, slots, attn)


def test_mixture_error_weights_pixels_far_from_the_median_colour():
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.mixture.foreground_weight = 1.0
    m = DSlate(cfg).eval()
    x = torch.full((2, 64, 64, 3), 0.3)
    x[:, 8:16, 8:16] = torch.tensor([0.1, 0.7, 0.1])       # one "cube", far from the floor
    r = m.infer((x * 255).round().to(torch.uint8))
    x = (x * 255).round() / 255
    plain = m.mixture_error(x, r.slots, r.attention)
    override = m.mixture_error(x, r.slots, r.attention, foreground_weight=5.0)   # the polish phase's way
    m.cfg.mixture.foreground_weight = 5.0
    weighted = m.mixture_error(x, r.slots, r.attention)
    assert torch.equal(override, weighted)
    patches, _ = m.mixture(r.slots, r.attention)
    err = (patches - patchify(x, 64 // m.mixture.grid)).pow(2)
    far = torch.zeros(2, 64, 64, 3)
    far[:, 8:16, 8:16] = 1
    cube = (err * patchify(far, 64 // m.mixture.grid)).sum(dim=(1, 2))
    assert torch.allclose(weighted, plain + 4 * cube, rtol=1e-4)
    with pytest.raises(ValueError, match="foreground_weight must be >= 1, got 0.5"):
        cfg.mixture.foreground_weight = 0.5
        cfg.validate()


def test_per_slot_error_charges_blended_looks_and_equals_the_mixed_error_on_hard_masks():
    """mixture.error "per_slot": sum over slots of alpha_k |look_k - x|^2. Two slots whose looks
    average to a cube's colour explain it at no cost under "mixed" and pay under "per_slot"."""
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.mixture.appearance, cfg.mixture.foreground_weight = "type", 1.0
    m = DSlate(cfg).eval()
    x = torch.rand(2, 64, 64, 3)
    r = m.infer((x * 255).round().to(torch.uint8))
    soft = torch.softmax(torch.randn_like(r.attention) * 3, dim=1)
    hard = F.one_hot(soft.argmax(1), soft.shape[1]).movedim(-1, 1).float()
    mixed = m.mixture_error(x, r.slots, soft)
    m.cfg.mixture.error = "per_slot"
    per_slot = m.mixture_error(x, r.slots, soft)
    assert (per_slot > mixed).all()                     # Jensen: the looks' spread is charged
    looks, alpha = m.mixture.paint(r.slots, soft)
    target = patchify(x, 64 // m.mixture.grid)
    assert torch.allclose(per_slot, (alpha[..., None] * (looks - target[:, None]).pow(2)).sum((1, 2, 3)))
    on_hard = m.mixture_error(x, r.slots, hard)
    m.cfg.mixture.error = "mixed"
    assert torch.allclose(on_hard, m.mixture_error(x, r.slots, hard), rtol=1e-5)
    with pytest.raises(ValueError, match="mixture.error must be 'mixed' or 'per_slot', got 'sum'"):
        cfg.mixture.error = "sum"
        cfg.validate()


def test_mixture_decoder_alpha_and_permutation():
    torch.manual_seed(0)
    mix = MixtureDecoder(slot_dim=6, grid=4, patch=2, hidden=8)
    slots = torch.randn(2, 3, 6)
    patches, alpha = mix(slots)
    assert patches.shape == (2, 16, 12) and alpha.shape == (2, 3, 16)
    assert torch.allclose(alpha.sum(1), torch.ones(2, 16))
    perm = torch.tensor([2, 0, 1])
    p2, a2 = mix(slots[:, perm])
    assert torch.allclose(p2, patches, atol=1e-6) and torch.allclose(a2, alpha[:, perm])


def test_mixture_decoder_attention_alpha():
    torch.manual_seed(0)
    mix = MixtureDecoder(slot_dim=6, grid=4, patch=2, hidden=8, alpha="attention")
    slots, attn = torch.randn(2, 3, 6), torch.softmax(torch.randn(2, 3, 16), dim=1)
    patches, alpha = mix(slots, attn)
    assert torch.equal(alpha, attn)                               # the masks are the mixing weights
    each = mix.mlp(mix.inp(slots)[:, :, None] + mix.pos[:, None])  # (B, K, N, 12): every slot's paint
    assert torch.allclose(patches, (attn[..., None] * each).sum(1), atol=1e-6)
    attn.requires_grad_(True)
    mix(slots, attn)[0].pow(2).sum().backward()
    assert attn.grad.abs().sum() > 0                              # the error reaches the masks
    with pytest.raises(ValueError, match="needs attention of shape"):
        mix(slots)
    with pytest.raises(ValueError, match="alpha must be one of"):
        MixtureDecoder(6, 4, 2, 8, alpha="slots")


def test_mixture_decoder_type_appearance_paints_one_look_from_z_alone():
    """appearance "type": a slot paints the same patch at every position, read from z only."""
    torch.manual_seed(0)
    mix = MixtureDecoder(slot_dim=6, grid=4, patch=2, hidden=8, alpha="attention",
                         appearance="type", type_dim=2)
    slots, attn = torch.randn(2, 3, 6), torch.softmax(torch.randn(2, 3, 16), dim=1)
    one_slot = torch.zeros_like(attn)
    one_slot[:, 1] = 1.0                                          # slot 1 takes every position
    patches, _ = mix(slots, one_slot)
    assert torch.allclose(patches, patches[:, :1].expand_as(patches))   # the same look everywhere
    restated = torch.cat([slots[..., :2], torch.randn(2, 3, 4)], -1)    # another state s
    assert torch.allclose(mix(restated, attn)[0], mix(slots, attn)[0])
    with pytest.raises(ValueError, match="needs alpha 'attention'"):
        MixtureDecoder(6, 4, 2, 8, alpha="decoder", appearance="type", type_dim=2)


def test_state_mask_decoder_reads_positions_as_coordinates():
    from ncs_lite.models.state_decoder import StateMaskDecoder, coordinate_grid

    grid = coordinate_grid(4)
    assert grid.shape == (16, 2) and torch.allclose(grid[0], torch.tensor([-0.75, -0.75]))
    assert torch.allclose(grid[1], torch.tensor([-0.75, -0.25]))   # row-major like the tokens
    dec = StateMaskDecoder(state_dim=5, grid=4)
    states = torch.randn(2, 3, 5)
    logits = dec(states)
    assert logits.shape == (2, 3, 16)
    perm = torch.tensor([2, 0, 1])
    assert torch.allclose(dec(states[:, perm]), logits[:, perm])         # per slot
    # each slot's logits peak at the grid cell nearest its bump's centre, a linear map of s
    centre = dec.bumps(states)["centre"]                                  # (2, 3, 2)
    sigma = dec.bumps(states)["sigma"]
    nearest = ((grid[None, None] - centre[:, :, None]) / sigma[:, :, None]).norm(dim=-1).argmin(-1)
    assert torch.equal(logits.argmax(-1), nearest)


@pytest.mark.parametrize("slot_grad", [0.0, 0.5])
def test_slot_grad_scales_what_decoder_losses_send_to_slots(slot_grad):
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.decoder.slot_grad, cfg.mixture.weight = slot_grad, 0.0
    m = DSlate(cfg)
    v, a = videos(B=2, T=2)
    torch.manual_seed(1)
    out = m(v, a, tau=1.0)
    (out["ce"] + out["ce_dyn"]).backward()
    g = m.slot_attn.to_q.weight.grad
    assert (g is None or float(g.abs().sum()) == 0.0) == (slot_grad == 0.0)
    assert m.decoder.head.weight.grad.abs().sum() > 0             # the decoder still learns
    if slot_grad:                                                 # the gradient is scaled, not cut
        g_half = g.clone()
        m.zero_grad()
        cfg.decoder.slot_grad = 1.0
        torch.manual_seed(1)
        out = m(v, a, tau=1.0)
        (out["ce"] + out["ce_dyn"]).backward()
        assert torch.allclose(g_half, 0.5 * m.slot_attn.to_q.weight.grad, rtol=1e-4, atol=1e-7)


def test_bad_inputs_give_clear_errors():
    m = DSlate(tiny_cfg())
    with pytest.raises(ValueError, match=r"shape \(B, H, W, 3\) with H = W = 64, got \(2, 32, 32, 3\)"):
        m.infer(torch.zeros(2, 32, 32, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match="dtype uint8.*got torch.float32"):
        m.infer(torch.zeros(2, 64, 64, 3))
    with pytest.raises(ValueError, match=r"got \(64, 64, 3\)"):
        m.infer(torch.zeros(64, 64, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 6\), got \(2, 3\)"):
        m.predict(torch.zeros(2, 3, 16), torch.zeros(2, 3))
    v, a = videos()
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 1, 6\)"):
        m(v, a[:, :, :3], tau=1.0)


def test_tiny_batch_overfits():
    """80 Adam steps on two fixed two-frame videos (a coloured square on a grey floor) cut the
    training loss at least 2x."""
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.decoder.dropout = cfg.dynamics.dropout = cfg.decoder.token_dropout = 0.0
    m = DSlate(cfg)
    v = torch.full((2, 2, 64, 64, 3), 90, dtype=torch.uint8)
    v[0, :, 8:16, 8:16] = torch.tensor([230, 30, 30], dtype=torch.uint8)
    v[1, :, 40:48, 20:28] = torch.tensor([30, 200, 40], dtype=torch.uint8)
    a = torch.zeros(2, 1, 6)
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    losses = []
    for _ in range(80):
        loss = m(v, a, tau=0.1)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 2, (losses[0], losses[-1])


def test_token_dropout_only_in_training():
    torch.manual_seed(0)
    cfg = tiny_cfg()
    cfg.decoder.token_dropout = 0.5
    m = DSlate(cfg)
    ids = torch.randint(0, cfg.dvae.vocab_size, (4, cfg.num_tokens))
    emb = m._embed(ids)
    dropped = (m._drop_tokens(ids, emb) != emb).any(-1).float().mean().item()
    assert 0.4 < dropped < 0.6                               # about half the inputs masked
    m.eval()
    assert torch.equal(m._drop_tokens(ids, emb), emb)       # never at inference


# ---------------------------------------------------------------- metrics
def test_adjusted_rand_index_known_values():
    assert adjusted_rand_index([0, 0, 1, 1], [1, 1, 0, 0]) == pytest.approx(1.0)
    assert adjusted_rand_index([0, 0, 1, 1], [0, 0, 1, 2]) == pytest.approx(4 / 7)
    assert adjusted_rand_index([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(-0.5)


def test_foreground_ari_ignores_background():
    true = np.zeros((1, 2, 4, 4), bool)
    true[0, 0, :2, :2] = True
    true[0, 1, 2:, 2:] = True
    pred = np.zeros((1, 3, 4, 4))
    pred[0, 0, :2, :2] = 1                                   # object 0 -> slot 0
    pred[0, 1, 2:, 2:] = 1                                   # object 1 -> slot 1
    pred[0, 0, :2, 2:] = 1                                   # background split arbitrarily
    pred[0, 2, 2:, :2] = 1
    assert foreground_ari(pred, true)[0] == pytest.approx(1.0)
    merged = pred.copy()
    merged[0, 0, 2:, 2:], merged[0, 1, 2:, 2:] = 1, 0        # both objects in slot 0
    assert foreground_ari(merged, true)[0] == pytest.approx(0.0)
    with pytest.raises(ValueError, match="must be bool"):
        foreground_ari(pred, true.astype(float))


def test_absorbed_by_background_names_the_merged_object():
    true = np.zeros((1, 2, 8, 8), bool)
    true[0, 0, :2, :2] = True            # object 0 gets its own slot (1)
    true[0, 1, 4:6, 4:6] = True          # object 1 is painted by the floor's slot (0)
    pred = np.zeros((1, 3, 8, 8))
    pred[0, 0] = 1.0
    pred[0, 0, :2, :2], pred[0, 1, :2, :2] = 0.0, 1.0
    np.testing.assert_array_equal(absorbed_by_background(pred, true), [[False, True]])
    with pytest.raises(ValueError, match="equal B, H, W"):
        absorbed_by_background(pred, true[:, :, :4])


@pytest.mark.parametrize("part, name, value, message", [
    ("slots", "encoder", "pixels", "slots.encoder must be 'tokens' or 'cnn', got 'pixels'"),
    ("mixture", "alpha", "slots", "mixture.alpha must be 'decoder' or 'attention', got 'slots'"),
    ("train", "precision", "fp16", "train.precision must be 'auto', 'bf16' or 'fp32', got 'fp16'"),
])
def test_config_rejects_bad_values_by_name(part, name, value, message):
    cfg = get_preset("ci")
    setattr(getattr(cfg, part), name, value)
    with pytest.raises(ValueError, match=re.escape(message)):
        cfg.validate()


def test_position_prior_gives_a_slot_that_attends_to_nothing_the_prior_state():
    cfg = tiny_cfg()                                          # ci: position_state, 32x32 masks
    cfg.slots.position_prior = 0.0
    N = cfg.mask_grid ** 2
    attn = torch.zeros(1, 3, N)
    attn[0, 0, : N // 2] = 1.0                                # the top half of the image
    attn[0, 1, N // 2:] = 1.0                                 # the bottom half
    attn[0, 2, 0] = 1e-3                                      # a stray speck in a corner
    plain = DSlate(cfg)._with_position(torch.zeros(1, 3, cfg.slots.slot_dim), attn)[0, :, -4:]
    cfg.slots.position_prior = 0.5
    prior = DSlate(cfg)._with_position(torch.zeros(1, 3, cfg.slots.slot_dim), attn)[0, :, -4:]
    assert plain[2, 0] < -0.9 and plain[2, 2] < 0.01          # the speck's centroid, no spread
    assert torch.allclose(prior[2], torch.tensor([0.0, 0.0, 3 ** -0.5, 3 ** -0.5]), atol=2e-3)
    assert torch.allclose(prior[:2], plain[:2], atol=2e-3)    # 512 cells of mass: the prior is nothing
    cfg.slots.position_prior = -1.0
    with pytest.raises(ValueError, match="slots.position_prior must be >= 0, got -1"):
        cfg.validate()


def test_a_saved_config_without_a_newer_field_reads_it_as_its_default():
    cfg = get_preset("ci")
    saved = to_dict(cfg)
    del saved["train"]["render_lr"]                           # ci keeps the default
    assert saved_config_diff(saved, cfg) == []
    del saved["slots"]["position_prior"]                      # ci sets 2; the default is 0
    assert saved_config_diff(saved, cfg) == ["slots.position_prior: 0.0 != 2.0"]
