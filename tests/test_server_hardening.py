"""The play server against hostile and unlucky clients: a real uvicorn on loopback, real sockets, real files.

The rule under test: hostile or broken input gets a clear error and costs no game, neither its
own nor anyone else's; finished games are never lost, not even to kill -9 or SIGTERM.
"""

import asyncio
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from websockets.asyncio.client import connect as aconnect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from bench.fuzz_server import hostile, hostile_frames
from colorgrid.replay import load, verify
from server.limits import FloodRule, TokenBucket
from tests.conftest import ROOT, start_server, stop_server
from tests.helpers import wait_until

MOVES = ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"]
RELEASED = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"


def recv(ws, *types, timeout=20.0):
    end = time.monotonic() + timeout
    while True:
        msg = json.loads(ws.recv(timeout=max(0.01, end - time.monotonic())))
        if not types or msg["type"] in types:
            return msg


def play_turns(ws, steps, start_seq=0):
    """Press ``steps`` keys in a turn-based game, each waiting for the state that applied it (not an earlier
    state still in flight, such as the one sent with ``welcome``); returns the last state."""
    state = None
    for t in range(steps):
        ws.send(json.dumps({"type": "key", "key": MOVES[t % 4], "seq": start_seq + t, "t_client": time.time() * 1000}))
        state = recv(ws, "state")
        while state["last_applied_seq"] != start_seq + t:
            state = recv(ws, "state")
    return state


def http(server, path, headers=None):
    request = urllib.request.Request(server.url + path, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, response.read(), dict(response.headers)
    except urllib.error.HTTPError as err:
        return err.code, err.read(), dict(err.headers)


def no_partial_files(folder: Path) -> bool:
    return not [p for p in folder.rglob("*") if p.name.startswith(".")]


def assert_no_tracebacks(server):
    log = server.log_path.read_text()
    assert "Traceback" not in log, log[-3000:]


# --------------------------------------------------------------------------- fuzz
def test_fuzzing_costs_no_game_and_a_game_played_alongside_verifies(tmp_path):
    srv = start_server(tmp_path, "--follower", "copy", "--new-games-per-minute", "1000")
    try:
        rng = random.Random(7)
        counts = {"sent": 0, "replies": 0, "errors": 0, "closed": {}}
        saved = []

        async def fuzz():  # hostile input, half of it inside games of its own; paced so it is read, not refused
            overs = await asyncio.gather(*(hostile(srv.ws_url, hostile_frames(rng, 250), i % 2 == 0, counts)
                                           for i in range(12)))
            saved.extend(o is not None and o["replay_id"] is not None for o in overs)

        fuzzer = background(lambda: asyncio.run(fuzz()))
        with connect(srv.ws_url, open_timeout=20, max_size=2**22) as ws:  # the legitimate player
            ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 60, "follower": "copy"}))
            recv(ws, "welcome")
            play_turns(ws, 60)
            over = recv(ws, "game_over")
        fuzzer.join(120)
        assert not fuzzer.is_alive()
        assert over["reason"] == "complete"
        replay = load(srv.replays_dir / f"{over['replay_id']}.replay.json")
        assert verify(replay).ok and replay.num_steps == 60
        assert counts["sent"] == 12 * 250 and counts["errors"] > 2000  # answered with errors, not dropped
        assert saved == [True, False] * 6  # the games that got hostile input are saved too
        for path in srv.replays_dir.glob("*.replay.json"):
            assert verify(load(path)).ok, path
        health = srv.get("/api/health")[0]
        assert health["games"] == 0 and health["save_failures"] == 0
        assert_no_tracebacks(srv)
    finally:
        stop_server(srv)


def background(target):
    import threading

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = start_server(tmp_path_factory.mktemp("hardening"), "--follower", "copy", "--max-sessions", "10",
                          "--new-games-per-minute", "1000", "--max-messages-per-s", "10",
                          "--connection-idle-s", "2", "--header-timeout-s", "1", "--max-replay-mb", "1", "--rejoin-grace-s", "1",
                          "--max-exports", "1", "--allowed-origin", "https://study.example.org")
    yield server
    stop_server(server)


