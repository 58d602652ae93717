"""One backend process of a cluster: ``python -m server.cluster.process``, started by the launcher.

The launcher writes a ``BackendSpec`` (pickled) to the process's standard input: the settings it serves with
(its loopback port), the plugin when one runs (the application served: a study), and its membership. The process
then is an ordinary play server (uvicorn, one worker, its own inference process) that also answers as one of the
cluster (``server.cluster.siblings``). It stops the usual way on SIGTERM (every live game saved, each player told),
and stops so, too, if the launcher dies without stopping it.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import time
from dataclasses import dataclass

from server.settings import ServerSettings


@dataclass(frozen=True)
class BackendSpec:
    """What one backend process runs."""

    settings: ServerSettings
    member: object
    """Its ``server.cluster.plan.Membership``."""
    log_level: str = "info"
    plugin: object | None = None
    """The application served (a study) instead of free play (a ``server.backend.Plugin``), or None."""
    launcher_pid: int = 0
    """The launcher's process id: the process stops once its parent is another (0: its parent when it starts)."""


def stop_with_parent(parent: int, every_s: float = 1.0, said: str = "") -> None:
    """Stop this process as SIGTERM does once ``parent`` is gone (its parent is then another), so that it does not
    outlive it: a backend its launcher, a launcher started with ``--stop-with-parent`` the program that started it.
    ``said`` is printed first."""
    while os.getppid() == parent:
        time.sleep(every_s)
    if said:
        print(said, flush=True)
    os.kill(os.getpid(), signal.SIGTERM)


def main() -> int:
    parent = os.getppid()  # before the slow imports: a launcher that dies meanwhile is not missed
    from server.run import serve

    spec: BackendSpec = pickle.load(sys.stdin.buffer)
    sys.stdin.close()
    launcher = spec.launcher_pid or parent
    threading.Thread(target=stop_with_parent, args=(launcher,), daemon=True, name="launcher-watch").start()
    serve(spec.settings, spec.log_level, spec.plugin, spec.member)
    return 0


if __name__ == "__main__":
    sys.exit(main())
