"""A real browser (Debian chromium, driven by playwright) plays a short game and finds its replay."""

import shutil

import pytest
from playwright.sync_api import expect, sync_playwright

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        yield b
        b.close()


def test_play_a_short_game_in_the_browser(server, browser):
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    expect(page.locator("#follower option")).to_have_count(5)
    page.select_option("#mode", "turn")
    page.fill("#horizon", "6")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    expect(page.locator("#step")).to_have_text("0 / 6")
    for t in range(6):
        before = int(board.get_attribute("data-leader"))
        follower = int(board.get_attribute("data-follower"))
        key, target = ("ArrowRight", before + 1) if before % 32 < 31 else ("ArrowLeft", before - 1)
        page.keyboard.press(key)
        if t < 5:
            expect(board).to_have_attribute("data-step", str(t + 1))
            expect(page.locator("#step")).to_have_text(f"{t + 1} / 6")
            after = int(board.get_attribute("data-leader"))
            assert after == (before if target == follower else target), "the leader moved, unless blocked"
            expect(page.locator(".belief-row")).to_have_count(3)
            widths = page.locator(".belief-fill").evaluate_all("els => els.map(e => parseFloat(e.style.width))")
            assert abs(sum(widths) - 100) < 1.0, "belief bars add up to 100%"
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#over-scores")).to_contain_text("after 6 steps")
    link = page.locator("#replay-link")
    href = link.get_attribute("href")
    replay_id = href.split("id=")[1]
    link.click()
    row = page.locator(f"tr[data-id='{replay_id}']")
    page.select_option("#source", "play")
    expect(row).to_be_visible()
    expect(row).to_have_class("highlight")
    expect(row.locator("td").nth(1)).to_have_text("play")
    assert (server.replays_dir / f"{replay_id}.replay.json").exists()
    assert errors == []
    page.close()


def test_belief_can_be_hidden(server, browser):
    page = browser.new_page()
    page.goto(server.url + "/")
    page.fill("#horizon", "3")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    page.keyboard.press("ArrowUp")
    expect(page.locator(".belief-row")).to_have_count(3)
    page.uncheck("#belief-toggle")
    expect(page.locator(".belief-row")).to_have_count(0)
    page.keyboard.press("ArrowDown")
    expect(page.locator("#board")).to_have_attribute("data-step", "2")
    expect(page.locator(".belief-row")).to_have_count(0)
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    page.close()
