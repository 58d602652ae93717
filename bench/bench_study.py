"""Load on a study: P simulated participants through a short real-time study, on N backends behind HAProxy.

Usage: python bench/bench_study.py --participants 40 --processes 2 [--trial-steps 50] [--tick-hz 5]
                                  [--follower bayes-people] [--side-load] [--database URL] [--arrival-s 0]
                                  [--max-connections N]

Writes a short version of the example study (``studies/belief_display.toml``: consent, instructions,
a practice game, four real-time trials of ``--trial-steps`` steps, a question after each, the final
questionnaire), starts ``colorgrid study run STUDY --processes N`` on a free loopback port (N=1: one
server, no proxy), and sends P participants at once (or spread over ``--arrival-s``). Each joins with
its own ``PROLIFIC_PID`` and goes through every page as the study page does: the HTTP study API for
the pages, one WebSocket per game, a random arrow key about three times a second, an answer to
every question. Then prints, with the machine and the CPU time the hypervisor stole:

* completion: participants who reached the debrief, and games that ended;
* assignment: participants per order (the study's balance), from the admin summary;
* p99 tick lateness per backend (each backend's own ``/api/health``, through the proxy's
  ``backends`` list where there is one);
* CPU seconds per process: the launcher, each backend and its inference process, HAProxy;
* games lost: games a participant saw end (``game_over``) without a replay file in the
  recordings folder (must be 0);
* refusals, in one line: participants whose play socket a server process refused or closed (each
  takes at most 400 sockets unless ``--max-connections`` raises its limit for the run).

``--side-load`` runs, during the whole study, 8 GIF/MP4 exports of replays (``colorgrid export``
processes) and repeated loads of a 150 MB replay file, on the same machine at ``nice`` 10, the
priority the play server gives its own export and replay workers: live games may not be late
because of them.

The participants are asyncio tasks in this process on the same machine as the servers; in a
deployment they are people's browsers elsewhere, so their CPU use is printed too.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_server import KEYS, cpu_seconds, cpu_times, refusals  # noqa: E402
from common import machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "bench-study-admin-token"
SIDE_NICE = 10
"""The side load's CPU priority: the play server's own export and replay workers run at ``nice`` 10 (server/jobs.py)."""


def study_file(folder: Path, participants: int, trial_steps: int, tick_hz: float, follower: str | None) -> Path:
    """The example study, short: ``trial_steps`` per trial, a 20-step practice, room for ``participants``."""
    text = (ROOT / "studies" / "belief_display.toml").read_text()
    quota = -(-participants // 4)  # four orders
    for pattern, value in ((r"max_participants = \d+", f"max_participants = {4 * quota}"),
                           (r"quota = \d+", f"quota = {quota}"), (r"horizon = 100", f"horizon = {trial_steps}"),
                           (r"tick_hz = [\d.]+", f"tick_hz = {tick_hz}"), (r"horizon = 40", "horizon = 20")):
        text, n = re.subn(pattern, value, text, count=1)
        if n != 1:
            raise SystemExit(f"the example study changed: {pattern!r} not found in studies/belief_display.toml")
    if follower:
        text = text.replace('follower = ["bayes-people", "ippo-people"]', f'follower = ["{follower}", "copy"]')
    path = folder / "bench_study.toml"
    path.write_text(text)
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(base: str, path: str, body: dict | None = None, token: str | None = None) -> tuple[int, dict | bytes]:
    headers = {"Content-Type": "application/json"} if body is not None else {}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(base + path, data=data, headers=headers, method="POST" if data else "GET")
    try:
        with urllib.request.urlopen(req, timeout=120) as response:
            raw = response.read()
            status = response.status
    except urllib.error.HTTPError as err:
        raw, status = err.read(), err.code
    try:
        return status, json.loads(raw)
    except ValueError:
        return status, raw


def answers(questions: list[dict], rng: random.Random) -> dict:
    """A valid answer to each question, as a participant might give."""
    out = {}
    for q in questions:
        if q["kind"] == "likert":
            out[q["id"]] = rng.randint(1, q["scale"])
        elif q["kind"] == "choice":
            out[q["id"]] = rng.choice(q["options"])
        else:
            out[q["id"]] = None if not q.get("required", True) else "fine"
    return out


async def play(ws_url: str, ref: dict, rng: random.Random) -> dict:
    """One real-time game of the study, keys about three times a second, until it ends: its ``game_over``; a socket
    the server refuses or closes first: ``closed`` with its close code and reason."""
    try:
        return await play_game(ws_url, ref, rng)
    except ConnectionClosed as closed:  # refused past a process's --max-connections (1013), or dropped
        return {"type": "closed", "code": closed.rcvd.code if closed.rcvd else None,
                "reason": closed.rcvd.reason if closed.rcvd else "no close frame"}
    except InvalidStatus as err:  # refused at the handshake (past --max-connections: 403)
        return {"type": "closed", "code": None, "reason": f"handshake answered {err.response.status_code}"}
    except (OSError, InvalidHandshake) as err:  # not even connected
        return {"type": "closed", "code": None, "reason": f"{type(err).__name__}: {err}"}


async def play_game(ws_url: str, ref: dict, rng: random.Random) -> dict:
    async with connect(ws_url, max_size=2**22, open_timeout=60) as ws:
        await asyncio.sleep(3.0)  # the page's 3-2-1 countdown comes before new_game
        await ws.send(json.dumps({"type": "new_game", "study": ref, "viewport": [1280, 800]}))
        done, started = asyncio.Event(), asyncio.Event()

        async def press():  # as the page does: keys once the game is on, until it ends
            await started.wait()
            seq = 0
            while not done.is_set():
                await asyncio.sleep(rng.uniform(0.2, 0.45))
                if not done.is_set():
                    try:
                        await ws.send(json.dumps({"type": "key", "key": rng.choice(KEYS), "seq": seq}))
                    except ConnectionClosed:  # the game ended: the server closes its socket after game_over
                        return
                    seq += 1

        presser = asyncio.create_task(press())
        game_id = None
        try:
            async for raw in ws:
                msg = json.loads(raw)
                if msg["type"] == "welcome":
                    game_id = msg.get("game_id")
                    started.set()
                elif msg["type"] == "game_over" or (msg["type"] == "error" and game_id is None):
                    return {**msg, "game_id": game_id}
                # an error once the game is on: a key that crossed the game's end (the page ignores it too)
            return {"type": "closed"}
        finally:
            done.set()
            presser.cancel()


async def participant(base: str, ws_url: str, pid: str, rng: random.Random, delay: float, out: dict) -> None:
    loop = asyncio.get_running_loop()
    call = lambda path, body: loop.run_in_executor(None, request, base, path, body)  # noqa: E731
    await asyncio.sleep(delay)
    status, joined = await call(f"/api/study/join?pid={pid}", {"params": {"PROLIFIC_PID": pid, "SESSION_ID": "bench"}})
    if status != 200:
        out["refused"] = f"{status} {joined}"
        return
    who = {"pid": pid, "session": joined["session"]}
    view = joined["view"]
    games = out.setdefault("games", [])
    while view["kind"] != "debrief":
        body: dict = {}
        if view["kind"] == "consent":
            body = {"agree": True}
        elif view.get("game"):
            over = await play(f"{ws_url}?pid={pid}", {"participant": pid, "session": joined["session"]}, rng)
            games.append(over)
            if over["type"] != "game_over":
                out["error"] = over
                return
        elif view.get("questions"):
            body = {"answers": answers(view["questions"], rng)}
        status, view = await call(f"/api/study/advance?pid={pid}", {**who, "step": view["step"], **body})
        if status != 200:
            out["error"] = f"advance: {status} {view}"
            return
    out["completed"] = True


def process_tree(pid: int) -> list[int]:
    """``pid`` and every process below it (Linux ``/proc``)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def process_name(pid: int, children: dict[int, list[int]] | None = None) -> str:
    """What a process of the study is: the launcher or single server, a backend, HAProxy, or a worker."""
    try:
        words = [w.decode(errors="replace") for w in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if w]
    except OSError:
        return "?"
    joined = " ".join(words)
    if words and "haproxy" in Path(words[0]).name:
        return "haproxy"
    if "server.cluster.process" in joined:
        return f"backend (pid {pid})"
    if "study run" in joined or " play" in joined:
        return "launcher or single server"
    if "multiprocessing" in joined:
        return "workers (inference, replay jobs)"
    return " ".join(words[:3])[:60]


