"""Evaluation speed: 100 episodes of a leader and a follower, median over repeats.

Usage: python bench/bench_eval.py [--follower bayes] [--episodes 100] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, timed  # noqa: E402

from colorgrid import EnvConfig  # noqa: E402
from colorgrid.evaluate import evaluate  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--leader", default="astar")
    parser.add_argument("--follower", nargs="+", default=["copy", "bayes"])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"machine: {machine()}")
    for follower in args.follower:
        wall, cpu = timed(lambda: evaluate(EnvConfig(), args.leader, follower, args.episodes, 0), args.repeats)
        print(f"{args.leader} + {follower}: {args.episodes} episodes in {wall:.2f} s wall, {cpu:.2f} s CPU (median)")


if __name__ == "__main__":
    main()
