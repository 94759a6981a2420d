"""Experience buffer: round trip, determinism, resume, one object per transition."""
import json
import os

import numpy as np
import pytest

from ncs_lite.__main__ import main
from ncs_lite.data import EpisodeDataset, collect, load_buffer


def test_round_trip_and_semantics(tmp_path):
    collect(tmp_path, episodes=12, seed=1, shard_size=5)
    b = load_buffer(tmp_path)
    assert b["frames"].shape == (12, 5, 64, 64, 3) and b["frames"].dtype == np.uint8
    assert b["actions"].shape == (12, 4, 6) and b["masks"].shape == (12, 5, 4, 64, 64)
    assert sorted(p.name for p in tmp_path.glob("shard-*.npz")) == [
        "shard-00000.npz", "shard-00001.npz", "shard-00002.npz"]
    # each transition moves exactly one object, the one the action picked
    delta = np.linalg.norm(np.diff(b["positions"], axis=1), axis=-1) > 1e-6   # (E, 4, k)
    assert (delta.sum(-1) == 1).all()
    np.testing.assert_array_equal(delta.argmax(-1), b["moved"])
    # the action's (w + dw) is where the moved cube landed
    landed = np.take_along_axis(b["positions"][:, 1:], b["moved"][..., None, None], 2)[:, :, 0, :2]
    np.testing.assert_allclose(b["actions"][..., :2] + b["actions"][..., 3:5], landed, atol=1e-5)
    meta = json.loads((tmp_path / "manifest.json").read_text())
    assert meta["env"]["num_objects"] == 4 and meta["seed"] == 1 and "pybullet" in meta["versions"]


def test_deterministic_and_independent_of_shard_size(tmp_path):
    collect(tmp_path / "a", episodes=6, seed=3, shard_size=6)
    collect(tmp_path / "b", episodes=6, seed=3, shard_size=4)
    collect(tmp_path / "c", episodes=6, seed=4, shard_size=6)
    a, b, c = (load_buffer(tmp_path / x) for x in "abc")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["frames"], c["frames"])


def test_resume_after_interruption(tmp_path, monkeypatch):
    import ncs_lite.data.buffer as buffer

    monkeypatch.setenv("NCS_LITE_WORKERS", "1")    # the patched recorder lives in this process only
    full = tmp_path / "full"
    collect(full, episodes=9, seed=2, shard_size=3)
    part = tmp_path / "part"
    real = buffer.record_episode
    calls = {"n": 0}

    def dying(env, seq):
        calls["n"] += 1
        if calls["n"] == 5:          # dies inside the second shard
            raise KeyboardInterrupt
        return real(env, seq)

    monkeypatch.setattr(buffer, "record_episode", dying)
    with pytest.raises(KeyboardInterrupt):
        collect(part, episodes=9, seed=2, shard_size=3)
    assert [p.name for p in part.glob("shard-*.npz")] == ["shard-00000.npz"]
    assert not list(part.glob("*.tmp"))                     # nothing half-written
    with pytest.raises(ValueError, match="incomplete"):
        load_buffer(part)
    first = (part / "shard-00000.npz").stat().st_mtime_ns
    monkeypatch.setattr(buffer, "record_episode", real)
    collect(part, episodes=9, seed=2, shard_size=3)
    assert (part / "shard-00000.npz").stat().st_mtime_ns == first   # never rewritten
    for k, v in load_buffer(full).items():
        np.testing.assert_array_equal(load_buffer(part)[k], v)


def test_worker_processes_write_the_same_buffer(tmp_path):
    serial = collect(tmp_path / "serial", episodes=8, seed=3, shard_size=2, workers=1)
    parallel = collect(tmp_path / "parallel", episodes=8, seed=3, shard_size=2, workers=2)
    for k, v in load_buffer(serial).items():
        np.testing.assert_array_equal(load_buffer(parallel)[k], v)


def test_mismatched_buffer_is_refused(tmp_path):
    collect(tmp_path, episodes=2, seed=0)
    with pytest.raises(ValueError, match="different buffer"):
        collect(tmp_path, episodes=2, seed=1)


def test_dataset_windows(tmp_path):
    collect(tmp_path, episodes=3, seed=0)
    ds = EpisodeDataset(tmp_path, window=2)
    assert len(ds) == 3 * 4
    item = ds[5]                      # episode 1, start 1
    b = load_buffer(tmp_path)
    np.testing.assert_array_equal(item["frames"].numpy(), b["frames"][1, 1:3])
    np.testing.assert_array_equal(item["actions"].numpy(), b["actions"][1, 1:2])
    with pytest.raises(ValueError, match="window"):
        EpisodeDataset(tmp_path, window=6)


