"""Environment throughput: the batch env at several sizes and the PettingZoo view.

Usage: python bench/bench_env.py [--steps 512] [--repeats 5]
Prints env-steps per wall second and per CPU second (medians over repeats);
observations are produced every step (the batch env's buffer, updated in place).
The last rows compare team shapes at N=1024: 1:1, 2:1, 1:2, 2:2 and 3:3 (leaders:followers).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, timed  # noqa: E402

from colorgrid import BatchEnv, EnvConfig, parallel_env  # noqa: E402


def bench_batch(n: int, steps: int, repeats: int, config: EnvConfig = EnvConfig()) -> tuple[float, float]:
    env = BatchEnv(config, num_envs=n, seed=0)
    env.reset()
    actions = np.random.default_rng(0).integers(0, 4, (steps, n, config.num_agents))

    def run():
        for a in actions:
            env.step(a)

    wall, cpu = timed(run, repeats)
    return steps * n / wall, steps * n / cpu


def bench_pettingzoo(steps: int, repeats: int) -> tuple[float, float]:
    env = parallel_env()
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 4, (steps, 2)).tolist()

    def run():
        for leader, follower in actions:
            if not env.agents:
                env.reset()
            env.step({"leader": leader, "follower": follower})

    wall, cpu = timed(run, repeats)
    return steps / wall, steps / cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"{'view':<24}{'env-steps/s':>14}{'env-steps/CPU-s':>18}")
    for n in (1, 64, 256, 1024, 4096):
        wall, cpu = bench_batch(n, args.steps, args.repeats)  # 512 steps span 4 episodes (resets included)
        print(f"{'BatchEnv N=' + str(n):<24}{wall:>14,.0f}{cpu:>18,.0f}")
    wall, cpu = bench_pettingzoo(args.steps * 4, args.repeats)
    print(f"{'parallel_env (1 env)':<24}{wall:>14,.0f}{cpu:>18,.0f}")
    env = parallel_env()
    env.reset(seed=0)
    wall, cpu = timed(lambda: [env.reset() for _ in range(200)], args.repeats)
    print(f"parallel_env reset (fresh seed, new layout): {wall / 200 * 1e6:.0f} us wall, {cpu / 200 * 1e6:.0f} us CPU")
    print(f"{'team at N=1024':<24}{'env-steps/s':>14}{'env-steps/CPU-s':>18}{'of 1:1':>10}")
    base = None
    for leaders, followers in ((1, 1), (2, 1), (1, 2), (2, 2), (3, 3)):
        config = EnvConfig(num_leaders=leaders, num_followers=followers)
        wall, cpu = bench_batch(1024, args.steps, args.repeats, config)
        base = cpu if base is None else base
        print(f"{f'{leaders}:{followers}':<24}{wall:>14,.0f}{cpu:>18,.0f}{cpu / base:>10.2f}")


if __name__ == "__main__":
    main()
