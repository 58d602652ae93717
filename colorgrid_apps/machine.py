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


def cpu_family() -> str:
    """The CPU's family and model numbers and its widest vector extension, e.g. ``family 25 model 17, AVX-512``:
    machines sold under one name ("AMD EPYC") differ in both, and benchmark figures and float paths with them."""
    try:
        with open("/proc/cpuinfo") as f:
            fields = dict(line.split(":", 1) for line in f.read().split("\n\n")[0].splitlines() if ":" in line)
    except OSError:
        return platform.machine()
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    flags = set(fields.get("flags", "").split())
    vector = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"family {fields.get('cpu family', '?')} model {fields.get('model', '?')}, {vector}"


def describe() -> str:
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    capability = os.environ.get("ATEN_CPU_CAPABILITY")
    return (f"{cpu_name()} ({cpu_family()}); {os.cpu_count()} CPUs; Python {platform.python_version()}; "
            f"OMP_NUM_THREADS={threads}" + (f"; ATEN_CPU_CAPABILITY={capability}" if capability else ""))
