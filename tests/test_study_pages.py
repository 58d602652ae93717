"""The study's participant page in chromium, against a real study server: who is who on the board, the goal frame
and its switches (by the pixels), a layout that stays put, the practice game, the end of a game, questionnaire answers
that cannot be taken, a participant coming back, and the admin's page."""

from __future__ import annotations

import io
import json
import re
import sqlite3
import time

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import expect

from colorgrid.presets import env_config
from colorgrid.render import AGENT_COLORS, PALETTE, look
from server.cluster.plan import RESTARTS_ENV
from tests.conftest import start_server, stop_server
from tests.helpers import js_fixed

TOKEN = "pages-admin-token"
FRAME = 16  # web/study_game.js: the goal frame's width on the study page, in pixels
STUDY = """
id = "pages"
title = "Pages"
completion_code = "PAGES1"
redirect_url = "https://example.org/done?cc={code}"
[factors]
show_belief = [true, false]
[defaults]
follower = "bayes"
mode = "turn"
horizon = 3
[design]
assignment = "within"
order = "fixed"

[[pages]]
kind = "consent"
text = "Agree?"

[[pages]]
kind = "instructions"
title = "How to play"
text = "You lead; your AI partner follows."

[[pages]]
kind = "practice"
title = "Practice game"
text = "Play with your AI partner."
game = { follower = "copy", horizon = 3, mode = "turn" }

[[pages]]
kind = "trials"
text = "Play with your AI partner."

[[pages.after_each]]
id = "helpful"
kind = "likert"
prompt = "How helpful was your AI partner?"
scale = 5
labels = ["not at all", "very"]

[[pages.after_each]]
id = "understood"
kind = "likert"
prompt = "How well did your AI partner understand the goal?"
scale = 5
labels = ["not at all", "perfectly"]

[[pages]]
kind = "questionnaire"
id = "final"
title = "Last questions"

[[pages.questions]]
id = "preferred"
kind = "choice"
prompt = "Which game did you prefer?"
options = ["the first", "the second"]

[[pages.questions]]
id = "comments"
kind = "text"
prompt = "Anything else you want to tell us? (optional)"
required = false

[[pages]]
kind = "debrief"
text = "Thank you."
"""


@pytest.fixture(scope="module")
def pages_server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("study-pages")
    (tmp / "pages.toml").write_text(STUDY)
    # RESTARTS_ENV: as if a launcher had started this process again twice (its health says so)
    server = start_server(tmp, command=("study", "run", str(tmp / "pages.toml")),
                          env={"COLORGRID_ADMIN_TOKEN": TOKEN, RESTARTS_ENV: "2"})
    yield server
    stop_server(server)


def rgb(hex_color: str) -> str:
    return "rgb({}, {}, {})".format(*(int(hex_color[i:i + 2], 16) for i in (1, 3, 5)))


def play(page, steps: int = 2) -> None:
    """The first ``steps`` steps of a turn-based game (one key a step); the game stays on screen."""
    page.click("#play")
    expect(page.locator("#board")).to_be_visible()
    page.locator("#board").focus()
    for i in range(steps):
        expect(page.locator("#board")).to_have_attribute("data-step", str(i))
        page.keyboard.press("ArrowUp" if i % 2 else "ArrowLeft")
    expect(page.locator("#board")).to_have_attribute("data-step", str(steps))


LAID_OUT = ("#board", "#game aside", "#game-name", "#first-game-note", "#game-legend", "#step >> xpath=..",
            "#goal-name >> xpath=../..", "#score-team >> xpath=..", "#belief-panel", "#belief-words", "#belief",
            "#game aside > p.note:last-child")
"""The parts of a game's view (each row, not its text, whose width follows the numbers)."""


def boxes(page) -> dict:
    """Where each part of the game's view is (x, y, width, height), in pixels."""
    return {selector: page.locator(selector).bounding_box() for selector in LAID_OUT}


