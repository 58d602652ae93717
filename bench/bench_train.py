"""Training throughput: env-steps per second of whole PPO iterations (rollout + update), both agents learning.

Prints the median over ``--iterations`` iterations (after one warm-up) and CPU seconds per
iteration, split into rollout and update, for the fast default network and the paper's
architecture, at the paper's batch (16 envs x 128 steps) or another number of envs (``--num-envs``).

Also prints each setup's arithmetic: floating-point operations per env-step (counted with
torch's FlopCounterMode on a short rollout and one update epoch, scaled to the configured
epochs) and the ceiling this machine's own matrix-multiply rate puts on env-steps/s.

With ``--pack K [K ...]``, each setup is also measured as a pack of K trials (seeds 0..K-1) trained as one
(``train.pack``): the pack's env-steps/s are all its trials' steps together, and its share of the ceiling
is what the machine does for all of them.

``--setup goal-vector goal-planes`` compares the goal's two ways into the fast network, both agents seeing it.

Usage: python bench/bench_train.py [--setup fast fast-lstm paper] [--iterations 5] [--threads 0] [--device auto]
                                  [--num-envs 16] [--pack 1 2 4 8 16] [--pack-mode auto]

On a GPU (``--device cuda``) the ceiling is the GPU's own float32 matrix-multiply rate.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

import torch  # noqa: E402

from train.config import from_dict  # noqa: E402
from train.metrics import MetricsLog  # noqa: E402
from train.pack import Pack  # noqa: E402
from train.placement import PACK_MODES  # noqa: E402
from train.trainer import Trainer  # noqa: E402

SETUPS = {
    "fast": {},
    "fast-threads": {"update_processes": False},  # the learners' updates on two threads of one process
    "fast-lstm": {"follower": {"net": {"lstm": True, "extra_inputs": True, "belief_input": True}}},
    # as the paper_* presets run it (keep_freed_memory; see docs/PERFORMANCE.md and bench/bench_memory.py)
    "paper": {"leader": {"net": {"arch": "paper"}}, "follower": {"net": {"arch": "paper"}}, "keep_freed_memory": True},
    "paper-default-malloc": {"leader": {"net": {"arch": "paper"}}, "follower": {"net": {"arch": "paper"}}},
    # the goal's two ways in, both agents seeing it (env.asymmetric=false, as Table 1's sweeps run), nothing else
    # changed: a vector joined after the convolutions (sweeps/paper_table1_eighth.toml's), or input planes through
    # them (sweeps/paper_table1_small.toml's)
    "goal-vector": {"env": {"asymmetric": False}},
    "goal-planes": {"env": {"asymmetric": False}, "leader": {"net": {"goal_fusion": "planes"}},
                    "follower": {"net": {"goal_fusion": "planes"}}},
}


def setup_config(name: str, num_envs: int, **settings) -> dict:
    """A setup's training config as plain data, at ``num_envs`` envs a rollout (the same number of minibatches,
    each of more envs)."""
    ppo = {"num_envs": num_envs, **settings.pop("ppo", {})}
    return {**SETUPS[name], "ppo": ppo, **settings}


def measure(name: str, iterations: int, threads: int, device: str, num_envs: int = 16, pack: int = 1,
            mode: str = "auto", after_warmup: Callable[[], object] | None = None) -> dict:
    """Median figures of ``iterations`` PPO iterations (after one warm-up) of setup ``name``: one trial, or a pack
    of ``pack`` trials (seeds 0..pack-1) trained as one, whose env-steps/s count every trial's steps."""
    configs = [from_dict(setup_config(name, num_envs, threads=threads, device=device, eval_every=0,
                                      total_steps=10**9, seed=seed)) for seed in range(pack)]
    with tempfile.TemporaryDirectory() as tmp:
        trainers = [Trainer(config, Path(tmp) / str(k), progress=False, tensorboard=False)
                    for k, config in enumerate(configs)]
        for trainer in trainers:
            trainer.run_dir.mkdir()
            trainer.log = MetricsLog(trainer.run_dir, tensorboard=False)
        together = Pack(trainers, mode=mode)
        walls, cpus, rollout, update = [], [], [], []
        for i in range(iterations + 1):
            c, w = cpu_seconds(), time.perf_counter()
            rows = together.train_iteration()
            if i == 0 and after_warmup is not None:
                after_warmup()
            if i:  # the first iteration warms caches and allocators
                walls.append(time.perf_counter() - w)
                cpus.append(cpu_seconds() - c)
                rollout.append(configs[0].batch_steps / rows[0]["rollout_sps"])  # the pack's seconds
                update.append(configs[0].batch_steps / rows[0]["update_sps"])
        together.close()
        for trainer in trainers:
            trainer.log.close()
    steps = pack * configs[0].batch_steps
    return {
        "setup": name, "device": str(trainers[0].device), "threads": torch.get_num_threads(), "pack": pack,
        "sps": steps / statistics.median(walls), "rollout_sps": steps / statistics.median(rollout),
        "update_sps": steps / statistics.median(update),
        "cpu_s_per_iter": statistics.median(cpus), "steps_per_iter": steps, "num_envs": configs[0].ppo.num_envs,
    }


def cpu_seconds() -> float:
    """CPU seconds of this process and of the processes below it still running (a learner's update process, a
    child of the fork server that is this process's child; Linux)."""
    ticks: dict[int, tuple[int, int]] = {}  # pid: (parent, CPU ticks)
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        # fields from the state on: ppid, ..., utime (12th), stime (13th)
        ticks[int(stat.parent.name)] = (int(fields[1]), int(fields[11]) + int(fields[12]))
    below, total = {os.getpid()}, 0
    while True:
        more = {pid for pid, (parent, _) in ticks.items() if parent in below} - below
        if not more:
            break
        below |= more
        total += sum(ticks[pid][1] for pid in more)
    return time.process_time() + total / os.sysconf("SC_CLK_TCK")