def test_non_finite_numbers_and_deep_nesting_get_errors_and_the_game_is_saved(srv):
    with connect(srv.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 5}))
        recv(ws, "welcome")
        for raw in ('{"type":"key","key":"ArrowUp","seq":0,"t_client":NaN}',
                    '{"type":"key","key":"ArrowUp","seq":0,"t_client":Infinity}',
                    '{"type":"key","key":"ArrowUp","seq":0,"t_client":1e400}'):
            ws.send(raw)
            err = recv(ws, "error")
            assert err["code"] == "invalid_message" and "t_client" in err["message"], err
        ws.send("[" * 2000)
        err = recv(ws, "error")
        assert err["code"] == "bad_json" and "nested too deeply" in err["message"]
        last = play_turns(ws, 5)
        over = recv(ws, "game_over")
    assert over["reason"] == "complete" and over["scores"] == last["scores"]
    assert verify(load(srv.replays_dir / f"{over['replay_id']}.replay.json")).ok


def test_max_sessions_holds_exactly_under_concurrency_and_every_refusal_is_answered(srv):
    horizons = [7, 8, 9, 10, 11] * 12

    async def race():
        replies, everyone_answered = [], asyncio.Event()

        async def ask(horizon):
            async with aconnect(srv.ws_url, open_timeout=60) as ws:
                await ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": horizon}))
                while True:
                    msg = json.loads(await asyncio.wait_for(ws.recv(), 60))
                    if msg["type"] in ("welcome", "full", "error"):
                        replies.append(msg["type"])
                        break
                if len(replies) == len(horizons):
                    everyone_answered.set()
                await asyncio.wait_for(everyone_answered.wait(), 120)  # a game is kept until every socket has its answer

        await asyncio.gather(*(ask(h) for h in horizons))
        return replies

    replies = asyncio.run(race())
    assert replies.count("welcome") == 10 and replies.count("full") == 50, replies
    wait_until(lambda: srv.get("/api/health")[0]["games"] == 0, "the games of the closed sockets to end")


def test_origin_and_host_are_checked(srv):
    with pytest.raises(InvalidStatus) as refused:
        connect(srv.ws_url, open_timeout=20, origin="http://evil.example")
    assert refused.value.response.status_code == 403
    for origin in (f"http://127.0.0.1:{srv.port}", "https://study.example.org"):  # its own pages, the allow-list
        with connect(srv.ws_url, open_timeout=20, origin=origin) as ws:
            ws.send(json.dumps({"type": "ping"}))
            assert recv(ws, "pong")
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as raw:  # a rebound WebSocket handshake
        raw.sendall(b"GET /ws/play HTTP/1.1\r\nHost: evil.example\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
        assert raw.recv(100).split(b"\r\n")[0] in (b"HTTP/1.1 400 Bad Request", b"HTTP/1.1 403 Forbidden")
    status, body, _ = http(srv, "/api/health", {"Host": "rebound.example:80"})
    assert status == 400 and b"Invalid host" in body
    assert http(srv, "/api/health", {"Host": f"localhost:{srv.port}"})[0] == 200


def test_game_creation_is_rate_limited_per_address(tmp_path):
    server = start_server(tmp_path, "--follower", "copy", "--new-games-per-minute", "3")
    try:
        replies = []
        for _ in range(4):  # one game a socket: the server closes each after its game_over
            with connect(server.ws_url, open_timeout=20) as ws:
                ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 5}))
                msg = recv(ws, "welcome", "error")
                replies.append(msg)
                if msg["type"] == "welcome":
                    ws.send(json.dumps({"type": "quit"}))
                    recv(ws, "game_over")
        assert [m["type"] for m in replies] == ["welcome"] * 3 + ["error"]
        assert "at most 3 a minute" in replies[-1]["message"]
    finally:
        stop_server(server)


