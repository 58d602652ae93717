"""How best to fill a CPU with trials: P processes side by side, each training a pack of K trials at T threads.

``bench_train.py --pack K`` measures one process. A sweep on a CPU runs ``--local P`` processes, each a pack
of ``[resources] pack`` trials at ``cpus_per_trial`` threads, so the layouts compared here are the sweep's
own: e.g. ``P=2 K=1 T=1`` (two trials side by side, the way the Table 1 sweeps ran), ``P=1 K=8 T=2`` (one
pack of eight on both cores) and ``P=2 K=4 T=1`` (two packs of four). Each process measures its own median
iteration (after one warm-up) while the others run; the figure is their env-steps/s together and its share
of this machine's ceiling (``bench_train.py``'s: the matmul rate over the fast network's work an env-step).

Usage: python bench/bench_pack.py [--layouts 2x1x1 1x8x2 2x4x1] [--iterations 5] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train import flops_per_env_step, matmul_rate, measure  # noqa: E402
from common import machine  # noqa: E402


_BARRIER = None
"""The layout's processes meet here after their warm-up (``share_barrier``), so that they are measured together."""


def share_barrier(barrier) -> None:
    global _BARRIER
    _BARRIER = barrier


def one(args: tuple[int, int, int]) -> float:
    """One process's pack of ``K`` trials at ``T`` threads: its env-steps/s while the layout's others run."""
    pack, threads, iterations = args
    return measure("fast", iterations, threads, "cpu", 16, pack, after_warmup=_BARRIER.wait)["sps"]


def layout(text: str) -> tuple[int, int, int]:
    processes, pack, threads = (int(x) for x in text.split("x"))
    return processes, pack, threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--layouts", nargs="+", type=layout, default=[(2, 1, 1), (1, 8, 2), (2, 4, 1)],
                        help="PROCESSESxPACKxTHREADS each")
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3, help="runs of every layout, in turn")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    ceiling = matmul_rate(0) / flops_per_env_step("fast")
    print(f"ceiling of the fast network on this CPU: {ceiling:,.0f} env-steps/s")
    runs: dict[tuple, list[float]] = {lay: [] for lay in args.layouts}
    context = get_context("spawn")
    for _ in range(args.repeats):
        for processes, pack, threads in args.layouts:
            # (not a multiprocessing.Pool: its daemonic workers may not fork a learner's update process)
            with ProcessPoolExecutor(processes, mp_context=context, initializer=share_barrier,
                                     initargs=(context.Barrier(processes),)) as pool:
                rates = list(pool.map(one, [(pack, threads, args.iterations)] * processes))
            runs[processes, pack, threads].append(sum(rates))
    print(f"{'processes':>9} {'pack':>4} {'threads':>7} {'env-steps/s (runs)':>40} {'median':>8} {'share':>6}")
    for (processes, pack, threads), rates in runs.items():
        median = statistics.median(rates)
        shown = ", ".join(f"{r:,.0f}" for r in rates)
        print(f"{processes:>9} {pack:>4} {threads:>7} {shown:>40} {median:>8,.0f} {median / ceiling:>6.0%}")


if __name__ == "__main__":
    main()
