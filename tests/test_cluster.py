"""Several play-server processes behind HAProxy (``--processes N``), for real: the launcher, Debian's haproxy,
uvicorn backends. Here: bad input in one line, the HAProxy configuration, and free play over two backends (the
browser's routing cookie, a room opened on one backend and joined, by its link or its typed code, from a page that
reached the other). The helpers start a cluster the way a researcher does, from the command line, in a process
group of its own."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import expect
from websockets.sync.client import connect

from colorgrid_apps.cli import main
from server.cluster.haproxy import BACKEND_COOKIE, BACKEND_HEADER, ROUTE_COOKIE, check_config, proxy_config
from server.cluster.plan import ClusterPlan, Member
from server.settings import ServerSettings
from tests.conftest import ROOT, free_port

FAST_FOLLOWERS = ("--follower", "bayes", "--followers", "copy")
"""No trained follower to load: each backend is ready in seconds."""


@dataclass
class RunningCluster:
    """A launcher started from the command line, its HAProxy's address and the folder it writes to."""

    process: subprocess.Popen
    url: str
    folder: Path
    log_path: Path

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://") + "/ws/play"

    def request(self, path: str, body: dict | None = None, cookies: dict | None = None,
                token: str | None = None) -> httpx.Response:
        """Through the proxy (a POST with ``body``), carrying ``cookies`` (and an admin ``token``); redirects are
        not followed."""
        headers = {"Cookie": "; ".join(f"{k}={v}" for k, v in cookies.items())} if cookies else {}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        return httpx.request("POST" if body is not None else "GET", self.url + path, json=body, headers=headers,
                             timeout=30)

    def health(self) -> dict:
        return self.request("/api/health").json()

    def log(self) -> str:
        return self.log_path.read_text()


def start_cluster(tmp: Path, *flags: str, command: tuple[str, ...] = ("play",), processes: int = 2,
                  env: dict | None = None) -> RunningCluster:
    """``colorgrid COMMAND --processes N`` on a free port, once every backend is ready behind the proxy; it stops
    with the tests, should they be killed (``--stop-with-parent``)."""
    port = free_port()
    folder = tmp / "recordings"
    log_path = tmp / "cluster.log"
    process = subprocess.Popen(
        [sys.executable, "-m", "colorgrid_apps", *command, "--processes", str(processes), "--port", str(port),
         "--replays-dir", str(folder), "--log-level", "warning", "--stop-with-parent", *FAST_FOLLOWERS, *flags],
        cwd=ROOT, stdout=open(log_path, "w"), stderr=subprocess.STDOUT, start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})})
    cluster = RunningCluster(process, f"http://127.0.0.1:{port}", folder, log_path)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the launcher exited: {cluster.log()}")
        try:
            if cluster.health()["cluster"]["ready"] == processes:
                return cluster
        except (httpx.HTTPError, ValueError, KeyError, TypeError):
            pass
        time.sleep(0.3)
    stop_cluster(cluster)
    raise RuntimeError(f"the cluster was not ready in 180 s: {cluster.log()}")


def stop_cluster(cluster: RunningCluster) -> int:
    """Ctrl+C, as a terminal sends it; the launcher's exit code."""
    if cluster.process.poll() is None:
        cluster.process.send_signal(signal.SIGINT)
    try:
        return cluster.process.wait(timeout=90)
    except subprocess.TimeoutExpired:
        os.killpg(cluster.process.pid, signal.SIGKILL)
        raise


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] if Path(f"/proc/{pid}").exists() else "X"
    return state not in ("Z", "X")


def children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def socket_to(cluster: RunningCluster, cookies: dict):
    """A play socket through the proxy carrying ``cookies``, as a page's socket carries its cookies."""
    cookie = "; ".join(f"{k}={v}" for k, v in cookies.items())
    return connect(cluster.ws_url, open_timeout=20, additional_headers={"Cookie": cookie})


def receive(ws, *types: str, timeout: float = 20.0) -> dict:
    """The next message of one of ``types`` (others are skipped)."""
    end = time.monotonic() + timeout
    while True:
        msg = json.loads(ws.recv(timeout=max(0.01, end - time.monotonic())))
        if msg["type"] in types:
            return msg


