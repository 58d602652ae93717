"""Helpers shared by the benchmark scripts: machine description and timing."""

from __future__ import annotations

import statistics
import time


def machine() -> str:
    """One line naming the machine, CPU count and thread settings the figures were taken on."""
    from colorgrid_apps.machine import describe

    return describe()


def timed(fn, repeats: int) -> tuple[float, float]:
    """Median wall seconds and median CPU seconds of ``fn()`` over ``repeats`` runs."""
    walls, cpus = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return statistics.median(walls), statistics.median(cpus)
