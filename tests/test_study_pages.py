"""The study's participant page in chromium, against a real study server: who is who on the board, the
practice game, and questionnaire answers that cannot be taken."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from colorgrid.presets import env_config
from colorgrid.render import look
from tests.conftest import start_server, stop_server

STUDY = """
id = "pages"
title = "Pages"
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
game = { follower = "copy", horizon = 3, mode = "turn" }

[[pages]]
kind = "trials"

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
    server = start_server(tmp, command=("study", "run", str(tmp / "pages.toml")))
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


def finish(page) -> None:
    """The last step of a game of 3, and back to its page."""
    page.keyboard.press("ArrowDown")
    expect(page.locator("#game")).to_be_hidden(timeout=20_000)
    expect(page.locator("#next")).to_be_visible(timeout=20_000)


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
    page.click("#next")

    # The practice (a follower without a belief): the first game says who is who; nothing of a belief; its
    # score is marked as practice, and so is its ending.
    expect(page.locator("#page-title")).to_have_text("Practice game")
    expect(page.locator("#legend")).to_be_visible()
    play(page)
    expect(page.locator("#first-game-note")).to_have_text("You are L. Your AI partner is F.")
    expect(page.locator("#game-legend [data-who=you]")).to_have_text("LYou")
    expect(page.locator("#score-label")).to_have_text("practice score (does not count)")
    expect(page.locator("#belief-panel")).to_be_hidden()
    assert "You (L) at row" in page.locator("#board").get_attribute("aria-label")
    finish(page)
    expect(page.locator("#status")).to_contain_text("Practice over.")
    expect(page.locator("#status")).not_to_contain_text("Game over")
    page.click("#next")

    # Trial 1 (belief shown): the reminder again, the belief once the partner has one, a team score.
    expect(page.locator("#page-title")).to_have_text("Game 1 of 2")
    play(page)
    expect(page.locator("#first-game-note")).to_be_visible()
    expect(page.locator("#score-label")).to_have_text("team score")
    expect(page.locator("#belief-panel")).to_be_visible()
    expect(page.locator("#belief .belief-row")).to_have_count(3)
    finish(page)
    expect(page.locator("#status")).to_contain_text("Game over. Your team scored")
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
    page.locator("fieldset[data-id=helpful] input[value='4']").check()
    page.click("#next")  # one left: the answered one is cleared
    expect(page.locator("fieldset[data-id=helpful] .problem")).to_have_count(0)
    expect(page.locator("fieldset[data-id=understood] .problem")).to_have_count(1)
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
    context.close()