def test_rejoin_takes_the_game_over_and_the_old_socket_can_no_longer_move_it(srv):
    old = connect(srv.ws_url, open_timeout=20)
    old.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 6}))
    welcome = recv(old, "welcome")
    play_turns(old, 2)
    with connect(srv.ws_url, open_timeout=20) as new:
        new.send(json.dumps({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]}))
        assert recv(new, "welcome")["game_id"] == welcome["game_id"]
        assert recv(new, "state")["step"] == 2
        replaced = recv(old, "replaced")
        assert replaced["game_id"] == welcome["game_id"]
        old.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": 99}))
        assert recv(old, "error")["code"] == "rejected"
        old.close()  # the old socket's close does not touch the game
        wait_until(lambda: srv.get("/api/health")[0]["connections"] == 1, "the server to see the old socket closed")
        play_turns(new, 4, start_seq=2)
        over = recv(new, "game_over")
    assert over["reason"] == "complete" and over["steps"] == 6
    replay = load(srv.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok and [e["seq"] for e in replay.key_events] == list(range(6))


def test_idle_sockets_are_closed_and_connections_are_capped(tmp_path):
    server = start_server(tmp_path, "--follower", "copy", "--max-connections", "3", "--connection-idle-s", "1.5")
    try:
        sockets = [connect(server.ws_url, open_timeout=20) for _ in range(3)]
        with pytest.raises(InvalidStatus):
            connect(server.ws_url, open_timeout=20)
        with pytest.raises(ConnectionClosed) as closed:
            sockets[0].recv(timeout=10)
        assert closed.value.rcvd.code == 1001 and "idle" in closed.value.rcvd.reason
        for ws in sockets:
            ws.close()
        wait_until(lambda: server.get("/api/health")[0]["connections"] == 0, "the server to see the sockets closed")
        with connect(server.ws_url, open_timeout=20) as ws:  # room again
            ws.send(json.dumps({"type": "ping"}))
            assert recv(ws, "pong")
    finally:
        stop_server(server)


def test_half_sent_http_requests_are_closed(srv):
    conns = []
    for _ in range(5):
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=60)
        s.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        conns.append(s)
    for s in conns:  # the headers never end: each read waits until the server closes the connection
        assert s.recv(100) == b""  # closed by the server (--header-timeout-s 1), not answered
        s.close()
    assert srv.get("/api/health")[1] == 200


def test_a_flood_closes_the_socket(srv):
    """Pings as fast as a client can send them, against --max-messages-per-s 10: closed for flooding, and not
    before the server has refused more than 5 x 10 of them after the 2 x 10 it lets through at once."""
    closes = []

    def read(ws):  # a client that reads, so that the close frame reaches it
        try:
            for _ in ws:
                pass
        except ConnectionClosed as err:
            closes.append(err.rcvd)

    sent = 0
    with connect(srv.ws_url, open_timeout=20) as ws:
        reader = background(lambda: read(ws))
        with pytest.raises(ConnectionClosed):
            for sent in range(1, 1_000_001):  # ended by the server's close, long before the last
                ws.send(json.dumps({"type": "ping"}))
        reader.join(60)
    assert not reader.is_alive()
    assert closes and closes[0] is not None and closes[0].code == 1008 and closes[0].reason == "message flood"
    assert sent > 20 + 50, sent


def test_the_flood_rule_on_a_fixed_clock():
    """The socket's limits as ``server.connection`` sets them for 10 messages/s (bursts of 20, a flood past 50
    refused within 5 s), read on a clock the test moves: 25 messages a second are a flood within 5 s, 15 a second
    never are, and a burst is one at exactly its 20 + 51st message."""
    now = [0.0]

    def first_flood(interval_s: float, messages: int) -> int | None:
        now[0] = 0.0
        bucket, flood = TokenBucket(10, burst=20, clock=lambda: now[0]), FloodRule(50, 5.0, clock=lambda: now[0])
        for k in range(messages):
            now[0] = k * interval_s
            if not bucket.allow() and flood.refuse():
                return k + 1
        return None

    faster = first_flood(1 / 25, 10_000)
    assert faster is not None and faster / 25 <= 5.0, faster
    assert first_flood(1 / 15, 15 * 600) is None  # ten minutes at 15 a second: refused in part, never a flood
    assert first_flood(0.0, 1000) == 71