def export(replay: Path, out: Path) -> subprocess.Popen:
    """``colorgrid export`` of ``replay`` to ``out`` (GIF or MP4 by its suffix), as a process of its own."""
    return subprocess.Popen([sys.executable, "-m", "colorgrid_apps", "export", str(replay), "--format", out.suffix[1:],
                             "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=lambda: os.nice(SIDE_NICE))


def side_load(folder: Path, stop: float) -> list[subprocess.Popen]:
    """8 exports in flight (each a ``colorgrid export`` process, started again when it ends) and loads of a 150 MB
    replay file, until ``stop`` (``time.monotonic()``); returns the processes still running."""
    source = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"
    big = folder / "big.replay.json"
    data = json.loads(source.read_text())
    data.setdefault("meta", {})["padding"] = "x" * 150_000_000
    big.write_text(json.dumps(data))
    script = (f"import time, json\nfrom colorgrid.replay import load\nend = {stop!r}\n"
              f"while time.monotonic() < end:\n    load({str(big)!r})\n")
    running = [subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                preexec_fn=lambda: os.nice(SIDE_NICE))]
    exports = []
    for i in range(8):
        out = folder / f"export{i}.{'gif' if i % 2 else 'mp4'}"
        exports.append(export(source, out))
    return running + exports


async def keep_exports_going(folder: Path, processes: list[subprocess.Popen], stop: float, made: list) -> None:
    source = ROOT / "replays" / "default" / "astar+bayes_seed2026.replay.json"
    while time.monotonic() < stop:
        await asyncio.sleep(0.5)
        for i, p in enumerate(processes):
            if i and p.poll() is not None:  # an export ended: count it, start the next
                made.append(p.returncode)
                out = folder / f"export{i}_{len(made)}.{'gif' if i % 2 else 'mp4'}"
                processes[i] = export(source, out)


def start(args, folder: Path) -> tuple[subprocess.Popen, str]:
    study = study_file(folder, args.participants, args.trial_steps, args.tick_hz, args.follower)
    port = free_port()
    command = [sys.executable, "-m", "colorgrid_apps", "study", "run", str(study), "--port", str(port),
               "--replays-dir", str(folder / "recordings"), "--log-level", "warning", "--stop-with-parent",
               "--max-sessions", str(max(100, 2 * args.participants)),
               "--new-games-per-minute", str(max(30, 20 * args.participants))]  # every participant is on loopback
    if args.processes > 1:
        command += ["--processes", str(args.processes)]
    if args.max_connections:
        command += ["--max-connections", str(args.max_connections)]
    if args.database:
        command += ["--database", args.database]
    server = subprocess.Popen(command, stdout=open(folder / "server.log", "w"), stderr=subprocess.STDOUT,
                              env={**os.environ, "COLORGRID_ADMIN_TOKEN": TOKEN}, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise SystemExit(f"the study server exited: {(folder / 'server.log').read_text()[-2000:]}")
        try:
            health = request(base, "/api/health")[1]
            backends = health.get("backends") if isinstance(health, dict) else None
            if isinstance(health, dict) and health.get("ready") and \
                    (backends is None or sum(1 for b in backends if b.get("ready")) >= args.processes):
                return server, base
        except OSError:
            pass
        time.sleep(0.5)
    server.kill()
    raise SystemExit(f"the study was not ready in 300 s; see {folder / 'server.log'}")


def backend_healths(health: dict) -> list[dict]:
    """One health answer per backend: the proxy's ``backends`` list, or the one server's own answer."""
    return health.get("backends") or [health]


async def run(args) -> None:
    folder = Path(tempfile.mkdtemp(prefix="colorgrid-study-load-"))
    server, base = start(args, folder)
    ws_url = base.replace("http://", "ws://") + "/ws/play"
    tree0 = {pid: cpu_seconds(pid) for pid in process_tree(server.pid)}
    wall0, own0, machine0 = time.perf_counter(), cpu_seconds(os.getpid()), cpu_times()
    rng = random.Random(args.seed)
    outcomes = [{} for _ in range(args.participants)]
    side, exports_made = [], []
    try:
        tasks = [participant(base, ws_url, f"bench-{i:04d}", random.Random(rng.random()),
                             rng.uniform(0, args.arrival_s), outcomes[i]) for i in range(args.participants)]
        if args.side_load:
            stop = time.monotonic() + 3600
            side = side_load(folder, stop)
            keeper = asyncio.create_task(keep_exports_going(folder, side, stop, exports_made))
        await asyncio.gather(*tasks)
        if args.side_load:
            keeper.cancel()
        wall = time.perf_counter() - wall0
        cpu: dict[str, float] = {}
        for pid in process_tree(server.pid):
            try:
                seconds = cpu_seconds(pid) - tree0.get(pid, 0.0)
            except OSError:  # ended meanwhile
                continue
            cpu[process_name(pid)] = cpu.get(process_name(pid), 0.0) + seconds
        own = cpu_seconds(os.getpid()) - own0
        machine1 = cpu_times()
        health = request(base, "/api/health")[1]
        summary = request(base, "/api/study/admin/summary", token=TOKEN)[1]
    finally:
        for p in side:
            p.kill()
        os.killpg(server.pid, 15)
        try:
            server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, 9)
    completed = sum(1 for o in outcomes if o.get("completed"))
    games = [g for o in outcomes for g in o.get("games", [])]
    ended = [g for g in games if g.get("type") == "game_over"]
    saved = {p.name for p in (folder / "recordings").rglob("*.replay.json")}
    lost = [g for g in ended if not any(name.endswith(f"{g['game_id']}.replay.json") for name in saved)]
    print(f"machine: {machine()}")
    print(f"{args.participants} participants, {args.processes} backend(s), {args.trial_steps}-step real-time trials "
          f"at {args.tick_hz} Hz, arrival over {args.arrival_s:.0f} s, side load: {'on' if args.side_load else 'off'}; "
          f"{wall:.0f} s")
    print(f"completed: {completed}/{args.participants}; games ended {len(ended)} of {len(games)} started; "
          f"games lost (ended, no replay file): {len(lost)}")
    problems = [o.get("refused") or o.get("error") for o in outcomes if not o.get("completed")]
    refused = refusals([p for p in problems if isinstance(p, dict)], args.participants, "participants")
    if refused:
        print(refused)
    others = [p for p in problems if not (isinstance(p, dict) and p.get("type") == "closed")]
    if others:
        print(f"  not completed ({len(others)}): {str(others[:3])[:400]}")
    arms = summary.get("arms") if isinstance(summary, dict) else None
    if arms:
        print("assignment per order (completed + active): " +
              ", ".join(f"{a['label']} {a['completed']} + {a['active']}" for a in arms))
    for h in backend_healths(health):
        name = h.get("backend") or h.get("name") or "server"
        late = {k: h.get(k, float("nan")) for k in ("tick_lateness_p50_ms", "tick_lateness_p99_ms", "max_lateness_ms")}
        print(f"  {name}: tick lateness p50 {late['tick_lateness_p50_ms']:.2f} ms, "
              f"p99 {late['tick_lateness_p99_ms']:.2f} ms, max {late['max_lateness_ms']:.1f} ms "
              f"over {h.get('ticks')} ticks; follower deadline misses {h.get('deadline_misses')}")
    print("CPU seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in sorted(cpu.items())) +
          f"; participants (this process) {own:.1f}")
    if machine0 and machine1 and machine1[0] > machine0[0]:
        print(f"CPU time stolen by the hypervisor during the run: "
              f"{100 * (machine1[1] - machine0[1]) / (machine1[0] - machine0[0]):.1f}%")
    if args.side_load:
        print(f"side load (nice {SIDE_NICE}): {len(exports_made)} exports finished "
              f"({sum(1 for r in exports_made if r == 0)} ok), a 150 MB replay loaded over and over")
    print(f"recordings and log: {folder}")
    if not args.keep:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--participants", type=int, default=40)
    parser.add_argument("--processes", type=int, default=1)
    parser.add_argument("--trial-steps", type=int, default=50)
    parser.add_argument("--tick-hz", type=float, default=5.0)
    parser.add_argument("--follower", default=None, help="the study's first follower (default: the example's)")
    parser.add_argument("--database", default=None, help="a PostgreSQL URL (default: the study's SQLite file)")
    parser.add_argument("--arrival-s", type=float, default=0.0, help="spread the arrivals over this many seconds")
    parser.add_argument("--side-load", action="store_true", help="8 exports and a 150 MB replay loaded meanwhile")
    parser.add_argument("--max-connections", type=int, default=None,
                        help="each server process's limit of open play sockets for this run (default: its own, 400)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", action="store_true", help="keep the recordings folder")
    args = parser.parse_args()
    if not 1 <= args.participants <= 1000 or not 1 <= args.processes <= 16:
        raise SystemExit("--participants must be in 1..1000 and --processes in 1..16 (a bounded load)")
    if not 5 <= args.trial_steps <= 500:
        raise SystemExit("--trial-steps must be in 5..500")
    if args.max_connections is not None and not 1 <= args.max_connections <= 10_000:
        raise SystemExit("--max-connections must be in 1..10000")
    asyncio.run(run(args))


if __name__ == "__main__":
    main()