def test_cli_collect(tmp_path, capsys):
    assert main(["collect", "--episodes", "2", "--seed", "0", "--out", str(tmp_path)]) == 0
    assert load_buffer(tmp_path)["frames"].shape[0] == 2
    assert main(["collect", "--episodes", "0", "--out", str(tmp_path / "x")]) == 2
    assert "episodes must be" in capsys.readouterr().err


def _rewrite(shard, change):
    """Save `change(arrays)` over `shard`, the way `collect` saves one."""
    with np.load(shard) as z:
        arrays = {k: z[k] for k in z.files}
    with open(shard, "wb") as f:
        np.savez_compressed(f, **change(arrays))


def _flip_a_frames_byte(shard):
    import zipfile

    with zipfile.ZipFile(shard) as z:
        info = z.getinfo("frames.npy")
    data = bytearray(shard.read_bytes())
    at = info.header_offset + 30 + len(info.filename) + info.compress_size // 2   # inside the deflate stream
    data[at] ^= 0xFF
    shard.write_bytes(bytes(data))


@pytest.fixture(scope="module")
def buffers(tmp_path_factory):
    root = tmp_path_factory.mktemp("buffers")
    return (collect(root / "good", episodes=4, seed=5, shard_size=2),
            collect(root / "other", episodes=4, seed=6, shard_size=2))


SHARD_SPOILS = {  # how shard 0 is spoilt: what the one-line error says
    "truncated": (lambda p, other: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
                  "is not a readable .npz (BadZipFile"),
    "empty": (lambda p, other: p.write_bytes(b""), "is not an .npz (an empty file)"),
    "not an npz": (lambda p, other: p.write_text("hello"), "is not an .npz (it starts with b'hell', not a zip header)"),
    "a flipped byte": (lambda p, other: _flip_a_frames_byte(p), "is corrupted (BadZipFile: Bad CRC-32 for file 'frames.npy')"),
    "an array missing": (lambda p, other: _rewrite(p, lambda a: {k: v for k, v in a.items() if k != "moved"}),
                         "lacks the arrays ['moved']; expected frames, actions"),
    "fewer episodes": (lambda p, other: _rewrite(p, lambda a: {k: v[:1] if v.ndim else v for k, v in a.items()}),
                       "holds 1 episodes in 'frames', expected 2"),
    "more episodes": (lambda p, other: _rewrite(p, lambda a: {k: np.concatenate([v, v[:1]]) if v.ndim else v
                                                              for k, v in a.items()}),
                      "holds 3 episodes in 'frames', expected 2"),
    "another buffer's": (lambda p, other: p.write_bytes((other / p.name).read_bytes()), "belongs to another buffer"),
    # arrays that read but do not hold what the manifest says (these loaded, or failed in numpy)
    "smaller images": (lambda p, other: _rewrite(p, lambda a: {**a, "frames": a["frames"][:, :, :32, :32]}),
                       "holds 'frames' of shape (2, 5, 32, 32, 3) and dtype uint8, expected (episodes, 5, 64, 64, 3) "
                       "of uint8"),
    "float frames": (lambda p, other: _rewrite(p, lambda a: {**a, "frames": a["frames"].astype(np.float32)}),
                     "holds 'frames' of shape (2, 5, 64, 64, 3) and dtype float32"),
    "NaN actions": (lambda p, other: _rewrite(p, lambda a: {**a, "actions": np.full_like(a["actions"], np.nan)}),
                    "holds non-finite values in 'actions'; expected finite ones"),
    "a moved cube that is not there": (lambda p, other: _rewrite(p, lambda a: {**a, "moved": np.full_like(a["moved"], 17)}),
                                       "holds 'moved' values in 17..17, expected -1..3"),
    "a FIFO": (lambda p, other: (p.unlink(), os.mkfifo(p)), "is not a regular file, expected an .npz"),   # read: a hang
}


