"""Experience buffer: round trip, determinism, resume, one object per transition."""
import json

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
