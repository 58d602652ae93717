"""Helpers shared by the benchmark scripts: machine description and timing."""

from __future__ import annotations

import statistics
import time


def machine() -> str:
    """One line naming the machine, CPU count and thread settings the figures were taken on."""
    from colorgrid.machine import describe

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


def start_play_server(prefix: str, *flags: str):
    """``colorgrid play`` on a free loopback port with its replays in a new temporary folder, ready to play:
    returns ``(process, base_url, folder)``; its log is ``folder / "server.log"``."""
    import json
    import socket
    import subprocess
    import sys
    import tempfile
    import urllib.request
    from pathlib import Path

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    process = subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "play", "--port", str(port), "--replays-dir",
                                str(folder), "--log-level", "warning", *flags],
                               stdout=open(folder / "server.log", "w"), stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    for _ in range(600):  # until the server has loaded its follower and the compiled env step
        try:
            if json.loads(urllib.request.urlopen(base + "/api/health", timeout=2).read()).get("ready"):
                return process, base, folder
        except OSError:
            pass
        time.sleep(0.2)
    process.kill()
    raise RuntimeError(f"the server was not ready in 120 s; see {folder / 'server.log'}")
