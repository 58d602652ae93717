"""What the fork server of update processes (``train.update_process``) loads before its first fork, so that each
process it forks starts ready: that module, and torch's Adam made once. A process's first ``torch.optim.Adam``
imports part of torch (its compiler's front end, ``torch._dynamo``) lazily, which ``bench/bench_update_start.py``
times; made here, every process inherits it imported. Nothing here starts a thread (the server forks with the one
it has, and OpenBLAS's, which is safe to fork).
"""

import torch

import train.update_process  # noqa: F401  (the processes' code)

torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-3, eps=1e-5, fused=True)