@pytest.mark.parametrize("spoil", SHARD_SPOILS)
def test_a_bad_shard_is_named_and_collected_again(spoil, buffers, tmp_path, capsys):
    import shutil

    good, other = buffers
    case = tmp_path / "b"
    shutil.copytree(good, case)
    shard = case / "shard-00000.npz"
    how, message = SHARD_SPOILS[spoil]
    how(shard, other)
    with pytest.raises(ValueError) as err:
        load_buffer(case)
    assert message in str(err.value) and str(shard) in str(err.value), err.value
    assert "rerun the same `collect` command" in str(err.value)
    assert main(["train", "--preset", "ci", "--data", str(case), "--out", str(tmp_path / "m.pt")]) == 2
    captured = capsys.readouterr().err
    assert message in captured and captured.count("\n") == 1
    # collect over it makes that shard again (never "buffer ready" over a bad one)
    assert main(["collect", "--episodes", "4", "--seed", "5", "--shard-size", "2", "--out", str(case)]) == 0
    out = capsys.readouterr().out
    assert f"collecting {shard.name} again: buffer shard {shard}" in out and message in out
    for k, v in load_buffer(good).items():
        np.testing.assert_array_equal(load_buffer(case)[k], v)


def test_legacy_shards_load_and_a_broken_manifest_is_named(buffers, tmp_path, capsys):
    import shutil

    from ncs_lite.data import manifest_hash
    from ncs_lite.data.buffer import SHARD_ID

    good, _ = buffers
    with np.load(good / "shard-00001.npz") as z:
        assert str(z[SHARD_ID]) == manifest_hash(good)     # each shard names its buffer
    legacy = tmp_path / "legacy"
    shutil.copytree(good, legacy)
    for shard in legacy.glob("shard-*.npz"):                # shards from before the hash
        _rewrite(shard, lambda a: {k: v for k, v in a.items() if k != SHARD_ID})
    for k, v in load_buffer(good).items():
        np.testing.assert_array_equal(load_buffer(legacy)[k], v)
    manifest = json.loads((good / "manifest.json").read_text())
    cases = {"{": "is not a readable buffer manifest (JSONDecodeError",
             "[]": "is not a valid buffer manifest: it holds a JSON list, expected an object",
             json.dumps({**manifest, "episodes": "4"}): "episodes must be an integer >= 1, got '4'",
             json.dumps({k: v for k, v in manifest.items() if k != "shard_size"}): "shard_size must be an integer",
             json.dumps({**manifest, "format": 0}): "format 0, this code reads format 1",
             None: "is not a regular file, expected a buffer manifest"}       # a FIFO: reading it hung
    for text, message in cases.items():
        case = tmp_path / f"m{len(text or '')}"
        shutil.copytree(good, case)
        if text is None:
            (case / "manifest.json").unlink()
            os.mkfifo(case / "manifest.json")
        else:
            (case / "manifest.json").write_text(text)
        path = str(case / "manifest.json")
        for args in (["collect", "--episodes", "4", "--seed", "5", "--shard-size", "2", "--out", str(case)],
                     ["train", "--preset", "ci", "--data", str(case), "--out", str(tmp_path / "m.pt")]):
            assert main(args) == 2
            err = capsys.readouterr().err
            assert message in err and path in err and err.count("\n") == 1, err


def test_cached_buffer_is_keyed_by_the_code_that_records_it(tmp_path, monkeypatch):
    import ncs_lite.cache as cache
    import ncs_lite.data.buffer as buffer
    from ncs_lite.data import cached_buffer, manifest_hash
    from ncs_lite.data.buffer import BUFFER_CODE

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path))
    old = cached_buffer(2)
    assert old.parent == tmp_path / "buffers" and old.name == f"block-rearrange-k4-e2-s0-v1-{cache.code_digest(*BUFFER_CODE)}"
    assert cached_buffer(2) == old
    monkeypatch.setattr(buffer, "code_digest", lambda *parts: "0123456789abcdef")    # as after an edit of envs/
    new = cached_buffer(2)
    assert new != old and new.name.endswith("-0123456789abcdef") and (new / "shard-00000.npz").exists()
    assert manifest_hash(new) == manifest_hash(old)     # what checkpoints name a buffer by: they still fit


def test_find_buffer_by_its_manifest_hash(tmp_path, monkeypatch):
    """A graph names its buffer by folder and manifest hash: when the folder is gone (collected
    under another name), the cache's buffer with that hash is the one; none is a clear error."""
    from ncs_lite.data import cached_buffer, find_buffer, manifest_hash

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path))
    there = cached_buffer(2)
    sha = manifest_hash(there)
    assert find_buffer(there, sha) == there
    assert find_buffer(tmp_path / "moved-away", sha) == there
    assert find_buffer(tmp_path / "moved-away", None) == tmp_path / "moved-away"   # nothing to look up by
    with pytest.raises(FileNotFoundError, match=r"none with manifest hash 0123456789abcdef"):
        find_buffer(tmp_path / "moved-away", "0123456789abcdef")
    other = cached_buffer(2, seed=1)                 # a buffer at the recorded folder, but another one
    assert find_buffer(other, sha) == there
