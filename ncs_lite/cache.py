"""Load-or-compute for the kit's expensive passes (the UvA notebooks' "load if present, else
compute"), keyed by what the result depends on: its inputs AND the code that computes it.

    key = {"buffer": buffer_digest(path), "model": digest(model), "code": code_digest("models")}
    value = cached("transitions", lambda: perception.transitions(buffer), **key)

The first call computes `value` and writes `<cache>/computed/<name>-<hash of key>.pt`
(atomically); a later call with an equal key loads it (`torch.load(weights_only=True)`); a
call with any part of the key changed, e.g. after an edit of the code it names, computes
afresh. A fresh clone has no cache and computes everything. Every call prints one line
saying which of the two it did ("computed transitions in 3.0 s, saved to cache", "loaded transitions
from cache"), so a notebook's output shows where each number came from.

What goes in a key: digests (`digest` of tensors, models, graphs; `buffer_digest` of a
buffer's files; `code_digest` of the kit's source files) and plain parameters. The torch
version and thread count are added to every key: another thread count changes the
floating-point order of a result.
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from .utils import atomic_path, cache_dir, relative_to_repo, source_hash

__all__ = ["cached", "cache_path", "digest", "buffer_digest", "code_digest"]

FORMAT = 1


# ------------------------------------------------------------------------------- digests
def _feed(h, obj) -> None:
    """Feed `obj` into the hash `h` canonically (same value -> same bytes)."""
    if isinstance(obj, torch.nn.Module):
        obj = obj.state_dict()
    elif hasattr(obj, "state_dict") and callable(obj.state_dict):   # e.g. TransitionGraph
        obj = obj.state_dict()
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"tensor{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype == object:
            raise TypeError("cannot digest a NumPy object array")
        h.update(f"ndarray{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, dict):
        h.update(f"dict{len(obj)}".encode())
        for k in sorted(obj, key=str):
            _feed(h, str(k))
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"{type(obj).__name__}{len(obj)}".encode())
        for v in obj:
            _feed(h, v)
    elif isinstance(obj, np.generic):
        _feed(h, obj.item())
    elif obj is None or isinstance(obj, (str, int, float, bool)):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    else:
        raise TypeError(f"cannot digest a {type(obj).__name__}: pass tensors, arrays, models, "
                        "graphs, dicts, lists or plain values")


def digest(*objects) -> str:
    """A 16-hex-digit sha256 of tensors, arrays, models (their state_dict), graphs, and
    dicts/lists/plain values holding them. Equal values give equal digests."""
    h = hashlib.sha256()
    for obj in objects:
        _feed(h, obj)
    return h.hexdigest()[:16]


def buffer_digest(directory: str | Path) -> str:
    """Digest of a buffer's content: its manifest and every shard file, byte for byte."""
    directory = Path(directory)
    files = [directory / "manifest.json", *sorted(directory.glob("shard-*.npz"))]
    if not files[0].exists():
        raise FileNotFoundError(f"no buffer at {directory} (missing manifest.json)")
    h = hashlib.sha256()
    for f in files:
        if not f.is_file():              # a FIFO would block the read for ever
            raise ValueError(f"{f} is not a regular file, expected a file of the buffer {directory}")
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def code_digest(*parts: str) -> str:
    """Digest of the kit's source files under `parts` (files or folders of ncs_lite/, e.g.
    "models", "ncs/perception.py"): the code version a cached result is keyed by."""
    if not parts:
        raise ValueError("code_digest needs at least one file or folder of ncs_lite/")
    return source_hash(*parts)


# ----------------------------------------------------------------------- value encoding
# torch.load(weights_only=True) reads tensors, dicts, lists, tuples and plain values, not
# NumPy arrays: arrays are stored as tensors under a marker and come back as arrays.
_ARRAY = "__ndarray__"


