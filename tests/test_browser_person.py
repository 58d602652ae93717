"""The person in the follower seat, in chromium: the probe opens without moving the page, the hint and the probe say
their keys, a refused request shows the server's reason, the game-over card sets the goal's history against the
person's statements, and the replay player draws the person's statements and probe answers beside an AI follower
watching their seat, with both sides' measures (``/timeline`` and ``/people``, checked against
``colorgrid.replay.human_follower``)."""

import json
import time
import urllib.error
import urllib.parse

import pytest
from playwright.sync_api import expect

from colorgrid import EnvConfig
from colorgrid.evaluate import record_batch
from colorgrid.policies import make_policy
from colorgrid.replay import save
from colorgrid.replay.apart import SET_APART
from colorgrid.replay.human_follower import MEASURE_WORDS, PAGE_MEASURES, person_measures, watched
from colorgrid.rollout import run_episodes
from tests.conftest import start_server, stop_server
from tests.helpers import js_fixed, js_round
from tests.test_browser import pixel
from tests.test_browser_follower import open_setup, replay_of
from tests.test_human_follower import shown_game

BOXES = ("#board", "#belief-slot", "#mode-label")
"""What must not move when a probe opens: the board, the slot of the probe and the statement panel, and what is below
it (down to the last step's events, whose line a pickup may lengthen)."""


@pytest.fixture(scope="module")
def seat_server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("person"), "--max-sessions", "4", "--leaders", "astar")
    yield srv
    stop_server(srv)


@pytest.fixture(scope="module")
def played(seat_server, browser):
    """A turn-based game of 8 steps in the follower seat: green said by key at 0, probes at 2 (blue, 80% by a click
    and the range) and 4 (red by keys, 5 points surer with the right arrow); its page left on the game-over card."""
    page, errors = open_setup(seat_server, browser, "turn", 8, "2,4")
    page.click("#start")
    board = page.locator("#board")
    expect(board).to_have_attribute("data-step", "0")
    expect(page.locator("#status")).to_have_text(
        "your move: \u2191 or W, \u2193 or S, \u2190 or A, \u2192 or D. Say which color you believe is the goal with "
        "1, 2, 3 or a click on a color.")
    page.keyboard.press("2")
    expect(page.locator("#stated-now")).to_have_text("You said the goal is green.")
    page.keyboard.press("ArrowUp")
    expect(board).to_have_attribute("data-step", "1")
    before = {sel: page.locator(sel).bounding_box() for sel in BOXES}
    page.keyboard.press("ArrowUp")
    expect(page.locator("#probe")).to_be_visible()
    yield_page = {"page": page, "errors": errors, "before": before,
                  "after": {sel: page.locator(sel).bounding_box() for sel in BOXES},
                  "status": page.locator("#status").text_content(),
                  "keys": page.locator("#probe-keys").text_content(),
                  "color_keys": page.locator(".probe-color kbd").all_text_contents()}
    page.locator("#probe-confidence").evaluate("r => { r.value = 80; r.dispatchEvent(new Event('input')); }")
    page.click(".probe-color[data-color='2']")
    page.click("#probe-answer")
    expect(page.locator("#probe")).to_be_hidden()
    expect(page.locator("#status")).to_contain_text("your move:")
    yield_page["closed"] = {sel: page.locator(sel).bounding_box() for sel in BOXES}
    for t in (2, 3):
        page.keyboard.press("ArrowLeft")
        expect(board).to_have_attribute("data-step", str(t + 1))
    expect(page.locator("#probe")).to_be_visible()
    start = int(page.locator("#probe-confidence").input_value())
    page.keyboard.press("1")
    page.keyboard.press("ArrowRight")  # turn-based: the arrows set how sure you are while the probe asks
    expect(page.locator("#probe-percent")).to_have_text(f"{start + 5}%")
    expect(board).to_have_attribute("data-step", "4")
    page.keyboard.press("Enter")
    expect(page.locator("#probe")).to_be_hidden()
    for t in (4, 5, 6, 7):
        page.keyboard.press("ArrowDown")
    expect(page.locator("#over")).to_be_visible()
    yield_page["replay"] = replay_of(page, seat_server)
    yield_page["start"] = start
    yield yield_page
    page.close()


def test_a_probe_opens_without_moving_the_page_and_names_its_keys(played):
    for sel in BOXES:
        assert played["after"][sel] == played["before"][sel], f"{sel} moved when the probe opened"
        assert played["closed"][sel] == played["before"][sel], f"{sel} moved when the probe closed"
    assert played["status"] == "Answer the question: 1, 2, 3 choose the color, \u2190 \u2192 set how sure you are, " \
                               "Enter answers."
    assert played["keys"] == "Keys: 1, 2, 3 choose the color (or click one); \u2190 \u2192 set how sure you are; " \
                             "Enter answers."
    assert played["color_keys"] == ["1", "2", "3"]
    replay = played["replay"]
    assert [(p["color"], p["confidence"]) for p in replay.probes] == [(2, 0.8), (0, (played["start"] + 5) / 100)]
    assert played["errors"] == []


