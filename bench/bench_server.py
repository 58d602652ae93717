"""Load on the play server: N concurrent scripted players in real time over WebSockets on loopback.

Usage: python bench/bench_server.py [--players 100] [--seconds 20] [--tick-hz 5] [--follower bayes]
                                   [--exports 8] [--large-replays] [--client-nice 10] [--max-connections N]

Starts ``colorgrid play`` on a free loopback port, connects N players (real-time games
that last the whole run), each pressing a random move key about 3 times a second, then
quits them all. Prints tick lateness p50/p99 (server side), key-to-applied latency
(client side: key sent -> first state that reports it applied), follower deadline
misses, the server's CPU use, and whether every game was saved. Bounded: N connections,
``--seconds`` of play, loopback only. The server takes at most 400 play sockets unless
``--max-connections`` raises its limit for the run; players past it are refused (close code 1013),
and the bench says so in one line.

``--exports K`` keeps K GIF/MP4 exports of distinct replays in flight for the whole run (the
server runs with ``--max-exports K``); ``--large-replays`` puts a 150 MB file (over the
server's limit) and a 40 MB replay (under it) among the server's replays and requests both,
list, file and timeline, over and over. Both measure whether live games stay on time.

The load clients run in this process on the same machine as the server; in a deployment they
are people's browsers elsewhere. ``--client-nice N`` lowers this process's CPU priority by N
(Linux ``nice``; the server keeps its own), so that on a machine with few cores the clients
take what the server leaves instead of competing with it. The clients' CPU use is printed
either way.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import statistics
import sys
from collections import Counter
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, start_play_server  # noqa: E402

KEYS = ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"]


def cpu_times() -> tuple[float, float] | None:
    """(all CPU time, time stolen by the hypervisor), in clock ticks summed over CPUs (``/proc/stat``), or None."""
    try:
        fields = [float(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return None
    return sum(fields[:8]), fields[7] if len(fields) > 7 else 0.0


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def player(url: str, seconds: float, latencies: list, results: list, rng: random.Random) -> None:
    """One player's game; a socket the server refuses or closes before the game's end is recorded as ``closed``
    (its close code and reason), not raised."""
    try:
        await play(url, seconds, latencies, results, rng)
    except ConnectionClosed as closed:  # refused past the server's --max-connections (1013), or dropped
        results.append({"type": "closed", "code": closed.rcvd.code if closed.rcvd else None,
                        "reason": closed.rcvd.reason if closed.rcvd else "no close frame"})
    except InvalidStatus as err:  # refused at the handshake (past --max-connections: 403)
        results.append({"type": "closed", "code": None, "reason": f"handshake answered {err.response.status_code}"})
    except (OSError, InvalidHandshake) as err:  # not even connected
        results.append({"type": "closed", "code": None, "reason": f"{type(err).__name__}: {err}"})


async def play(url: str, seconds: float, latencies: list, results: list, rng: random.Random) -> None:
    async with connect(url, max_size=2**22) as ws:
        await ws.send(json.dumps({"type": "new_game", "mode": "realtime", "horizon": 1000}))
        sent: dict[int, float] = {}
        seq = 0
        end = time.monotonic() + seconds

        async def press():
            nonlocal seq
            while time.monotonic() < end:
                await asyncio.sleep(rng.uniform(0.2, 0.45))
                sent[seq] = time.perf_counter()
                await ws.send(json.dumps({"type": "key", "key": rng.choice(KEYS), "seq": seq}))
                seq += 1
            await ws.send(json.dumps({"type": "quit"}))

        presser = asyncio.create_task(press())
        last_seen = -1
        try:
            async for raw in ws:
                msg = json.loads(raw)
                if msg["type"] == "state" and msg["last_applied_seq"] is not None:
                    now = time.perf_counter()
                    # Superseded keys are never applied: latency is measured for the key that was.
                    if msg["last_applied_seq"] > last_seen and msg["last_applied_seq"] in sent:
                        latencies.append((now - sent[msg["last_applied_seq"]]) * 1000)
                    last_seen = max(last_seen, msg["last_applied_seq"])
                elif msg["type"] == "game_over":
                    results.append(msg)
                    break
                elif msg["type"] in ("full", "error"):
                    results.append(msg)
            await presser
        finally:
            presser.cancel()


def refusals(results: list[dict], people: int, what: str) -> str | None:
    """One line on the sockets the server closed before their game's end (``closed`` results), or None."""
    closed = [r for r in results if r.get("type") == "closed"]
    if not closed:
        return None
    why = Counter(f"close {r['code']}: {r['reason']}" if r["code"] else r["reason"] for r in closed)
    return (f"refused: {len(closed)} of {people} {what} had their play socket refused or closed before their game "
            "ended ("
            + "; ".join(f"{n} x {reason}" for reason, n in why.most_common(3))
            + "); a server process takes at most --max-connections sockets (400 unless set): raise it for this run "
              "with this bench's --max-connections")