def finish(page) -> None:
    """The last step of a game of 3, and back to its page."""
    page.keyboard.press("ArrowDown")
    expect(page.locator("#game")).to_be_hidden()
    expect(page.locator("#next")).to_be_visible()


def test_a_participant_sees_which_disc_is_theirs_a_quiet_practice_and_every_missing_answer(pages_server, browser):
    agents = {a["role"]: a for a in look(env_config("default"))["agents"]}
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    page.goto(f"{pages_server.url}/study?PROLIFIC_PID=pages-1")
    page.click("#next")  # consent

    # Before any game: a legend says which disc is "You" and which "Your AI partner", in the board's colors.
    expect(page.locator("#page-title")).to_have_text("How to play")
    you, partner = page.locator("#legend [data-who=you]"), page.locator("#legend [data-who=partner]")
    expect(you).to_have_text(f"{agents['leader']['symbol']}You")
    expect(partner).to_have_text(f"{agents['follower']['symbol']}Your AI partner")
    expect(you.locator(".disc")).to_have_css("background-color", rgb(agents["leader"]["body"]))
    expect(you.locator(".disc")).to_have_css("color", rgb(agents["leader"]["ink"]))
    expect(partner.locator(".disc")).to_have_css("background-color", rgb(agents["follower"]["body"]))
    assert "leader" not in page.locator("#page").inner_text().lower()
    # ... and a picture of the board drawn by the renderer, labelled: the discs, the frame.
    picture = page.locator("#board-picture img")
    expect(picture).to_be_visible()
    assert picture.evaluate("img => img.complete && img.naturalWidth") > 0, "the picture loads"
    assert "yellow disc marked F" in picture.get_attribute("alt")
    page.click("#next")
    expect(page.locator("#board-picture")).to_be_hidden()

    # The practice (a follower without a belief): the first game says who is who; nothing of a belief; its
    # score is marked as practice, and so is its ending.
    expect(page.locator("#page-title")).to_have_text("Practice game")
    expect(page.locator("#legend")).to_be_visible()
    play(page)
    expect(page.locator("#game-name")).to_have_text("Practice game (it does not count)")  # which game, during it
    expect(page.locator("#first-game-note")).to_have_text("You are L. Your AI partner is F.")
    expect(page.locator("#game-legend [data-who=you]")).to_have_text("LYou")
    expect(page.locator("#score-label")).to_have_text("practice score (does not count)")
    expect(page.locator("#belief-panel")).to_be_hidden()
    assert "You (L) at row" in page.locator("#board").get_attribute("aria-label")
    finish(page)
    # The end of a game: a panel of its own, not the card that said "play".
    expect(page.locator("#game-end")).to_be_visible()
    expect(page.locator("#game-end-title")).to_have_text("The practice game is over")
    expect(page.locator("#game-end-score")).to_contain_text("(practice: it does not count)")
    expect(page.locator("#game-end")).not_to_contain_text("Game over")
    expect(page.locator("#page-text")).to_be_hidden()
    page.click("#next")

    # Trial 1 (belief shown): the reminder again, the belief from the first step (nothing moves once it has one),
    # in words, a team score.
    expect(page.locator("#page-title")).to_have_text("Game 1 of 2")
    expect(page.locator("#game-end")).to_be_hidden()
    expect(page.locator("#page-text")).to_be_visible()
    page.click("#play")
    expect(page.locator("#board")).to_have_attribute("data-step", "0")
    expect(page.locator("#belief-panel")).to_be_visible()
    first = boxes(page)
    page.locator("#board").focus()
    page.keyboard.press("ArrowLeft")
    expect(page.locator("#board")).to_have_attribute("data-step", "1")
    page.keyboard.press("ArrowUp")
    expect(page.locator("#board")).to_have_attribute("data-step", "2")
    expect(page.locator("#belief-words")).to_have_text(re.compile(
        r"^Your AI partner (thinks the goal is (red|green|blue) \(\d+% sure\)|is unsure: .*)\.$"))
    assert boxes(page) == first, "the layout stays as it was at the first step"
    expect(page.locator("#game-name")).to_have_text("Game 1 of 2")
    expect(page.locator("#first-game-note")).to_be_visible()
    expect(page.locator("#score-label")).to_have_text("team score")
    expect(page.locator("#belief .belief-row")).to_have_count(3)
    expect(page.locator("#belief .belief-value").first).to_have_text(re.compile(r"^\d+%$"))
    finish(page)
    expect(page.locator("#game-end-title")).to_have_text("Game 1 of 2 is over")
    expect(page.locator("#game-end-score")).to_have_text(re.compile(r"^Your team scored [+-]?\d+$"))
    expect(page.locator("#status")).to_have_text("")
    page.click("#next")

    # Questions after it, sent empty: both problems at once, beside their questions, in their words.
    expect(page.locator("fieldset.question")).to_have_count(2)
    page.click("#next")
    for qid in ("helpful", "understood"):
        box = page.locator(f"fieldset[data-id={qid}]")
        expect(box.locator(".problem")).to_have_text("Please answer this question.")
        expect(box).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#status li")).to_have_text(["How helpful was your AI partner?",
                                                     "How well did your AI partner understand the goal?"])
    assert "helpful:" not in page.locator("main").inner_text()  # no internal ids
    page.locator("fieldset[data-id=helpful] input[value='4']").check()  # its problem goes at once
    expect(page.locator("fieldset[data-id=helpful] .problem")).to_have_count(0)
    expect(page.locator("fieldset[data-id=helpful]")).not_to_have_attribute("aria-invalid", "true")
    expect(page.locator("#status li")).to_have_text(["How well did your AI partner understand the goal?"])
    page.click("#next")  # one left
    expect(page.locator("fieldset[data-id=helpful] .problem")).to_have_count(0)
    expect(page.locator("fieldset[data-id=understood] .problem")).to_have_count(1)
    page.locator("fieldset[data-id=understood] input[value='1']").check()
    expect(page.locator("#status")).to_have_text("")  # none left: the status line is clear
    page.locator("fieldset[data-id=understood] input[value='2']").check()
    page.click("#next")

    # Trial 2 (belief hidden): no first-game reminder, no belief.
    expect(page.locator("#page-title")).to_have_text("Game 2 of 2")
    play(page)
    expect(page.locator("#first-game-note")).to_be_hidden()
    expect(page.locator("#belief-panel")).to_be_hidden()
    expect(page.locator("#game-legend [data-who=partner]")).to_have_text("FYour AI partner")
    finish(page)
    page.click("#next")
    page.locator("fieldset[data-id=helpful] input[value='5']").check()
    page.locator("fieldset[data-id=understood] input[value='5']").check()
    page.click("#next")

    # The last questionnaire: "(optional)" once; the required question's problem beside it.
    expect(page.locator("#page-title")).to_have_text("Last questions")
    assert page.locator("fieldset[data-id=comments] legend").inner_text().count("(optional)") == 1
    page.click("#next")
    expect(page.locator("fieldset[data-id=preferred] .problem")).to_have_text("Please answer this question.")
    expect(page.locator("fieldset[data-id=comments] .problem")).to_have_count(0)
    expect(page.locator("#status li")).to_have_text(["Which game did you prefer?"])
    page.locator("fieldset[data-id=preferred] input[value='the second']").check()
    page.click("#next")
    expect(page.locator("#completion")).to_be_visible()
    expect(page.locator("#completion-code")).to_have_text("PAGES1")
    context.close()


