"""One line naming the machine figures were taken on (benchmarks, model cards)."""

from __future__ import annotations

import os
import platform


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def describe() -> str:
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    return f"{cpu_name()}; {os.cpu_count()} CPUs; Python {platform.python_version()}; OMP_NUM_THREADS={threads}"
