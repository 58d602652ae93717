"""Fuzz the play server: hostile WebSocket frames from many connections while real games play.

Usage: python bench/fuzz_server.py [--connections 200] [--frames 100] [--games 10] [--follower ippo]

Starts ``colorgrid play`` on a free loopback port. Each hostile connection sends ``--frames``
frames drawn from ``hostile_frames`` (non-finite numbers, deep nesting, binary, oversize,
wrong types, junk, impossible values), paced under the rate limit so that they are read, not
refused; half of them first start a game of their own, so the hostile input lands inside a
live game. Meanwhile ``--games`` players play turn-based games to the end. Prints the frames
sent, the replies, how sockets were closed, the games played alongside, whether every replay
verifies, and the games lost (a game with moves whose replay is missing). Bounded: a fixed
number of connections and frames, loopback only.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import time
import urllib.request
from pathlib import Path

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, start_play_server  # noqa: E402

MOVES = ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"]


def hostile_frames(rng: random.Random, n: int) -> list:
    """A mix of what breaks servers: non-finite numbers, deep nesting, binary, oversize, wrong types, junk."""
    makers = [
        lambda: '{"type":"key","key":"ArrowUp","seq":1,"t_client":NaN}',
        lambda: '{"type":"key","key":"ArrowUp","seq":2,"t_client":Infinity}',
        lambda: '{"type":"key","key":"ArrowUp","seq":3,"t_client":-Infinity}',
        lambda: '{"type":"key","key":"ArrowUp","seq":4,"t_client":1e400}',
        lambda: '{"type":"key","key":"ArrowUp","seq":1e400}',
        lambda: "[" * rng.randint(1000, 2000),
        lambda: '{"a":' * 700 + "1" + "}" * 700,
        lambda: bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 64))),
        lambda: "x" * rng.randint(2049, 4000),
        lambda: json.dumps(rng.choice([None, 1, -1.5, "key", [1, 2], {"type": None}, {"type": ["key"]}])),
        lambda: json.dumps({"type": rng.choice(["new_game", "rejoin", "key", "quit", "ping", "nope"]),
                            rng.choice(["seq", "key", "horizon", "game_id", "mode"]):
                                rng.choice([-1, 10**20, "A" * 40, None, True, [], {}, 1.5])}),
        lambda: json.dumps({"type": "new_game", "horizon": rng.choice([0, -5, 10**6, "10", 2.5]),
                            "follower": rng.choice(["../../etc/passwd", "nosuch", "x" * 500])}),
        lambda: json.dumps({"type": "rejoin", "game_id": "a" * 64, "token": "b" * 128}),
        lambda: "".join(chr(rng.randint(1, 0xD7FF)) for _ in range(rng.randint(1, 200))),
        lambda: '{"type":"key","key":"ArrowUp","seq":5,"t_client":1, "type":"key"}' + " " * rng.randint(0, 10),
    ]
    return [rng.choice(makers)() for _ in range(n)]


async def hostile(url: str, frames: list, start_game: bool, counts: dict) -> dict | None:
    """Send ``frames``; returns this connection's ``game_over`` if it started a game."""
    try:
        async with connect(url, max_size=2**22, open_timeout=60) as ws:
            async def read():
                async for raw in ws:
                    msg = json.loads(raw)
                    counts["replies"] += 1
                    counts["errors"] += msg["type"] == "error"
                    if msg["type"] == "game_over":
                        return msg

            reader = asyncio.create_task(read())
            if start_game:
                await ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": 500}))
                await ws.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": 0}))
            for frame in frames:
                await ws.send(frame)
                counts["sent"] += 1
                await asyncio.sleep(0.03)
            await ws.send(json.dumps({"type": "quit"}))
            return await asyncio.wait_for(reader, 60) if start_game else None
    except ConnectionClosed as err:
        code = err.rcvd.code if err.rcvd else None
        counts["closed"][code] = counts["closed"].get(code, 0) + 1
        return None


async def legit(url: str, horizon: int) -> dict:
    async with connect(url, max_size=2**22, open_timeout=60) as ws:
        await ws.send(json.dumps({"type": "new_game", "mode": "turn", "horizon": horizon}))
        for t in range(horizon):
            await ws.send(json.dumps({"type": "key", "key": MOVES[t % 4], "seq": t, "t_client": time.time() * 1000}))
            while json.loads(await ws.recv())["type"] != "state":
                pass
        while True:
            msg = json.loads(await ws.recv())
            if msg["type"] == "game_over":
                return msg


async def run(args) -> None:
    from colorgrid.replay import load, verify

    total = args.connections + args.games
    server, base, tmp = start_play_server("colorgrid-fuzz-", "--follower", args.follower, "--max-sessions", str(total),
                                          "--max-connections", str(2 * total), "--new-games-per-minute", str(10 * total))
    url = base.replace("http://", "ws://") + "/ws/play"
    try:
        rng = random.Random(args.seed)
        counts = {"sent": 0, "replies": 0, "errors": 0, "closed": {}}
        start = time.perf_counter()
        results = await asyncio.gather(
            *(hostile(url, hostile_frames(rng, args.frames), i % 2 == 0, counts) for i in range(args.connections)),
            *(legit(url, args.horizon) for _ in range(args.games)))
        wall = time.perf_counter() - start
        hostile_overs = [r for r in results[:args.connections] if r is not None]
        legit_overs = results[args.connections:]
        health = json.loads(urllib.request.urlopen(base + "/api/health", timeout=5).read())
    finally:
        server.terminate()
        server.wait(timeout=60)
    saved = {p.name[: -len(".replay.json")]: p for p in tmp.glob("*.replay.json")}
    verified = sum(verify(load(p)).ok for p in saved.values())
    wanted = [o["replay_id"] for o in legit_overs] + [o["replay_id"] for o in hostile_overs]
    lost = sum(1 for r in wanted if r is None or r not in saved) + (args.connections // 2 - len(hostile_overs))
    log = (tmp / "server.log").read_text()
    print(f"machine: {machine()}")
    print(f"{args.connections} hostile connections x {args.frames} frames, {args.games} games of {args.horizon} "
          f"steps alongside, follower {args.follower}, {wall:.0f} s")
    print(f"frames sent {counts['sent']}, replies {counts['replies']} ({counts['errors']} errors), "
          f"sockets closed by the server {counts['closed'] or 'none'}")
    print(f"games played alongside: {sum(o['reason'] == 'complete' for o in legit_overs)}/{args.games} complete; "
          f"games with hostile input saved: {len(hostile_overs)}/{args.connections // 2}")
    print(f"replays saved {len(saved)}, verified {verified}; games lost: {lost}; "
          f"server save failures {health['save_failures']}, deadline misses {health['deadline_misses']}, "
          f"tracebacks in the log: {log.count('Traceback')}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--connections", type=int, default=200)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--games", type=int, default=10)
    parser.add_argument("--horizon", type=int, default=100)
    parser.add_argument("--follower", default="ippo")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if not (1 <= args.connections <= 1000 and 1 <= args.frames <= 1000 and 0 <= args.games <= 100
            and 1 <= args.horizon <= 1000):
        raise SystemExit("--connections 1..1000, --frames 1..1000, --games 0..100, --horizon 1..1000 (a bounded load)")
    asyncio.run(run(args))


if __name__ == "__main__":
    main()
