"""How long a learner's update process takes to start (``train/update_process.py``): the first trainer of a
process starts its fork server (a fresh interpreter loading ``train/update_server.py``) at its first
update; every trainer after it only forks a process from that server. Prints, for ``--trainers`` trainers made
one after the other in this process (the fast network, two learners, two torch threads, a small batch), the
first update (which starts the process) and the second (which does not), in wall seconds; then, with the server
running, ``--trainers`` more processes started alone for the last trainer's follower (what the start itself takes),
and the first ``torch.optim.Adam`` of ``--trainers`` fresh interpreters (what ``train/update_server.py`` makes once in
the server so that no process pays it).

Usage: python bench/bench_update_start.py [--trainers 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

FIRST_ADAM = ("import time, torch, train.update_process; start = time.perf_counter(); "
              "torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-3, eps=1e-5, fused=True); "
              "print(time.perf_counter() - start)")
"""A fresh interpreter's first Adam, after the imports an update process has (run with ``-c``)."""


def spread(values: list[float], what: str) -> str:
    return (f"median {statistics.median(values):.3f} s (range {min(values):.3f}-{max(values):.3f}, "
            f"{len(values)} {what})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trainers", type=int, default=5)
    args = parser.parse_args()
    if args.trainers < 2:
        parser.error(f"--trainers must be at least 2 (the first starts the server), got {args.trainers}")
    from train.config import from_dict
    from train.trainer import Trainer
    from train.update_process import UpdateProcess

    config = from_dict({"threads": 2, "eval_every": 0, "ppo": {"num_envs": 4, "num_steps": 16}})
    firsts, nexts, alone = [], [], []
    for k in range(args.trainers):
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
                for _ in range(args.trainers if k == args.trainers - 1 else 0):
                    start = time.perf_counter()
                    UpdateProcess(trainer.learners[1]).close()
                    alone.append(time.perf_counter() - start)
            finally:
                trainer.close()
        firsts.append(timings[0])
        nexts.append(timings[1])
    adams = [float(subprocess.run([sys.executable, "-c", FIRST_ADAM], capture_output=True, text=True, check=True,
                                  cwd=Path(__file__).resolve().parents[1]).stdout) for _ in range(args.trainers)]
    print(machine())
    print(f"first trainer's first update (starts the fork server and a process): {firsts[0]:.2f} s")
    print(f"later trainers' first update (a process from the server): {spread(firsts[1:], 'trainers')}")
    print(f"an update with the process running: {spread(nexts, 'trainers')}")
    print(f"a process from the server, started and closed alone: {spread(alone, 'processes')}")
    print(f"a fresh interpreter's first torch.optim.Adam (made once in the server): {spread(adams, 'interpreters')}")


if __name__ == "__main__":
    main()
