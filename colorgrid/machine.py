"""One line naming the machine figures were taken on (benchmarks, model cards)."""

from __future__ import annotations

import os
import platform


def _cpuinfo() -> dict[str, str]:
    """The first CPU's fields in /proc/cpuinfo (empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            block = f.read().split("\n\n")[0]
    except OSError:
        return {}
    return {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in block.splitlines() if ":" in line)}


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` knows of it."""
    return _cpuinfo().get("model name") or platform.processor() or platform.machine()


def cpu_family() -> str:
    """The CPU's family and model numbers and its widest vector extension, e.g. ``family 25 model 17, AVX-512``:
    machines sold under one name ("AMD EPYC") differ in both, and benchmark figures and float paths with them."""
    fields = _cpuinfo()
    if not fields:
        return platform.machine()
    flags = set(fields.get("flags", "").split())
    vector = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"family {fields.get('cpu family', '?')} model {fields.get('model', '?')}, {vector}"


def describe() -> str:
    """The machine in one line: CPU, its family, CPU count, Python and the thread settings that change timings."""
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    capability = os.environ.get("ATEN_CPU_CAPABILITY")
    return (f"{cpu_name()} ({cpu_family()}); {os.cpu_count()} CPUs; Python {platform.python_version()}; "
            f"OMP_NUM_THREADS={threads}" + (f"; ATEN_CPU_CAPABILITY={capability}" if capability else ""))
