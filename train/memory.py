"""Keep freed memory in the process: large tensors are then reused instead of re-faulted from the OS.

glibc's malloc serves large blocks (the paper network's activations are ~100 MB per
minibatch) with ``mmap`` and unmaps them when freed, so each PPO minibatch pays page faults
for all of its activations again: a third of a paper minibatch's time was system time
(``bench/bench_memory.py``). With mmap off, a single arena and no trimming, freed blocks stay in the heap
and the next minibatch reuses them. The cost is memory: the process keeps what it freed, and
the heap can fragment (a large block freed with a small one allocated after it, repeated,
grows the heap every time: the next aligned large request does not fit the freed block). A
paper-network run settles at about 3 GB, so the ``paper_*`` presets turn it on
(``TrainConfig.keep_freed_memory``); it is off by default.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# mallopt parameters (malloc.h)
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_MAX, M_ARENA_MAX = -1, -2, -4, -8


def keep_freed_memory() -> bool:
    """Tune glibc's malloc as above; returns False (and changes nothing) where there is no glibc."""
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (macOS, musl without mallopt, Windows)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    settings = ((M_ARENA_MAX, 1), (M_MMAP_MAX, 0), (M_TRIM_THRESHOLD, 2**31 - 1), (M_TOP_PAD, 64 << 20))
    return all(mallopt(param, value) == 1 for param, value in settings)