def flops_per_env_step(name: str) -> float:
    """Floating-point operations of one env-step of training (both learners' rollout forward + PPO update)."""
    from torch.utils.flop_counter import FlopCounterMode

    config = from_dict({**SETUPS[name], "threads": 1, "device": "cpu", "eval_every": 0, "total_steps": 10**9,
                        "ppo": {"num_steps": 8, "num_minibatches": 1, "update_epochs": 1}})
    epochs = from_dict(SETUPS[name]).ppo.update_epochs
    threads = torch.get_num_threads()
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(config, tmp, progress=False, tensorboard=False)
        with FlopCounterMode(display=False) as rollout:
            trainer.collect_rollout()
        with FlopCounterMode(display=False) as update:
            trainer._update_learners()
    torch.set_num_threads(threads)
    samples = config.batch_steps
    return (rollout.get_total_flops() + epochs * update.get_total_flops()) / samples


def matmul_rate(threads: int, size: int = 2048, repeats: int = 5, device: str = "cpu") -> float:
    """This machine's float32 matrix-multiply rate (FLOP/s) on ``device``: the practical ceiling for dense layers."""
    if threads:
        torch.set_num_threads(threads)
    on_gpu = device.startswith("cuda")
    size = 8192 if on_gpu else size  # a GPU needs a larger product to reach its rate
    a, b = torch.randn(size, size, device=device), torch.randn(size, size, device=device)
    torch.mm(a, b)
    times = []
    for _ in range(repeats):
        if on_gpu:
            torch.cuda.synchronize()
        t = time.perf_counter()
        torch.mm(a, b)
        if on_gpu:
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    return 2 * size ** 3 / statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--setup", nargs="+", default=["fast", "fast-lstm", "paper"], choices=sorted(SETUPS))
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: all cores)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--num-envs", type=int, default=16, help="envs a rollout (the paper's 16 by default)")
    parser.add_argument("--pack", type=int, nargs="+", default=[1],
                        help="trials a pack, each measured (e.g. 1 2 4 8 16; 32 64 on CUDA)")
    parser.add_argument("--pack-mode", default="auto", choices=sorted(PACK_MODES),
                        help="how a pack acts and updates (auto: stacked on a CPU, vmap on a GPU)")
    parser.add_argument("--profile", action="store_true", help="print torch's profile of one update (first setup)")
    args = parser.parse_args()
    print(f"machine: {machine()}; torch {torch.__version__}; cuda: {torch.cuda.is_available()}; "
          f"pack mode: {args.pack_mode}")
    print(f"{'setup':<12} {'pack':>4} {'device':<7} {'threads':>7} {'env-steps/s':>12} {'rollout/s':>10} "
          f"{'update/s':>10} {'CPU s/iter':>10}")
    measured = {}
    for name in args.setup:
        for pack in args.pack:
            r = measured[name, pack] = measure(name, args.iterations, args.threads, args.device, args.num_envs, pack,
                                               args.pack_mode)
            print(f"{r['setup']:<12} {pack:>4} {r['device']:<7} {r['threads']:>7} {r['sps']:>12.0f} "
                  f"{r['rollout_sps']:>10.0f} {r['update_sps']:>10.0f} {r['cpu_s_per_iter']:>10.2f}", flush=True)
    print(f"(median over iterations of {args.num_envs} envs x 128 steps a trial, both agents learning, every trial of "
          "a pack counted; the paper's public trainer: about 36 env-steps/s on a 2-core CPU)")
    device = next(iter(measured.values()))["device"]
    rate = matmul_rate(args.threads, device=device)
    where = torch.cuda.get_device_name() if device.startswith("cuda") else f"this CPU ({torch.get_num_threads()} threads)"
    print(f"\n{where}: float32 matmul rate {rate / 1e9:.0f} GFLOP/s")
    print(f"{'setup':<12} {'pack':>4} {'GFLOP/env-step':>15} {'ceiling env-steps/s':>20} {'share of the ceiling':>21}")
    for name in args.setup:
        work = flops_per_env_step(name)
        ceiling = rate / work
        for pack in args.pack:
            print(f"{name:<12} {pack:>4} {work / 1e9:>15.4f} {ceiling:>20.0f} "
                  f"{measured[name, pack]['sps'] / ceiling:>21.0%}", flush=True)
    print("(the ceiling: every operation at the matmul rate; nothing else costs time)")
    if args.profile:
        profile_update(args.setup[0], args.threads, args.device)


def profile_update(name: str, threads: int, device: str) -> None:
    """Where one learner's PPO update spends its time (after one warm-up iteration)."""
    from torch.profiler import ProfilerActivity, profile

    config = from_dict({**SETUPS[name], "threads": threads, "device": device, "eval_every": 0, "total_steps": 10**9})
    with tempfile.TemporaryDirectory() as tmp:
        from train.metrics import MetricsLog

        trainer = Trainer(config, tmp, progress=False, tensorboard=False)
        trainer.log = MetricsLog(Path(tmp), tensorboard=False)
        trainer.train_iteration()
        trainer.collect_rollout()
        learner = trainer.learners[0]
        bootstrap = learner.value(trainer._learner_tensors(learner))
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            learner.update(bootstrap)
        trainer.close()
        trainer.log.close()
    print(f"profile of one {name} update (leader):")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=12))


if __name__ == "__main__":
    main()
