"""A person plays the assistant in chromium: the follower seat beside an AI leader, turn-based and in real time,
stating beliefs and answering probes; the games are saved, verify, and their measures are counted by hand."""

import subprocess
import sys

import pytest
from playwright.sync_api import expect

from colorgrid.replay import load
from colorgrid.replay.human_follower import person_measures
from tests.conftest import start_server, stop_server
from tests.test_browser import pixel


@pytest.fixture(scope="module")
def seat_server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("assist"), "--max-sessions", "4", "--tick-hz", "10",
                       "--leaders", "astar", "--leaders", "person:slip=0.1,notice_delay=3")
    yield srv
    stop_server(srv)


def open_setup(server, browser, mode: str, horizon: int, probes: str, leader: str = "astar"):
    page = browser.new_page(viewport={"width": 1100, "height": 820})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    expect(page.locator("#seat-choice")).to_be_visible()
    page.select_option("#seat", "follower")
    expect(page.locator("#setup-title")).to_have_text("Play the assistant")
    expect(page.locator("#who-assists")).to_be_visible()
    expect(page.locator("#follower-choice")).to_be_hidden()  # 1:1: you are the only follower
    page.select_option("#seat-leader", leader)
    page.select_option("#probe-kind", "steps")
    page.fill("#probe-steps", probes)
    page.select_option("#mode", mode)
    page.fill("#horizon", str(horizon))
    return page, errors


def replay_of(page, server):
    href = page.locator("#replay-link").get_attribute("href")
    path = server.replays_dir / f"{href.split('id=')[1]}.replay.json"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "verify", str(path)],
                          capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip().endswith(": ok"), done.stdout
    return load(path)


def test_a_turn_based_game_in_the_follower_seat_with_beliefs_and_probes(seat_server, browser):
    page, errors = open_setup(seat_server, browser, "turn", 8, "2,5", leader="person:slip=0.1,notice_delay=3")
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    # the page says plainly which disc is yours, that the goal is hidden from you, and what you are asked to do
    expect(page.locator("#stated-task")).to_contain_text("You are F, the assistant")
    expect(page.locator("#stated-task")).to_contain_text("it is hidden from you")
    expect(page.locator("#stated-task")).to_contain_text("work out which color it is after, and say so")
    expect(page.locator("#agent-scores [data-agent=follower] .who")).to_have_text("you")
    expect(page.locator("#agent-scores [data-agent=leader] .who")).to_have_text("the AI leader")
    expect(page.locator("#goal-name")).to_have_text("hidden from you")
    assert pixel(page, 1, 1) == "#999999", "no goal frame: the goal is hidden"
    page.keyboard.press("2")  # a belief, not a move
    expect(page.locator("#stated-now")).to_have_text("You said the goal is green.")
    expect(board).to_have_attribute("data-step", "0")
    page.keyboard.press("ArrowUp")
    expect(board).to_have_attribute("data-step", "1")
    page.click(".stated-color[data-color='0']")  # a click on red
    expect(page.locator(".stated-color.chosen")).to_have_attribute("data-color", "0")
    page.keyboard.press("ArrowUp")
    expect(page.locator("#probe")).to_be_visible()  # step 2 asks
    expect(page.locator("#probe-note")).to_have_text("The game waits for your answer.")
    page.keyboard.press("ArrowLeft")  # the game waits: a move does nothing meanwhile
    # an answer the server refuses (a confidence below chance, forced past the page's range) is asked again
    page.locator("#probe-confidence").evaluate("r => { r.min = 0; r.value = 10; }")
    page.click(".probe-color[data-color='2']")
    page.click("#probe-answer")
    expect(page.locator("#probe-problem")).to_have_text("Choose how sure you are: from a guess to certain.")
    expect(page.locator("#probe")).to_be_visible()
    # the server answered the move before that answer (one socket, in order): had it stepped, its state came first
    expect(board).to_have_attribute("data-step", "2")
    page.locator("#probe-confidence").evaluate("r => { r.min = 34; r.value = 80; "
                                               "r.dispatchEvent(new Event('input')); }")
    expect(page.locator("#probe-percent")).to_have_text("80%")
    page.click(".probe-color[data-color='2']")
    page.click("#probe-answer")
    expect(page.locator("#probe")).to_be_hidden()
    expect(page.locator("#stated-now")).to_have_text("You said the goal is blue.")
    for t in (2, 3, 4):
        page.keyboard.press("ArrowLeft")
        expect(board).to_have_attribute("data-step", str(t + 1))
    expect(page.locator("#probe")).to_be_visible()  # step 5 asks: answered by keys, 1 then Enter
    page.keyboard.press("1")
    page.keyboard.press("Enter")
    expect(page.locator("#probe")).to_be_hidden()
    for t in (5, 6, 7):
        page.keyboard.press("ArrowDown")
    expect(page.locator("#over")).to_be_visible()
    replay = replay_of(page, seat_server)
    assert replay.stated_beliefs["follower"] == [1, 0, 2, 2, 2, 0, 0, 0]
    assert [(p["status"], p["color"], p["confidence"], p["refused"]) for p in replay.probes] == [
        ("answered", 2, 0.8, 1), ("answered", 0, 0.67, 0)]
    assert [e["via"] for e in replay.belief_events] == ["key", "click", "probe", "probe"]
    # the measures, counted by hand on the recorded game
    goal, stated = replay.goal, replay.stated_beliefs["follower"]
    m = person_measures(replay, "follower")
    assert m["accuracy"] == pytest.approx(sum(s == g for s, g in zip(stated, goal)) / 8)
    assert m["probe_accuracy"] == pytest.approx(((goal[2] == 2) + (goal[5] == 0)) / 2)
    final = replay.final()
    assert m["net_pickups"] == final["follower_goal_pickups"] - final["follower_wrong_pickups"]
    assert errors == []
    page.close()


def test_a_realtime_game_in_the_follower_seat_asks_without_stopping_the_clock(seat_server, browser):
    page, errors = open_setup(seat_server, browser, "realtime", 600, "8")  # a minute: the test quits it
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()  # after the 3-2-1
    board = page.locator("#board")
    page.keyboard.press("3")
    expect(page.locator("#stated-now")).to_have_text("You said the goal is blue.")
    expect(page.locator("#probe")).to_be_visible()
    expect(page.locator("#probe-note")).to_have_text("The game goes on while you answer.")
    asked = int(board.get_attribute("data-step"))
    expect(board).not_to_have_attribute("data-step", str(asked))  # the clock goes on
    page.click(".probe-color[data-color='1']")
    page.click("#probe-answer")
    expect(page.locator("#probe")).to_be_hidden()
    answered = int(board.get_attribute("data-step"))  # the answer is a statement from the next recorded step on
    page.wait_for_function("s => +document.querySelector('#board').dataset.step >= s", arg=answered + 2)
    page.click("#quit")
    expect(page.locator("#over")).to_be_visible()
    replay = replay_of(page, seat_server)
    probe = replay.probes[0]
    assert probe["status"] == "answered" and probe["color"] == 1 and probe["answered_step"] > probe["step"] == 8
    stated = replay.stated_beliefs["follower"]
    assert stated[-1] == 1 and 2 in stated and stated[0] in (None, 2)
    assert errors == []
    page.close()
