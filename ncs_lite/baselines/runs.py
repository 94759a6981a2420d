"""Training the learned baselines and building NF's graph: the commands and the notebooks' cache.

    python -m ncs_lite train-baseline --method bc --data DIR --out bc.pt [--preset reduced]
        [--set bc.steps=2000] [--resume | --force]
    python -m ncs_lite graph-nf (--checkpoint CKPT | --oracle) --data DIR --out nf.pt
        [--bind-graph GRAPH] [--state mask|slot]
    model, path = obtain_policy("bc", "reduced")      # notebooks: train once, then reuse

A run records its env, buffer (manifest hash), config, `--set` overrides, code version and
commit. `--resume` continues a run only with the same config, env and buffer; an existing
run at `--out` is never replaced unless `--force`.
"""
from __future__ import annotations

import json
from pathlib import Path

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
    from ..config import section_config

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
    from ..cache import code_digest
    from ..data import load_buffer, load_manifest, manifest_hash
    from ..envs import make
    from ..utils import check_file_env, check_out_file, provenance, recorded_env, relative_to_repo

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
    from dataclasses import asdict

    from ..cache import code_digest
    from ..data import load_manifest, manifest_hash

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
    from ..cache import load_or_train
    from ..data import cached_buffer
    from ..inference import TRAIN_EPISODES
    from ..utils import cache_dir

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


# ---------------------------------------------------------------------- CLI
def _train_baseline(args) -> None:
    cfg = policy_config(args.method, args.preset, args.overrides, args.seed)
    model, log = train_policy(args.method, cfg, args.data, args.out, args.env, resume=args.resume,
                              force=args.force, overrides=args.overrides, allow_dirty=args.allow_dirty)
    print(json.dumps({"out": args.out, "method": args.method, "steps": len(log),
                      "last": {k: round(v, 5) for k, v in log[-1].items() if k != "step"} if log else None}))


def _graph_nf(args) -> None:
    from ..config import ncs_config, to_dict
    from ..data import load_manifest, manifest_hash
    from ..inference import load_dslate
    from ..ncs.graph import TransitionGraph
    from ..ncs.perception import buffer_transitions, graph_perception, slot_read
    from ..utils import check_file_env, check_out_file, provenance, recorded_env, relative_to_repo
    from .nf import set_graph_from_transitions

    if (args.checkpoint is None) == (not args.oracle):
        raise ValueError("give exactly one of --checkpoint CKPT (learned NF) or --oracle")
    check_out_file(args.out, "NF graph")
    env = load_manifest(args.data)["env"]["env"]
    bind = TransitionGraph.load(args.bind_graph) if args.bind_graph else None
    if bind is not None:
        check_file_env("--bind-graph", args.bind_graph, recorded_env(bind.info), env)
    model = None if args.oracle else load_dslate(args.checkpoint)
    if model is not None:
        check_file_env("--checkpoint", args.checkpoint, model.checkpoint_info.get("env"), env)
    if bind is not None and args.clusters is not None and args.clusters != bind.num_nodes:
        raise ValueError(f"--clusters {args.clusters}: the entities bind to --bind-graph's {bind.num_nodes} "
                         "nodes; drop --clusters (it sets NF's own k-means, without --bind-graph)")
    cfg = ncs_config(args.overrides, clusters=bind.num_nodes if bind else args.clusters,
                     state=args.state or (bind.state if bind else None))
    made = provenance(args.out, args.allow_dirty)
    perception = graph_perception(cfg, model)                    # as `graph` reads the buffer
    transitions = buffer_transitions(perception, args.data)      # cached, shared with `graph`
    try:
        graph = set_graph_from_transitions(transitions, bind, clusters=cfg.clusters, state=cfg.state, seed=cfg.seed)
    except ValueError as exc:
        if bind is None:
            raise
        raise ValueError(f"--bind-graph {args.bind_graph}: {exc}") from None
    graph.info.update(env=env, data=relative_to_repo(args.data), manifest_sha256=manifest_hash(args.data),
                      checkpoint=relative_to_repo(args.checkpoint) if args.checkpoint else None,
                      bind_graph=relative_to_repo(args.bind_graph) if args.bind_graph else None,
                      oracle=args.oracle, ncs=to_dict(cfg), overrides=list(args.overrides),
                      **slot_read(perception), **made)
    graph.save(args.out)
    print(json.dumps({"out": args.out, "state": graph.state, "scene_nodes": graph.num_nodes,
                      "edges": graph.num_edges, "entity_nodes": int(graph.centroids.shape[0])}))


def add_subcommand(subparsers) -> None:
    """Register `train-baseline` and `graph-nf` on the CLI (ncs_lite/__main__.py)."""
    from ..training import add_run_arguments

    p = subparsers.add_parser("train-baseline", help="train the BC or IQL baseline on a buffer")
    p.add_argument("--method", required=True, help="bc | iql")
    p.add_argument("--env", default="block-rearrange", help="environment the buffer comes from")
    p.add_argument("--preset", default="reduced", help="ci | reduced | paper")
    p.add_argument("--data", required=True, help="buffer directory (python -m ncs_lite collect)")
    p.add_argument("--out", required=True, help="checkpoint path (.pt)")
    p.add_argument("--seed", type=int, default=None, help="= --set METHOD.seed")
    p.add_argument("--resume", action="store_true", help="continue the run at --out")
    p.add_argument("--force", action="store_true", help="replace an existing run at --out")
    add_run_arguments(p)
    p.set_defaults(func=_train_baseline)

    p = subparsers.add_parser("graph-nf", help="build the NF baseline's graph over whole entity sets")
    p.add_argument("--checkpoint", help="dSLATE checkpoint (learned entities)")
    p.add_argument("--oracle", action="store_true", help="ground-truth entities instead")
    p.add_argument("--data", required=True, help="buffer directory (python -m ncs_lite collect)")
    p.add_argument("--bind-graph", help="NCS graph whose entity nodes bind NF's entities (default: NF's "
                                        "own k-means with --clusters)")
    p.add_argument("--clusters", type=int, default=None, help="entity nodes without --bind-graph (= --set ncs.clusters)")
    p.add_argument("--state", default=None, help="mask | slot (default: the --bind-graph's, else mask)")
    p.add_argument("--out", required=True)
    add_run_arguments(p)
    p.set_defaults(func=_graph_nf)


__all__ = ["POLICIES", "load_trained_policy", "obtain_policy", "policy_config", "train_policy"]