def http_status(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=120) as response:
            response.read()
            return response.status
    except urllib.error.HTTPError as err:
        return err.code


async def exporter(base: str, ids: list[str], end: float, counts: dict) -> None:
    """Export one replay after another (each new, so nothing comes from the cache) until ``end``."""
    loop = asyncio.get_running_loop()
    while time.monotonic() < end and ids:
        replay_id, fmt = ids.pop(), random.choice(["gif", "mp4"])
        status = await loop.run_in_executor(None, http_status, f"{base}/api/replays/{replay_id}/export?format={fmt}")
        counts[status] = counts.get(status, 0) + 1
        if status == 503:
            await asyncio.sleep(1.0)


async def large_requests(base: str, end: float, counts: dict) -> None:
    loop = asyncio.get_running_loop()
    while time.monotonic() < end:
        for path in ("/api/replays?limit=5", "/api/replays/released--huge", "/api/replays/released--huge/timeline",
                     "/api/replays/released--big", "/api/replays/released--big/timeline"):
            status = await loop.run_in_executor(None, http_status, base + path)
            counts[(path, status)] = counts.get((path, status), 0) + 1


def prepare_replays(folder: Path, exports: int, large: bool) -> list[str]:
    """Copies of a released replay to export (distinct ids), and the large files."""
    from colorgrid.replay import load, save

    source = Path(__file__).resolve().parents[1] / "replays" / "default" / "astar+bayes_seed2026.replay.json"
    ids = []
    if exports:
        (folder / "exports").mkdir()
        for i in range(40 * exports):
            (folder / "exports" / f"copy{i}.replay.json").write_bytes(source.read_bytes())
            ids.append(f"released--exports--copy{i}")
    if large:
        (folder / "huge.replay.json").write_bytes(b" " * 150_000_000 + source.read_bytes())
        replay = load(source)
        replay.meta["padding"] = "x" * 40_000_000
        save(replay, folder / "big.replay.json")
    return ids


