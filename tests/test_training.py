"""Training loop: checkpoints, exact resume, NaN detection, mismatch errors (ci preset)."""
import csv

import pytest
import torch

from ncs_lite.config import get_preset, to_dict
from ncs_lite.inference import load_dslate
from ncs_lite.models.dslate import DSlate
from ncs_lite.training import MIXTURE_PARTS, SLATE_PARTS, BatchOrder, lr_at, phases, train


@pytest.fixture(scope="module")
def buffer(tmp_path_factory):
    from ncs_lite.data import collect

    return collect(tmp_path_factory.mktemp("buf"), episodes=4, num_objects=4, seed=3, shard_size=4)


def ci(**train):
    cfg = get_preset("ci")
    for k, v in train.items():
        setattr(cfg.train, k, v)
    return cfg


def starts(cfg):
    """{phase name: its first step} of the config's phases."""
    return {p.name: p.start for p in phases(cfg)}


def rows(path):
    with open(path.with_suffix(".csv")) as f:
        return list(csv.reader(f))


def test_checkpoint_round_trip(buffer, tmp_path):
    out = train(ci(), buffer, tmp_path / "m.pt", max_steps=2)
    ckpt = torch.load(out, weights_only=True)                 # only tensors, dicts, primitives
    assert ckpt["step"] == 2 and ckpt["config"] == to_dict(get_preset("ci"))
    model = load_dslate(out)
    assert not model.training
    for k, v in model.state_dict().items():
        assert torch.equal(v, ckpt["model"][k]), k
    assert [r[0] for r in rows(out)] == ["step", "1", "2"]
    r = model.infer(torch.zeros(1, 64, 64, 3, dtype=torch.uint8))
    assert torch.allclose(r.masks.sum(1), torch.ones(1, 64, 64), atol=1e-5)


def test_resume_equals_uninterrupted_run(buffer, tmp_path):
    cfg = ci(epochs=2)                                        # 8 steps, checkpoint every 2
    full = train(cfg, buffer, tmp_path / "full.pt", max_steps=6)
    part = train(cfg, buffer, tmp_path / "part.pt", max_steps=3)
    # pretend the run died after step 3: rows past the checkpoint must be dropped on resume
    with open(part.with_suffix(".csv"), "a") as f:
        f.write("4,1,1,1,1,1,1,1,1\n")
    part = train(cfg, buffer, part, resume=True, max_steps=6)
    a, b = torch.load(full, weights_only=True), torch.load(part, weights_only=True)
    assert a["step"] == b["step"] == 6
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert torch.equal(a["rng"]["torch"], b["rng"]["torch"])
    ra, rb = rows(full), rows(part)
    assert [r[:8] for r in ra] == [r[:8] for r in rb]         # same losses (not wall time)
    assert len(ra) == 7
    # and the model did change over those steps
    first = train(cfg, buffer, tmp_path / "one.pt", max_steps=1)
    w = "slot_attn.mu"
    assert not torch.equal(torch.load(first, weights_only=True)["model"][w], a["model"][w])


def test_polish_steps_freeze_the_dvae_and_raise_the_foreground_weight(buffer, tmp_path, monkeypatch):
    cfg = ci()                                                # 4 scheduled steps, then 2 polish steps
    main = cfg.train.main_steps()
    assert starts(cfg)["polish"] == main and starts(cfg)["dynamics"] == main + cfg.train.polish_steps == main + 2
    before = train(cfg, buffer, tmp_path / "m.pt", max_steps=main)
    before = {k: v.clone() for k, v in torch.load(before, weights_only=True)["model"].items()}
    weights, forward = [], DSlate.forward

    def spy(self, *args, **kwargs):
        weights.append((kwargs.get("foreground_weight"), kwargs.get("mixture_error")))
        return forward(self, *args, **kwargs)

    monkeypatch.setattr(DSlate, "forward", spy)
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt", resume=True, max_steps=main + 2),
                       weights_only=True)
    assert after["step"] == main + 2
    assert weights == [(cfg.train.polish_foreground_weight, cfg.train.polish_mixture_error)] * 2
    assert all(torch.equal(before[k], after["model"][k]) for k in before if k.startswith("dvae."))
    assert not torch.equal(before["slot_attn.mu"], after["model"]["slot_attn.mu"])
    with pytest.raises(ValueError, match="train.polish_steps must be an integer >= 0, got -1"):
        ci(polish_steps=-1).validate()
    with pytest.raises(ValueError, match="train.polish_mixture_error must be 'mixed' or 'per_slot', got 'blend'"):
        ci(polish_mixture_error="blend").validate()


