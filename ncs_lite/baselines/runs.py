"""Training the learned baselines (BC, IQL): what `train-baseline` runs, and the notebooks' cache.

    python -m ncs_lite train-baseline --method bc --data DIR --out bc.pt [--preset reduced]
        [--set bc.steps=2000] [--resume | --force]
    model, path = obtain_policy("bc", "reduced")      # notebooks: train once, then reuse

A run records its env, buffer (manifest hash), config, `--set` overrides, code version and
commit. `--resume` continues a run only with the same config, env and buffer; an existing
run at `--out` is never replaced unless `--force`. The commands' options: ncs_lite/__main__.py
(which also builds NF's graph, `graph-nf`, with `nf.set_graph_from_transitions`).
"""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from ..cache import code_digest, load_or_train
from ..config import section_config
from ..data import cached_buffer, load_buffer, load_manifest, manifest_hash
from ..envs import make
from ..inference import TRAIN_EPISODES
from ..utils import cache_dir, check_out_file, provenance, relative_to_repo
from .bc import bc_config, load_bc, train_bc
from .goal_conditioned import read_checkpoint
from .iql import iql_config, load_iql, train_iql

POLICIES = {"bc": (bc_config, train_bc, load_bc), "iql": (iql_config, train_iql, load_iql)}
CHECKPOINT_EVERY = 500
# the code a trained policy depends on (its cache key besides config and buffer)
POLICY_CODE = ("baselines/goal_conditioned.py", "baselines/bc.py", "baselines/iql.py")


def _method(method: str) -> str:
    if method not in POLICIES:
        raise ValueError(f"unknown learned baseline {method!r}; expected one of {', '.join(POLICIES)}")
    return method


def policy_config(method: str, preset: str = "reduced", overrides=(), seed: int | None = None):
    """The `preset` config of BC or IQL with `--seed` and `--set METHOD.FIELD=VALUE` applied."""
    cfg = POLICIES[_method(method)][0](preset)
    if seed is not None:
        cfg.seed = int(seed)
    return section_config(cfg, method, overrides)


def load_trained_policy(path, method: str | None = None):
    """A BC or IQL model from its checkpoint; the kind is read from the file (and must be
    `method` when given)."""
    kind = read_checkpoint(path, method)["kind"]
    if kind not in POLICIES:
        raise ValueError(f"{path} is a {kind!r} checkpoint, expected one of {', '.join(POLICIES)}")
    return POLICIES[kind][2](path)


def train_policy(method: str, cfg, data, out, env: str = "block-rearrange", *, resume: bool = False,
                 force: bool = False, overrides=(), allow_dirty: bool = False):
    """Train BC or IQL (`cfg`) on the buffer directory `data` into the checkpoint `out`.
    Returns (model, log)."""
    _method(method)
    out = check_out_file(out, f"{method} checkpoint")
    if resume and force:
        raise ValueError("give --resume or --force, not both")
    made = provenance(out, allow_dirty)
    env_obj = make(env)
    try:
        action_space = env_obj.action_space
    finally:
        env_obj.close()
    collected_on = load_manifest(data)["env"].get("env", env)
    if collected_on != env:
        raise ValueError(f"the buffer {data} was collected on {collected_on!r}, not --env {env!r}")
    info = {"env": env, "data": relative_to_repo(data), "manifest_sha256": manifest_hash(data),
            "overrides": list(overrides), "code": code_digest(*POLICY_CODE), **made}
    if out.exists() and not (resume or force):
        raise ValueError(f"{out} already holds a {method} run: pass --resume to continue it or --force "
                         "to replace it")
    if resume:
        if not out.exists():
            raise FileNotFoundError(f"--resume: no {method} run at {out}")
        stored = read_checkpoint(out, method)["info"]
        for key in ("env", "manifest_sha256"):
            if stored.get(key) != info[key]:
                raise ValueError(f"--resume: {out} was trained with {key} {stored.get(key)!r}, not {info[key]!r}")
    train = POLICIES[method][1]
    return train(load_buffer(data), action_space, cfg, out=out, checkpoint_every=CHECKPOINT_EVERY,
                 resume=resume, info=info)


def _unfit(path: Path, method: str, cfg, env: str, data: Path) -> str | None:
    """Why the cached policy at `path` cannot be reused or resumed, or None."""
    try:
        ckpt = read_checkpoint(path, method)
    except ValueError as e:
        return f"it cannot be read ({e})"
    info = ckpt["info"]
    if json.loads(json.dumps(ckpt["config"])) != json.loads(json.dumps(asdict(cfg))):   # tuples read back as lists
        return "it was trained with another config"
    if info.get("env") != env or info.get("manifest_sha256") != manifest_hash(data):
        return "it was trained on another env or buffer"
    if info.get("code") != code_digest(*POLICY_CODE):
        return "the baselines' training code changed since"
    return None


def obtain_policy(method: str, preset: str = "reduced", seed: int = 0, env: str = "block-rearrange"):
    """The notebooks' trained BC or IQL: `<cache>/checkpoints/<method>-<env>-<preset>-s<seed>.pt`,
    trained on the 4-object buffer dSLATE trains on (`inference.TRAIN_EPISODES[preset]`).
    A finished, fitting run is reused, an interrupted one resumed, an unfit one (another
    config, buffer or code) retrained; each decision is printed. Returns (model, path)."""
    cfg = policy_config(method, preset, seed=seed)
    path = cache_dir() / "checkpoints" / f"{method}-{env}-{preset}-s{seed}.pt"
    data = cached_buffer(TRAIN_EPISODES[preset], env=env, num_objects=4, seed=0)

    def unfinished(ckpt: Path) -> str | None:
        step = int(read_checkpoint(ckpt, method)["step"])
        return None if step >= cfg.steps else f"at step {step} of {cfg.steps}"

    model = load_or_train(path, unfit=lambda ckpt: _unfit(ckpt, method, cfg, env, data), unfinished=unfinished,
                          train=lambda resume, force: train_policy(method, cfg, data, path, env, resume=resume,
                                                                   force=force),
                          load=lambda ckpt: load_trained_policy(ckpt, method), who="obtain_policy")
    return model, path          # with its log, info and step


__all__ = ["POLICIES", "load_trained_policy", "obtain_policy", "policy_config", "train_policy"]