async def run(args) -> None:
    folder = Path(tempfile.mkdtemp(prefix="colorgrid-replays-"))
    export_ids = prepare_replays(folder, args.exports, args.large_replays)
    server, base, tmp = start_play_server("colorgrid-load-", "--tick-hz", str(args.tick_hz), "--follower",
                                          args.follower, "--max-sessions", str(args.players), "--new-games-per-minute",
                                          str(10 * args.players), "--max-exports", str(max(1, args.exports)),
                                          "--released-dir", str(folder),
                                          *(["--max-connections", str(args.max_connections)] if args.max_connections
                                            else []))
    port = base.rsplit(":", 1)[1]
    if args.client_nice:
        os.nice(args.client_nice)  # this thread, and the executor threads it starts from here on
    try:
        inference = json.loads(urllib.request.urlopen(base + "/api/health", timeout=5).read()).get("inference_pid")
        server_pids = [server.pid] + ([inference] if inference else [])
        cpu0 = [cpu_seconds(pid) for pid in server_pids]
        wall0, own0, machine0 = time.perf_counter(), cpu_seconds(os.getpid()), cpu_times()
        latencies: list[float] = []
        results: list[dict] = []
        rng = random.Random(0)
        export_counts: dict = {}
        large_counts: dict = {}
        end = time.monotonic() + args.seconds
        side = [exporter(base, export_ids, end, export_counts) for _ in range(args.exports)]
        if args.large_replays:
            side.append(large_requests(base, end, large_counts))
        await asyncio.gather(*side, *(player(f"ws://127.0.0.1:{port}/ws/play", args.seconds, latencies, results,
                                             random.Random(rng.random())) for _ in range(args.players)))
        cpu = [cpu_seconds(pid) - c0 for pid, c0 in zip(server_pids, cpu0)]
        wall = time.perf_counter() - wall0
        own = cpu_seconds(os.getpid()) - own0
        machine1 = cpu_times()
        health = json.loads(urllib.request.urlopen(base + "/api/health", timeout=5).read())
        saved = len(list(tmp.glob("play-*.replay.json")))
        await asyncio.sleep(0)
        ended = sum(1 for r in results if r["type"] == "game_over")
        print(f"machine: {machine()}")
        print(f"{args.players} real-time games at {args.tick_hz} Hz, follower {args.follower}, {args.seconds:.0f} s")
        print(f"tick lateness: p50 {health['tick_lateness_p50_ms']:.2f} ms, p99 {health['tick_lateness_p99_ms']:.2f} ms, "
              f"max {health['max_lateness_ms']:.1f} ms over {health['ticks']} ticks")
        if latencies:
            q = statistics.quantiles(latencies, n=100)
            print(f"key to applied: p50 {q[49]:.0f} ms, p99 {q[98]:.0f} ms over {len(latencies)} keys "
                  f"(a key waits for the next tick: up to {1000 / args.tick_hz:.0f} ms by design)")
        print(f"follower deadline misses: {health['deadline_misses']}")
        parts = f" (inference process {cpu[1]:.1f} s)" if len(cpu) > 1 else ""
        print(f"server CPU: {sum(cpu):.1f} s over {wall:.1f} s wall ({100 * sum(cpu) / wall:.0f}% of one core)"
              f"{parts}; replay and export workers not counted")
        print(f"load clients' CPU: {own:.1f} s ({100 * own / wall:.0f}% of one core), nice +{args.client_nice}")
        if machine0 and machine1 and machine1[0] > machine0[0]:
            steal = 100 * (machine1[1] - machine0[1]) / (machine1[0] - machine0[0])
            print(f"CPU time stolen by the hypervisor during the run: {steal:.1f}% (a virtual machine's neighbours)")
        print(f"games ended {ended}/{args.players}, replays saved {saved}/{args.players}; server log {tmp / 'server.log'}")
        refused = refusals(results, args.players, "players")
        if refused:
            print(refused)
        if args.exports:
            print(f"exports alongside ({args.exports} in flight): {export_counts.get(200, 0)} made, "
                  f"{export_counts.get(503, 0)} answered busy (503), other {[k for k in export_counts if k not in (200, 503)]}")
        if args.large_replays:
            print("large replay requests (path, status): count: "
                  + ", ".join(f"{p} {st}: {n}" for (p, st), n in sorted(large_counts.items())))
    finally:
        server.terminate()
        server.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--players", type=int, default=100)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--tick-hz", type=float, default=5.0)
    parser.add_argument("--follower", default="bayes")
    parser.add_argument("--exports", type=int, default=0, help="exports kept in flight during the run (0..16)")
    parser.add_argument("--large-replays", action="store_true", help="also request a 150 MB and a 40 MB replay")
    parser.add_argument("--client-nice", type=int, default=0,
                        help="lower the load clients' CPU priority by this much (0..19; the server keeps its own)")
    parser.add_argument("--max-connections", type=int, default=None,
                        help="the server's limit of open play sockets for this run (default: its own, 400); more "
                             "players than it are refused")
    args = parser.parse_args()
    if args.max_connections is not None and not 1 <= args.max_connections <= 10_000:
        raise SystemExit("--max-connections must be in 1..10000")
    if not 0 <= args.client_nice <= 19:
        raise SystemExit("--client-nice must be in 0..19")
    if not 0 <= args.exports <= 16:
        raise SystemExit("--exports must be in 0..16")
    if not 1 <= args.players <= 500 or not 1 <= args.seconds <= 300:
        raise SystemExit("--players must be in 1..500 and --seconds in 1..300 (a bounded load)")
    asyncio.run(run(args))


if __name__ == "__main__":
    main()