# ---------------------------------------------------------------- the board, by its pixels
def at_practice(browser, server, pid: str):
    """A new participant's page on the practice game's page (consent agreed, instructions read)."""
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    page.goto(f"{server.url}/study?PROLIFIC_PID={pid}")
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("How to play")
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("Practice game")
    return context, page


def pixels(image_bytes: bytes) -> np.ndarray:
    """[H, W, 3] uint8 of a screenshot."""
    return np.asarray(Image.open(io.BytesIO(image_bytes)).convert("RGB"))


def hex_color(rgb) -> str:
    return "#%02x%02x%02x" % tuple(int(v) for v in rgb)


def most_common(region: np.ndarray) -> str:
    """The color most pixels of ``region`` have, as ``#rrggbb``."""
    colors, counts = np.unique(region.reshape(-1, 3), axis=0, return_counts=True)
    return hex_color(colors[counts.argmax()])


def rewrite_states(page, change) -> None:
    """Every ``state`` the server sends the page passes through ``change(msg)`` first (the page's play socket is
    routed through playwright); everything else, both ways, passes as it is."""
    def route(ws):
        server = ws.connect_to_server()

        def from_server(message):
            msg = json.loads(message)
            if msg.get("type") == "state":
                change(msg)
                message = json.dumps(msg)
            ws.send(message)

        server.on_message(from_server)
        ws.on_message(server.send)

    page.route_web_socket(re.compile(r"/ws/play$"), route)


