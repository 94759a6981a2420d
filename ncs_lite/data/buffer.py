"""The experience buffer: short random 'video demonstrations' stored as compressed shards.

Each episode has `frames` = 5 images and 4 pick-and-move actions; each action moves one
random object to a random free place (Appendix A; docs/environments.md, "The experience
buffer"). A buffer directory holds

    manifest.json        what was asked for (env config, episodes, seed, format, versions)
    shard-00000.npz ...  `shard_size` episodes each, written atomically, with the manifest's
                         hash (`manifest_sha256`: the buffer the shard belongs to)

Episode e is generated from `SeedSequence([seed, e])` alone, so the buffer does not depend
on the shard size or on where an interrupted collection stopped: `collect` skips finished
shards and writes the rest, which gives byte-identical arrays to an uninterrupted run.
Every shard is checked when it is read (a readable npz, every array, the manifest's number
of episodes, this buffer's hash; shards from before the hash have none): `load_buffer`
refuses a bad one naming it, and `collect` collects it again.
"""
from __future__ import annotations

import hashlib
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np
import torch

from ..cache import code_digest
from ..envs import make
from ..envs.common import outside_action_space
from ..utils import atomic_path, atomic_write_json, cache_dir, check_out_dir, one_line, package_versions
from ..workers import default_workers, map_jobs

FORMAT = 1
FRAMES = 5  # frames per episode: 4 actions
ARRAYS = ("frames", "actions", "positions", "masks", "colors", "moved")
SHARD_ID = "manifest_sha256"   # the array naming the buffer a shard belongs to


def _manifest(env: str, episodes: int, num_objects: int, seed: int, shard_size: int) -> dict:
    probe = make(env, num_objects=num_objects)
    env_config = probe.describe()
    probe.close()
    return {"format": FORMAT, "env": env_config, "episodes": episodes, "seed": seed,
            "frames": FRAMES, "shard_size": shard_size}


