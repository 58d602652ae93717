"""Fixtures: a real play server (uvicorn, started by the ``colorgrid play`` command) on a free loopback port.

Suite-wide rules set here: playwright's ``expect`` waits up to ``EXPECT_TIMEOUT_MS`` (a loaded 2-core CI machine,
not a fast desk), a skipped test fails the run unless ``ALLOWED_SKIPS`` names it (a missing dependency of the
project is a broken install, not a reason to pass), and every Ray the tests start runs its workers at the tests'
own priority (``RAY_WORKER_NICENESS``) and every torch waits for work without spinning (``OMP_WAIT_POLICY``)."""

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from playwright.sync_api import expect

ROOT = Path(__file__).resolve().parents[1]
EXPECT_TIMEOUT_MS = 30_000
"""How long an ``expect(...)`` waits for its condition, for every test: what a page shows within a second on a desk
may take many on a CI machine running a sweep beside the suite."""
expect.set_options(timeout=EXPECT_TIMEOUT_MS)
RAY_WORKER_NICENESS = "0"
"""Ray starts its worker processes (a sweep's trials, RLlib's runners) at nice 15 unless ``RAY_worker_niceness`` says
otherwise, so that its own services keep the CPU. Beside the suite's other workers, at nice 0, they then get almost
none: beside two busy cores, ``tests/test_sweep.py::test_tiny_sweep_writes_tables_and_report`` took 224 s at nice
15 and 25 s at nice 0 (docs/PERFORMANCE.md, run 46). Set here, before any test starts a Ray (in this process, or a
``colorgrid`` or ``ray start`` subprocess, which inherit it); a sweep's results do not depend on it."""
os.environ["RAY_worker_niceness"] = RAY_WORKER_NICENESS
OMP_WAIT_POLICY = "PASSIVE"
"""torch's OpenMP threads sleep between parallel regions instead of spinning a while first (libgomp's default), unless
the caller sets ``OMP_WAIT_POLICY`` itself. The suite's workers, servers and subprocesses share two cores with any
torch at its default two threads; a spinning thread burns CPU that they need. Beside a two-trial training sweep,
``python bench/bench_eval.py --leader population:people#training --follower checkpoints/follower_cautious.pt`` took
19.9 s with the variable unset and 4.9 s with it passive, and
``tests/test_train.py::test_the_cautious_follower_reproduces_its_card_and_meets_its_held_out_figures`` 60 s wall and
57 s CPU active against 40 s and 26 s passive (docs/PERFORMANCE.md). A whole ``make test`` with nothing beside it did
not change measurably (run 48). What torch computes does not change, only how an idle thread waits. Set here, before
torch is imported in this process (``TORCH_LOADED_BEFORE``: a rule test holds it False), and inherited by every
subprocess the tests start."""
TORCH_LOADED_BEFORE = "torch" in sys.modules
"""Whether torch was imported before this file set ``OMP_WAIT_POLICY`` (its OpenMP runtime would then not read it)."""
os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY)
ALLOWED_SKIPS: dict[str, str] = {}
"""Tests that may skip (node id -> why): none today. Any other skip is reported as a failure."""


def fail_a_skip(report) -> None:
    """Report a skip (a test's, or a module's at collection: ``importorskip``) as a failure, unless it is allowed."""
    if report.skipped and not hasattr(report, "wasxfail") and report.nodeid not in ALLOWED_SKIPS:
        reason = (report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr))
        reason = reason.removeprefix("Skipped: ")
        report.outcome = "failed"
        report.longrepr = (f"skipped ({reason}); a skip fails the run: install what it needs (make test installs "
                           "every extra), or list the test in ALLOWED_SKIPS (tests/conftest.py) with its reason")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    fail_a_skip(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    fail_a_skip(outcome.get_result())


def pytest_xdist_make_scheduler(config, log):
    """`make test` runs the tests on several workers (pytest-xdist, ``-n $TEST_WORKERS --dist loadscope``: the
    Makefile says how many) by file: a file's tests run on one worker in their order, so that a module's server or
    cluster starts once and each test finds it as the test before left it; the files that start a Ray run on one
    worker, one after another (``tests/scheduling.py``)."""
    if config.getoption("dist") == "loadscope":
        from tests.scheduling import FileScheduling

        return FileScheduling(config, log)
    return None


def free_port() -> int:
    """A port free a moment ago, for servers that take a port number only (HAProxy, Ray): another process may take
    it before they bind it. The play server is started on port 0 instead and says which port it got."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RunningServer:
    def __init__(self, port: int, replays_dir: Path, process: subprocess.Popen, log_path: Path):
        self.port, self.replays_dir, self.process, self.log_path = port, replays_dir, process, log_path
        self.url = f"http://127.0.0.1:{port}"
        self.ws_url = f"ws://127.0.0.1:{port}/ws/play"

    def get(self, path: str):
        with urllib.request.urlopen(self.url + path, timeout=30) as response:
            body = response.read()
            kind = response.headers.get("content-type", "")
            return (json.loads(body) if "json" in kind else body), response.status, kind


def start_server(tmp: Path, *flags: str, command: tuple[str, ...] = ("play",), env: dict | None = None,
                 own_group: bool = False, python: str = sys.executable, cwd: Path = ROOT) -> RunningServer:
    """``colorgrid play`` (or ``command``) on port 0 (a free one, bound by the server, which prints its address),
    once ready; ``own_group`` starts it in a process group of its own, as a terminal runs a command (Ctrl+C signals
    the whole group). ``python`` and ``cwd``: another installation (a virtualenv) run from another folder."""
    replays_dir = tmp / "recordings"
    log_path = tmp / "server.log"
    log = open(log_path, "w")
    process = subprocess.Popen(
        [python, "-m", "colorgrid_apps", *command, "--port", "0", "--replays-dir", str(replays_dir),
         "--log-level", "warning", *flags],
        cwd=cwd, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        start_new_session=own_group,
    )
    server = None
    deadline = time.monotonic() + 180  # a fresh checkout compiles the env step and loads torch first
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"server exited: {log_path.read_text()}")
        if server is None:  # the address it printed once its port was bound
            announced = re.search(r"http://127\.0\.0\.1:(\d+)/", log_path.read_text())
            server = RunningServer(int(announced.group(1)), replays_dir, process, log_path) if announced else None
        try:
            if server is not None and server.get("/api/health")[0]["ready"]:
                return server
        except OSError:
            pass
        time.sleep(0.2)
    process.kill()
    raise RuntimeError(f"server was not ready in 180 s: {log_path.read_text()}")


def stop_server(server: RunningServer) -> None:
    server.process.terminate()
    try:
        server.process.wait(timeout=20)
    except subprocess.TimeoutExpired:
        server.process.kill()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("server"), "--max-sessions", "4", "--rejoin-grace-s", "1.5",
                       "--tick-hz", "20")
    yield srv
    stop_server(srv)


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]


@pytest.fixture(scope="module")
def browser():
    """Debian's chromium driven by playwright (no browser download)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


@pytest.fixture(scope="session")
def postgres():
    """A PostgreSQL cluster of the tests' own (``tests/pg.py``), started on first use and removed at the end."""
    from tests.pg import PostgresCluster

    cluster = PostgresCluster.start()
    yield cluster
    cluster.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def study_database(request, tmp_path):
    """A new, empty study database on each backend: an SQLite file's path, or a PostgreSQL database's URL."""
    if request.param == "sqlite":
        return tmp_path / "study.sqlite"
    return request.getfixturevalue("postgres").new_database()