# ---------------------------------------------------------------- bad input, the configuration
@pytest.mark.parametrize("flags, words", [
    (["--processes", "0"], "--processes must be at least 1, got 0"),
    (["--processes", "9999"], "--processes 9999 is more than this machine can run"),
    (["--processes", "2", "--cluster", "cluster.json"], "--processes and --cluster are one or the other"),
    (["--backends", "10.0.0.1"], "--backends: '10.0.0.1' is not HOST:PORT"),
    (["--cluster", "missing.json"], "missing.json"),
])
def test_bad_cluster_flags_are_one_line_and_exit_code_2(flags, words, tmp_path, capsys):
    assert main(["play", "--replays-dir", str(tmp_path), "--port", "0", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("colorgrid play: error: ") and words in err and err.count("\n") == 1, err


def test_a_missing_haproxy_is_one_line_and_exit_code_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLORGRID_HAPROXY", str(tmp_path / "no-haproxy"))
    assert main(["play", "--replays-dir", str(tmp_path), "--port", "0", "--processes", "2"]) == 2
    err = capsys.readouterr().err
    assert "COLORGRID_HAPROXY" in err and err.count("\n") == 1, err
    monkeypatch.setenv("COLORGRID_HAPROXY", "")
    monkeypatch.setenv("PATH", str(tmp_path))
    import server.cluster.haproxy as haproxy

    monkeypatch.setattr(haproxy.shutil, "which", lambda *args, **kwargs: None)  # as on a machine without it
    assert main(["play", "--replays-dir", str(tmp_path), "--port", "0", "--processes", "2"]) == 2
    assert "apt-get install haproxy" in capsys.readouterr().err


def test_the_haproxy_configuration_is_valid_and_routes_by_the_study_id_then_the_cookie(tmp_path):
    plan = ClusterPlan.local("0.0.0.0", 8080, 3)
    text = proxy_config(plan, ServerSettings(idle_timeout_s=7200), ("PROLIFIC_PID", "pid"))
    path = tmp_path / "haproxy.cfg"
    path.write_text(text)
    check_config("haproxy", path)
    route = [line.split()[-1] if "unless" not in line else line.split()[2] for line in text.splitlines()
             if "set-var(txn.route)" in line]
    assert route == ["url_param(PROLIFIC_PID)", "url_param(pid)", f"req.cook({ROUTE_COOKIE})"]
    assert "    bind :8080" in text and "hash-type consistent" in text and "timeout tunnel 7260s" in text
    assert [line.split()[1] for line in text.splitlines() if line.startswith("    server ")] == ["b1", "b2", "b3"]
    remote = ClusterPlan.remote("::", 443, "10.0.0.11:9001, [fd00::2]:9001")
    assert [m.address for m in remote.members] == ["10.0.0.11:9001", "[fd00::2]:9001"]
    assert "    bind [::]:443" in proxy_config(remote, ServerSettings())


DOCUMENTED = ClusterPlan("0.0.0.0", 8000, (Member("b1", "127.0.0.1", 41237), Member("b2", "127.0.0.1", 39411),
                                            Member("b3", "127.0.0.1", 45063)), "secret")
"""The plan whose configuration docs/STUDIES.md shows."""


def test_docs_show_the_configuration_colorgrid_writes():
    text = proxy_config(DOCUMENTED, ServerSettings(), ("PROLIFIC_PID", "pid"))
    assert f"```\n{text}```" in (ROOT / "docs" / "STUDIES.md").read_text()


def test_haproxy_keeps_its_port_to_itself(tmp_path):
    # A listener with port reuse, as another study's HAProxy: without `noreuseport` a second one would share the port.
    import socket

    with socket.socket() as other:
        other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        other.bind(("127.0.0.1", 0))
        other.listen()
        plan = ClusterPlan("127.0.0.1", other.getsockname()[1], (Member("b1", "127.0.0.1", free_port()),), "secret")
        path = tmp_path / "haproxy.cfg"
        path.write_text(proxy_config(plan, ServerSettings()))
        try:
            result = subprocess.run(["haproxy", "-db", "-f", str(path)], capture_output=True, text=True, timeout=30)
        except subprocess.TimeoutExpired:
            raise AssertionError("a second HAProxy started on a port in use") from None
    assert result.returncode != 0 and "Address already in use" in result.stderr, result.stderr


# ---------------------------------------------------------------- free play over two backends
@pytest.fixture(scope="module")
def play_cluster(tmp_path_factory):
    cluster = start_cluster(tmp_path_factory.mktemp("play-cluster"), "--new-games-per-minute", "200")
    yield cluster
    stop_cluster(cluster)


def backend_of(cluster: RunningCluster, key: str) -> str:
    return cluster.request("/api/options", cookies={ROUTE_COOKIE: key}).headers[BACKEND_HEADER]


def test_a_browser_keeps_its_backend_by_the_cookie_the_play_page_sets(play_cluster):
    page = play_cluster.request("/")
    key = page.cookies[ROUTE_COOKIE]
    assert page.status_code == 200 and len(key) >= 12
    backend = backend_of(play_cluster, key)
    assert {backend_of(play_cluster, key) for _ in range(5)} == {backend}
    with socket_to(play_cluster, {ROUTE_COOKIE: key}) as ws:
        assert ws.response.headers[BACKEND_HEADER] == backend
        ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 3, "follower": "copy"}))
        assert receive(ws, "welcome")["mode"] == "turn"
    # a page that comes back keeps its key; another browser gets its own
    assert ROUTE_COOKIE not in play_cluster.request("/", cookies={ROUTE_COOKIE: key}).cookies
    assert play_cluster.request("/").cookies[ROUTE_COOKIE] != key


