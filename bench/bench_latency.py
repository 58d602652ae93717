"""Key to frame through a network as participants have it: how long after a key press the page shows the move.

Usage: python bench/bench_latency.py [--delay-ms 150] [--jitter-ms 30] [--keys 120] [--tick-hz 5] [--follower copy]

Starts ``colorgrid play`` on a free loopback port, puts ``tests/delay_proxy.py`` in front of it (``--delay-ms`` each
way, plus a uniform jitter of up to ``--jitter-ms``), opens the play page in Debian's chromium (playwright) through the
proxy and plays one real-time game: a free move (on the board, away from the follower), then, once the server's state
shows it, a pause of 0.1-0.4 s, and the next, ``--keys`` times. For each key, by the page's own clock, from the
keydown event to the first animation frame after:

* drawn: the page draws the person's disc on the key's cell (``web/predict.js`` draws it at once);
* confirmed: the server's state shows it there, which is when the page showed the move before it predicted it (the
  server applies a key at its next tick, and the state comes back a network trip later).

Prints the machine (CPU model, CPUs, thread settings), the network, and the median, p90 and p99 of both, with the
game's key log (every key applied: none superseded, none lost). docs/PERFORMANCE.md, "Key to frame", has the figures.
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
from common import machine, start_play_server  # noqa: E402

from colorgrid.presets import env_config  # noqa: E402
from colorgrid.replay import load  # noqa: E402
from colorgrid.roles import columns  # noqa: E402
from tests.conftest import CHROMIUM, CHROMIUM_ARGS  # noqa: E402
from tests.delay_proxy import DelayProxy  # noqa: E402

ARROWS = {"ArrowUp": (-1, 0), "ArrowDown": (1, 0), "ArrowLeft": (0, -1), "ArrowRight": (0, 1)}
MEASURE = """
// Before the page's own scripts: each arrow key's press time (a capturing listener on window runs before the page's
// on document), then the first animation frame after the board shows the disc on the key's cell: drawn (data-you,
// where the page draws it) and confirmed (data-leader, the server's state).
window.__keys = [];
addEventListener("keydown", (event) => {
  if (event.key in { ArrowUp: 1, ArrowDown: 1, ArrowLeft: 1, ArrowRight: 1 } && window.__target != null) {
    window.__keys.push({ t: event.timeStamp, target: window.__target, drawn: null, confirmed: null });
    window.__target = null;
  }
}, true);
document.addEventListener("DOMContentLoaded", () => {
  const board = document.getElementById("board");
  const frame = (key, field) => {
    key[field] = -1;
    requestAnimationFrame(() => { key[field] = performance.now() - key.t; });
  };
  new MutationObserver(() => {
    const key = window.__keys.at(-1);
    if (!key) return;
    if (key.drawn === null && Number(board.dataset.you) === key.target) frame(key, "drawn");
    if (key.confirmed === null && Number(board.dataset.leader) === key.target) frame(key, "confirmed");
  }).observe(board, { attributes: true, attributeFilter: ["data-you", "data-leader"] });
});
"""


def free_move(width: int, height: int, allowed: tuple[int, int], leader: int, follower: int) -> tuple[str, int]:
    """A move of the leader on the board and in its columns, not near the follower, towards the board's middle."""
    row, col = divmod(leader, width)
    f_row, f_col = divmod(follower, width)
    moves = []
    for key, (dr, dc) in ARROWS.items():
        r, c = row + dr, col + dc
        if 0 <= r < height and allowed[0] <= c < allowed[1] and (r, c) != (f_row, f_col):
            near = abs(r - f_row) + abs(c - f_col) < 3
            moves.append((near, abs(r - height / 2) + abs(c - sum(allowed) / 2), key, r * width + c))
    _, _, key, target = min(moves)
    return key, target


