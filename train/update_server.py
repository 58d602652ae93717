"""What the fork server of update processes (``train.update_process``) loads before its first fork, so that each
process it forks starts ready: that module, and torch's Adam made once. A process's first ``torch.optim.Adam``
imports part of torch (its compiler's front end, ``torch._dynamo``) lazily, which ``bench/bench_update_start.py``
times; made here, every process inherits it imported. Nothing here starts a thread (the server forks with the one
it has, and OpenBLAS's, which is safe to fork). First, as in each process: a SIGABRT from a trainer that finds the
server blocked writes its threads' stacks to stderr (``faulthandler``), and no core file.
"""

import faulthandler
import resource

resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
faulthandler.enable(all_threads=True)

import torch  # noqa: E402

import train.update_process  # noqa: E402, F401  (the processes' code)

torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-3, eps=1e-5, fused=True)
