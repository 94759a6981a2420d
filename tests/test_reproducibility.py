"""Config overrides, resume/overwrite rules, provenance, and the CLI chain a user runs."""
import csv
import json

import pytest
import torch

from ncs_lite import utils
from ncs_lite.__main__ import main
from ncs_lite.config import NCSConfig, apply_overrides, get_preset, ncs_config
from ncs_lite.data import collect
from ncs_lite.inference import read_checkpoint
from ncs_lite.experiments.reproduce import mean_sd
from ncs_lite.training import run_lock, train



@pytest.fixture(scope="module")
def buffer(tmp_path_factory):
    return collect(tmp_path_factory.mktemp("buf") / "b", episodes=8, seed=0, shard_size=4)


def test_override_sets_typed_values():
    cfg = apply_overrides(get_preset("ci"), ["train.lr=2e-3", "slots.num_slots=4",
                                             "train.lr_decay=cosine", "decoder.dropout=0"])
    assert cfg.train.lr == 2e-3 and cfg.slots.num_slots == 4 and cfg.decoder.dropout == 0.0
    assert isinstance(cfg.slots.num_slots, int) and cfg.train.lr_decay == "cosine"
    assert get_preset("ci").train.lr != 2e-3              # the preset itself is untouched


@pytest.mark.parametrize("text, message", [
    ("train.lrr=1", r"unknown field 'lrr' of train; allowed fields: .*batch_size.*lr"),
    ("bogus.lr=1", r"unknown config section 'bogus'; sections: decoder, dvae"),
    ("train.lr=abc", r"expected a finite float, got 'abc'"),
    ("train.lr=nan", r"expected a finite float"),
    ("slots.num_slots=2.5", r"expected a finite int"),
    ("train.lr", r"takes section.field=value"),
    ("train.precision=fp16", r"train.precision must be"),        # the config's own validation
    # values that trained silently or failed deep inside torch (ZeroDivisionError, empty stacks)
    ("slots.heads=0", r"slots.heads must be an integer >= 1, got 0"),
    ("downsample=0", r"downsample must be an integer >= 1, got 0"),
    ("train.batch_size=0", r"train.batch_size must be an integer >= 1, got 0"),
    ("train.checkpoint_every=0", r"train.checkpoint_every must be an integer >= 1, got 0"),
    ("train.epochs=-1", r"train.epochs must be an integer >= 1, got -1"),
    ("dvae.vocab_size=0", r"dvae.vocab_size must be an integer >= 1, got 0"),
    ("train.lr=-1", r"train.lr must be > 0, got -1.0"),
    ("mixture.weight=-1", r"mixture.weight must be >= 0, got -1.0"),
    ("decoder.dropout=1.5", r"decoder.dropout must be in \[0, 1\), got 1.5"),
    ("decoder.token_dropout=2", r"decoder.token_dropout must be in \[0, 1\), got 2.0"),
    ("train.grad_clip_norm=bogus", r"train.grad_clip_norm must be the order of a norm.*got 'bogus'"),
    ("action_dim=3", r"action_dim must be 6 \(the envs' action \(w, dw\)\), got 3"),
])
def test_override_errors_name_the_field(text, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(get_preset("ci"), [text])


def test_ncs_overrides():
    assert ncs_config(["ncs.restarts=1"], clusters=20) == NCSConfig(clusters=20, restarts=1)
    with pytest.raises(ValueError, match="NCS fields only; allowed fields: ncs.clusters"):
        ncs_config(["train.lr=1"])
    with pytest.raises(ValueError, match="ncs.restarts must be an integer >= 1"):
        ncs_config(["ncs.restarts=0"])
    assert ncs_config(["ncs.restarts=32"]).restarts == 32 and NCSConfig().restarts is None   # None: the env's
    assert ncs_config(["ncs.restarts=32", "ncs.restarts=none"]).restarts is None
    assert ncs_config(["ncs.graph_restarts=2"]).graph_restarts == 2
    with pytest.raises(ValueError, match="ncs.graph_restarts must be an integer >= 1, got 0"):
        ncs_config(["ncs.graph_restarts=0"])
    with pytest.raises(ValueError, match=r"restarts=x: expected a finite int, got 'x'"):
        ncs_config(["ncs.restarts=x"])
    assert ncs_config(["ncs.nearest_variance=1"]).nearest_variance == 1
    with pytest.raises(ValueError, match=r"ncs.nearest_variance must be a number in \(0, 1\], got 1.5"):
        ncs_config(["ncs.nearest_variance=1.5"])


def test_overrides_recorded_and_resume_refuses_differences(buffer, tmp_path):
    cfg = apply_overrides(get_preset("ci"), ["train.lr=2e-3"])
    out = train(cfg, buffer, tmp_path / "m.pt", max_steps=2, overrides=["train.lr=2e-3"])
    ckpt = read_checkpoint(out)
    assert ckpt["overrides"] == ["train.lr=2e-3"]
    assert len(ckpt["data"]["manifest_sha256"]) == 16
    assert ckpt["code_version"]["training_code"]
    with pytest.raises(ValueError, match=r"precision: 'fp32' != 'bf16'"):
        train(cfg, buffer, out, resume=True, precision="bf16")
    with pytest.raises(ValueError, match=r"unknown environment 'other'"):     # refused before resuming
        train(cfg, buffer, out, resume=True, env="other")
    other = collect(tmp_path / "other", episodes=8, seed=1, shard_size=4)
    with pytest.raises(ValueError, match=r"buffer manifest"):
        train(cfg, other, out, resume=True)


def test_new_run_needs_force_and_force_starts_clean(buffer, tmp_path):
    out = train(get_preset("ci"), buffer, tmp_path / "m.pt", max_steps=2)
    before = out.read_bytes()
    with pytest.raises(ValueError, match="already exists: pass --resume .* or --force"):
        train(get_preset("ci"), buffer, out, max_steps=2)
    assert out.read_bytes() == before                       # nothing was touched
    train(get_preset("ci"), buffer, out, max_steps=3, force=True)
    with open(out.with_suffix(".csv")) as f:
        steps = [int(r["step"]) for r in csv.DictReader(f)]
    assert steps == [1, 2, 3]                               # one run's log, not two


def test_two_runs_on_one_out_refuse_each_other(tmp_path):
    with run_lock(tmp_path / "m.pt"):
        with pytest.raises(ValueError, match=r"another training run \(pid \d+\) is writing"):
            with run_lock(tmp_path / "m.pt"):
                pass
    with run_lock(tmp_path / "m.pt"):                        # released afterwards
        pass


def test_provenance_refuses_dirty_writes_into_committed_folders(tmp_path, monkeypatch):
    guarded = tmp_path / "figures"
    monkeypatch.setattr(utils, "committed_result_dirs", lambda: (guarded,))
    monkeypatch.setattr(utils, "dirty_files", lambda: ["ncs_lite/training.py"])
    monkeypatch.delenv("NCS_LITE_ALLOW_DIRTY", raising=False)
    with pytest.raises(ValueError, match=r"uncommitted changes \(ncs_lite/training.py\).*--allow-dirty"):
        utils.provenance(guarded / "x" / "a.json")
    assert utils.provenance(guarded / "a.json", allow_dirty=True)["dirty"] is True
    assert utils.provenance(tmp_path / "elsewhere.json")["dirty"] is True   # not guarded
    monkeypatch.setattr(utils, "dirty_files", lambda: [])
    assert utils.provenance(guarded / "a.json")["dirty"] is False


def test_dirty_tree_sends_figures_elsewhere(tmp_path, monkeypatch):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ncs_lite import figures

    monkeypatch.setenv("NCS_LITE_FIGURES", str(tmp_path / "figures"))
    monkeypatch.setattr(figures, "REPO_DIR", tmp_path)
    monkeypatch.setattr(utils, "committed_result_dirs", lambda: (tmp_path / "figures",))
    monkeypatch.setattr(utils, "dirty_files", lambda: ["ncs_lite/x.py"])
    monkeypatch.delenv("NCS_LITE_ALLOW_DIRTY", raising=False)
    fig = plt.figure()
    png = figures.save_fig(fig, "nb", "f")
    plt.close(fig)
    assert png.parent == tmp_path / "build" / "figures-dirty" / "nb"
    assert json.loads(png.with_suffix(".json").read_text())["dirty"] is True


def test_mean_sd():
    assert mean_sd([1.0, 0.5, 0.0]) == {"mean": 0.5, "sd": 0.5, "n": 3}
    assert mean_sd([0.7])["n"] == 1 and mean_sd([0.7])["sd"] != mean_sd([0.7])["sd"]   # nan


def test_cli_chain(tmp_path, monkeypatch, capsys):
    """collect -> train --preset ci -> graph -> evaluate, as a user runs them."""
    monkeypatch.chdir(tmp_path)
    assert main(["collect", "--episodes", "8", "--out", "data", "--shard-size", "4"]) == 0
    assert main(["train", "--preset", "ci", "--data", "data", "--out", "m.pt",
                 "--set", "train.lr=2e-3"]) == 0
    assert read_checkpoint("m.pt")["config"]["train"]["lr"] == 2e-3
    assert main(["train", "--preset", "ci", "--data", "data", "--out", "m.pt"]) == 2   # no --force
    assert "already exists" in capsys.readouterr().err
    assert main(["train", "--preset", "ci", "--data", "data", "--out", "m.pt", "--set", "train.nope=1"]) == 2
    assert "unknown field 'nope' of train" in capsys.readouterr().err
    assert main(["graph", "--checkpoint", "m.pt", "--data", "data", "--out", "g.pt",
                 "--set", "ncs.clusters=5", "--set", "ncs.restarts=2"]) == 0
    info = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert info["nodes"] == 5
    assert main(["evaluate", "--method", "ncs", "--checkpoint", "m.pt", "--graph", "g.pt",
                 "--episodes", "2", "--set", "ncs.restarts=1", "--out", "r.csv"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["episodes"] == 2 and 0 <= summary["success"] <= 1
    with open("r.csv") as f:
        assert len(list(csv.DictReader(f))) == 2


def test_atomic_writes_get_the_umask_mode_and_clear_stale_temporaries(tmp_path):
    import os
    import time

    from ncs_lite.utils import STALE_TMP_SECONDS, atomic_write_text

    stale, fresh = tmp_path / ".x.txt.abc.tmp", tmp_path / ".x.txt.def.tmp"
    for f in (stale, fresh):
        f.write_text("left by a killed write")
    os.utime(stale, (time.time() - 2 * STALE_TMP_SECONDS,) * 2)
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "x.txt", "hi")
    finally:
        os.umask(old)
    assert (tmp_path / "x.txt").stat().st_mode & 0o777 == 0o644      # not mkstemp's 0600
    assert not stale.exists() and fresh.exists()                     # a recent one may be a live write
    # a temporary whose writer has ended is removed at once; a live writer's is kept
    dead, live = tmp_path / f".x.txt.{2 ** 22 + 1}.abc.tmp", tmp_path / f".x.txt.{os.getpid()}.def.tmp"
    for f in (dead, live):
        f.write_text("half written")
    atomic_write_text(tmp_path / "x.txt", "again")
    assert not dead.exists() and live.exists()
    assert not [f for f in tmp_path.glob(".x.txt.*.tmp") if f not in (fresh, live)]


def test_bad_files_and_arguments_get_one_line_errors(tmp_path, capsys):
    """A checkpoint passed as a graph, a truncated, empty or corrupted graph, a directory or a
    FIFO, an unknown env or device, a file the method does not read or of another env, a
    graph of another perception, arguments checked only after the work: exit 2 with one
    line naming the file or value."""
    import os

    from ncs_lite.__main__ import main
    from ncs_lite.data import cached_buffer
    from ncs_lite.inference import (ROBOGYM_POSITION_GRAPH, SHIPPED_CHECKPOINT, SHIPPED_GRAPH, SHIPPED_POLICIES,
                                    SHIPPED_SLOT_GRAPH)
    from ncs_lite.ncs.graph import TransitionGraph, content_digest

    graph = TransitionGraph.load(SHIPPED_GRAPH)
    graph.save(tmp_path / "g.pt")
    data = (tmp_path / "g.pt").read_bytes()
    (tmp_path / "half.pt").write_bytes(data[: len(data) // 2])
    sd = torch.load(tmp_path / "g.pt", weights_only=True)
    sd["edge_action"][0, 0] += 1.0
    torch.save(sd, tmp_path / "flipped.pt")
    cases = {str(SHIPPED_CHECKPOINT): "holds a dSLATE checkpoint", str(tmp_path / "half.pt"): "is not a readable",
             str(tmp_path / "flipped.pt"): "is corrupted", str(tmp_path): "is a directory"}
    (tmp_path / "empty.pt").write_bytes(b"")
    os.mkfifo(tmp_path / "fifo.pt")                             # reading it would hang
    cases.update({str(tmp_path / "empty.pt"): "is an empty file, expected a transition graph file",
                  str(tmp_path / "fifo.pt"): "is not a regular file, expected a transition graph file"})
    spoilt = {  # file: (how a sound graph is changed, saved with a fresh digest; what the line says)
        "nan-actions.pt": (lambda g: g["edge_action"].fill_(float("nan")), "edge actions must be finite"),
        "negative-counts.pt": (lambda g: g["edge_count"].fill_(-3), "edge counts must be >= 1, got -3"),
        "bogus-state.pt": (lambda g: g["info"].update(state="bogus"), "unknown state 'bogus'"),
        "list-metric.pt": (lambda g: g.update(bind_metric=["cosine"]), "unknown bind metric ['cosine']"),
        "list-actions.pt": (lambda g: g.update(edge_action=[[0.0] * 6]), "its edge_action is a list, expected a tensor"),
        "float-index.pt": (lambda g: g.update(edge_index=g["edge_index"].float()), "its edge_index has dtype torch.float32"),
    }
    for name, (spoil, message) in spoilt.items():
        sd = torch.load(tmp_path / "g.pt", weights_only=True)
        spoil(sd)
        torch.save({**sd, "content_digest": content_digest(sd)}, tmp_path / name)
        cases[str(tmp_path / name)] = message
    for path, message in cases.items():
        assert main(["evaluate", "--method", "ncs-oracle", "--graph", path, "--episodes", "1"]) == 2
        err = capsys.readouterr().err
        assert message in err and path in err and err.count("\n") == 1, (path, err)
    buf = str(cached_buffer(16))
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    slot_graph, bc = str(SHIPPED_SLOT_GRAPH), str(SHIPPED_POLICIES["bc"])
    commands = [  # arguments, what the one line says: each was a traceback, a silent default or a hang
        (["evaluate", "--method", "ncs-oracle", "--graph", slot_graph, "--episodes", "1"],
         f"--graph {slot_graph}: the graph's nodes are 'slot' states of 4 numbers but the perception reads states of 3"),
        (["evaluate", "--method", "ncs", "--graph", slot_graph, "--set", "ncs.slot_position=attention", "--episodes", "1"],
         f"--graph {slot_graph}: the graph was built on slot states read with slot_position 'assigned'; "
         "the agent would act with 'attention'"),
        (["evaluate", "--method", "ncs-oracle", "--graph", str(ROBOGYM_POSITION_GRAPH), "--episodes", "1"],
         f"--graph {ROBOGYM_POSITION_GRAPH} was made on 'robogym-rearrange', not 'block-rearrange'"),
        (["graph-nf", "--oracle", "--bind-graph", slot_graph, "--data", buf, "--out", str(tmp_path / "nf.pt")],
         f"--bind-graph {slot_graph}: the graph's nodes are 'slot' states of 4 numbers"),
        (["evaluate", "--method", "random", "--checkpoint", str(SHIPPED_CHECKPOINT), "--episodes", "1"],
         f"method 'random' reads no dSLATE checkpoint (--checkpoint), got {SHIPPED_CHECKPOINT}"),
        (["evaluate", "--method", "random", "--set", "mpc.population=5", "--episodes", "1"],
         "--set mpc.population=5: mpc fields set MPC's planner; method 'random' has none"),
        (["evaluate", "--method", "bc", "--env", "robogym-rearrange", "--policy", bc, "--episodes", "1"],
         f"--policy {bc} was trained on 'block-rearrange', not --env 'robogym-rearrange'"),
        (["graph", "--oracle", "--clusters", "0", "--data", buf, "--out", str(tmp_path / "g0.pt")],
         "ncs.clusters must be an integer >= 1, got 0"),
        (["train", "--preset", "ci", "--set", "image_size=32", "--data", buf, "--out", str(tmp_path / "m.pt")],
         f"the buffer {buf} holds 64x64 images, but the config's image_size is 32"),
        (["train-baseline", "--method", "bc", "--preset", "ci", "--env", "robogym-rearrange", "--data", buf,
          "--out", str(tmp_path / "bc.pt")], f"the buffer {buf} was collected on 'block-rearrange', not --env"),
        (["reproduce", "seeds", "--preset", "bogus"], "unknown preset 'bogus' for the seeds table"),
        (["reproduce", "seeds", "--preset", "ci", "--episodes", "0"], "--episodes must be an integer >= 1, got 0"),
        (["reproduce", "seeds", "--preset", "ci", "--set", "ncs.restarts=0", "--runs", str(tmp_path)],
         "ncs.restarts must be an integer >= 1, got 0"),
        (["reproduce", "baselines", "--env", "bogus"], "unknown --env 'bogus'; expected one of block-rearrange"),
        (["reproduce", "clusters", "--env", "robogym-rearrange"],
         "the clusters table does not read --env; it reads --checkpoint, --episodes"),
        (["reproduce", "robogym", "--set", "ncs.clusters=9"], "the robogym table does not read --set"),
        (["reproduce", "baselines", "--objects", "4"], "the baselines table does not read --objects"),
        (["reproduce", "clusters", "--segmentation-only"], "the clusters table does not read --segmentation-only"),
        (["reproduce", "clusters", "--task-seed", "3"], "the clusters table does not read --task-seed"),
        (["reproduce", "seeds", "--task-seed", "-1"], "--task-seed must be an integer >= 0, got -1"),
        (["reproduce", "seeds", "--seeds", "0", "0"], "--seeds must be distinct, got [0, 0]"),
        (["evaluate", "--method", "random", "--set", "ncs.clusters=99", "--episodes", "1"],
         "--set ncs.clusters=99: evaluate reads a built graph"),
        (["graph", "--oracle", "--clusters", "4", "--set", "ncs.clusters=6", "--data", buf, "--out",
          str(tmp_path / "g46.pt")], "give the number of nodes once: --clusters 4 or --set ncs.clusters=N"),
        (["reproduce", "clusters", "--out-dir", str(afile)], f"--out-dir {afile} is a file; expected a table directory"),
        (["bench", "envs", "--out", str(tmp_path)], f"--out {tmp_path} is a directory; expected the path of a JSON file"),
    ]
    for args, message in commands:
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (args, err)
    assert main(["train", "--preset", "ci", "--env", "bogus", "--data", buf, "--out", str(tmp_path / "m.pt")]) == 2
    assert "unknown environment 'bogus'" in capsys.readouterr().err
    assert main(["train", "--preset", "ci", "--device", "bogus", "--data", buf, "--out", str(tmp_path / "m.pt")]) == 2
    assert "unknown device 'bogus'" in capsys.readouterr().err


def _flip_a_weight_byte(src, dst):
    """A copy of checkpoint `src` with one byte of its largest weight flipped, as on a bad disk."""
    model = torch.load(src, weights_only=True)["model"]
    raw = max(model.values(), key=lambda t: t.numel()).numpy().tobytes()
    data = bytearray(src.read_bytes())
    at = data.find(raw[:64])
    assert at > 0
    data[at + 4] ^= 0x01
    dst.write_bytes(bytes(data))
    return str(dst)


def test_bad_checkpoints_get_one_line_errors(buffer, tmp_path, capsys):
    """dSLATE and BC/IQL checkpoints carry a kind tag and a digest of their tensors: a flipped
    byte, non-finite weights or another kind of file is refused in one line naming the path
    and what the file is; files written before the tag and digest (the shipped ones) load."""
    from ncs_lite import tensor_files as u
    from ncs_lite.baselines import bc as bc_module, goal_conditioned, nf
    from ncs_lite.baselines.runs import load_trained_policy
    from ncs_lite.inference import SHIPPED_CHECKPOINT, SHIPPED_GRAPH, SHIPPED_POLICIES, load_dslate
    from ncs_lite.ncs import graph as graph_module
    from ncs_lite import inference

    dslate = train(get_preset("ci"), buffer, tmp_path / "m.pt", max_steps=1)
    bc = tmp_path / "bc.pt"
    assert main(["train-baseline", "--method", "bc", "--preset", "ci", "--set", "bc.steps=2",
                 "--data", str(buffer), "--out", str(bc)]) == 0
    assert {"kind", "content_digest"} <= set(read_checkpoint(dslate))
    sd = torch.load(dslate, weights_only=True)
    for t in sd["model"].values():
        t.fill_(float("nan"))
    del sd["content_digest"]                              # a file from before the digest
    torch.save(sd, tmp_path / "nan.pt")
    model = load_trained_policy(bc, "bc")
    for p in model.parameters():
        p.data.fill_(float("nan"))
    bc_module.save_bc(tmp_path / "nan-bc.pt", model)      # digest of the NaNs it saved

    def variant(src, name, change, digest=True):
        """A copy of checkpoint `src` changed by `change(dict)`, with its digest stored anew (or dropped)."""
        sd = torch.load(src, weights_only=True)
        change(sd)
        keys = inference.DIGESTED if sd.get("kind") == "dslate" else goal_conditioned.DIGESTED
        sd.pop("content_digest")
        torch.save({**sd, "content_digest": u.tensor_digest(sd, keys)} if digest else sd, tmp_path / name)
        return str(tmp_path / name)

    graph = str(SHIPPED_GRAPH)
    capsys.readouterr()                                     # the training bars above
    cases = [  # (flag, method, file, what the one line says)
        # were tracebacks from deep inside (ZeroDivisionError, KeyError, AttributeError) or loaded silently
        ("--checkpoint", "ncs", variant(dslate, "heads0.pt", lambda c: c["config"]["slots"].update(heads=0)),
         "holds a config this code cannot use: slots.heads must be an integer >= 1, got 0"),
        ("--checkpoint", "ncs", variant(dslate, "lr-str.pt", lambda c: c["config"]["train"].update(lr="fast")),
         "holds a config this code cannot use: train.lr must be a finite number, got 'fast'"),
        ("--checkpoint", "ncs", variant(dslate, "model-list.pt", lambda c: c.update(model=[1]), digest=False),
         "is corrupted: its 'model' must be a dict of tensors, got list"),
        ("--policy", "bc", variant(bc, "no-log.pt", lambda c: c.pop("log")), "is corrupted: it lacks ['log']"),
        ("--policy", "bc", variant(bc, "no-box.pt", lambda c: c["model"].pop("box.low"), digest=False),
         "holds a bc checkpoint this code cannot use: ValueError: its model lacks the action bounds"),
        ("--policy", "bc", variant(bc, "box-inverted.pt", lambda c: c["model"].update({"box.low": c["model"]["box.high"] + 1})),
         "holds a bc checkpoint this code cannot use: ValueError: action bounds need high > low"),
        ("--checkpoint", "ncs", _flip_a_weight_byte(dslate, tmp_path / "flip.pt"), "is corrupted"),
        ("--checkpoint", "ncs", str(tmp_path / "nan.pt"), "holds non-finite weights"),
        ("--checkpoint", "ncs", graph, "is not a dSLATE checkpoint (kind 'dslate' with 'model' and 'config'); "
                                       "it holds an NCS transition graph"),
        ("--checkpoint", "ncs", str(bc), "it holds a BC checkpoint"),
        ("--policy", "bc", _flip_a_weight_byte(bc, tmp_path / "flip-bc.pt"), "is corrupted"),
        ("--policy", "bc", str(tmp_path / "nan-bc.pt"), "holds non-finite weights"),
        ("--policy", "bc", str(dslate), "is not an ncs-lite baseline checkpoint (format 1, kind 'bc' or 'iql'); "
                                        "it holds a dSLATE checkpoint"),
        ("--policy", "bc", graph, "it holds an NCS transition graph"),
        ("--graph", "ncs-oracle", str(dslate), "it holds a dSLATE checkpoint"),
        ("--graph", "ncs-oracle", str(bc), "it holds a BC checkpoint"),
    ]
    for flag, method, path, message in cases:
        assert main(["evaluate", "--method", method, flag, path, "--episodes", "1"]) == 2, path
        err = capsys.readouterr().err
        assert message in err and path in err and err.count("\n") == 1, (path, err)
    resumed = tmp_path / "resumed.pt"                       # a checkpoint without its optimizer state
    variant(dslate, "resumed.pt", lambda c: c.pop("optimizer"), digest=False)
    assert main(["train", "--preset", "ci", "--data", str(buffer), "--out", str(resumed), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"cannot resume {resumed}: it lacks ['optimizer']" in err and err.count("\n") == 1, err
    # files written before the kind tag and digest load unchanged
    legacy = variant(dslate, "legacy.pt", lambda c: c.pop("kind"), digest=False)
    assert not {"kind", "content_digest"} & set(torch.load(legacy, weights_only=True))
    assert load_dslate(legacy).checkpoint_info["step"] > 0
    assert "content_digest" in torch.load(SHIPPED_CHECKPOINT, weights_only=True)   # the shipped file is digested
    assert load_dslate(SHIPPED_CHECKPOINT).checkpoint_info["step"] > 0
    for method, path in SHIPPED_POLICIES.items():
        assert load_trained_policy(path, method).step > 0
    # every kind tag the kit writes has a name for those messages
    kinds = {inference.CHECKPOINT_KIND, *goal_conditioned.KINDS, graph_module.GRAPH_KIND, nf.GRAPH_KIND}
    assert kinds == set(u.FILE_KINDS)


def test_out_that_is_a_directory_or_below_a_file_is_refused(buffer, tmp_path, capsys):
    """Every command that writes --out checks it first: one line naming it, exit 2, nothing written."""
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    data = ["--data", str(buffer)]
    commands = {  # command: (its arguments but --out, what --out should be)
        "train": (["train", "--preset", "ci", *data], "file", "checkpoint"),
        "train-baseline": (["train-baseline", "--method", "bc", "--preset", "ci", *data], "file", "bc checkpoint"),
        "graph": (["graph", "--oracle", *data], "file", "graph"),
        "graph-nf": (["graph-nf", "--oracle", *data], "file", "NF graph"),
        "evaluate": (["evaluate", "--method", "random", "--episodes", "1"], "file", "CSV"),
        "collect": (["collect", "--episodes", "2"], "dir", "buffer"),
    }
    for name, (args, kind, what) in commands.items():
        bad = ({tmp_path: f"--out {tmp_path} is a directory; expected the path of a {what} file"} if kind == "file"
               else {afile: f"--out {afile} is a file; expected a {what} directory"})
        bad[afile / "sub" / "x"] = f"--out {afile / 'sub' / 'x'} lies below {afile}, which is a file, not a directory"
        for out, message in bad.items():
            before = sorted(tmp_path.iterdir())
            assert main([*args, "--out", str(out)]) == 2, name
            err = capsys.readouterr().err
            assert message in err and err.count("\n") == 1, (name, err)
            assert sorted(tmp_path.iterdir()) == before, name          # no lock, log or temporary left


def test_a_table_stage_is_reused_only_for_the_same_inputs_and_code(tmp_path, monkeypatch):
    from ncs_lite.experiments import reproduce

    calls = []

    def compute():
        calls.append(1)
        return len(calls)

    path = tmp_path / "stage.json"
    assert reproduce._stage(path, {"checkpoint": "a"}, compute) == 1
    assert reproduce._stage(path, {"checkpoint": "a"}, compute) == 1       # reloaded
    assert reproduce._stage(path, {"checkpoint": "b"}, compute) == 2       # other inputs
    monkeypatch.setattr(reproduce, "source_hash", lambda *parts: "edited")
    assert reproduce._stage(path, {"checkpoint": "b"}, compute) == 3       # other code
    assert json.loads(path.read_text())["key"] == {"checkpoint": "b", "code": "edited"}


def test_reproduce_robogym_reads_the_given_graph(tmp_path, capsys):
    (tmp_path / "half.pt").write_bytes(b"not a graph")
    assert main(["reproduce", "robogym", "--graph", str(tmp_path / "half.pt"), "--out-dir", str(tmp_path),
                 "--allow-dirty"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "half.pt") in err and err.count("\n") == 1, err


def test_a_graph_whose_actions_leave_the_action_space_is_refused():
    from ncs_lite.envs import make
    from ncs_lite.evaluation import check_graph_actions
    from ncs_lite.inference import ROBOGYM_POSITION_GRAPH
    from ncs_lite.ncs.graph import TransitionGraph

    env = make("block-rearrange", num_objects=4)
    try:
        with pytest.raises(ValueError, match="edge actions lie outside the env's action space"):
            check_graph_actions(TransitionGraph.load(ROBOGYM_POSITION_GRAPH), env.action_space)
    finally:
        env.close()


def test_code_keys_ignore_prose_but_not_code():
    from ncs_lite.utils import code_of

    base = 'def f(x):\n    """Adds one."""\n    return x + 1  # one\n'
    assert code_of(base) == code_of('def f(x):\n    """Adds one, for a reason."""\n\n    return x + 1\n')
    assert code_of(base) == code_of("def f(x):\n    return x + 1\n")
    assert code_of(base) != code_of('def f(x):\n    """Adds one."""\n    return x + 2\n')
    assert code_of('X = "a"\n') != code_of('X = "b"\n')                 # a string that is code
    assert code_of('class A:\n    """Doc."""\n') == code_of("class A:\n    pass\n")


def test_a_segmentation_only_seeds_table_leaves_out_what_reads_untrained_parts(tmp_path):
    """`reproduce seeds --segmentation-only`: the recipe's overrides name the schedule, and the
    split's measures of the dynamics, the renderer and the dVAE, which it leaves untrained, are
    not reported; the segmentation's and NCS's columns are."""
    from ncs_lite.experiments.reproduce import SEGMENTATION_ONLY, SPLIT_METRICS_SEGMENTATION

    assert main(["reproduce", "seeds", "--preset", "ci", "--seeds", "0", "--segmentation-only", "--objects", "4",
                 "--episodes", "1", "--runs", str(tmp_path / "runs"), "--out-dir", str(tmp_path / "tables"),
                 "--allow-dirty", "--set", "train.num_objects=3"]) == 0
    saved = json.loads((tmp_path / "tables" / "seeds_ci.json").read_text())
    assert saved["overrides"] == ["train.num_objects=3", *SEGMENTATION_ONLY]
    row = saved["rows"][0]
    assert {"fg_ari_7_r1", "shared_7_r1", "ncs_4", "ncs_slot_4", "heldout_error_4_r8"} <= set(row)
    # NCS with one slot-attention pass too (the paper's reading), on each state
    assert {"ncs_4_r1", "ncs_4_r1_ci", "ncs_slot_4_r1"} <= set(row) and "ncs_4_r1_constraints" not in row
    split = {c.split("_", 1)[1] for c in row if c.startswith("split_") and not c.startswith("split_r")}
    assert split == set(SPLIT_METRICS_SEGMENTATION)
    assert not any(m in c for c in row for m in ("moved_slot", "render_", "dvae_floor", "predicted_"))


def test_seeds_table_on_robogym_reports_every_count_the_references_and_the_shipped_seed(tmp_path):
    """`reproduce seeds --env robogym-rearrange` at `ci`: slot states only (Table 3), 4-7
    objects, the oracle and Random on the same tasks, and the seed its rule ships."""
    from ncs_lite.experiments.reproduce import seeds_table

    out = seeds_table("ci", seeds=(0,), runs=tmp_path / "runs", episodes=1, images=4,
                      env="robogym-rearrange", out_dir=tmp_path / "tables", allow_dirty=True,
                      overrides=["train.num_objects=3"])     # the recipe names its buffer's count
    row = out["rows"][0]
    for k in (4, 5, 6, 7):
        assert {f"ncs_{k}", f"ncs_oracle_{k}", f"random_{k}", f"placed_fraction_{k}"} <= set(row)
    assert "ncs_slot_4" not in row and "heldout_error" in row and out["shipped_seed"] == 0
    # the shipping rule reads the error at the largest count, each frame's best of 8 starts
    assert row["heldout_error_7_r8"] > 0
    saved = json.loads((tmp_path / "tables" / "seeds_robogym_ci.json").read_text())
    assert saved["env"] == "robogym-rearrange" and saved["clusters"] == 8 and saved["shipped_seed"] == 0
    assert "robogym-rearrange-k3-" in saved["buffer"]
    assert "heldout_error_7_r8" in saved["shipped_rule"]


def test_a_seeds_table_keeps_the_rows_of_other_seeds_measured_alike(tmp_path, capsys):
    """`reproduce seeds --seeds 3 4` after `--seeds 0 1 2` writes one five-seed table when both
    runs measured with the same settings and code; a seed run again replaces its row, and a
    table of other settings is replaced with a line naming what differs."""
    from ncs_lite.experiments.reproduce import with_earlier_seeds

    settings = {"preset": "reduced", "overrides": ["slots.iterations=5"], "objects": (4, 7), "code": "abc"}
    path = tmp_path / "seeds_reduced.json"
    assert with_earlier_seeds(path, [{"seed": 3, "ncs_4": 1.0}], settings) == [{"seed": 3, "ncs_4": 1.0}]
    path.write_text(json.dumps({**settings, "objects": [4, 7],
                                "rows": [{"seed": s, "ncs_4": 0.5} for s in (0, 1, 3)]}))
    rows = with_earlier_seeds(path, [{"seed": 3, "ncs_4": 1.0}, {"seed": 4, "ncs_4": 0.9}], settings)
    assert rows == [{"seed": 0, "ncs_4": 0.5}, {"seed": 1, "ncs_4": 0.5}, {"seed": 3, "ncs_4": 1.0},
                    {"seed": 4, "ncs_4": 0.9}]
    assert "keeping seeds 0, 1" in capsys.readouterr().out
    for other in ({"code": "def"}, {"overrides": []}):
        assert with_earlier_seeds(path, [{"seed": 4, "ncs_4": 0.9}], {**settings, **other}) == [{"seed": 4, "ncs_4": 0.9}]
        assert f"with another {next(iter(other))}; the table is replaced" in capsys.readouterr().out


def test_paths_in_results_are_relative_to_the_repo_through_a_linked_cache(tmp_path, monkeypatch):
    """A worktree whose `.cache` links to another checkout's records `.cache/...`, not the
    other checkout's path (tables compare their inputs across machines by these names)."""
    elsewhere = tmp_path / "other" / ".cache"
    (elsewhere / "buffers").mkdir(parents=True)
    repo = tmp_path / "repo"
    repo.mkdir()
    (repo / ".cache").symlink_to(elsewhere)
    monkeypatch.setattr(utils, "REPO_DIR", repo)
    assert utils.relative_to_repo(repo / ".cache" / "buffers") == ".cache/buffers"
    assert utils.relative_to_repo(repo / "figures" / "x.json") == "figures/x.json"
    assert utils.relative_to_repo(tmp_path / "other" / "y") == str(tmp_path / "other" / "y")
