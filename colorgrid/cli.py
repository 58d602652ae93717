"""The ``colorgrid`` command line: one sub-command per job."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from colorgrid.cli_config import add_config_arguments, config_from_args
from colorgrid.config import AGENTS


def cmd_demo(args: argparse.Namespace) -> int:
    """Play one episode with random agents and draw it in the terminal."""
    from colorgrid.env import BatchEnv
    from colorgrid.render import render_ansi

    config = config_from_args(args)
    env = BatchEnv(config, num_envs=1, seed=args.seed)
    env.reset()
    rng = np.random.default_rng(args.seed)
    for _ in range(config.horizon):
        _, _, _, truncs, _ = env.step(rng.integers(0, config.num_actions, (1, config.num_agents)))
        if not args.quiet:
            print("\x1b[H\x1b[2J" + render_ansi(env.state, config), flush=True)
            time.sleep(1.0 / args.fps)
        if truncs.all():
            break
    scores = dict(zip(AGENTS, env.state.score[0].tolist()))
    print(f"episode over: {scores}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="colorgrid", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="draw an episode of scripted agents in the terminal")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--fps", type=float, default=10.0)
    demo.add_argument("--quiet", action="store_true", help="print only the final score")
    add_config_arguments(demo)
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as err:
        print(f"colorgrid {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
