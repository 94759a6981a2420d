"""Command line: `python -m ncs_lite COMMAND ...` (`--help` lists the commands).

Every command is here, its options (`build_parser`) beside a short function that reads them
and calls the library, so no module of the library parses arguments.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .experiments import reproduce
from .baselines import MPC_PRESETS, SetGraph
from .baselines.nf import set_graph_from_transitions
from .baselines.runs import load_trained_policy, policy_config, train_policy
from .bench import run as run_benchmark
from .config import (CLUSTERS_BY_ENV, EDGE_ACTION_BY_ENV, STATE_BY_ENV, DSlateConfig, apply_overrides, get_preset,
                     ncs_config, parse_override, section_config, split_overrides, to_dict)
from .data import collect, load_manifest, manifest_hash
from .evaluation import (NEED_NAMES, NEEDS, TaskSet, agent_factory, check_graph_actions, check_graph_reading, evaluate,
                         summarize, write_csv)
from .inference import load_dslate, read_checkpoint, shipped_asset
from .ncs.graph import BUILD_FIELDS, TransitionGraph, buffer_perception, graph_from_buffer
from .ncs.perception import buffer_transitions, slot_read
from .training import EXTENDABLE, train
from .utils import check_file_env, check_out_file, provenance, recorded_env, relative_to_repo, sha256_file


def add_run_arguments(p) -> None:
    """`--set` and `--allow-dirty`, shared by every command that takes a config."""
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override one config field, e.g. --set train.lr=1e-3 (repeatable)")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write into figures/ or ncs_lite/assets/ from a tree with uncommitted changes "
                        "(recorded as dirty)")


def _collect(args):
    out = collect(args.out, episodes=args.episodes, env=args.env, num_objects=args.num_objects,
                  seed=args.seed, shard_size=args.shard_size)
    print(f"buffer ready: {out}")


def _bench(args):
    if args.out is not None:
        check_out_file(args.out, "JSON")          # before the benchmark, not after it
    print(json.dumps(run_benchmark(args.name, args.out), indent=2))


def _graph(args):
    if (args.checkpoint is None) == (not args.oracle):
        raise ValueError("give exactly one of --checkpoint CKPT (learned NCS) or --oracle")
    check_out_file(args.out, "graph")
    env = load_manifest(args.data)["env"]["env"]          # Tables 3-4 give each env's defaults
    if args.clusters is not None and any(o.split("=", 1)[0].strip() == "ncs.clusters" for o in args.overrides):
        raise ValueError(f"give the number of nodes once: --clusters {args.clusters} or --set ncs.clusters=N, "
                         "not both")
    clusters = args.clusters if args.clusters is not None else CLUSTERS_BY_ENV.get(env)   # 0 is refused
    cfg = ncs_config(args.overrides, clusters=clusters, seed=args.seed,
                     state=args.state or STATE_BY_ENV.get(env), edge_action=EDGE_ACTION_BY_ENV.get(env))
    model = None if args.oracle else load_dslate(args.checkpoint)
    if model is not None:
        check_file_env("--checkpoint", args.checkpoint, model.checkpoint_info.get("env"), env)
    made = provenance(args.out, args.allow_dirty)
    graph = graph_from_buffer(cfg, model, args.data)      # the buffer pass is cached
    graph.info.update(checkpoint=relative_to_repo(args.checkpoint) if args.checkpoint else None,
                      checkpoint_sha256=sha256_file(args.checkpoint) if args.checkpoint else None,
                      overrides=list(args.overrides), **made)
    graph.save(args.out)
    print(json.dumps({"out": args.out, "state": graph.state, "nodes": graph.num_nodes,
                      "edges": graph.num_edges, "coverage": graph.info.get("coverage")}))


def _evaluate(args):
    if args.out:
        check_out_file(args.out, "CSV")         # before the episodes, not after them
    sections = split_overrides(args.overrides, ("ncs", "mpc"))
    needs = NEEDS.get(args.method, ())
    # without a path, a method runs from the shipped `reduced` assets of --env
    paths = {"graph": args.graph, "model": args.checkpoint, "policy": args.policy}
    for need, path in paths.items():            # a file the method would not read is refused, not ignored
        if path is not None and args.method in NEEDS and need not in needs:
            reads = " and ".join(f"a {NEED_NAMES[n]}" for n in needs) or "no file"
            raise ValueError(f"method {args.method!r} reads no {NEED_NAMES[need]}, got {path}; it reads {reads}")
    built = [o for o in sections["ncs"] if parse_override(o)[0] in BUILD_FIELDS]
    if built:                                   # fields of how a graph is built, which acting never reads
        raise ValueError(f"--set {built[0]}: evaluate reads a built graph (its nodes, k-means seed and buffer "
                         f"pass are fixed); set {', '.join(BUILD_FIELDS)} when building it "
                         "(python -m ncs_lite graph)")
    if sections["mpc"] and args.method != "mpc":
        raise ValueError(f"--set {sections['mpc'][0]}: mpc fields set MPC's planner; method {args.method!r} has none")
    asked = args.state or next((parse_override(o)[1] for o in sections["ncs"]
                                if parse_override(o)[0] == "ncs.state"), None)
    state = asked or STATE_BY_ENV.get(args.env, "mask")      # the shipped graph to default to
    for need in needs:
        paths[need] = paths[need] or shipped_asset(args.env, args.method, need, state)
    graph = None
    if "graph" in needs:
        graph = (SetGraph if args.method.startswith("nf") else TransitionGraph).load(paths["graph"])
        check_file_env("--graph", paths["graph"], recorded_env(graph.info), args.env)
    # the agent reads the kind of state its graph was built on: unless --state (or
    # --set ncs.state) says otherwise, and then the graph must agree (checked below)
    cfg = ncs_config(sections["ncs"], state=args.state if asked or graph is None else graph.state)
    mpc = section_config(MPC_PRESETS[args.preset], "mpc", sections["mpc"]) if args.method == "mpc" else None
    if args.out:
        provenance(args.out, args.allow_dirty)
    model = load_dslate(paths["model"]) if "model" in needs else None
    policy = load_trained_policy(paths["policy"], args.method) if "policy" in needs else None
    trained_on = {"--checkpoint": (paths["model"], model.checkpoint_info.get("env") if model else None),
                  "--policy": (paths["policy"], policy.info.get("env") if policy else None)}
    for flag, (path, env) in trained_on.items():     # the files record their env
        if env is not None and env != args.env:
            raise ValueError(f"{flag} {path} was trained on {env!r}, not --env {args.env!r}; evaluate it with "
                             f"--env {env}, or pass a {flag[2:]} trained on {args.env}")
    tasks = TaskSet(env=args.env, num_objects=args.num_objects, goal=args.goal,
                    num_constrained=args.num_constrained, horizon_multiplier=args.horizon_multiplier,
                    action_noise=args.action_noise, episodes=args.episodes, seed=args.seed)
    if graph is not None:       # the kind and size of state its nodes are, and its actions fit the env
        env = tasks.make_env()
        try:
            check_graph_reading(graph, args.method, cfg, model)
            check_graph_actions(graph, env.action_space)
        except ValueError as exc:
            raise ValueError(f"--graph {paths['graph']}: {exc}") from None
        finally:
            env.close()
    rows = evaluate(agent_factory(args.method, graph=graph, model=model, seed=args.seed, ncs=cfg,
                                  policy=policy, mpc=mpc), tasks, args.method)
    if args.out:
        write_csv(rows, args.out)
    print(json.dumps(summarize(rows)[0]))


def config_from_args(args) -> DSlateConfig:
    """The preset of `args.preset` with `--seed` and `--set` applied."""
    cfg = get_preset(args.preset, getattr(args, "env", "block-rearrange"))
    if getattr(args, "seed", None) is not None:
        if args.seed < 0:
            raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
        cfg.train.seed = args.seed
    return apply_overrides(cfg, args.overrides)


def _train(args) -> None:
    cfg = config_from_args(args)
    t0 = time.perf_counter()
    path = train(cfg, args.data, args.out, resume=args.resume, device=args.device,
                 max_steps=args.steps, env=args.env, precision=args.precision, compile=args.compile,
                 force=args.force, overrides=args.overrides, allow_dirty=args.allow_dirty,
                 extend=args.extend)
    ckpt = read_checkpoint(path)
    print(f"wrote {path} (step {ckpt['step']}, {ckpt['precision']}, loss {ckpt['last'].get('loss')}, "
          f"{ckpt['seconds'] / 60:.1f} min of training, {(time.perf_counter() - t0) / 60:.1f} min "
          f"this run); losses in {Path(path).with_suffix('.csv')}")


def _train_baseline(args) -> None:
    cfg = policy_config(args.method, args.preset, args.overrides, args.seed)
    model, log = train_policy(args.method, cfg, args.data, args.out, args.env, resume=args.resume,
                              force=args.force, overrides=args.overrides, allow_dirty=args.allow_dirty)
    print(json.dumps({"out": args.out, "method": args.method, "steps": len(log),
                      "last": {k: round(v, 5) for k, v in log[-1].items() if k != "step"} if log else None}))


def _graph_nf(args) -> None:
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
    perception = buffer_perception(cfg, model, args.data)        # as `graph` reads the buffer
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


def _reproduce(args) -> None:
    print(json.dumps(reproduce.run_table(args.table, args), indent=2, default=str))


def build_parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per `_add_<command>`."""
    parser = argparse.ArgumentParser(prog="python -m ncs_lite", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_collect, _add_bench, _add_graph, _add_evaluate, _add_train, _add_train_baseline,
                _add_graph_nf, _add_reproduce):
        add(sub)
    return parser


