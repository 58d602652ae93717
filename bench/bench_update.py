"""What bounds the PPO update of two learners side by side: one learner's update alone, the two updates on two
threads of one process (the trainer with ``update_processes=false``), and on two processes at once (as the trainer
runs them by default: ``train/update_process.py``).

Each figure is the median over ``--repeats`` updates of the same rollout from the same weights (the fast
network, the paper's batch: 16 envs x 128 steps, 4 epochs of 4 minibatches, no early stop), one torch
thread per update, with the page faults and voluntary context switches of the runs in this process. If two
processes take what one takes alone while two threads take longer, the cores' shared cache and memory are
not the limit: the learners' Python between operations is, serialised by the GIL, each hand-over of which
is a voluntary context switch (docs/PERFORMANCE.md, "Each learner's update in a process of its own").

Usage: python bench/bench_update.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import copy
import multiprocessing
import resource
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402


def setup():
    """A trainer after one iteration and one more rollout, with each learner's weights and inputs to restart from."""
    import torch

    from train.config import from_dict
    from train.metrics import MetricsLog
    from train.trainer import Trainer

    torch.set_num_threads(1)
    config = from_dict({"threads": 1, "eval_every": 0, "total_steps": 10**9, "ppo": {"target_kl": None}})
    folder = tempfile.mkdtemp(prefix="bench_update_")
    trainer = Trainer(config, folder, progress=False, tensorboard=False)
    trainer.log = MetricsLog(Path(folder), tensorboard=False)
    trainer.train_iteration()
    trainer.collect_rollout()
    learners = list(trainer.learners.values())
    inputs = [trainer._learner_tensors(learner) for learner in learners]
    saved = [copy.deepcopy((lr.model.state_dict(), lr.optimizer.state_dict(), lr.generator.get_state()))
             for lr in learners]
    return learners, inputs, saved


def update(learners, inputs, saved, i: int) -> float:
    """Seconds of learner ``i``'s update from its saved weights, optimizer and generator."""
    learner = learners[i]
    model, optimizer, generator = saved[i]
    learner.model.load_state_dict(model)
    learner.optimizer.load_state_dict(optimizer)
    learner.generator.set_state(generator)
    start = time.perf_counter()
    learner.update(learner.value(inputs[i]))
    return time.perf_counter() - start


def usage() -> tuple[int, int]:
    """This process's minor page faults and voluntary context switches so far (all its threads)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_minflt, r.ru_nvcsw


def per_repeat(before: tuple[int, int], after: tuple[int, int], repeats: int) -> str:
    faults, switches = ((b - a) / repeats for a, b in zip(before, after))
    return f"{faults:,.0f} page faults, {switches:,.0f} voluntary context switches a repeat"


def in_process(repeats: int, barrier) -> list[float]:
    """One process's learner-0 updates, each started with the other process's (``barrier``)."""
    learners, inputs, saved = setup()
    update(learners, inputs, saved, 0)  # warm-up
    times = []
    for _ in range(repeats):
        barrier.wait()
        times.append(update(learners, inputs, saved, 0))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    from train.trainer import at_threads

    print(f"machine: {machine()}; one torch thread per update")
    learners, inputs, saved = setup()
    for i in range(2):
        update(learners, inputs, saved, i)  # warm-up
    before = usage()
    alone = [update(learners, inputs, saved, 0) for _ in range(args.repeats)]
    alone_usage = per_repeat(before, usage(), args.repeats)
    pool = ThreadPoolExecutor(1)
    threads = []
    before = usage()
    for _ in range(args.repeats):
        start = time.perf_counter()
        other = pool.submit(at_threads, 1, update, learners, inputs, saved, 1)
        update(learners, inputs, saved, 0)
        other.result()
        threads.append(time.perf_counter() - start)
    threads_usage = per_repeat(before, usage(), args.repeats)
    pool.shutdown()
    context = multiprocessing.get_context("spawn")
    with context.Manager() as manager:
        barrier = manager.Barrier(2)
        with context.Pool(2) as processes:
            results = [processes.apply_async(in_process, (args.repeats, barrier)) for _ in range(2)]
            per_process = [r.get() for r in results]
    both = [max(a, b) for a, b in zip(*per_process)]
    print(f"{'one learner alone':<40} {statistics.median(alone):.3f} s ({min(alone):.3f}-{max(alone):.3f}); "
          f"{alone_usage}")
    print(f"{'two learners, two threads of one process':<40} {statistics.median(threads):.3f} s "
          f"({min(threads):.3f}-{max(threads):.3f}); {threads_usage}")
    print(f"{'two learners, two processes':<40} {statistics.median(both):.3f} s ({min(both):.3f}-{max(both):.3f})")
    print("(median over repeats of one update: 16 envs x 128 steps, 4 epochs of 4 minibatches; two at once: until "
          "both have finished)")


if __name__ == "__main__":
    main()
