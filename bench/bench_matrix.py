"""How long a leader x follower matrix takes: 10 leaders x 5 followers, 100 episodes per cell.

Usage: python bench/bench_matrix.py [--episodes 100] [--workers N]

The 10 leaders are the training part of ``populations/people.json`` plus its first two
held-out members; the followers are copy, bayes, bayes-people, ippo and ippo-people. Prints
the machine, the worker count and the wall time of ``colorgrid_apps.matrix.evaluate_matrix``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

from colorgrid import EnvConfig  # noqa: E402
from colorgrid.policies.population import load_population  # noqa: E402
from colorgrid_apps.matrix import evaluate_matrix  # noqa: E402

FOLLOWERS = ["copy", "bayes", "bayes-people", "ippo", "ippo-people"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=None, help="processes (default: one per CPU)")
    args = parser.parse_args()
    held_out = list(load_population("people#held_out").items())
    leaders = {**load_population("people#training"), **dict(held_out[:2])}
    start = time.perf_counter()
    report = evaluate_matrix(EnvConfig(), leaders, FOLLOWERS, args.episodes, 0, workers=args.workers)
    wall = time.perf_counter() - start
    print(f"machine: {machine()}")
    print(f"{len(leaders)} leaders x {len(FOLLOWERS)} followers, {args.episodes} episodes per cell, "
          f"{report['workers']} worker processes (of {os.cpu_count()} CPUs): {wall:.0f} s wall")


if __name__ == "__main__":
    main()
