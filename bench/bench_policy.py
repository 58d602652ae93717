"""Inference time of one batched policy call, as the play server makes it (one row per game).

Usage: python bench/bench_policy.py [--policy ippo] [--rows 1 10 100] [--threads 1] [--repeats 50]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

import numpy as np  # noqa: E402

from colorgrid import BatchEnv, EnvConfig  # noqa: E402
from colorgrid.policies import make_policy  # noqa: E402
from colorgrid.config import FOLLOWER  # noqa: E402
from colorgrid.step_inputs import StepInputs  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", default="ippo")
    parser.add_argument("--rows", type=int, nargs="+", default=[1, 10, 100])
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the play server uses 1)")
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    config = EnvConfig(allow_stay=True)  # the server's real-time mode
    policy = make_policy(args.policy, role="follower")
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(args.threads)
    print(f"machine: {machine()}; policy {args.policy}; torch threads {args.threads}")
    for n in args.rows:
        env = BatchEnv(config, num_envs=n, seed=0)
        obs, _ = env.reset()
        policy.reset(config, n, 1, seed=0)
        inp = StepInputs.begin(config, n).agent_input(obs, FOLLOWER, 1.0, env.state.goal,
                                                      episode_start=np.zeros(n, dtype=bool))
        times = []
        for i in range(args.repeats + 3):
            start = time.perf_counter()
            policy.act(inp, rows=np.arange(n))
            if i >= 3:
                times.append(time.perf_counter() - start)
        print(f"{n:>4} rows: median {statistics.median(times) * 1e3:.2f} ms, "
              f"p90 {statistics.quantiles(times, n=10)[-1] * 1e3:.2f} ms per call")


if __name__ == "__main__":
    main()
