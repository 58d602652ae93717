"""Draw README's pictures of the board and of the web pages again, after a change to how they look::

    python docs/images/draw.py            # from the repository root; writes the four pictures below

- ``board.png``: the renderer's picture (``colorgrid.render.render_rgb``, 16 pixels a cell) of step 20 of the
  released replay ``replays/default/astar+bayes_seed2026.replay.json`` (A* leader, Bayesian follower, seed 2026).
- ``play.png``: the play page, one person leading the Bayesian follower for people (``bayes-people``, which also
  plays in teams; the server's default is ``ippo-shielded``) in turn-based mode, after a few fixed key presses: the
  board, the scores and the follower's belief.
- ``play_team.png``: the play page in a team of one person and two Bayesian followers (1:2, ``bayes-people``), after
  a few fixed key presses: each follower's belief is shown.
- ``replay_player.png``: the replay player at step 57 of the same released replay as ``board.png``.

The web pages are those of the real play server (``colorgrid play``), started here on a free loopback port with
its replays written to a temporary folder, and seen through Debian's chromium driven by playwright (no browser
download: ``executable_path``), as the browser tests do. The server is started with ``--first-seed`` (``GAME_SEED``):
its games' seeds count from there instead of from the clock, so a rerun plays the same boards and draws the same
pictures.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images"
sys.path.insert(0, str(ROOT))

RELEASED = "default/astar+bayes_seed2026"
"""The released replay drawn in ``board.png`` and ``replay_player.png`` (under ``replays/``)."""
BOARD_STEP = 20
REPLAY_STEP = 57
REPLAY_SIZE = (1040, 960)
"""The replay player's window: wide enough for the board and the panel beside it, tall enough for the chart's note."""
GAME_SEED = 2026
"""The seed of the first game the server opens (the next game gets the next seed)."""
PLAY_KEYS = ["ArrowUp", "ArrowUp", "ArrowRight", "ArrowRight", "ArrowRight", "ArrowDown", "ArrowRight", "ArrowRight"]
TEAM_KEYS = ["ArrowLeft", "ArrowLeft", "ArrowUp", "ArrowUp", "ArrowUp", "ArrowLeft", "ArrowLeft", "ArrowDown",
             "ArrowLeft", "ArrowLeft"]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                 "--font-render-hinting=none"]

def draw_board() -> None:
    from PIL import Image

    from colorgrid.render import render_rgb
    from colorgrid.replay.format import load
    from colorgrid.replay.simulate import replay_states

    replay = load(ROOT / "replays" / f"{RELEASED}.replay.json")
    state = replay_states(replay)[BOARD_STEP]
    Image.fromarray(render_rgb(state, replay.config, cell=16)).save(OUT / "board.png", optimize=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(tmp: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    log = open(tmp / "server.log", "w")
    process = subprocess.Popen(
        [sys.executable, "-m", "colorgrid_apps", "play", "--port", str(port), "--first-seed", str(GAME_SEED),
         "--replays-dir", str(tmp / "recordings"), "--log-level", "warning"],
        cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the play server exited: {(tmp / 'server.log').read_text()}")
        try:
            with urllib.request.urlopen(url + "/api/health", timeout=10) as response:
                if json.loads(response.read())["ready"]:
                    return process, url
        except OSError:
            pass
        time.sleep(0.2)
    process.kill()
    raise RuntimeError("the play server was not ready in 180 s")


def play(browser, url: str, name: str, size: tuple[int, int], team: str, keys: list[str]) -> None:
    """Start a turn-based game of ``team`` beside ``bayes-people`` (each AI follower), press ``keys``, screenshot the page."""
    from playwright.sync_api import expect

    page = browser.new_page(viewport={"width": size[0], "height": size[1]})
    page.goto(url + "/")
    page.select_option("#team", team)
    page.select_option("#follower", "bayes-people")
    page.select_option("#mode", "turn")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    for t, key in enumerate(keys, 1):
        page.keyboard.press(key)
        expect(board).to_have_attribute("data-step", str(t))
    expect(page.locator(".belief-fill").first).to_be_visible()
    page.mouse.move(size[0] - 1, size[1] - 1)  # no hover on the page's links
    page.wait_for_timeout(300)
    page.screenshot(path=str(OUT / name))
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    page.close()


def replay_player(browser, url: str) -> None:
    from playwright.sync_api import expect

    page = browser.new_page(viewport={"width": REPLAY_SIZE[0], "height": REPLAY_SIZE[1]})
    replay_id = "released--" + RELEASED.replace("/", "--")
    page.goto(url + f"/replay?id={replay_id}&step={REPLAY_STEP}")
    expect(page.locator("#player")).to_be_visible(timeout=60_000)
    expect(page.locator("#step")).to_contain_text(f"{REPLAY_STEP} /")
    page.check("#trails")
    page.mouse.move(REPLAY_SIZE[0] - 1, REPLAY_SIZE[1] - 1)
    page.wait_for_timeout(500)
    page.screenshot(path=str(OUT / "replay_player.png"))
    page.close()


def draw_pages() -> None:
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="colorgrid-pictures-") as folder:
        process, url = start_server(Path(folder))
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
                try:
                    play(browser, url, "play.png", (1000, 700), "1:1", PLAY_KEYS)
                    play(browser, url, "play_team.png", (1200, 820), "1:2", TEAM_KEYS)
                    replay_player(browser, url)
                finally:
                    browser.close()
        finally:
            process.terminate()
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()


if __name__ == "__main__":
    draw_board()
    draw_pages()
    for name in ("board.png", "play.png", "play_team.png", "replay_player.png"):
        print(OUT / name)