def test_a_mixture_polish_trains_segmentation_alone(buffer, tmp_path, monkeypatch):
    cfg = ci(polish_loss="mixture")                           # 4 scheduled steps, then 2 polish steps
    main = cfg.train.main_steps()
    assert [p.loss for p in phases(cfg) if p.name == "polish"] == ["mixture"]
    before = torch.load(train(cfg, buffer, tmp_path / "m.pt", max_steps=main), weights_only=True)["model"]
    before = {k: v.clone() for k, v in before.items()}
    calls, mixture_loss = [], DSlate.mixture_loss

    def spy(self, *args, **kwargs):
        calls.append(args[1:])
        return mixture_loss(self, *args, **kwargs)

    monkeypatch.setattr(DSlate, "mixture_loss", spy)
    monkeypatch.setattr(DSlate, "forward", lambda *a, **k: pytest.fail("the polish ran the full SLATE loss"))
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt", resume=True, max_steps=main + 2),
                       weights_only=True)["model"]
    assert [c[0] for c in calls] == [cfg.train.polish_foreground_weight] * 2
    assert [c[2] for c in calls] == [cfg.train.polish_mixture_error] * 2
    assert all(c[1] is not None for c in calls)               # the colour-permuted videos (ci: channels)
    changed = {k.split(".")[0] for k in before if not torch.equal(before[k], after[k])}
    assert {"slot_attn", "mixture"} <= changed <= set(MIXTURE_PARTS)
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))[-2:]
    assert all(float(r["mix"]) > 0 and float(r["ce"]) == float(r["mse"]) == float(r["ce_dyn"]) == 0 for r in rows)
    with pytest.raises(ValueError, match="train.polish_loss must be 'slate' or 'mixture', got 'tokens'"):
        ci(polish_loss="tokens").validate()


def test_a_segmentation_only_schedule_trains_segmentation_alone(buffer, tmp_path, monkeypatch):
    from ncs_lite.config import apply_overrides
    from ncs_lite.experiments.reproduce import SEGMENTATION_ONLY, trains_segmentation_only
    from ncs_lite.utils import seed_everything

    cfg = apply_overrides(get_preset("ci"), SEGMENTATION_ONLY)
    assert trains_segmentation_only(cfg) and not trains_segmentation_only(get_preset("reduced"))
    run = phases(cfg)
    assert [(p.name, p.loss) for p in run] == [("dvae_warmup", "dvae"), ("main", "mixture"), ("polish", "mixture")]
    assert run[1].trains == MIXTURE_PARTS and run[1].dvae_lr == 0.0
    # the schedule's steps are the recipe's up to the polish: slot attention trains as long
    assert [p.steps for p in run] == [p.steps for p in phases(get_preset("ci"))][:3]
    cfg.train.dvae_warmup_steps = 0                           # the dVAE's own phase aside, nothing moves it
    seed_everything(cfg.train.seed)                           # as the run initialises its model
    init = {k: v.clone() for k, v in DSlate(cfg).state_dict().items()}
    monkeypatch.setattr(DSlate, "forward", lambda *a, **k: pytest.fail("the schedule ran the full SLATE loss"))
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt"), weights_only=True)["model"]
    changed = {k.split(".")[0] for k in init if not torch.equal(init[k], after[k])}
    assert {"slot_attn", "mixture"} <= changed <= set(MIXTURE_PARTS)
    with pytest.raises(ValueError, match="train.main_loss must be 'slate' or 'mixture', got 'tokens'"):
        ci(main_loss="tokens").validate()
    with pytest.raises(ValueError, match="train.main_loss 'mixture' trains slot attention on the mixture"):
        apply_overrides(get_preset("ci"), ["train.main_loss=mixture", "mixture.weight=0",
                                           "mixture.state_mask_weight=0", "mixture.render_hidden=0",
                                           "train.render_steps=0", "train.render_mask_steps=0",
                                           "train.polish_steps=0", "train.color_augment=none"]).validate()