def test_the_goal_frame_is_wide_in_the_goal_color_and_a_new_goal_is_announced(pages_server, browser):
    config = env_config("default")
    palette, colors = look(config)["palette"], config.color_names
    context, page = at_practice(browser, pages_server, "frame-1")
    first = {}

    def switch_at_step_2(msg):  # the server's goal until step 2, then the next color: a switch the test knows of
        first.setdefault("goal", msg["goal"])
        msg["goal"] = first["goal"] if msg["step"] < 2 else (first["goal"] + 1) % len(colors)

    rewrite_states(page, switch_at_step_2)
    play(page, steps=1)
    board = page.locator("#board")
    goal = int(board.get_attribute("data-goal"))
    shot = pixels(board.screenshot())
    h, w = shot.shape[:2]
    edges = [(1, h // 2), (FRAME - 2, h // 2), (w - FRAME + 1, h // 2), (w // 2, 1), (w // 2, FRAME - 2),
             (w // 2, h - 2), (2, 2)]
    assert {hex_color(shot[y, x]) for x, y in edges} == {palette[goal]}, "a frame as wide as FRAME, in the goal color"
    assert hex_color(shot[h // 2, FRAME + 1]) != palette[goal], "the board inside it"
    expect(page.locator("#goal-news")).to_be_hidden()

    page.keyboard.press("ArrowUp")
    expect(board).to_have_attribute("data-step", "2")
    new = (goal + 1) % len(colors)
    expect(board).to_have_attribute("data-goal", str(new))
    shot = pixels(board.screenshot())
    assert {hex_color(shot[y, x]) for x, y in edges} == {palette[new]}, "the frame changes with the goal"
    news = page.locator("#goal-news")
    expect(news).to_be_visible()
    expect(news).to_have_text(f"The goal is now {colors[new]}")
    expect(news).to_have_attribute("aria-live", "assertive")
    expect(news.locator(".swatch")).to_have_css("background-color", rgb(palette[new]))
    expect(page.locator("#goal-name")).to_have_text(colors[new])
    context.close()


def test_the_ai_partner_is_a_yellow_disc_inside_its_cell_with_a_legible_label_and_a_trail(pages_server, browser):
    config = env_config("default")
    width = config.width
    partner = look(config)["agents"][1]
    assert partner["body"] == hex_color(AGENT_COLORS["follower"][0])
    context, page = at_practice(browser, pages_server, "partner-1")
    start = 16 * width + 10

    def walk_right(msg):  # the partner walks along an empty stretch of row 16, a cell a step; the participant far off
        msg["follower"], msg["leader"] = start + msg["step"], 4 * width + 4
        msg["blocks"] = msg["blocks"][:start] + "..." + msg["blocks"][start + 3:]

    rewrite_states(page, walk_right)
    play(page, steps=2)
    board = page.locator("#board")
    expect(board).to_have_attribute("data-follower", str(start + 2))
    shot = pixels(page.screenshot())
    box = board.bounding_box()
    cell = (box["width"] - 2 * FRAME) / width

    def centre(index: int) -> tuple[int, int]:
        r, c = divmod(index, width)
        return round(box["x"] + FRAME + (c + 0.5) * cell), round(box["y"] + FRAME + (r + 0.5) * cell)

    x, y = centre(start + 2)
    on_board = most_common(shot[y - 4:y + 5, x - 8:x + 9])
    disc = page.locator("#game-legend [data-who=partner] .disc").bounding_box()
    in_legend = most_common(shot[round(disc["y"]) + 2:round(disc["y"] + disc["height"]) - 2,
                                 round(disc["x"]) + 2:round(disc["x"] + disc["width"]) - 2])
    assert on_board == in_legend == partner["body"], "the legend's disc is the board's, in the server's color"
    # inside its own cell: its color fills most of the cell and none of it reaches past the cell's edges (a pixel of
    # smoothing allowed), so it covers no neighbouring block and never the frame
    r, c = divmod(start + 2, width)
    left, top = box["x"] + FRAME + c * cell, box["y"] + FRAME + r * cell
    y0, x0 = round(top - cell), round(left - cell)
    around = shot[y0:round(top + 2 * cell), x0:round(left + 2 * cell)]
    ys, xs = np.nonzero((around == np.array(AGENT_COLORS["follower"][0])).all(axis=-1))
    assert len(ys) > 0.25 * cell ** 2, f"a disc about as wide as its cell, its label on it ({len(ys)} pixels)"
    assert top - 1 <= y0 + ys.min() and y0 + ys.max() <= top + cell + 1, "the disc stays inside its cell's rows"
    assert left - 1 <= x0 + xs.min() and x0 + xs.max() <= left + cell + 1, "the disc stays inside its cell's columns"
    # legible: its label (pixels nearer its ink than its body) stands more than half the cell high
    inside = shot[round(top) + 2:round(top + cell) - 2,  # the middle of the cell, clear of the disc's black ring
                  round(left + cell / 4):round(left + 3 * cell / 4)].astype(int)
    ink, fill = (np.array([int(partner[k][i:i + 2], 16) for i in (1, 3, 5)]) for k in ("ink", "body"))
    label_rows = np.nonzero((np.abs(inside - ink).sum(-1) < np.abs(inside - fill).sum(-1)).any(axis=1))[0]
    assert label_rows.max() - label_rows.min() + 1 > 0.5 * cell, f"a label {label_rows.tolist()} in a {cell} px cell"
    for behind in (start, start + 1):  # where it was: dots of its color, fainter, on the floor
        bx, by = centre(behind)
        dot = shot[by - 1:by + 2, bx - 1:bx + 2].reshape(-1, 3).astype(int)
        assert (dot[:, 0] - dot[:, 2] > 60).all(), f"a yellowish trail dot at cell {behind}: {dot.tolist()}"
    context.close()


# ---------------------------------------------------------------- coming back
def post(server, path: str, body: dict) -> tuple[int, dict]:
    import urllib.error
    import urllib.request

    request = urllib.request.Request(server.url + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def database(server) -> sqlite3.Connection:
    """The study's database (SQLite, beside the recordings), as another process of the study would open it."""
    return sqlite3.connect(server.replays_dir / "study.sqlite", timeout=30)


def test_an_interrupted_game_tells_the_participant_to_press_the_button_they_see(pages_server, browser):
    context, page = at_practice(browser, pages_server, "interrupted-1")
    with database(pages_server) as db:  # the practice game began on a process that died before it could end it
        db.execute("INSERT INTO games (pid, step, attempt, kind, settings, game_id, started) "
                   "VALUES ('interrupted-1', 2, 0, 'practice', '{}', 'lost-game', ?)", (time.time(),))
    page.reload()
    expect(page.locator("#play")).to_be_visible()
    expect(page.locator("#status")).to_have_text(
        'Your game was interrupted: the server running it stopped. Press "Start the game" to play this game again.')
    expect(page.locator("#play")).to_have_text("Start the game")
    context.close()


def test_a_participant_coming_back_from_another_browser_is_told_in_their_words(pages_server, browser):
    assert post(pages_server, "/api/study/join", {"params": {"PROLIFIC_PID": "done-1"}})[0] == 200
    assert post(pages_server, "/api/study/join", {"params": {"PROLIFIC_PID": "started-1"}})[0] == 200
    with database(pages_server) as db:  # done-1 finished the study
        db.execute("UPDATE participants SET status = 'completed', completed = ? WHERE pid = 'done-1'", (time.time(),))
    context = browser.new_context()  # another browser: none of their session
    page = context.new_page()
    page.goto(f"{pages_server.url}/study?PROLIFIC_PID=done-1")
    expect(page.locator("#page-title")).to_have_text("You have completed this study")
    expect(page.locator("#page-text")).to_have_text(
        "You have already completed this study: thank you for taking part. Your completion code is PAGES1.")
    expect(page.locator("#completion-code")).to_have_text("PAGES1")
    expect(page.locator("#redirect")).to_have_attribute("href", "https://example.org/done?cc=PAGES1")

    page.goto(f"{pages_server.url}/study?PROLIFIC_PID=started-1")
    expect(page.locator("#page-title")).to_have_text("This study cannot continue here")
    expect(page.locator("#page-text")).to_contain_text("You have already started this study in another browser")
    expect(page.locator("#completion")).to_be_hidden()

    page.goto(f"{pages_server.url}/study")
    expect(page.locator("#page-text")).to_have_text(
        "This link has no participant id in it. Please open the study from the link you were given (on the study "
        "platform), without changing it.")
    for hidden_words in ("PROLIFIC_PID", "pid"):
        assert hidden_words not in page.locator("#page").inner_text()
    context.close()


# ---------------------------------------------------------------- the instructions' picture
def test_the_instructions_picture_is_the_renderers_board_labelled():
    from server.study.picture import GOAL, OUT, board_picture

    drawn, places = board_picture()
    committed = np.asarray(Image.open(OUT).convert("RGB"))
    assert committed.shape == drawn.shape
    same = (committed == drawn).all(axis=-1).mean()
    assert same > 0.99, f"{OUT} is not the picture the renderer draws now ({same:.1%} alike): " \
                        "python -m server.study.picture"
    for place in ("frame", "goal_label"):
        x, y = places[place]
        assert hex_color(committed[y, x]) == hex_color(PALETTE[GOAL]), place
    for role in ("leader", "follower"):  # each disc beside its words, in the renderer's colors
        x, y = places[f"{role}_label"]
        assert most_common(committed[y - 12:y + 13, x - 12:x + 13]) == hex_color(AGENT_COLORS[role][0]), role


# ---------------------------------------------------------------- the admin's page
def test_the_admin_page_forgets_a_wrong_token_and_shows_processes_lost_games_and_arm_figures(pages_server, browser):
    assert pages_server.get("/api/health")[0]["restarts"] == 2  # what each process reports to the cluster's health
    status, joined = post(pages_server, "/api/study/join", {"params": {"PROLIFIC_PID": "admin-1"}})
    assert status == 200
    now = time.time()
    with database(pages_server) as db:  # a trial played to its end, and one lost with its process
        db.execute("INSERT INTO games (pid, step, attempt, kind, trial_index, condition, settings, game_id, ended, "
                   "started, finished, team_score, follower_net_pickups, follower_wrong_pickups, belief_accuracy) "
                   "VALUES ('admin-1', 3, 1, 'trial', 0, 0, '{}', 'g-admin-1', 'complete', ?, ?, 3, 2, 1, 0.5)",
                   (now, now))
        db.execute("INSERT INTO games (pid, step, attempt, kind, trial_index, condition, settings, game_id, ended, "
                   "started, finished) VALUES ('admin-1', 3, 0, 'trial', 0, 0, '{}', 'g-admin-0', 'server_lost', ?, ?)",
                   (now, now))
    summary = {}

    def with_processes(route):  # the server's summary, as behind HAProxy: three processes, one started again
        response = route.fetch()
        data = response.json()
        data["backends"] = [
            {"name": f"b{i}", "address": f"127.0.0.1:4123{i}", "up": True, "ready": True, "pid": 100 + i, "games": 3,
             "connections": 6, "tick_lateness_p50_ms": 0.41, "tick_lateness_p99_ms": 3.27, "late_ticks": 0,
             "deadline_misses": 0, "restarts": 2 if i == 2 else 0, "inference_restarts": 1 if i == 2 else 0}
            for i in (1, 2)] + [{"name": "b3", "address": "127.0.0.1:41233", "up": False,
                                 "problem": "connection refused by the address it was asked at"}]
        summary.update(data)
        route.fulfill(response=response, json=data)

    context = browser.new_context(viewport={"width": 640, "height": 900})
    page = context.new_page()
    page.route("**/api/study/admin/summary", with_processes)
    page.goto(f"{pages_server.url}/study/admin")
    page.fill("#token", "not-the-token")
    page.click("#open")
    expect(page.locator("#status")).to_contain_text("token printed when the study started")
    page.fill("#token", TOKEN)
    page.click("#open")
    expect(page.locator("#dashboard")).to_be_visible()
    expect(page.locator("#status")).to_have_text("")  # the wrong token's error is gone

    rows = page.locator("#backends tr")
    expect(rows).to_have_count(4)
    header = rows.nth(0).locator("th").all_inner_texts()
    assert header[-1] == "restarts: process / inference"
    assert rows.nth(2).locator("td").last.inner_text() == "2 / 1"
    for card in page.locator("#dashboard .card").all():  # nothing spills out of its card, however narrow the page
        assert card.evaluate("c => c.scrollWidth <= c.clientWidth"), card.inner_text()[:60]
    assert page.evaluate("() => document.documentElement.scrollWidth <= window.innerWidth")

    expect(page.locator("#endings")).to_contain_text("Played again: 1 lost with a process that stopped (server_lost)")
    assert summary["endings"]["played_again"] == {"server_lost": 1}
    trials = summary["arms"][0]["trials"]
    arm = page.locator("#arms tr").nth(1).locator("td").all_inner_texts()
    assert arm[5:] == [str(trials["games"]), js_fixed(trials["team_score"], 2), js_fixed(trials["follower_net_pickups"], 2),
                       js_fixed(trials["follower_wrong_pickups"], 2),
                       js_fixed(trials["belief_accuracy"], 2) if trials["belief_accuracy"] is not None else "",
                       "0", "0"]  # trials and participants excluded: this study declares no [exclusions]
    assert summary["arms"][0]["excluded"]["trials"] == 0 and summary["arms"][0]["excluded"]["participants"] == 0
    assert trials["games"] >= 1
    context.close()


def test_the_example_study_speaks_of_your_ai_partner_never_of_followers_or_leaders():
    from server.study.config import load_study
    from tests.conftest import ROOT

    study = load_study(ROOT / "studies" / "belief_display.toml")
    questions = [q for page in study.pages for q in (*page.questions, *page.after_each)]
    shown = [page.title + "\n" + page.text for page in study.pages]
    shown += [" ".join((q.prompt, *q.labels, *q.options)) for q in questions]
    for text in shown:
        assert not re.search(r"\b(followers?|leaders?)\b", text, re.IGNORECASE), text
    debrief = next(page.text for page in study.pages if page.kind == "debrief")
    assert "AI partner" in debrief
    instructions = next(page.text for page in study.pages if page.kind == "instructions")
    assert "yellow disc marked **F**" in instructions  # as the renderer draws it (colorgrid.render.FOLLOWER_RGB)
