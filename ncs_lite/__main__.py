"""Command line: `python -m ncs_lite COMMAND ...` (`--help` lists the commands)."""
from __future__ import annotations

import argparse
import importlib
import json
import sys

# Modules that add their own subcommand through `add_subcommand(subparsers)`.
COMMAND_MODULES = ("ncs_lite.training",)


def _collect(args):
    from .data import collect

    out = collect(args.out, episodes=args.episodes, env=args.env, num_objects=args.num_objects,
                  seed=args.seed, shard_size=args.shard_size)
    print(f"buffer ready: {out}")


def _bench(args):
    from .bench import run

    print(json.dumps(run(args.name, args.out), indent=2))


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
    p.add_argument("name", help="envs | train | kmeans")
    p.add_argument("--out", help="JSON file to write")
    p.set_defaults(func=_bench)

    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        module.add_subcommand(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