def a_key_on_each_backend(cluster: RunningCluster) -> list[tuple[str, str]]:
    """(backend, routing key) for each backend of a two-backend cluster: one browser on each."""
    keys = {}
    for i in range(40):
        keys.setdefault(backend_of(cluster, f"browser-{i}"), f"browser-{i}")
    assert len(keys) == 2
    return sorted(keys.items())


def test_a_room_link_opened_on_the_other_backend_is_sent_to_the_backend_holding_the_room(play_cluster):
    (home, opener), (away, joiner) = a_key_on_each_backend(play_cluster)
    with socket_to(play_cluster, {ROUTE_COOKIE: opener}) as first:
        assert first.response.headers[BACKEND_HEADER] == home
        first.send(json.dumps({"type": "create_room", "team": "2:1", "mode": "turn", "horizon": 3,
                               "follower": "copy"}))
        code = receive(first, "room")["code"]
        moved = play_cluster.request(f"/?room={code}", cookies={ROUTE_COOKIE: joiner})
        assert moved.status_code == 307 and moved.headers[BACKEND_HEADER] == away
        assert moved.headers["location"] == f"/?room={code}" and moved.cookies[BACKEND_COOKIE] == home
        sent = {ROUTE_COOKIE: joiner, BACKEND_COOKIE: home}
        page = play_cluster.request(f"/?room={code}", cookies=sent)
        assert page.status_code == 200 and page.headers[BACKEND_HEADER] == home
        with socket_to(play_cluster, sent) as second:
            assert second.response.headers[BACKEND_HEADER] == home
            second.send(json.dumps({"type": "join_room", "code": code}))
            joined = receive(second, "room", "error")
            assert joined["type"] == "room" and joined["you"] == "leader_1", joined
    unknown = play_cluster.request("/?room=ABCDEFGH", cookies={ROUTE_COOKIE: joiner})
    assert unknown.status_code == 200 and unknown.headers[BACKEND_HEADER] == away  # the page says so itself
    assert play_cluster.request(f"/api/cluster/rooms/{code}").status_code == 403  # only backends ask each other


def test_a_second_server_on_an_address_in_use_is_refused_in_one_line_before_anything_starts(play_cluster, tmp_path):
    from tests.test_study import fast_study

    port = play_cluster.url.rsplit(":", 1)[1]
    study = str(fast_study(tmp_path))
    commands = {"study, 2 processes": ("study", "run", study, "--processes", "2"), "study": ("study", "run", study),
                "play, 2 processes": ("play", "--processes", "2"), "play": ("play",),
                "play, proxy alone": ("play", "--backends", "127.0.0.1:9"),
                "play, one backend": ("play", "--cluster", str(play_cluster.folder / "cluster.json"))}
    started = {}
    for name, command in commands.items():
        folder = tmp_path / name.replace(" ", "_").replace(",", "")
        started[name] = folder, subprocess.Popen(
            [sys.executable, "-m", "colorgrid_apps", *command, "--port", port, "--replays-dir", str(folder),
             *FAST_FOLLOWERS], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            start_new_session=True)
    for name, (folder, process) in started.items():
        try:
            out, err = process.communicate(timeout=120)
        except subprocess.TimeoutExpired:  # it started: a second server on the address
            os.killpg(process.pid, signal.SIGTERM)
            process.communicate(timeout=60)
            raise AssertionError(f"{name}: started on 127.0.0.1:{port}, where another server listens") from None
        assert process.returncode == 2, (name, out, err)
        assert err.count("\n") == 1 and f"127.0.0.1:{port} is in use" in err, (name, err)
        assert not (folder / "haproxy.cfg").exists() and not (folder / "study.sqlite").exists(), name  # nothing started


def raw_get(url: str, target: str, headers: dict) -> tuple[int, dict]:
    """``GET target`` sent as written (no client re-encodes it) to ``url``'s host and port: the status and headers."""
    import http.client

    host, port = url.removeprefix("http://").rsplit(":", 1)
    connection = http.client.HTTPConnection(host, int(port), timeout=30)
    try:
        connection.request("GET", target, headers=headers)
        answer = connection.getresponse()
        answer.read()
        return answer.status, {k.lower(): v for k, v in answer.getheaders()}
    finally:
        connection.close()