def _add_collect(sub) -> None:
    """The `collect` command's arguments."""
    p = sub.add_parser("collect", help="collect a buffer of random pick-and-move episodes")
    p.add_argument("--env", default="block-rearrange")
    p.add_argument("--episodes", type=int, required=True)
    p.add_argument("--num-objects", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shard-size", type=int, default=100)
    p.add_argument("--out", required=True)
    p.set_defaults(func=_collect)


def _add_bench(sub) -> None:
    """The `bench` command's arguments."""
    p = sub.add_parser("bench", help="run a benchmark, write JSON")
    p.add_argument("name", help="envs | train | kmeans | ncs")
    p.add_argument("--out", help="JSON file to write")
    p.set_defaults(func=_bench)


def _add_graph(sub) -> None:
    """The `graph` command's arguments."""
    p = sub.add_parser("graph", help="build the NCS transition graph of a buffer")
    p.add_argument("--checkpoint", help="dSLATE checkpoint (learned entities)")
    p.add_argument("--oracle", action="store_true", help="ground-truth entities instead")
    p.add_argument("--data", required=True, help="buffer directory (python -m ncs_lite collect)")
    p.add_argument("--clusters", type=int, default=None,
                   help="nodes (= --set ncs.clusters; default Table 4's: 30 block-rearrange, 45 robogym-rearrange, "
                        "47 block-stacking)")
    p.add_argument("--seed", type=int, default=None, help="k-means seed (= --set ncs.seed)")
    p.add_argument("--state", default=None,
                   help="entity state, Table 3: mask | slot (= --set ncs.state; default Table 3's: mask "
                        "block-rearrange, slot robogym-rearrange and block-stacking; the oracle's "
                        "stand-in for slot states is the object's position)")
    p.add_argument("--out", required=True)
    add_run_arguments(p)
    p.set_defaults(func=_graph)


def _add_evaluate(sub) -> None:
    """The `evaluate` command's arguments."""
    p = sub.add_parser("evaluate", help="evaluate a method on a seeded task set")
    p.add_argument("--env", default="block-rearrange")
    p.add_argument("--method", required=True,
                   help="ncs | ncs-oracle | nf | nf-oracle | mpc | bc | iql | random | random-object "
                        "(a calibration row: a random object to a random place)")
    p.add_argument("--checkpoint", help="dSLATE checkpoint (ncs, nf, mpc; default: the shipped one)")
    p.add_argument("--graph", help="NCS graph (ncs, ncs-oracle; `graph`) or NF graph (nf, nf-oracle; "
                                   "`graph-nf`); default: the shipped one for the method and state")
    p.add_argument("--policy", help="trained BC or IQL checkpoint (`train-baseline`; default: the shipped one)")
    p.add_argument("--preset", default="reduced", choices=["ci", "reduced", "paper"],
                   help="mpc: CEM settings (reduced and paper: Appendix B's)")
    p.add_argument("--state", default=None,
                   help="mask | slot (= --set ncs.state); default: the state the graph was built on, "
                        "a different one is refused")
    p.add_argument("--num-objects", type=int, default=4)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--goal", default="complete", help="complete | partial")
    p.add_argument("--num-constrained", type=int)
    p.add_argument("--horizon-multiplier", type=float, default=4.0)
    p.add_argument("--action-noise", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="tidy CSV, one row per episode")
    add_run_arguments(p)
    p.set_defaults(func=_evaluate)


def _add_train(sub) -> None:
    """The `train` command's arguments."""
    p = sub.add_parser("train", help="train dSLATE on an experience buffer",
                              description="Train dSLATE (dVAE + slot attention + SLATE decoder + "
                                          "dynamics) on a buffer made by `collect`.")
    p.add_argument("--env", default="block-rearrange", help="environment the buffer comes from")
    p.add_argument("--preset", default="reduced", help="config preset: ci, reduced or paper")
    p.add_argument("--data", required=True, help="buffer directory (from `collect`)")
    p.add_argument("--out", required=True, help="checkpoint path (.pt); the loss CSV goes beside it")
    p.add_argument("--resume", action="store_true", help="continue from --out")
    p.add_argument("--extend", default=None, metavar="CHECKPOINT",
                   help="continue a finished run (another file) into --out under a schedule that only adds "
                        f"steps after its end ({', '.join(EXTENDABLE)}), e.g. the render phase")
    p.add_argument("--steps", type=int, default=None,
                   help="stop at this global step (default: the preset's full schedule)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    p.add_argument("--precision", default=None, choices=["auto", "bf16", "fp32"],
                   help="override the preset's precision")
    p.add_argument("--compile", action="store_true",
                   help="torch.compile the forward (faster steps after a compilation pause)")
    p.add_argument("--seed", type=int, default=None,
                   help="override the preset's train.seed (initial weights and batch order)")
    add_run_arguments(p)
    p.add_argument("--force", action="store_true",
                   help="delete an existing run at --out (checkpoint and loss log) and start afresh")
    p.set_defaults(func=_train)


def _add_train_baseline(sub) -> None:
    """The `train-baseline` command's arguments."""
    p = sub.add_parser("train-baseline", help="train the BC or IQL baseline on a buffer")
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


def _add_graph_nf(sub) -> None:
    """The `graph-nf` command's arguments."""
    p = sub.add_parser("graph-nf", help="build the NF baseline's graph over whole entity sets")
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


def _add_reproduce(sub) -> None:
    """The `reproduce` command's arguments."""
    p = sub.add_parser("reproduce",
                              help="regenerate a README table (seeds, clusters, baselines, robogym, stacking, fig9, fig10, "
                                   "fig11)",
                              description=reproduce.__doc__.split("\n\n")[0])
    p.add_argument("table", choices=sorted(reproduce.TABLES))
    p.add_argument("--preset", default="reduced", help="seeds: the recipe to train; baselines, fig10, fig11: "
                   "the assets (and fig10, fig11: the tasks per point)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds: training seeds (the table "
                   "keeps its rows of other seeds measured with the same settings and code)")
    p.add_argument("--runs", default=None, help="seeds: folder of the per-seed runs (default: "
                   "<cache>/seeds)")
    p.add_argument("--task-seed", type=int, default=0,
                   help="seeds: the seed of the tasks NCS is measured on (default 0, every table's; another: "
                   "tasks no table has used, as `figures/tables/shipped/` measures the shipped seed on)")
    p.add_argument("--segmentation-only", action="store_true",
                   help="seeds: train segmentation alone, in about half a run's time (the --set list "
                   "ncs_lite.experiments.reproduce.SEGMENTATION_ONLY): for ablations of what concerns segmentation")
    p.add_argument("--checkpoint", help="clusters, robogym, stacking: checkpoint (default: the shipped one)")
    p.add_argument("--graph", help="robogym, stacking: the learned NCS graph on slot states (default: the shipped one)")
    p.add_argument("--oracle-graph", help="robogym, stacking: the position oracle's graph (default: the shipped one)")
    p.add_argument("--episodes", type=int, default=None,
                   help="tasks per object count (default: 100; baselines: the preset's, reduced 50); fig10, fig11: "
                   "tasks per point (default: the preset's, ncs_lite.experiments.stress.TASKS)")
    p.add_argument("--mpc-episodes", type=int, default=None,
                   help="baselines: MPC's tasks per object count (default: the preset's, reduced 25); fig10, "
                   "fig11: MPC's tasks per point")
    p.add_argument("--executor", default="local",
                   help="fig10, fig11: where the sweep's jobs run: local (this machine's worker processes) or "
                   "submitit (a Slurm job array when Slurm is found, else local processes; needs the "
                   "`sweeps` extra)")
    p.add_argument("--sweep-folder", default=None,
                   help="fig10, fig11 with --executor submitit: the jobs' pickles and logs (default: "
                   "<cache>/submitit/<job id>)")
    p.add_argument("--env", default="block-rearrange", help="seeds: the environment to train on; baselines: "
                   "the environment (its shipped assets)")
    p.add_argument("--objects", type=int, nargs="+", default=None,
                   help="robogym, stacking, seeds: object counts to evaluate (default: robogym 4 5 6 7, "
                   "stacking 3 4 5 6, block-rearrange seeds 4 7)")
    p.add_argument("--out-dir", default=None, help="table folder (default: figures/tables)")
    add_run_arguments(p)
    p.set_defaults(func=_reproduce)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ValueError, OSError, FloatingPointError) as exc:   # bad input or file, a diverged run: one line
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