def test_segmentation_starts_keep_the_start_with_the_lowest_mixture_error(buffer, tmp_path, monkeypatch):
    import ncs_lite.training as training

    cfg = ci(segmentation_starts=3, segmentation_start_steps=4)
    (chooser,) = [p for p in phases(cfg) if p.name == "starts"]
    assert (chooser.start, chooser.steps, chooser.starts, chooser.loss) == (1, 12, 3, "mixture")
    assert starts(cfg)["main"] == 13 and cfg.train.total_steps() == 12 + get_preset("ci").train.total_steps()
    assert [chooser.data_step(s) for s in range(1, 13)] == [1, 2, 3, 4] * 3          # the same batches
    assert [chooser.lr_at(i) for i in range(8)] == [chooser.lr_at(i) for i in range(4)] * 2
    seen, select = [], training.select_start

    def spy(model, *args):
        before = {k: v.clone() for k, v in model.state_dict().items() if k.split(".")[0] in MIXTURE_PARTS}
        record = select(model, *args)
        seen.append((before, {k: model.state_dict()[k].clone() for k in before}, record))
        return record

    monkeypatch.setattr(training, "select_start", spy)
    out = train(cfg, buffer, tmp_path / "m.pt", max_steps=14)
    record = torch.load(out, weights_only=True)["starts"]
    mix = [float(r["mix"]) for r in csv.DictReader(open(tmp_path / "m.csv"))]
    assert record["scores"] == pytest.approx([mix[4], mix[8], mix[12]])      # each start's last quarter
    assert record["best"] == min(range(3), key=record["scores"].__getitem__) and record["weights"] == {}
    assert len(seen) == 3
    for c, (trained, now, _) in enumerate(seen[:2], 1):      # starts 1 and 2 begin afresh
        fresh = training._initial_weights(cfg, MIXTURE_PARTS, c)
        assert all(torch.equal(now[k], fresh[k]) for k in now)
        assert not all(torch.equal(now[k], trained[k]) for k in now)
    best_trained, restored = seen[record["best"]][0], seen[2][1]
    assert all(torch.equal(restored[k], best_trained[k]) for k in restored)   # the main schedule starts from it
    # a run stopped inside a start and at a boundary, then resumed, chooses the same
    train(cfg, buffer, tmp_path / "r.pt", max_steps=6)
    train(cfg, buffer, tmp_path / "r.pt", resume=True, max_steps=9)
    resumed = torch.load(train(cfg, buffer, tmp_path / "r.pt", resume=True, max_steps=14), weights_only=True)
    full = torch.load(out, weights_only=True)
    assert resumed["starts"] == full["starts"]
    assert all(torch.equal(full["model"][k], resumed["model"][k]) for k in full["model"])
    with pytest.raises(ValueError, match="train.segmentation_starts must be an integer >= 1, got 0"):
        ci(segmentation_starts=0).validate()
    no_mixture = get_preset("paper")                          # Table 2: no mixture decoder
    no_mixture.train.segmentation_start_steps = 2
    with pytest.raises(ValueError, match="train.segmentation_start_steps > 0 trains slot attention on the mixture"):
        no_mixture.validate()


def test_dynamics_steps_train_the_dynamics_alone_on_the_latent_loss(buffer, tmp_path):
    cfg = ci()                                                # ... then 2 dynamics steps
    end = starts(cfg)["dynamics"]
    assert starts(cfg)["render_masks"] == end + cfg.train.dynamics_steps == end + 2
    before = torch.load(train(cfg, buffer, tmp_path / "m.pt", max_steps=end), weights_only=True)["model"]
    before = {k: v.clone() for k, v in before.items()}
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt", resume=True, max_steps=end + 2), weights_only=True)
    assert after["step"] == end + 2
    changed = {k for k in before if not torch.equal(before[k], after["model"][k])}
    assert changed and all(k.startswith("dynamics.") for k in changed)
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))[-2:]
    assert all(float(r["latent"]) > 0 and float(r["loss"]) == float(r["latent"]) and float(r["ce"]) == 0
               for r in rows)
    with pytest.raises(ValueError, match="dynamics_steps must be an integer >= 0"):
        ci(dynamics_steps=-1).validate()