def test_the_proxy_keeps_the_backends_questions_inside_however_the_path_is_written(play_cluster):
    plan = json.loads((play_cluster.folder / "cluster.json").read_text())
    secret = {"Authorization": f"Bearer {plan['secret']}"}  # the siblings' own: the backends would answer it
    backend = f"http://{plan['backends'][0]['host']}:{plan['backends'][0]['port']}"
    assert raw_get(backend, "/api/%63luster/rooms/ABCDEFGH", secret)[0] == 404  # decoded, it reaches the route
    assert raw_get(backend, "/api/cluster/rooms/%zz", secret)[0] == 404  # and so does an escape that is not one
    for target in ("/api/cluster/rooms/ABCDEFGH", "/api/%63luster/rooms/ABCDEFGH", "/%61pi/cluster/rooms/ABCDEFGH",
                   "/api%2Fcluster/rooms/ABCDEFGH", "/api/cluster%2Frooms/ABCDEFGH", "/api/cluster/rooms/%zz",
                   "/api/%63luster/rooms/%zz"):
        status, headers = raw_get(play_cluster.url, target, secret)
        assert status in (400, 403) and BACKEND_HEADER.lower() not in headers, (target, status, headers)
    assert raw_get(play_cluster.url, "/api/%6Fptions", {})[0] == 200  # other paths written so still pass


def test_a_room_code_typed_in_chromium_on_the_other_backend_joins_the_room(play_cluster, browser):
    (home, opener), (away, joiner) = a_key_on_each_backend(play_cluster)
    context = browser.new_context()
    context.add_cookies([{"name": ROUTE_COOKIE, "value": joiner, "url": play_cluster.url}])
    page = context.new_page()
    assert page.goto(play_cluster.url + "/").headers[BACKEND_HEADER.lower()] == away
    with socket_to(play_cluster, {ROUTE_COOKIE: opener}) as first:
        first.send(json.dumps({"type": "create_room", "team": "2:1", "mode": "turn", "horizon": 3,
                               "follower": "copy"}))
        code = receive(first, "room")["code"]
        page.fill("#join-code", code.lower())  # as typed
        page.click("#join")
        expect(page.locator("#joined")).to_be_visible()
        assert [s["status"] for s in receive(first, "room")["seats"]] == ["joined", "joined"]
    assert {c["name"]: c["value"] for c in context.cookies()}[BACKEND_COOKIE] == home
    context.close()


def test_health_through_the_proxy_reports_both_backends(play_cluster):
    health = play_cluster.health()
    cluster, backends = health["cluster"], health["backends"]
    assert cluster["size"] == cluster["up"] == cluster["ready"] == 2
    assert [b["name"] for b in backends] == ["b1", "b2"]
    assert health["backend"] in ("b1", "b2")
    for entry in backends:
        assert entry["up"] and {"games", "rooms", "connections", "tick_lateness_p50_ms", "tick_lateness_p99_ms",
                                "ticks", "deadline_misses", "pid"} <= set(entry)
    assert cluster["games"] == sum(b["games"] for b in backends)
    plan = json.loads((play_cluster.folder / "cluster.json").read_text())
    assert [b["name"] for b in plan["backends"]] == ["b1", "b2"]
    assert (play_cluster.folder / "cluster.json").stat().st_mode & 0o077 == 0  # the siblings' secret is in it
    assert "balance hash" in (play_cluster.folder / "haproxy.cfg").read_text()


def test_haproxy_alone_in_front_of_backends_elsewhere(play_cluster, tmp_path):
    """``--backends``: the proxy's role for backends on other machines (here: the two of the running cluster)."""
    plan = json.loads((play_cluster.folder / "cluster.json").read_text())
    backends = ",".join(f"{b['host']}:{b['port']}" for b in plan["backends"])
    port = free_port()
    log = tmp_path / "proxy.log"
    proxy = subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "play", "--backends", backends, "--port",
                              str(port), "--replays-dir", str(tmp_path), *FAST_FOLLOWERS], cwd=ROOT,
                             stdout=open(log, "w"), stderr=subprocess.STDOUT, start_new_session=True)
    alone = RunningCluster(proxy, f"http://127.0.0.1:{port}", tmp_path, log)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                answer = alone.request("/api/health", cookies={ROUTE_COOKIE: "someone"})
                break
            except httpx.HTTPError:
                assert proxy.poll() is None and time.monotonic() < deadline, log.read_text()
                time.sleep(0.2)
        assert answer.headers[BACKEND_HEADER] in ("b1", "b2") and len(answer.json()["backends"]) == 2
        assert "HAProxy in front of the backends" in log.read_text()
        written = json.loads((tmp_path / "cluster.json").read_text())
        assert [f"{b['host']}:{b['port']}" for b in written["backends"]] == backends.split(",")
    finally:
        assert stop_cluster(alone) == 0
