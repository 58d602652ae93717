"""A cluster's life as a researcher sees it, for real (the launcher, Debian's haproxy, uvicorn backends): what the
launcher's output says of a start, a backend killed and started again, and a stop in the middle of a game; and that
nothing it started outlives it, whether it is killed outright or the program that started it is
(``--stop-with-parent``)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import httpx

from server.cli import check_address_free
from server.cluster.haproxy import BACKEND_HEADER, ROUTE_COOKIE
from tests.conftest import ROOT, free_port
from tests.test_cluster import FAST_FOLLOWERS, RunningCluster, alive, children, receive, socket_to, start_cluster, \
    stop_cluster
from tests.test_study import TOKEN, fast_study, toml


def descendants(pid: int) -> list[int]:
    """Every process below ``pid``."""
    found, todo = [], [pid]
    while todo:
        below = children(todo.pop())
        found += below
        todo += below
    return found


def all_gone(pids: list[int], timeout_s: float) -> list[int]:
    """Those of ``pids`` still running after ``timeout_s`` (none, once all have ended)."""
    deadline = time.monotonic() + timeout_s
    while [p for p in pids if alive(p)] and time.monotonic() < deadline:
        time.sleep(0.3)
    return [p for p in pids if alive(p)]


def kill_left(pids: list[int]) -> None:
    """What a failed test leaves of the processes it started."""
    for pid in pids:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def long_practice_study(tmp: Path) -> Path:
    """The fast study with a turn-based practice game of 40 steps: a game that waits on its player."""
    import tomllib

    data = tomllib.loads(fast_study(tmp).read_text())
    for page in data["pages"]:
        if page["kind"] == "practice":
            page["game"] = {"mode": "turn", "horizon": 40, "follower": "copy"}
    path = tmp / "long_practice.toml"
    path.write_text(toml(data))
    return path


def wait_for_line(cluster: RunningCluster, words: str, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while words not in cluster.log():
        assert time.monotonic() < deadline, f"{words!r} is not in the launcher's output: {cluster.log()}"
        time.sleep(0.3)


def test_the_launchers_output_says_starts_restarts_and_the_stop_not_every_health_check(tmp_path):
    cluster = start_cluster(tmp_path, "--log-level", "info", command=("study", "run", str(long_practice_study(tmp_path))),
                            env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    try:
        pid, cookies = "lifecycle-1", {ROUTE_COOKIE: "lifecycle-1"}
        home = cluster.request(f"/study?PROLIFIC_PID={pid}").headers[BACKEND_HEADER]
        joined = cluster.request("/api/study/join", {"params": {"PROLIFIC_PID": pid}}, cookies).json()
        who = {"pid": pid, "session": joined["session"]}
        for step in range(2):  # consent, instructions
            cluster.request("/api/study/advance", {**who, "step": step, "agree": True}, cookies).raise_for_status()
        ws = socket_to(cluster, cookies)
        ws.send(json.dumps({"type": "new_game", "study": {"participant": pid, "session": joined["session"]}}))
        receive(ws, "welcome")  # the practice: a turn-based game waiting on its player, on its backend

        other = next(b for b in cluster.health()["backends"] if b["name"] != home)
        os.kill(other["pid"], signal.SIGKILL)
        # started again, and up once two of HAProxy's checks (every second) have passed: checks that are not logged
        wait_for_line(cluster, f"haproxy: {other['name']} is up again")

        # A stop while the game's backend cannot save it at once (the study's database is held): it takes a few
        # seconds, and HAProxy, told to stop, neither checks the backends meanwhile nor drops the game's socket.
        database = sqlite3.connect(cluster.folder / "study.sqlite", isolation_level=None, timeout=30)
        database.execute("BEGIN IMMEDIATE")
        cluster.process.send_signal(signal.SIGINT)
        wait_for_line(cluster, "stopping: the backends save their games")
        time.sleep(4)  # the save held this long: twice HAProxy's two checks a second apart, were it still checking
        database.execute("ROLLBACK")
        database.close()
        assert receive(ws, "game_over", timeout=60)["reason"] == "server_shutdown"  # told, through the proxy
        ws.close()
        assert cluster.process.wait(timeout=90) == 0
    finally:
        if cluster.process.poll() is None:
            stop_cluster(cluster)
    log = cluster.log()
    for said in ("starting 2 backends", "b1 ready on 127.0.0.1:", "b2 ready on 127.0.0.1:", "haproxy ready on",
                 f"{other['name']} stopped (killed by signal 9)", f"{other['name']} started again (restart 1",
                 f"haproxy: {other['name']} is down", "stopping: the backends save their games",
                 f'"GET /study?PROLIFIC_PID={pid} HTTP/1.1" 200', '"POST /api/study/join HTTP/1.1" 200'):
        assert said in log, (said, log)
    assert log.rstrip().endswith("colorgrid cluster: stopped"), log
    for noise in ("health?scope=backend", "leaked semaphore", "resource_tracker", "ALERT", "alert",
                  "Press CTRL+C", "Proxy colorgrid stopped", f"haproxy: {home} is down"):
        assert noise not in log, (noise, log)


def test_a_launcher_killed_outright_leaves_nothing_running(tmp_path):
    cluster = start_cluster(tmp_path, command=("study", "run", str(fast_study(tmp_path))),
                            env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    started = descendants(cluster.process.pid)  # the backends, their inference and worker processes, haproxy
    assert len(children(cluster.process.pid)) == 3
    try:
        os.kill(cluster.process.pid, signal.SIGKILL)  # no stop of its own: each child sees it gone
        cluster.process.wait(timeout=10)
        assert all_gone(started, timeout_s=120) == [], cluster.log()
        check_address_free("127.0.0.1", int(cluster.url.rsplit(":", 1)[1]))  # HAProxy's port is free again
    finally:
        kill_left(started)


def test_stop_with_parent_stops_the_launcher_and_all_it_started_when_its_parent_is_killed(tmp_path):
    port, log = free_port(), tmp_path / "cluster.log"
    launcher = [sys.executable, "-m", "colorgrid_apps", "play", "--processes", "2", "--port", str(port),
                "--replays-dir", str(tmp_path / "recordings"), "--log-level", "warning", *FAST_FOLLOWERS,
                "--stop-with-parent"]
    program = ("import subprocess, sys, time; "
               f"child = subprocess.Popen({launcher!r}, stdout=open({str(log)!r}, 'w'), stderr=subprocess.STDOUT); "
               "print(child.pid, flush=True); time.sleep(3600)")
    parent = subprocess.Popen([sys.executable, "-c", program], cwd=ROOT, stdout=subprocess.PIPE, text=True,
                              start_new_session=True)  # a bench, say, that starts a study and is killed
    started = [int(parent.stdout.readline())]
    try:
        deadline = time.monotonic() + 180
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5).json()["cluster"]["ready"] == 2:
                    break
            except (httpx.HTTPError, ValueError, KeyError, TypeError):
                pass
            assert alive(started[0]) and time.monotonic() < deadline, log.read_text()
            time.sleep(0.3)
        started += descendants(started[0])
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=10)
        assert all_gone(started, timeout_s=120) == [], log.read_text()
        text = log.read_text()
        assert "the program that started this one is gone: stopping" in text and "stopping: the backends" in text
        assert text.rstrip().endswith("colorgrid cluster: stopped"), text
    finally:
        if parent.poll() is None:
            os.kill(parent.pid, signal.SIGKILL)
        kill_left(started)