def _check(name: str, value: int, low: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def record_episode(env, seed_seq: np.random.SeedSequence) -> dict[str, np.ndarray]:
    """Roll one random pick-and-move episode. Returns per-episode arrays (see load_buffer)."""
    env_seed, action_seed = seed_seq.generate_state(2)
    rng = np.random.default_rng(action_seed)
    obs, info = env.reset(seed=int(env_seed))
    frames, positions, masks, actions, moved = [obs["image"]], [info["positions"]], [info["masks"]], [], []
    for _ in range(FRAMES - 1):
        action = env.random_pick_and_move(rng)
        obs, _, _, _, info = env.step(action)
        frames.append(obs["image"]); positions.append(info["positions"]); masks.append(info["masks"])
        actions.append(action); moved.append(info["moved"])
    return {"frames": np.stack(frames), "actions": np.stack(actions).astype(np.float32),
            "positions": np.stack(positions).astype(np.float32), "masks": np.stack(masks),
            "colors": info["colors"].astype(np.float32), "moved": np.asarray(moved, np.int64)}


def collect(out: str | Path, episodes: int, env: str = "block-rearrange", num_objects: int = 4,
            seed: int = 0, shard_size: int = 100, workers: int | None = None) -> Path:
    """Collect (or resume collecting) a buffer of `episodes` random episodes into `out`;
    `workers` processes write its shards (`workers.map_jobs`), with the same bytes."""
    episodes, shard_size = _check("episodes", episodes), _check("shard_size", shard_size)
    seed = _check("seed", seed, low=0)
    out = check_out_dir(out, "buffer")
    manifest = _manifest(env, episodes, num_objects, seed, shard_size)
    path = out / "manifest.json"
    if path.exists():
        old = load_manifest(out)
        diff = {k: (old.get(k), v) for k, v in manifest.items() if old.get(k) != v}
        if diff:
            raise ValueError(f"{out} holds a different buffer (stored vs asked: {diff}); "
                             "use another --out or delete it")
    else:
        atomic_write_json(path, {**manifest, "versions": package_versions()})
    buffer_id = manifest_hash(out)

    n_shards = -(-episodes // shard_size)
    todo = []
    for s in range(n_shards):
        shard = out / f"shard-{s:05d}.npz"
        if shard.exists():
            try:                        # a shard that a crash, a disk or a copy spoilt is made again
                _read_shard(shard, _shard_len(s, episodes, shard_size), buffer_id, shard_spec(manifest))
                continue
            except ValueError as e:
                print(f"collect: collecting {shard.name} again: {e}")
        todo.append(s)
    # shards are independent (episode e depends on (seed, e) alone): worker processes (one a
    # core: an env steps on one thread) write them, 4 jobs a worker for the progress bar, each
    # job with one env (a MuJoCo env takes about a second to make)
    n = min(default_workers(threads=1) if workers is None else workers, max(1, len(todo)))
    jobs = 1 if n == 1 else min(len(todo), 4 * n)
    map_jobs(_collect_shards, [(todo[i::jobs],) for i in range(jobs)], workers=n,
             shared=(out, env, num_objects, seed, episodes, shard_size, buffer_id),
             desc=f"collect {env}: {sum(_shard_len(s, episodes, shard_size) for s in todo)} episodes")
    return out


def _collect_shards(spec: tuple, shards: list[int]) -> None:
    """Record the episodes of `shards` and write each shard (a job of `collect`'s `map_jobs`)."""
    out, env, num_objects, seed, episodes, shard_size, buffer_id = spec
    env_ = make(env, num_objects=num_objects)
    try:
        for s in shards:
            first = s * shard_size
            eps = [record_episode(env_, np.random.SeedSequence([seed, e]))
                   for e in range(first, first + _shard_len(s, episodes, shard_size))]
            arrays = {k: np.stack([ep[k] for ep in eps]) for k in ARRAYS}
            with atomic_path(out / f"shard-{s:05d}.npz") as tmp, open(tmp, "wb") as f:
                np.savez_compressed(f, **arrays, **{SHARD_ID: np.array(buffer_id)})
    finally:
        env_.close()


def _shard_len(s: int, episodes: int, shard_size: int) -> int:
    return min(shard_size, episodes - s * shard_size)


def load_manifest(directory: str | Path) -> dict:
    """The buffer's manifest; FileNotFoundError without one, ValueError naming the file when
    it is not JSON or lacks what the loader reads (format, episodes, shard_size, seed, env)."""
    path = Path(directory) / "manifest.json"
    if not path.exists():
        raise FileNotFoundError(f"no buffer at {directory} (missing manifest.json); "
                                "create one with `python -m ncs_lite collect`")
    if not path.is_file() and not path.is_dir():   # a FIFO: reading it would block for ever
        raise ValueError(f"{path} is not a regular file, expected a buffer manifest (JSON)")
    try:
        m = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as e:     # JSONDecodeError is a ValueError
        raise ValueError(f"{path} is not a readable buffer manifest ({one_line(e)}); "
                         "delete the buffer and collect it again") from None
    problem = _manifest_problem(m)
    if problem:
        raise ValueError(f"{path} is not a valid buffer manifest: {problem}; delete the buffer and collect it again")
    return m


def _manifest_problem(m) -> str | None:
    if not isinstance(m, dict):
        return f"it holds a JSON {type(m).__name__}, expected an object"
    if m.get("format") != FORMAT:
        return f"format {m.get('format')!r}, this code reads format {FORMAT}"
    for name, low in (("episodes", 1), ("shard_size", 1), ("seed", 0)):
        value = m.get(name)
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            return f"{name} must be an integer >= {low}, got {value!r}"
    if not isinstance(m.get("env"), dict):
        return f"env must be the env's config (an object), got {m.get('env')!r}"
    return None


def manifest_hash(directory: str | Path) -> str:
    """sha256 of a buffer's manifest (canonical JSON): names the buffer a model was trained on."""
    text = json.dumps(load_manifest(directory), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def find_buffer(recorded: str | Path, manifest_sha256: str | None) -> Path:
    """The buffer a graph or table names: the directory it recorded when that buffer is there,
    else the buffer in the cache folder whose manifest hash is `manifest_sha256` (the same
    episodes under another folder name: `make`'s, or the code-keyed name of `cached_buffer`
    before an edit of its code). FileNotFoundError naming both when neither is found; with
    `manifest_sha256` None (a file that recorded none), the recorded directory as it is."""
    recorded = Path(recorded)
    if manifest_sha256 is None or ((recorded / "manifest.json").is_file()
                                   and manifest_hash(recorded) == manifest_sha256):
        return recorded
    for manifest in sorted((cache_dir() / "buffers").glob("*/manifest.json")):
        try:
            if manifest_hash(manifest.parent) == manifest_sha256:
                return manifest.parent
        except ValueError:                  # a broken buffer is not the one asked for
            continue
    raise FileNotFoundError(f"no buffer at {recorded} and none with manifest hash {manifest_sha256} in "
                            f"{cache_dir() / 'buffers'}; collect it with `python -m ncs_lite collect` "
                            "and the settings in the graph's info (env, episodes, seed)")


def load_buffer(directory: str | Path) -> dict[str, np.ndarray]:
    """All episodes of a finished buffer as arrays (E = episodes, k = cubes):

    frames (E, 5, 64, 64, 3) uint8, actions (E, 4, 6) float32, positions (E, 5, k, 3),
    masks (E, 5, k, 64, 64) bool, colors (E, k, 3), moved (E, 4) int64.
    """
    directory = Path(directory)
    m = load_manifest(directory)
    n_shards = -(-m["episodes"] // m["shard_size"])
    missing = [s for s in range(n_shards) if not (directory / f"shard-{s:05d}.npz").exists()]
    if missing:
        raise ValueError(f"buffer {directory} is incomplete: {len(missing)} of {n_shards} shards "
                         "missing; rerun the same `collect` command to resume it")
    buffer_id = manifest_hash(directory)
    parts = {k: [] for k in ARRAYS}
    for s in range(n_shards):
        try:
            arrays = _read_shard(directory / f"shard-{s:05d}.npz", _shard_len(s, m["episodes"], m["shard_size"]),
                                 buffer_id, shard_spec(m))
        except ValueError as e:
            raise ValueError(f"{e}; rerun the same `collect` command to collect it again") from None
        for k in ARRAYS:
            parts[k].append(arrays[k])
    return {k: np.concatenate(v) for k, v in parts.items()}


# what a spoilt npz raises: not a zip (truncated: no central directory), a short member,
# a bad CRC or deflate stream, an npy header that does not parse
_UNREADABLE = (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error)


def shard_spec(manifest: dict) -> dict[str, tuple]:
    """What each array of a shard holds per episode, from the manifest: (shape after the
    episode axis, None where the manifest does not say; dtype kinds; finite?). T frames,
    k objects, S x S images."""
    env = manifest.get("env") or {}
    t, k, s = (v if isinstance(v, int) and not isinstance(v, bool) else None
               for v in (manifest.get("frames", FRAMES), env.get("num_objects"), env.get("image_size")))
    return {"frames": ((t, s, s, 3), "u", False), "actions": ((t and t - 1, 6), "f", True),
            "positions": ((t, k, 3), "f", True), "masks": ((t, k, s, s), "b", False),
            "colors": ((k, 3), "f", True), "moved": ((t and t - 1,), "iu", False)}


def _check_arrays(path: Path, arrays: dict, spec: dict) -> None:
    """ValueError naming `path` when an array's shape, dtype or values are not what `spec` says."""
    for name, (shape, kinds, finite) in spec.items():
        v = arrays[name]
        fits = v.ndim == len(shape) + 1 and all(e is None or e == d for e, d in zip(shape, v.shape[1:]))
        if not fits or v.dtype.kind not in kinds or (name == "frames" and v.dtype != np.uint8):
            want = ", ".join("?" if e is None else str(e) for e in shape)
            dtype = {"u": "uint8", "f": "float", "b": "bool", "iu": "integer"}[kinds]
            raise ValueError(f"buffer shard {path} holds {name!r} of shape {v.shape} and dtype {v.dtype}, "
                             f"expected (episodes, {want}) of {dtype} (the manifest's env)")
        if finite and not np.isfinite(v).all():
            raise ValueError(f"buffer shard {path} holds non-finite values in {name!r}; expected finite ones")
    moved, k = arrays["moved"], spec["colors"][0][0]
    if k is not None and moved.size and (moved.min() < -1 or moved.max() >= k):
        raise ValueError(f"buffer shard {path} holds 'moved' values in {moved.min()}..{moved.max()}, expected "
                         f"-1..{k - 1} (the moved object of each step, -1 for none)")


def _read_shard(path: Path, episodes: int, buffer_id: str, spec: dict | None = None) -> dict[str, np.ndarray]:
    """The ARRAYS of one shard. ValueError naming `path` and what was expected when it is not
    a readable npz, lacks an array, holds another number of episodes than the manifest says,
    records another buffer's manifest hash, or (given `spec`, `shard_spec(manifest)`) holds
    an array of another shape or dtype, non-finite numbers, or moved objects that do not exist."""
    if path.exists() and not path.is_file() and not path.is_dir():    # a FIFO would block
        raise ValueError(f"buffer shard {path} is not a regular file, expected an .npz")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
        z = np.load(path) if head == b"PK\x03\x04" else None   # else np.load would unpickle it
    except _UNREADABLE as e:
        raise ValueError(f"buffer shard {path} is not a readable .npz ({one_line(e)})") from None
    if z is None:
        raise ValueError(f"buffer shard {path} is not an .npz ("
                         f"{f'it starts with {head!r}, not a zip header' if head else 'an empty file'})")
    with z:
        missing = [k for k in ARRAYS if k not in z.files]
        if missing:
            raise ValueError(f"buffer shard {path} lacks the arrays {missing}; expected {', '.join(ARRAYS)}")
        try:
            arrays = {k: z[k] for k in ARRAYS}
            stored = str(z[SHARD_ID]) if SHARD_ID in z.files else buffer_id    # none before the hash
        except _UNREADABLE as e:
            raise ValueError(f"buffer shard {path} is corrupted ({one_line(e)})") from None
    if stored != buffer_id:
        raise ValueError(f"buffer shard {path} belongs to another buffer (manifest hash {stored!r}, "
                         f"expected this buffer's {buffer_id!r})")
    for k, v in arrays.items():
        if v.shape[:1] != (episodes,):
            raise ValueError(f"buffer shard {path} holds {v.shape[0] if v.ndim else 0} episodes in {k!r}, "
                             f"expected {episodes} (the manifest's episodes and shard_size)")
    if spec is not None:
        _check_arrays(path, arrays, spec)
    return arrays


def check_actions(directory: str | Path, actions: np.ndarray) -> None:
    """ValueError naming the buffer unless its actions (..., 6) lie in the action space of
    the env its manifest describes (a shard can hold any numbers; `load_buffer` reads no env)."""
    config = dict(load_manifest(directory)["env"])
    try:
        env = make(config.pop("env", None), **config)
    except (TypeError, ValueError) as e:
        raise ValueError(f"buffer {directory}: its manifest's env config builds no env of this code ({e})") from None
    space = env.action_space
    env.close()
    if outside_action_space(actions, space).any():
        raise ValueError(f"buffer {directory} holds actions outside its env's action space (low "
                         f"{space.low.tolist()}, high {space.high.tolist()}); expected the actions `collect` records")


class EpisodeDataset(torch.utils.data.Dataset):
    """(frames, actions) windows of `window` consecutive frames from a buffer.

    item: {"frames": uint8 (T, 64, 64, 3), "actions": float32 (T-1, 6)} with T = window.
    Every start offset of every episode is one item: len = E x (5 - T + 1).
    """

    def __init__(self, directory: str | Path, window: int = FRAMES):
        self.buffer = load_buffer(directory)
        if not isinstance(window, int) or not 1 <= window <= FRAMES:
            raise ValueError(f"window must be an integer in 1..{FRAMES}, got {window!r}")
        self.window = window
        self.frames = torch.from_numpy(self.buffer["frames"])
        self.actions = torch.from_numpy(self.buffer["actions"])
        self.starts = FRAMES - window + 1

    def __len__(self) -> int:
        return len(self.frames) * self.starts

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} windows")
        e, t = divmod(i % len(self), self.starts)
        return {"frames": self.frames[e, t:t + self.window],
                "actions": self.actions[e, t:t + self.window - 1]}


# The code a buffer's episodes come from (rendering, physics, the recorder): the cache folder
# is keyed by it, so an edit there collects a fresh buffer instead of serving the old one.
BUFFER_CODE = ("envs", "data/buffer.py")


def cached_buffer(episodes: int, env: str = "block-rearrange", num_objects: int = 4,
                  seed: int = 0) -> Path:
    """A buffer in the cache folder, keyed by its config, the data format and the code that
    records it (BUFFER_CODE): collected on first use, resumed if interrupted, reused afterwards.

    Checkpoints and graphs name their buffer by its manifest hash, which holds the config but
    not this folder's name: one trained before a code change still fits the buffer collected
    after it (`training.obtain_dslate`, `train --resume`), so nothing retrains."""
    path = cache_dir() / "buffers" / f"{env}-k{num_objects}-e{episodes}-s{seed}-v{FORMAT}-{code_digest(*BUFFER_CODE)}"
    return collect(path, episodes=episodes, env=env, num_objects=num_objects, seed=seed)