def test_render_steps_fit_the_renderer_alone_to_the_frames(buffer, tmp_path):
    cfg = ci()                                                # ... then 2 render steps
    end = starts(cfg)["render_masks"]
    assert starts(cfg)["refit"] == end + cfg.train.render_steps == end + 2
    assert lr_at(end, cfg) == cfg.train.render_lr and lr_at(end - 1, cfg) == cfg.train.dynamics_lr
    before = torch.load(train(cfg, buffer, tmp_path / "m.pt", max_steps=end), weights_only=True)["model"]
    before = {k: v.clone() for k, v in before.items()}
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt", resume=True, max_steps=end + 2), weights_only=True)
    changed = {k for k in before if not torch.equal(before[k], after["model"][k])}
    assert changed and all(k.startswith("renderer.") for k in changed)
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))[-2:]
    assert all(float(r["loss"]) > 0 and float(r["latent"]) == float(r["mix"]) == 0 for r in rows)
    # the first (render_mask_steps) fits masks, a cross-entropy summed over cells; then pixels
    assert float(rows[0]["loss"]) > 1 > float(rows[1]["loss"])
    with pytest.raises(ValueError, match="render_steps > 0 fits the renderer, but mixture.render_hidden is 0"):
        _no_renderer(render_steps=2).validate()
    with pytest.raises(ValueError, match="train.render_lr must be > 0, got 0"):
        ci(render_lr=0.0).validate()
    with pytest.raises(ValueError, match=r"render_mask_steps \(3\) are the render phase's first steps"):
        ci(render_mask_steps=3).validate()


def test_refit_steps_train_the_dynamics_alone_again_after_the_render_phase(buffer, tmp_path):
    cfg = ci()                                                # ... then 2 refit steps
    end = starts(cfg)["refit"]
    assert cfg.train.total_steps() == end + cfg.train.refit_steps == end + 2
    assert lr_at(end, cfg) == cfg.train.dynamics_lr and lr_at(end - 1, cfg) == cfg.train.render_lr
    before = torch.load(train(cfg, buffer, tmp_path / "m.pt", max_steps=end), weights_only=True)["model"]
    before = {k: v.clone() for k, v in before.items()}
    after = torch.load(train(cfg, buffer, tmp_path / "m.pt", resume=True), weights_only=True)
    changed = {k for k in before if not torch.equal(before[k], after["model"][k])}
    assert changed and all(k.startswith("dynamics.") for k in changed)
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))[-2:]
    assert all(float(r["latent"]) > 0 and float(r["loss"]) == float(r["latent"]) for r in rows)
    with pytest.raises(ValueError, match="refit_steps must be an integer >= 0"):
        ci(refit_steps=-1).validate()


def _no_renderer(**train):
    """The recipe before the render phase (and the refit phase after it)."""
    cfg = ci(**{"refit_steps": 0, **train})
    cfg.mixture.render_hidden = 0
    cfg.train.render_mask_steps = min(cfg.train.render_mask_steps, cfg.train.render_steps)
    return cfg


def test_extend_by_the_render_phase_equals_a_straight_run(buffer, tmp_path):
    plain = _no_renderer(render_steps=0)
    plain.slots.position_prior = 0.0                 # acts from the render phase: extendable too
    done = train(plain, buffer, tmp_path / "plain.pt")
    out = train(ci(), buffer, tmp_path / "ext.pt", extend=done)
    straight = train(ci(), buffer, tmp_path / "straight.pt")
    a, b = torch.load(out, weights_only=True), torch.load(straight, weights_only=True)
    assert a["step"] == b["step"] == plain.train.total_steps() + 4     # render and refit phases
    assert a["model"].keys() == b["model"].keys() and any(k.startswith("renderer.") for k in a["model"])
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert a["lineage"][0]["fields"]["mixture.render_hidden"] == 0
    assert a["lineage"][0]["fields"]["slots.position_prior"] == 0
    # a run past the dynamics phase cannot take a longer dynamics phase
    with pytest.raises(ValueError, match=r"past where the changed fields act: train.dynamics_steps"):
        train(_no_renderer(render_steps=0, dynamics_steps=4), buffer, tmp_path / "d.pt", extend=done)