# ------------------------------------------------------------------ replay files
def make_bad_files(folder: Path, outside: Path) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    good = RELEASED.read_bytes()
    files = {
        "deep": ("[" * 100_000).encode(),
        "truncated": good[: len(good) // 2],
        "latin1": "{\"format\": \"caf\xe9\"}".encode("latin-1"),
        "empty": b"",
        "wrongtypes": json.dumps({"format": "colorgrid-replay", "format_version": 1, "steps": 5}).encode(),
        "toolarge": b" " * 1_200_000 + good,  # over --max-replay-mb 1
    }
    for name, data in files.items():
        (folder / f"{name}.replay.json").write_bytes(data)
    (folder / "adir.replay.json").mkdir()
    secret = outside / "secret.replay.json"
    secret.write_bytes(good)
    (folder / "link.replay.json").symlink_to(secret)
    (folder / "linkdir").symlink_to(outside, target_is_directory=True)
    return files


def test_broken_files_in_the_recordings_folder_get_clear_errors_and_nothing_outside_is_read(srv, tmp_path):
    files = make_bad_files(srv.replays_dir / "broken", tmp_path)
    listing = json.loads(http(srv, "/api/replays?limit=500")[1])
    by_id = {item["id"]: item for item in listing["items"]}
    for name in files:
        item = by_id[f"broken--{name}"]
        assert item["error"], item
    assert "nested too deeply" in by_id["broken--deep"]["error"]
    assert "the limit is 1.0 MB" in by_id["broken--toolarge"]["error"]
    assert not [i for i in by_id if "link" in i or "adir" in i]  # links and folders are not replays here
    for name in files:
        status, body, _ = http(srv, f"/api/replays/broken--{name}")
        assert status == 422 and "cannot be used" in json.loads(body)["detail"], (name, status, body[:200])
        status, body, _ = http(srv, f"/api/replays/broken--{name}/timeline")
        assert status == 200 and json.loads(body)["verified"] is False and json.loads(body)["problem"]
        assert http(srv, f"/api/replays/broken--{name}/export?format=gif")[0] == 422
    for replay_id in ("broken--link", "broken--adir", "broken--linkdir--secret"):
        assert http(srv, f"/api/replays/{replay_id}")[0] == 404
    assert_no_tracebacks(srv)


def test_exports_beyond_the_limit_answer_busy_and_run_off_the_event_loop(srv):
    ids = [f"released--{d}--astar+bayes_seed2026" for d in ("default", "symmetric", "stationary", "sparse")]

    async def fetch_all():
        loop = asyncio.get_running_loop()
        return await asyncio.gather(*(loop.run_in_executor(None, http, srv, f"/api/replays/{i}/export?format=gif")
                                      for i in ids))

    results = asyncio.run(fetch_all())
    statuses = [r[0] for r in results]
    assert statuses.count(200) >= 1 and statuses.count(503) >= 1, statuses
    busy = next(r for r in results if r[0] == 503)
    assert int(busy[2]["retry-after"]) > 0 and "busy" in json.loads(busy[1])["detail"]
    ok = next(r for r in results if r[0] == 200)
    assert ok[1][:6] == b"GIF89a"


# --------------------------------------------------------------- crashes and stops
def start_games(server, n, steps, follower="copy", hostile=False):
    clients = []
    for i in range(n):
        ws = connect(server.ws_url, open_timeout=20)
        ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 100, "follower": follower}))
        recv(ws, "welcome")
        play_turns(ws, steps)
        if hostile and i == 0:
            ws.send('{"type":"key","key":"ArrowUp","seq":500,"t_client":NaN}')
            assert recv(ws, "error")["code"] == "invalid_message"
        clients.append(ws)
    return clients