def test_the_game_over_card_sets_the_goal_against_what_the_person_said(played):
    page, replay = played["page"], played["replay"]
    m = person_measures(replay, "follower")
    expect(page.locator("#over-stated")).to_be_visible()
    said = (f"Your stated color was the goal at {js_round(100 * m['accuracy'])}% of the {m['stated_steps']} steps where "
            f"you had said one (of {m['steps']}).")
    answers = f" {js_round(100 * m['probe_accuracy'])}% of your 2 answers to the 2 questions named the goal."
    expect(page.locator("#over-accuracy")).to_have_text(said + answers)
    palette = played_palette(page)
    width = 520 / replay.num_steps
    for t in (0, replay.num_steps - 1):  # the goal strip on top, the stated color below it
        x = int((t + 0.5) * width)
        assert pixel(page, x, 10, "#over-history") == palette[replay.goal[t]]
        assert pixel(page, x, 30, "#over-history") == palette[replay.stated_beliefs["follower"][t]]


def played_palette(page) -> list[str]:
    """The palette the page draws with: the stated colors' swatches, as ``#rrggbb``."""
    colors = page.locator(".stated-color .swatch").evaluate_all(
        "ss => ss.map(s => getComputedStyle(s).backgroundColor)")
    return ["#" + "".join(f"{int(v):02x}" for v in c[4:-1].split(", ")) for c in colors]


def test_the_timeline_carries_the_persons_statements_probes_and_measures(seat_server, played):
    replay = played["replay"]
    replay_id = replay_id_of(played["page"])
    timeline = seat_server.get(f"/api/replays/{replay_id}/timeline")[0]
    assert timeline["stated_beliefs"] == {"follower": replay.stated_beliefs["follower"]}
    assert timeline["probes"] == replay.probes and timeline["belief_events"] == replay.belief_events
    assert timeline["person_measures"]["follower"] == json.loads(json.dumps(person_measures(replay, "follower")))
    assert timeline["person_measure_words"] == [[key, MEASURE_WORDS[key]] for key in PAGE_MEASURES]


def replay_id_of(page) -> str:
    return urllib.parse.unquote(page.locator("#replay-link").get_attribute("href").split("id=")[1])


def test_the_replay_player_draws_the_person_beside_the_ai_follower_with_both_measures(seat_server, browser, played):
    replay, replay_id = played["replay"], replay_id_of(played["page"])
    options = seat_server.get("/api/options")[0]
    first, second = options["default_follower"], next(f for f in options["followers"]
                                                       if f != options["default_follower"])
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{seat_server.url}/replay?id={urllib.parse.quote(replay_id)}&step=3")
    expect(page.locator("#player")).to_be_visible(timeout=60_000)  # the timeline is made by a low-priority worker
    panel = page.locator("#person-panel")
    expect(panel).to_have_attribute("data-follower", first, timeout=60_000)  # the follower watched in a worker
    palette = played_palette(played["page"])
    chart = page.locator("#chart")
    # the person's stated color: one step line per run of a color, at 1, in that color
    stated = replay.stated_beliefs["follower"]
    runs = json.loads(chart.get_attribute("data-stated-runs"))
    expected = []
    for t, color in enumerate(stated):
        if color is not None and (not expected or expected[-1][0] != color or expected[-1][2] != t):
            expected.append([color, t, t + 1])
        elif color is not None:
            expected[-1][2] = t + 1
    assert [[r["color"], r["from"], r["to"]] for r in runs] == expected
    for run in runs:  # along the top of its step, most pixels are its color (the cursor or a switch may cross it)
        along = [pixel(page, x, round(run["y"]), "#chart") for x in range(round(run["x0"]) + 2, round(run["x1"]) - 1)]
        assert along.count(palette[run["color"]]) > len(along) / 2, (run, along)
    # each probe's answer: a point in its color at its confidence
    points = json.loads(chart.get_attribute("data-probe-points"))
    assert [(p["color"], p["confidence"]) for p in points] == [(p["color"], p["confidence"]) for p in replay.probes]
    bottom, top = 170 - 26, 14  # the chart's plot: 0 at its bottom, 1 at its top
    for point in points:
        assert point["y"] == pytest.approx(bottom - point["confidence"] * (bottom - top), abs=0.1)
        assert pixel(page, round(point["x"]), round(point["y"]), "#chart") == palette[point["color"]]
    # both sides' measures, this game's: the person's and the AI follower's watching the seat
    for follower in (first, second):
        if follower != first:
            page.select_option("#branch-follower", follower)
            expect(panel).to_have_attribute("data-follower", follower, timeout=60_000)
        expect(page.locator("#person-ai")).to_have_text(follower)
        _, ai = watched(replay, "follower", follower)
        person = person_measures(replay, "follower")
        rows = page.locator(".person-table tbody tr")  # the server's words, in its order
        expect(rows).to_have_count(len(PAGE_MEASURES))
        assert [r.locator("td").first.inner_text() for r in rows.all()] == [MEASURE_WORDS[k] for k in PAGE_MEASURES]
        for key in ("accuracy", "probe_accuracy"):
            row = page.locator(f".person-table tr[data-measure={key}]")
            expect(row.locator("[data-who=person]")).to_have_text(f"{js_fixed(100 * person[key], 1)}%")
            expect(row.locator("[data-who=ai]")).to_have_text("\u2013" if ai is None else f"{js_fixed(100 * ai[key], 1)}%")
        people = seat_server.get(f"/api/replays/{urllib.parse.quote(replay_id)}/people?follower="
                                 f"{urllib.parse.quote(follower)}")[0]
        seat = people["seats"]["follower"]
        assert seat["person"] == json.loads(json.dumps(person)) and seat["follower"] == json.loads(json.dumps(ai))
        assert seat["set_apart"] is None and seat["set_apart_words"] is None  # the goal hidden, no study: pooled
        net = page.locator(".person-table tr[data-measure=net_pickups] [data-who=ai]")
        expect(net).to_have_text(f"{seat['net_pickups']:+d}" if seat["net_pickups"] else "0")
    assert errors == []
    page.close()