def test_extend_adds_the_dynamics_phase_to_a_finished_run(buffer, tmp_path):
    plain = _no_renderer(dynamics_steps=0, render_steps=0)
    done = train(plain, buffer, tmp_path / "plain.pt")
    with pytest.raises(ValueError, match="the changed fields|adds nothing"):
        train(plain, buffer, tmp_path / "same.pt", extend=done)
    out = train(_no_renderer(render_steps=0), buffer, tmp_path / "ext.pt", extend=done)
    a, b = torch.load(done, weights_only=True), torch.load(out, weights_only=True)
    assert b["step"] == a["step"] + 2
    changed = {k for k in a["model"] if not torch.equal(a["model"][k], b["model"][k])}
    assert changed and all(k.startswith("dynamics.") for k in changed)
    assert b["lineage"][0]["step"] == a["step"] and b["lineage"][0]["fields"]["train.dynamics_steps"] == 0
    rows = list(csv.DictReader(open(tmp_path / "ext.csv")))
    assert [int(r["step"]) for r in rows] == list(range(1, b["step"] + 1))   # the old log, continued
    with pytest.raises(ValueError, match=r"cannot extend.*train.lr"):
        train(ci(lr=2e-3), buffer, tmp_path / "other.pt", extend=done)
    half = train(plain, buffer, tmp_path / "half.pt", max_steps=2)
    with pytest.raises(ValueError, match="--resume it first"):
        train(ci(), buffer, tmp_path / "h2.pt", extend=half)
    with pytest.raises(ValueError, match="same file"):
        train(ci(), buffer, done, extend=done)


def test_nan_stops_and_keeps_last_good_checkpoint(buffer, tmp_path, monkeypatch):
    out = train(ci(), buffer, tmp_path / "m.pt", max_steps=2)
    before = out.read_bytes()
    forward = DSlate.forward

    def diverging(self, *args, **kwargs):      # NaN weights are refused on load: the loss goes NaN
        res = forward(self, *args, **kwargs)
        return {**res, "loss": res["loss"] * float("nan")}

    monkeypatch.setattr(DSlate, "forward", diverging)
    with pytest.raises(FloatingPointError, match=r"non-finite loss \(nan\) at step 3.*step 2\) was kept"):
        train(ci(), buffer, out, resume=True, max_steps=4)
    assert out.read_bytes() == before


