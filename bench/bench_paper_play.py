"""Whether the paper's networks keep time on the play server: follower deadline misses in real-time games.

Usage: python bench/bench_paper_play.py [--games 5] [--horizon 50] [--tick-hz 5] [--deadline-ms 100]

Imports the paper checkpoint the tests use (``tests/data/paper``) as a leader and as an asymmetric follower with an
LSTM (``colorgrid checkpoint import-paper``), starts ``colorgrid play`` with the paper follower as its default and the
paper leader offered, and plays ``--games`` real-time games of each kind one after another, nobody pressing a key:
the paper follower beside a person (1:1), and the paper leader beside a person (2:1). Each game's replay records the
steps at which a network missed the server's inference deadline (``--inference-deadline-ms``; a miss is played as an
idle move). Prints the machine (CPU model, CPUs, thread settings), the server's settings, and per kind of game the
misses over the steps played. tests/test_paper_play.py checks that these games are played and recorded; how often a
deadline is missed depends on the machine and what else runs on it, so it is measured here, not asserted there.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
from common import machine, start_play_server  # noqa: E402

from websockets.sync.client import connect  # noqa: E402

from colorgrid.replay import load  # noqa: E402
from tests.test_paper_play import import_paper_checkpoints  # noqa: E402


def play(ws_url: str, request: dict, timeout_s: float) -> str:
    """One real-time game nobody presses a key in, to its end: its replay id."""
    with connect(ws_url, open_timeout=30, max_size=2**22) as ws:
        ws.send(json.dumps({"type": "new_game", "mode": "realtime", **request}))
        while True:
            msg = json.loads(ws.recv(timeout=timeout_s))
            if msg["type"] in ("error", "full"):
                raise RuntimeError(f"the server refused the game: {msg}")
            if msg["type"] == "game_over":
                return msg["replay_id"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--games", type=int, default=5, help="games of each kind")
    parser.add_argument("--horizon", type=int, default=50, help="steps a game")
    parser.add_argument("--tick-hz", type=float, default=5.0, help="the server's steps a second")
    parser.add_argument("--deadline-ms", type=float, default=100.0, help="the server's --inference-deadline-ms")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-paper-") as imported:
        run(args, import_paper_checkpoints(Path(imported)))


def run(args: argparse.Namespace, checkpoints: dict) -> None:
    leader, follower = str(checkpoints["leader"]), str(checkpoints["follower"])
    process, base, folder = start_play_server(
        "bench-paper-play-", "--follower", follower, "--leaders", "astar", "--leaders", leader,
        "--tick-hz", str(args.tick_hz), "--inference-deadline-ms", str(args.deadline_ms),
        "--new-games-per-minute", "1000")
    ws_url = base.replace("http://", "ws://") + "/ws/play"
    kinds = {"paper follower beside a person (1:1)": {"team": "1:1"},
             "paper leader beside a person (2:1)": {"team": "2:1", "leader": leader}}
    try:
        print(f"machine: {machine()}")
        print(f"server: {args.tick_hz:g} steps/s, inference deadline {args.deadline_ms:g} ms, one inference process "
              f"(torch threads as the server sets them); {args.games} games of {args.horizon} steps of each kind")
        for label, request in kinds.items():
            misses, steps = [], 0
            for _ in range(args.games):
                replay_id = play(ws_url, {**request, "horizon": args.horizon}, timeout_s=60 + 10 * args.horizon)
                replay = load(folder / f"{replay_id}.replay.json")
                misses.append(len(replay.meta["deadline_misses"]))
                steps += replay.num_steps
            print(f"{label}: {sum(misses)} deadline misses in {steps} steps (per game: {misses})")
    finally:
        process.terminate()
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()


if __name__ == "__main__":
    main()
