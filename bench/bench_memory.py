"""What ``keep_freed_memory`` (train/memory.py) changes, each case in a fresh process.

* ``minibatches``: the paper encoder's forward and backward on 512 samples, one thread, with
  glibc's default malloc and with freed memory kept: wall, user and system seconds and page
  faults per minibatch (medians after the first).
* ``fragmentation``: a 100 MB tensor freed, then a small one allocated, repeated: resident
  memory after every 8 repeats (the pattern that makes a kept heap grow).
* ``trainer``: the paper network training both agents (one epoch per iteration, as the
  ``paper_*`` presets otherwise run it): resident memory after each iteration.

Usage: python bench/bench_memory.py [--cases minibatches fragmentation trainer] [--iterations 7]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

PRELUDE = """
import json, re, resource, statistics, sys, time
import torch
from train.memory import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
def rss_mb():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) // 1024
"""

MINIBATCHES = PRELUDE + """
from torch import nn
torch.set_num_threads(1)
net = nn.Sequential(nn.Conv2d(5, 32, 3), nn.LeakyReLU(), nn.Conv2d(32, 64, 3), nn.LeakyReLU(), nn.Conv2d(64, 64, 3),
                    nn.LeakyReLU(), nn.Flatten(), nn.Linear(43264, 192), nn.Tanh())
x = (torch.rand(512, 5, 32, 32) < 0.1).float()
rows = []
for _ in range(4):
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    net(x).sum().backward()
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    rows.append((time.perf_counter() - t0, r1.ru_utime - r0.ru_utime, r1.ru_stime - r0.ru_stime,
                 r1.ru_minflt - r0.ru_minflt))
print(json.dumps([statistics.median(col) for col in zip(*rows[1:])] + [rss_mb()]))
"""

FRAGMENTATION = PRELUDE + """
keep, out = [], []
for i in range(32):
    t = torch.ones(25_000_000)
    del t
    keep.append(torch.ones(1000))
    if i % 8 == 7:
        out.append(rss_mb())
print(json.dumps(out))
"""

TRAINER = PRELUDE + """
import tempfile
from pathlib import Path
from train.config import from_dict
from train.metrics import MetricsLog
from train.trainer import Trainer
config = from_dict({"leader": {"net": {"arch": "paper"}}, "follower": {"net": {"arch": "paper"}}, "eval_every": 0,
                    "total_steps": 10**9, "ppo": {"update_epochs": 1}, "keep_freed_memory": sys.argv[1] == "keep"})
with tempfile.TemporaryDirectory() as tmp:
    trainer = Trainer(config, tmp, progress=False, tensorboard=False)
    trainer.log = MetricsLog(Path(tmp), tensorboard=False)
    out = []
    for _ in range(int(sys.argv[2])):
        trainer.train_iteration()
        out.append(rss_mb())
print(json.dumps(out))
"""


def run(script: str, mode: str, *args: str) -> list:
    out = subprocess.run([sys.executable, "-c", script, mode, *args], capture_output=True, text=True, check=True,
                         cwd=ROOT)
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cases", nargs="+", default=["minibatches", "fragmentation", "trainer"],
                        choices=["minibatches", "fragmentation", "trainer"])
    parser.add_argument("--iterations", type=int, default=7, help="trainer iterations (about 20 s each)")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    modes = ("default", "keep")
    if "minibatches" in args.cases:
        print("paper encoder, 512 samples, forward + backward, 1 thread (medians of minibatches 2-4):")
        print(f"{'malloc':<8} {'wall s':>7} {'user s':>7} {'sys s':>7} {'page faults':>12} {'RSS MB':>7}")
        for mode in modes:
            wall, user, system, faults, rss = run(MINIBATCHES, mode)
            print(f"{mode:<8} {wall:>7.2f} {user:>7.2f} {system:>7.2f} {faults:>12,.0f} {rss:>7}")
    if "fragmentation" in args.cases:
        print("100 MB freed, then 4 kB allocated, repeated: RSS MB after 8, 16, 24, 32 repeats")
        for mode in modes:
            print(f"{mode:<8} {run(FRAGMENTATION, mode)}")
    if "trainer" in args.cases:
        print(f"paper network, both agents, 1 epoch per iteration: RSS MB after each of {args.iterations} iterations")
        print(f"keep     {run(TRAINER, 'keep', str(args.iterations))}")


if __name__ == "__main__":
    main()