def test_mismatched_checkpoint_errors(buffer, tmp_path):
    out = train(ci(), buffer, tmp_path / "m.pt", max_steps=2)
    with pytest.raises(ValueError, match=r"differs from this run.*train.lr: 0.001 != 0.002"):
        train(ci(lr=2e-3), buffer, out, resume=True, max_steps=4)
    ckpt = torch.load(out, weights_only=True)
    ckpt["model_version"] = "dslate-0"
    torch.save(ckpt, tmp_path / "old.pt")
    with pytest.raises(ValueError, match="another version of the code.*dslate-0"):
        load_dslate(tmp_path / "old.pt")
    ckpt = torch.load(out, weights_only=True)
    ckpt["model"]["slot_attn.mu"] = torch.zeros(1, 1, 3)
    del ckpt["content_digest"]                 # as written before the digest: the shapes catch it
    torch.save(ckpt, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="does not match this code's dSLATE"):
        load_dslate(tmp_path / "bad.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable dSLATE checkpoint"):
        load_dslate(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train(ci(), buffer, tmp_path / "absent.pt", resume=True)


def test_schedules_and_batch_order():
    cfg = get_preset("paper")
    assert lr_at(0, cfg) == pytest.approx(2e-4 / 30_000)
    assert lr_at(14_999, cfg) == pytest.approx(1e-4)
    assert lr_at(29_999, cfg) == lr_at(100_000, cfg) == pytest.approx(2e-4)
    red = get_preset("reduced")
    start = starts(red)
    main = start["main"]
    assert main == red.train.dvae_warmup_steps + 4 * 800 == 3800       # the dVAE, then four starts
    # the schedule's main_steps() count the dVAE warm-up among them
    assert start["polish"] == main + red.train.main_steps() - red.train.dvae_warmup_steps == 5388
    assert lr_at(5387, red) == pytest.approx(0.1 * red.train.lr, rel=1e-3)   # end of the cosine
    assert start["dynamics"] == 5388 + red.train.polish_steps == 6588
    assert start["render_masks"] == 6588 + red.train.dynamics_steps == 10588
    assert start["render"] == 10588 + red.train.render_mask_steps == 11588
    assert red.train.total_steps() == 10588 + red.train.render_steps == 12588
    assert lr_at(5388, red) == lr_at(6587, red) == red.train.polish_lr
    assert lr_at(6588, red) == lr_at(10587, red) == red.train.dynamics_lr
    assert lr_at(10588, red) == lr_at(12587, red) == red.train.render_lr
    order = BatchOrder(10, 4, seed=0)
    stream = [i for s in range(5) for i in order(s)]          # 20 = two full permutations
    assert sorted(stream[:10]) == list(range(10)) and sorted(stream[10:]) == list(range(10))
    assert stream[:10] != stream[10:]


def test_the_paper_trains_in_one_phase_and_reduced_in_seven():
    paper = get_preset("paper")
    (main,) = phases(paper)                                   # Table 2: everything jointly
    assert (main.name, main.start, main.steps, main.loss) == ("main", 0, paper.train.main_steps(), "slate")
    assert (main.lr, main.warmup, main.decay, main.dvae_lr) == (2e-4, 30_000, "none", 3e-4)
    assert main.trains == SLATE_PARTS and main.augment == "none" and main.position_prior == 0.0
    red = get_preset("reduced")
    run = phases(red)
    assert [p.name for p in run] == ["dvae_warmup", "starts", "main", "polish", "dynamics", "render_masks", "render"]
    assert [p.loss for p in run] == ["dvae", "mixture", "slate", "mixture", "dynamics", "render_masks", "render"]
    assert run[0].start == 0 and run[-1].end == red.train.total_steps()
    assert all(a.end == b.start for a, b in zip(run, run[1:]))
    assert run[0].lr == 0.0 and run[0].trains == ("dvae",)    # the dVAE alone ...
    assert run[3].dvae_lr == 0.0 and "dvae" not in run[3].trains   # ... and frozen from the polish on
    assert [p.position_prior for p in run] == [0.0] * 4 + [red.slots.position_prior] * 3
    # SLATE_PARTS and the renderer are every part of the model
    assert {k.split(".")[0] for k in DSlate(red).state_dict()} == set(SLATE_PARTS) | {"renderer"}
    with pytest.raises(ValueError, match=r"train.dvae_warmup_steps \(5\) are the schedule's first steps and "
                                         r"cannot exceed its 4"):
        ci(dvae_warmup_steps=5).validate()


def test_each_phase_moves_only_the_parts_it_trains(buffer, tmp_path):
    from ncs_lite.utils import seed_everything

    cfg = ci()
    seed_everything(cfg.train.seed)
    before = DSlate(cfg).state_dict()                          # the run's initialisation
    out = tmp_path / "m.pt"
    for i, phase in enumerate(phases(cfg)):                    # resumed at every phase's start
        after = torch.load(train(cfg, buffer, out, resume=i > 0, max_steps=phase.end), weights_only=True)
        changed = {k.split(".")[0] for k in before if not torch.equal(before[k], after["model"][k])}
        assert changed and changed <= set(phase.trains), (phase.name, changed)
        before = after["model"]
    with pytest.raises(ValueError, match=r"max_steps must be in 1..12 \(the last step of the config's phases\), "
                                         r"got 13"):
        train(cfg, buffer, tmp_path / "long.pt", max_steps=13)


def test_bench_times_the_trainers_own_step(monkeypatch):
    from ncs_lite import training
    from ncs_lite.bench import train_step as bench

    steps = []

    def spy(model, opt, phase, *args, **kwargs):
        steps.append(phase.name)
        return training.train_step(model, opt, phase, *args, **kwargs)

    monkeypatch.setattr(bench, "train_step", spy)
    cfg, cpu = get_preset("ci"), torch.device("cpu")
    model = DSlate(cfg)
    frames, actions = bench._batch(cfg, 2, cpu)
    before = model.slot_attn.mu.detach().clone()
    assert bench.step_flops(model, training.build_optimizer(model, cfg), frames, actions, cpu, "fp32") > 0
    assert steps == ["main"] and not torch.equal(before, model.slot_attn.mu)   # a real step, the main phase's


def test_cli_subcommand():
    from ncs_lite.__main__ import build_parser

    args = build_parser().parse_args(["train", "--env", "block-rearrange", "--preset", "reduced", "--data", "D",
                              "--out", "C.pt", "--resume", "--steps", "7"])
    assert (args.preset, args.data, args.out, args.resume, args.steps) == ("reduced", "D", "C.pt", True, 7)
    assert callable(args.func)


def test_obtain_dslate_trains_once_then_reuses(tmp_path, monkeypatch):
    from ncs_lite.training import obtain_dslate

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path))
    model, path = obtain_dslate("ci", seed=1)
    assert path.parent == tmp_path / "checkpoints" and model.cfg.train.seed == 1
    stamp = path.stat().st_mtime_ns
    again, path2 = obtain_dslate("ci", seed=1)                # finished: loaded, not retrained
    assert path2 == path and path.stat().st_mtime_ns == stamp
    for k, v in model.state_dict().items():
        assert torch.equal(v, again.state_dict()[k]), k
    import ncs_lite.data.buffer as buffer

    with monkeypatch.context() as m:     # after an edit of envs/ the buffer is collected into another
        m.setattr(buffer, "code_digest", lambda *parts: "0123456789abcdef")   # folder: the checkpoint,
        obtain_dslate("ci", seed=1)                           # which names it by its manifest, still fits
    assert path.stat().st_mtime_ns == stamp and len(list((tmp_path / "buffers").iterdir())) == 2
    ckpt = torch.load(path, weights_only=True)                # a cache left by an older preset
    ckpt["config"]["train"]["lr"] = 0.5
    torch.save(ckpt, path)
    _, path3 = obtain_dslate("ci", seed=1)                    # retrained, not an error
    assert path3 == path and torch.load(path, weights_only=True)["config"] == to_dict(model.cfg)