def _encode(v):
    if isinstance(v, np.ndarray):
        if v.dtype == object:
            raise TypeError("cannot cache a NumPy object array")
        return {_ARRAY: torch.from_numpy(np.ascontiguousarray(v))}
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, dict):
        if not all(isinstance(k, str) for k in v):
            raise TypeError("cached dicts need string keys")
        return {k: _encode(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return type(v)(_encode(x) for x in v)
    if v is None or isinstance(v, (torch.Tensor, str, int, float, bool)):
        return v
    raise TypeError(f"cannot cache a {type(v).__name__}: return tensors, arrays, dicts, lists, "
                    "tuples or plain values")


def _decode(v):
    if isinstance(v, dict):
        if set(v) == {_ARRAY}:
            return v[_ARRAY].numpy()
        return {k: _decode(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return type(v)(_decode(x) for x in v)
    return v


# -------------------------------------------------------------------------- the helper
def _full_key(name: str, key: dict) -> str:
    full = {"name": name, "format": FORMAT, "torch": torch.__version__,
            "threads": torch.get_num_threads(), **key}
    try:
        return json.dumps(full, sort_keys=True)
    except TypeError as e:
        raise TypeError(f"the key of cached({name!r}) must hold digests and plain values "
                        f"(use cache.digest for tensors and models): {e}") from None


def cache_path(name: str, **key) -> Path:
    """Where `cached(name, ..., **key)` stores its value."""
    if not name or not all(c.isalnum() or c in "-_." for c in name):
        raise ValueError(f"name must be letters, digits, '-', '_' or '.', got {name!r}")
    text = _full_key(name, key)
    return cache_dir() / "computed" / f"{name}-{hashlib.sha256(text.encode()).hexdigest()[:16]}.pt"


def cached(name: str, compute: Callable[[], Any], **key) -> Any:
    """`compute()`, or the value an earlier call with the same `name` and `key` stored.

    key: keyword parts naming every input and the code (digests and plain values). A stored
    file that cannot be read, or holds another key, is recomputed and replaced, and the
    printed line says why.
    """
    path = cache_path(name, **key)
    text = _full_key(name, key)
    why = ""
    if path.exists():
        try:
            stored = torch.load(path, weights_only=True, map_location="cpu")
            if isinstance(stored, dict) and stored.get("key") == text:
                print(f"loaded {name} from cache")
                return _decode(stored["value"])
            why = " (the cached file held another key)"
        except Exception as e:                  # unreadable: a truncated or foreign file
            why = f" (the cached file cannot be read: {type(e).__name__})"
    t0 = time.perf_counter()
    value = compute()
    with atomic_path(path) as tmp:          # readers see the old file or the new one, never half of one
        torch.save({"format": FORMAT, "key": text, "value": _encode(value)}, tmp)
    print(f"computed {name} in {time.perf_counter() - t0:.1f} s, saved to cache{why}")
    return value


def load_or_train(path: Path, *, unfit: Callable[[Path], str | None], unfinished: Callable[[Path], str | None],
                  train: Callable[..., Any], load: Callable[[Path], Any], who: str,
                  from_scratch: bool = False) -> Any:
    """The notebooks' "load the checkpoint if present, else train" for the training run at
    `path` (a dSLATE, `inference.obtain_dslate`; BC or IQL, `baselines.runs.obtain_policy`):
    a run there that fits (`unfit(path)` None, else why not) and is finished
    (`unfinished(path)` None, else where it stopped) is loaded (`load(path)`); an unfinished one
    is resumed (`train(resume=True, force=False)`); an unfit one, or any with `from_scratch`,
    is trained again from scratch (`force=True`); no run, trained. Each decision but the first
    is printed as `<who>: ...`. One process at a time decides and trains: another that asks for
    the same run meanwhile (a second notebook, a parallel test worker) waits, then loads it."""
    with _one_process_at_a_time(path, who):
        resume = force = False
        if path.exists() and not from_scratch:
            why = unfit(path)
            if why is None:
                left = unfinished(path)
                if left is None:
                    return load(path)
                resume = True
                print(f"{who}: resuming {relative_to_repo(path)} {left}")
            else:
                force = True
                print(f"{who}: retraining {relative_to_repo(path)} from scratch: {why}")
        elif path.exists():
            force = True
            print(f"{who}: retraining {relative_to_repo(path)} from scratch (train_from_scratch=True)")
        train(resume=resume, force=force)
        return load(path)


@contextlib.contextmanager
def _one_process_at_a_time(path: Path, who: str):
    """Hold an exclusive lock on `<path>.obtain.lock`, waiting (and saying so) while another
    process holds it. The file stays beside the run: a lock file removed on release could be
    held by a waiter on the removed file and by a newcomer on a new one at once."""
    lock = Path(f"{path}.obtain.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as f:                  # closing the file releases the lock
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"{who}: another process is making {relative_to_repo(path)}; waiting for it")
            fcntl.flock(f, fcntl.LOCK_EX)
        yield