def test_sigterm_saves_every_live_game_and_tells_each_player(tmp_path):
    server = start_server(tmp_path, "--follower", "copy")
    clients = start_games(server, 3, steps=4, hostile=True)
    http(server, "/api/replays/released--default--astar+bayes_seed2026/export?format=gif")  # fills the export cache
    caches = set(Path(tempfile.gettempdir()).glob(f"colorgrid-exports-{server.process.pid}-*"))
    assert caches
    server.process.send_signal(signal.SIGTERM)
    overs = []
    for ws in clients:
        over = recv(ws, "game_over", timeout=30)
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=30)
        assert closed.value.rcvd.code == 1012
        overs.append(over)
    assert server.process.wait(timeout=30) in (0, -signal.SIGTERM)  # uvicorn re-raises the signal once done
    assert [o["reason"] for o in overs] == ["server_shutdown"] * 3
    for over in overs:
        replay = load(server.replays_dir / f"{over['replay_id']}.replay.json")
        assert verify(replay).ok and replay.ended == "server_shutdown" and replay.num_steps == 4
    assert no_partial_files(server.replays_dir)
    assert not any(c.exists() for c in caches), "the export cache is removed at exit"


def test_ctrl_c_saves_live_games_and_ends_without_a_traceback(tmp_path):
    """Ctrl+C in a terminal signals the server and every process it started (replay workers, inference): the
    server saves and tells each player, and neither it nor its workers print a traceback."""
    server = start_server(tmp_path, "--follower", "bayes", own_group=True)
    clients = start_games(server, 2, steps=3, follower="bayes")
    assert http(server, "/api/replays/released--default--astar+bayes_seed2026/timeline")[0] == 200  # a worker runs
    os.killpg(server.process.pid, signal.SIGINT)
    overs = [recv(ws, "game_over", timeout=30) for ws in clients]
    assert server.process.wait(timeout=30) == 0
    assert [o["reason"] for o in overs] == ["server_shutdown"] * 2
    for over in overs:
        assert verify(load(server.replays_dir / f"{over['replay_id']}.replay.json")).ok
    log = server.log_path.read_text()
    assert "Traceback" not in log and "KeyboardInterrupt" not in log, log[-3000:]


def running(pid: str) -> bool:
    """Whether process ``pid`` runs (a zombie waiting for its parent to read its exit status does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_kill_9_loses_no_finished_game_leaves_no_partial_file_and_no_worker(tmp_path):
    server = start_server(tmp_path, "--follower", "copy")
    finished = []
    for _ in range(2):
        with connect(server.ws_url, open_timeout=20) as ws:
            ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 8}))
            recv(ws, "welcome")
            play_turns(ws, 8)
            finished.append(recv(ws, "game_over")["replay_id"])
    live = start_games(server, 2, steps=3)
    assert http(server, "/api/replays/released--default--astar+bayes_seed2026/timeline")[0] == 200  # a worker runs
    children = subprocess.run(["pgrep", "-P", str(server.process.pid)], capture_output=True, text=True).stdout.split()
    assert len(children) >= 2  # the inference process and a replay worker
    server.process.send_signal(signal.SIGKILL)
    server.process.wait(timeout=20)
    for ws in live:
        ws.close()
    wait_until(lambda: not any(map(running, children)), "the server's worker processes to end when it is killed")
    saved = sorted(p.name for p in server.replays_dir.glob("*.replay.json"))
    assert saved == sorted(f"{i}.replay.json" for i in finished)
    for replay_id in finished:
        assert verify(load(server.replays_dir / f"{replay_id}.replay.json")).ok
    assert no_partial_files(server.replays_dir)


# ------------------------------------------------------------------------- CLI
@pytest.mark.parametrize("flags, words", [
    (["--follower", "nosuch"], "--follower 'nosuch' cannot be used: unknown policy"),
    (["--follower", "missing.pt"], "--follower 'missing.pt' cannot be used"),
    (["--replays-dir", "IS_A_FILE/recordings"], "is not a writable folder"),
    (["--max-connections", "0"], "max_connections must be a positive integer"),
])
def test_play_refuses_to_start_with_a_clear_line(tmp_path, flags, words):
    afile = tmp_path / "afile"
    afile.write_text("x")
    flags = [f.replace("IS_A_FILE", str(afile)) for f in flags]
    if "--replays-dir" not in flags:
        flags += ["--replays-dir", str(tmp_path / "rec")]
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "play", "--port", "0", *flags],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("colorgrid play: error: ") and words in lines[0], lines