def test_permute_channels_reorders_each_video_once():
    import numpy as np

    from ncs_lite.data.augment import permute_channels

    videos = torch.randint(0, 256, (64, 2, 4, 4, 3), dtype=torch.uint8)
    out = permute_channels(videos, np.random.default_rng(0))
    orders = set()
    for v, o in zip(videos, out):
        # the same order in every frame of a video, and a true permutation of the channels
        order = [next(c for c in range(3) if torch.equal(o[..., j], v[..., c])) for j in range(3)]
        assert sorted(order) == [0, 1, 2]
        orders.add(tuple(order))
    assert len(orders) == 6                                    # all 3! orders occur, the identity too
    assert torch.equal(out, permute_channels(videos, np.random.default_rng(0)))
    with pytest.raises(ValueError, match=r"videos must have shape \(B, T, H, W, C\), got \(2, 4, 4, 3\)"):
        permute_channels(videos[0], np.random.default_rng(0))


def test_gamma_keeps_black_white_and_order_but_changes_how_close_two_colours_are():
    import numpy as np

    from ncs_lite.data.augment import augment_colors, permute_channels

    # orange and yellow (block-rearrange's nearest pair) in every video, beside black and white
    pixels = torch.tensor([[250, 140, 13], [242, 217, 26], [0, 0, 0], [255, 255, 255]], dtype=torch.uint8)
    videos = pixels[None, None, None].expand(64, 2, 1, 4, 3).contiguous()
    out = augment_colors("channels_gamma", videos, np.random.default_rng(0))
    permuted = permute_channels(videos, np.random.default_rng(0))        # the orders come first
    assert torch.equal(out[..., 2:, :], permuted[..., 2:, :])             # 0 and 255 are fixed points
    assert torch.equal(out[:, 0], out[:, 1])                              # one draw per video
    # a power is monotone: within a channel the order of the colours is kept
    assert torch.equal(torch.sign(out[:, 0, 0, 0].int() - out[:, 0, 0, 1].int()),
                       torch.sign(permuted[:, 0, 0, 0].int() - permuted[:, 0, 0, 1].int()))
    gap = (out[:, 0, 0, 0].float() - out[:, 0, 0, 1].float()).norm(dim=-1) / 255
    assert gap.min() < 0.2 < 0.45 < gap.max()                  # the 0.31 gap shrinks and stretches
    assert torch.equal(out, augment_colors("channels_gamma", videos, np.random.default_rng(0)))
    with pytest.raises(ValueError, match=r"colour augmentation must be one of 'channels', 'channels_gamma', got 'hue'"):
        augment_colors("hue", videos, np.random.default_rng(0))


