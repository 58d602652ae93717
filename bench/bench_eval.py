"""Evaluation speed: 100 episodes of a leader and a follower, median over repeats.

Usage: python bench/bench_eval.py [--leader astar] [--follower bayes] [--episodes 100] [--repeats 3] [--threads N]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, timed  # noqa: E402

import numpy as np  # noqa: E402

from colorgrid import EnvConfig  # noqa: E402
from colorgrid.evaluate import evaluate, switch_lags  # noqa: E402
from colorgrid.policies import make_policy  # noqa: E402
from colorgrid.rollout import run_episodes  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--leader", default="astar")
    parser.add_argument("--follower", nargs="+", default=["copy", "bayes"])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's own)")
    args = parser.parse_args()
    threads = "no torch (scripted agents only)"
    if importlib.util.find_spec("torch") is not None:  # a core-only install evaluates scripted agents without it
        import torch

        if args.threads is not None:
            torch.set_num_threads(args.threads)
        threads = torch.get_num_threads()
    print(f"machine: {machine()}; torch threads {threads}; "
          f"OMP_WAIT_POLICY {os.environ.get('OMP_WAIT_POLICY', 'unset')}")
    for follower in args.follower:
        wall, cpu = timed(lambda: evaluate(EnvConfig(), args.leader, follower, args.episodes, 0), args.repeats)
        print(f"{args.leader} + {follower}: {args.episodes} episodes in {wall:.2f} s wall, {cpu:.2f} s CPU (median)")
    if "bayes" in args.follower:
        batch = run_episodes(EnvConfig(), make_policy("astar"), make_policy("bayes"), 100, 1000)
        lags = switch_lags(batch.goal_probs[1], batch.goal)
        print(f"bayes switch tracking (seeds 1000..1099): {lags.size} switches, median {np.median(lags):.0f}, "
              f"max {lags.max()} leader moves to the new goal")


if __name__ == "__main__":
    main()