def test_people_refuses_an_unknown_follower_and_a_game_without_a_person(seat_server, tmp_path):
    config = EnvConfig(horizon=10)
    leader, follower = make_policy("astar"), make_policy("bayes")
    batch = run_episodes(config, leader, follower, 1, 3, record_hashes=True)
    seat_server.replays_dir.mkdir(parents=True, exist_ok=True)
    recorded, = record_batch(batch, "astar", "bayes", leader, follower, tmp_path, "eval")
    replay_id = "no-person-in-it"
    recorded.rename(seat_server.replays_dir / f"{replay_id}.replay.json")
    wait_listed(seat_server, replay_id)
    timeline = seat_server.get(f"/api/replays/{replay_id}/timeline")[0]
    assert timeline["verified"] and "stated_beliefs" not in timeline and "person_measures" not in timeline
    for query, code, words in (("follower=bayes", 422, "no person played a follower seat"),
                               ("follower=..%2Fsecret.pt", 400, "follower must be one of")):
        with pytest.raises(urllib.error.HTTPError) as refused:
            seat_server.get(f"/api/replays/{replay_id}/people?{query}")
        assert refused.value.code == code and words in json.loads(refused.value.read())["detail"]


def wait_listed(server, replay_id: str) -> None:
    """Until the server lists a replay file just written to its folder (at its next scan)."""
    listed = lambda: any(i["id"] == replay_id for i in server.get("/api/replays?limit=500")[0]["items"])
    deadline = time.monotonic() + 60  # a bound for a loaded machine
    while not listed():
        assert time.monotonic() < deadline, "the new replay was never listed"
        time.sleep(0.2)


def test_a_game_rescore_sets_apart_is_named_in_the_servers_words(seat_server, browser):
    """A game that showed the person the goal: ``/people`` sends what it is in words
    (``colorgrid.replay.apart.SET_APART``), and the person panel says them; the page keeps no words of its own."""
    replay_id = "goal-shown"
    seat_server.replays_dir.mkdir(parents=True, exist_ok=True)
    save(shown_game(8), seat_server.replays_dir / f"{replay_id}.replay.json")
    wait_listed(seat_server, replay_id)
    follower = seat_server.get("/api/options")[0]["default_follower"]
    people = seat_server.get(f"/api/replays/{replay_id}/people?follower={urllib.parse.quote(follower)}")[0]
    words = SET_APART["goal_shown"].game
    assert people["seats"]["follower"]["set_apart"] == "goal_shown"
    assert people["seats"]["follower"]["set_apart_words"] == words
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{seat_server.url}/replay?id={replay_id}")
    expect(page.locator("#person-panel")).to_have_attribute("data-follower", follower, timeout=60_000)
    expect(page.locator(".person-table + p")).to_contain_text(
        f"This is {words}: rescore reports it apart from the person's figures.")
    assert errors == []
    page.close()


def test_a_refused_new_game_shows_the_servers_reason(seat_server, browser):
    page = browser.new_page(viewport={"width": 1100, "height": 820})
    page.goto(seat_server.url + "/")
    page.select_option("#seat", "follower")
    page.select_option("#probe-kind", "steps")
    page.fill("#probe-steps", "10, abc")
    page.click("#start")
    expect(page.locator("#status")).to_have_text(
        "The server refused: probes 'steps:10,abc' is not a probe plan: 'none', 'steps:T1,T2,...' (steps 1..1000) or "
        "'random:P' (each step with probability P in (0, 1])")
    expect(page.locator("#status")).to_have_class("error")
    page.close()