def test_the_colour_augmentations_are_the_configs_choices():
    from ncs_lite.config import COLOR_AUGMENTS, get_preset
    from ncs_lite.data.augment import AUGMENTS

    assert COLOR_AUGMENTS == ("none", *AUGMENTS)            # config.py names them, augment.py draws them
    cfg = get_preset("ci")
    cfg.train.color_augment = 3
    with pytest.raises(ValueError, match=r"^train\.color_augment must be a string, got 3$"):
        cfg.validate()
    cfg.train.color_augment = "hue"
    with pytest.raises(ValueError, match=r"train\.color_augment must be 'none', 'channels' or 'channels_gamma', got 'hue'"):
        cfg.validate()


def test_mixture_videos_train_slot_attention_and_leave_the_rest_on_the_true_frames():
    torch.manual_seed(0)
    model = DSlate(get_preset("ci")).eval()                    # no dropout: equal inputs, equal losses
    videos = torch.randint(0, 256, (2, 2, 64, 64, 3), dtype=torch.uint8)
    actions = torch.zeros(2, 1, 6)
    seed = torch.random.get_rng_state()

    def losses(mixture_videos):
        torch.random.set_rng_state(seed)
        return model(videos, actions, tau=1.0, mixture_videos=mixture_videos)

    same, swapped = losses(videos), losses(videos.flip(-1))   # blue and red exchanged
    assert torch.equal(same["ce"], swapped["ce"]) and torch.equal(same["latent"], swapped["latent"])
    assert not torch.allclose(same["mix"], swapped["mix"])
    model.zero_grad()
    swapped["ce"].backward(retain_graph=True)                  # slot_grad 0: no path into slot attention
    assert all(p.grad is None or not p.grad.any() for p in model.slot_attn.parameters())
    swapped["mix"].backward()
    assert any(p.grad is not None and p.grad.any() for p in model.slot_attn.parameters())
    with pytest.raises(ValueError, match="mixture_videos must have the shape of videos"):
        model(videos, actions, tau=1.0, mixture_videos=videos[:1])


def test_seeds_keep_a_run_of_an_earlier_recipe_to_extend_it(buffer, tmp_path):
    from ncs_lite.experiments.reproduce import _keep_for_extending

    half = train(_no_renderer(render_steps=0), buffer, tmp_path / "half" / "dslate.pt", max_steps=2)
    with pytest.raises(ValueError, match="unfinished run of an earlier recipe"):
        _keep_for_extending(half, ci())
    assert half.exists()
    old = train(_no_renderer(render_steps=0), buffer, tmp_path / "dslate.pt")
    with pytest.raises(ValueError, match=r"another recipe \(train.lr"):
        _keep_for_extending(old, ci(lr=2e-3))
    _keep_for_extending(old, ci())
    base = tmp_path / f"dslate-step-{_no_renderer(render_steps=0).train.total_steps()}.pt"
    assert base.exists() and base.with_suffix(".csv").exists() and not old.exists()
    train(ci(), buffer, old, extend=base)
    _keep_for_extending(old, ci())                             # the extended run is this recipe's
    assert old.exists()


@pytest.mark.parametrize("env", ["block-rearrange", "robogym-rearrange", "block-stacking"])
def test_a_shipped_dslate_is_its_envs_reduced_preset(env):
    """What `make` would train is what ships: the shipped checkpoint's recipe is `reduced` with the
    env's ENV_OVERRIDES, up to the training seed its seeds table picked."""
    from dataclasses import replace

    from ncs_lite.config import from_dict
    from ncs_lite.inference import SHIPPED_MODELS, read_checkpoint

    shipped = from_dict(read_checkpoint(SHIPPED_MODELS[env])["config"])
    preset = get_preset("reduced", env)
    assert shipped == replace(preset, train=replace(preset.train, seed=shipped.train.seed))


def test_env_overrides_apply_to_their_preset_and_env_only():
    from ncs_lite.config import ENV_OVERRIDES, apply_overrides, get_preset

    assert get_preset("reduced", "robogym-rearrange").dvae.foreground_weight == 20.0
    assert get_preset("reduced").dvae.foreground_weight == 5.0
    for env, presets in ENV_OVERRIDES.items():
        for name, overrides in presets.items():
            assert get_preset(name, env) == apply_overrides(get_preset(name), overrides)
            assert get_preset(name, env) != get_preset(name)          # each changes something