def play(url: str, keys: int, preset: str, rng: random.Random) -> tuple[list[dict], str]:
    """One real-time game on the play page at ``url``: each key's measures, and the game's replay id."""
    from playwright.sync_api import expect, sync_playwright

    config = env_config(preset)
    allowed = columns(config, config.leaders[0])
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        page.add_init_script(MEASURE)
        page.goto(url + "/")
        page.select_option("#mode", "realtime")
        page.select_option("#preset", preset)
        page.fill("#horizon", "1000")
        page.click("#start")
        board = page.locator("#board")
        page.wait_for_function("() => Number(document.getElementById('board').dataset.step) > 0",
                               timeout=60_000)  # after the 3-2-1, the world moves
        board.focus()
        for _ in range(keys):
            leader, follower = (int(board.get_attribute(f"data-{name}")) for name in ("leader", "follower"))
            key, target = free_move(config.width, config.height, allowed, leader, follower)
            page.evaluate("target => { window.__target = target; }", target)
            page.keyboard.press(key)
            # the server's state showed it, or (the follower stepped in the way: blocked) 3 s went by
            page.wait_for_function("() => { const k = window.__keys.at(-1); "
                                   "return k && (k.confirmed >= 0 && k.confirmed !== null || performance.now() - k.t > "
                                   "3000); }", timeout=30_000)
            page.wait_for_timeout(rng.uniform(100, 400))
        measured = page.evaluate("window.__keys")
        page.click("#quit")
        expect(page.locator("#over")).to_be_visible(timeout=30_000)
        replay_id = page.locator("#replay-link").get_attribute("href").split("id=")[1]
        browser.close()
    return measured, replay_id


def summary(name: str, values: list[float]) -> str:
    p50, p90, p99 = np.percentile(values, [50, 90, 99])
    return f"{name:<42} {p50:8.0f} {p90:8.0f} {p99:8.0f}   ({len(values)} keys)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--delay-ms", type=float, default=150.0, help="the network's delay each way")
    parser.add_argument("--jitter-ms", type=float, default=30.0, help="plus or minus this, uniformly, per chunk")
    parser.add_argument("--keys", type=int, default=120, help="keys to press")
    parser.add_argument("--tick-hz", type=float, default=5.0, help="the server's real-time clock")
    parser.add_argument("--follower", default="copy", help="the AI follower (the server's only one)")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.keys < 1 or args.delay_ms < 0 or not 0 <= args.jitter_ms <= args.delay_ms:
        parser.error("--keys must be >= 1, --delay-ms >= 0 and --jitter-ms in [0, --delay-ms]")

    process, base, folder = start_play_server("bench-latency-", "--follower", args.follower, "--followers",
                                              args.follower, "--tick-hz", str(args.tick_hz))
    try:
        port = int(base.rsplit(":", 1)[1])
        with DelayProxy(port, args.delay_ms / 1000, args.jitter_ms / 1000, seed=args.seed) as proxy:
            started = time.perf_counter()
            measured, replay_id = play(proxy.url, args.keys, args.preset, random.Random(args.seed))
            wall = time.perf_counter() - started
        statuses = [e["status"] for e in load(folder / f"{replay_id}.replay.json").key_events]
    finally:
        process.terminate()
        process.wait(timeout=30)

    drawn = [k["drawn"] for k in measured if k["drawn"] is not None and k["drawn"] >= 0]
    confirmed = [k["confirmed"] for k in measured if k["confirmed"] is not None and k["confirmed"] >= 0]
    print(f"machine: {machine()}")
    print(f"network: {args.delay_ms:g} ms each way, jitter +-{args.jitter_ms:g} ms (tests/delay_proxy.py, loopback); "
          f"real time at {args.tick_hz:g} Hz, follower {args.follower}; chromium headless; {wall:.0f} s")
    print(f"key log: {len(statuses)} keys, {statuses.count('applied')} applied, "
          f"{statuses.count('superseded')} superseded, {statuses.count('unapplied')} unapplied; "
          f"{len(measured) - len(confirmed)} moves blocked (the follower stepped in the way), left out")
    print(f"{'key to frame (ms)':<42} {'median':>8} {'p90':>8} {'p99':>8}")
    print(summary("drawn at once (web/predict.js)", drawn))
    print(summary("server's state shows it (before prediction)", confirmed))


if __name__ == "__main__":
    main()
