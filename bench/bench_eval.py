"""Evaluation speed: 100 episodes of a leader and a follower, median over repeats.

Usage: python bench/bench_eval.py [--follower bayes] [--episodes 100] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, timed  # noqa: E402

import numpy as np  # noqa: E402

from colorgrid import EnvConfig  # noqa: E402
from colorgrid.evaluate import evaluate  # noqa: E402
from colorgrid.policies import make_policy  # noqa: E402
from colorgrid.rollout import run_episodes  # noqa: E402


def switch_lags(follower: str, episodes: int, seed: int) -> np.ndarray:
    """Leader moves until the follower's belief argmax reaches the new goal after each switch."""
    batch = run_episodes(EnvConfig(), make_policy("astar"), make_policy(follower), episodes, seed)
    probs, goal = batch.goal_probs[1], batch.goal
    lags = []
    for e in range(goal.shape[1]):
        for t in range(1, goal.shape[0]):
            if goal[t, e] != goal[t - 1, e]:
                k = 0
                while t + k < goal.shape[0] and goal[t + k, e] == goal[t, e] and probs[t + k, e].argmax() != goal[t, e]:
                    k += 1
                if t + k < goal.shape[0] and goal[t + k, e] == goal[t, e]:
                    lags.append(k)
    return np.array(lags)


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
    if "bayes" in args.follower:
        lags = switch_lags("bayes", 100, 1000)
        print(f"bayes switch tracking (seeds 1000..1099): {lags.size} switches, median {np.median(lags):.0f}, "
              f"max {lags.max()} leader moves to the new goal")


if __name__ == "__main__":
    main()
