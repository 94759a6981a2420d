"""Command line: `python -m ncs_lite COMMAND ...` (`--help` lists the commands)."""
from __future__ import annotations

import argparse
import importlib
import json
import sys

from .training import add_run_arguments

# Modules that add their own subcommand through `add_subcommand(subparsers)`.
COMMAND_MODULES = ("ncs_lite.training", "ncs_lite.baselines.runs", "ncs_lite.reproduce")


def _collect(args):
    from .data import collect

    out = collect(args.out, episodes=args.episodes, env=args.env, num_objects=args.num_objects,
                  seed=args.seed, shard_size=args.shard_size)
    print(f"buffer ready: {out}")


def _bench(args):
    from .bench import run
    from .utils import check_out_file

    if args.out is not None:
        check_out_file(args.out, "JSON")          # before the benchmark, not after it
    print(json.dumps(run(args.name, args.out), indent=2))


def _graph(args):
    from .config import ncs_config
    from .data import load_manifest
    from .inference import load_dslate
    from .ncs.graph import CLUSTERS_BY_ENV, EDGE_ACTION_BY_ENV, STATE_BY_ENV, graph_from_buffer
    from .utils import check_file_env, check_out_file, provenance, relative_to_repo, sha256_file

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
    from .baselines import MPC_PRESETS, SetGraph
    from .baselines.runs import load_trained_policy
    from .config import ncs_config, parse_override, section_config, split_overrides
    from .evaluation import (NEED_NAMES, NEEDS, TaskSet, agent_factory, check_graph_actions, check_graph_reading, evaluate,
                             summarize, write_csv)
    from .inference import load_dslate, shipped_asset
    from .ncs.graph import BUILD_FIELDS, TransitionGraph
    from .utils import check_file_env, check_out_file, provenance, recorded_env

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
    from .ncs.graph import STATE_BY_ENV

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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m ncs_lite", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("collect", help="collect a buffer of random pick-and-move episodes")
    p.add_argument("--env", default="block-rearrange")
    p.add_argument("--episodes", type=int, required=True)
    p.add_argument("--num-objects", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shard-size", type=int, default=100)
    p.add_argument("--out", required=True)
    p.set_defaults(func=_collect)

    p = sub.add_parser("bench", help="run a benchmark, write JSON")
    p.add_argument("name", help="envs | train | kmeans | ncs")
    p.add_argument("--out", help="JSON file to write")
    p.set_defaults(func=_bench)

    p = sub.add_parser("graph", help="build the NCS transition graph of a buffer")
    p.add_argument("--checkpoint", help="dSLATE checkpoint (learned entities)")
    p.add_argument("--oracle", action="store_true", help="ground-truth entities instead")
    p.add_argument("--data", required=True, help="buffer directory (python -m ncs_lite collect)")
    p.add_argument("--clusters", type=int, default=None,
                   help="nodes (= --set ncs.clusters; default Table 4's: 30 block-rearrange, 45 robogym-rearrange)")
    p.add_argument("--seed", type=int, default=None, help="k-means seed (= --set ncs.seed)")
    p.add_argument("--state", default=None,
                   help="entity state, Table 3: mask | slot (= --set ncs.state; default Table 3's: mask "
                        "block-rearrange, slot robogym-rearrange; the oracle's stand-in for slot "
                        "states is the object's position)")
    p.add_argument("--out", required=True)
    add_run_arguments(p)
    p.set_defaults(func=_graph)

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

    for name in COMMAND_MODULES:
        importlib.import_module(name).add_subcommand(sub)
    return parser


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
