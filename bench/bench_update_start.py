"""How long a learner's update process takes to start (``train/update_process.py``): the first trainer of a
process starts multiprocessing's fork server (a fresh interpreter loading ``train/update_server.py``) at its first
update; every trainer after it only forks a process from that server. Prints, for ``--trainers`` trainers made
one after the other in this process (the fast network, two learners, two torch threads, a small batch), the
first update (which starts the process) and the second (which does not), in wall seconds.

Usage: python bench/bench_update_start.py [--trainers 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trainers", type=int, default=5)
    args = parser.parse_args()
    if args.trainers < 2:
        parser.error(f"--trainers must be at least 2 (the first starts the server), got {args.trainers}")
    from train.config import from_dict
    from train.trainer import Trainer

    config = from_dict({"threads": 2, "eval_every": 0, "ppo": {"num_envs": 4, "num_steps": 16}})
    firsts, nexts = [], []
    for _ in range(args.trainers):
        with tempfile.TemporaryDirectory() as out:
            trainer = Trainer(config, out, progress=False, tensorboard=False)
            try:
                timings = []
                for _ in range(2):
                    trainer.collect_rollout()
                    start = time.perf_counter()
                    trainer._update_learners()
                    timings.append(time.perf_counter() - start)
                if not trainer._processes:
                    sys.exit("no update process started here (update_processes fell back to threads)")
            finally:
                trainer.close()
        firsts.append(timings[0])
        nexts.append(timings[1])
    print(machine())
    print(f"first trainer's first update (starts the fork server and a process): {firsts[0]:.2f} s")
    later = firsts[1:]
    print(f"later trainers' first update (a process from the server): median {statistics.median(later):.3f} s "
          f"(range {min(later):.3f}-{max(later):.3f}, {len(later)} trainers)")
    print(f"an update with the process running: median {statistics.median(nexts):.3f} s "
          f"(range {min(nexts):.3f}-{max(nexts):.3f}, {len(nexts)} trainers)")


if __name__ == "__main__":
    main()
