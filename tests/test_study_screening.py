"""Screening, checks and exclusions declared in a study file: one-line errors for a wrong declaration; a trial's time
away and longest stretch without a key counted by hand, and each trial's rule (away, idle, round trip) applied;
against a real study server, participants refused by the screening and because the study is full (told why, logged
and counted), a comprehension check answered wrong then right or failed on every try, and trials away from the page
or on a slow connection, all in the export's ``exclusions`` table with its declared types and counted per arm on the
admin page; in chromium, the screening's refusal and the comprehension check as a participant meets them."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from types import SimpleNamespace

import pandas as pd
import pyarrow.parquet as pq
import pytest
from playwright.sync_api import expect
from websockets.sync.client import connect

from server.study.config import StudyError, load_study, parse_study
from server.study.columns import check_arrow, check_frame, read_csv
from server.study.exclusions import attention_figures, away_seconds, exclusion_rows, idle_seconds
from server.study.export import write_tables
from server.study.schema import export_schema
from tests.conftest import start_server, stop_server
from tests.test_study import toml

TOKEN = "screening-admin-token"
RIGHT, WRONG = "the yellow disc marked F", "the dark disc marked L"


def study_data(**changes) -> dict:
    """A small study: two turn-based trials of 3 steps (a leader's seat, the copy follower), instructions with one
    comprehension check of two tries, screening and every exclusion rule."""
    data = {
        "id": "screened", "title": "Screened", "max_participants": 3, "completion_code": "SCR1",
        "redirect_url": "https://example.org/done?cc={code}",
        "factors": {"show_belief": [True, False]},
        "defaults": {"follower": "copy", "mode": "turn", "horizon": 3},
        "design": {"assignment": "within", "order": "fixed"},
        "screening": {"keyboard": True, "min_width": 1000, "min_height": 700, "pings": 3,
                      "max_round_trip_ms": 5000, "return_code": "SCR0"},
        "exclusions": {"away_s": 0, "round_trip_ms": 500, "failed_checks": 1},
        "pages": [
            {"kind": "consent", "text": "Agree?"},
            {"kind": "instructions", "title": "How to play", "text": "You are **the yellow disc marked F**.",
             "questions": [{"id": "your_disc", "kind": "check", "prompt": "Which disc is yours?",
                            "options": [WRONG, RIGHT], "answer": RIGHT, "tries": 2}]},
            {"kind": "trials", "text": "Play."},
            {"kind": "debrief", "text": "Thank you."},
        ],
    }
    for key, value in changes.items():
        data[key] = value
    return data


# ---------------------------------------------------------------- the declaration
def page_with(question: dict, kind: str = "instructions") -> dict:
    data = study_data()
    data["pages"][1] = {"kind": kind, "id": "p", "text": "Read.", "questions": [question]}
    return data


CHECK = {"id": "c", "kind": "check", "prompt": "Which?", "options": ["a", "b"], "answer": "a"}


@pytest.mark.parametrize("data, words", [
    (page_with({**CHECK, "answer": "c"}), "answer='c' is invalid: the right option, one of ['a', 'b']"),
    (page_with({**CHECK, "tries": 0}), "tries=0 is invalid: a whole number in 1..10"),
    (page_with({**CHECK, "required": False}), "required=False is invalid: true for a 'check' question"),
    (page_with({"id": "c", "kind": "choice", "prompt": "Which?", "options": ["a", "b"], "answer": "a"},
               kind="questionnaire"), "answer='a' is invalid: only for kind='check'"),
    (page_with({"id": "c", "kind": "likert", "prompt": "How?"}),
     "is invalid: only questions of kind 'check' on an instructions page"),
    (study_data(screening={"min_width": -1}), "screening.min_width=-1 is invalid: a whole number of CSS pixels"),
    (study_data(screening={"max_round_trip_ms": 0}), "screening.max_round_trip_ms=0 is invalid: a number of "
                                                     "milliseconds > 0"),
    (study_data(screening={"pings": 0}), "screening.pings=0 is invalid: a whole number in 1..50"),
    (study_data(exclusions={"away_s": -2}), "exclusions.away_s=-2 is invalid: a number >= 0, or leave it out"),
    (study_data(exclusions={"failed_checks": 0}), "exclusions.failed_checks=0 is invalid: a whole number in 1..100"),
    (study_data(exclusions={"idle": 5}), "unknown field(s) ['idle'] in exclusions; allowed: ['away_s', 'idle_s'"),
])
def test_a_wrong_screening_check_or_exclusion_is_one_line_naming_the_field(data, words):
    with pytest.raises(StudyError) as err:
        parse_study(data)
    message = str(err.value)
    assert words in message and "\n" not in message, message


def test_the_rules_of_screening_say_why_in_words_for_the_participant():
    screening = parse_study(study_data()).screening
    assert screening.problem(False, (1200, 800), [3.0, 4.0, 5.0]) == ("", "")
    reason, words = screening.problem(True, (1200, 800), [3.0, 4.0, 5.0])
    assert reason == "touch_only" and "needs a keyboard" in words
    reason, words = screening.problem(False, (900, 800), [3.0, 4.0, 5.0])
    assert reason == "viewport" and "at least 1000 by 700 pixels, and yours is 900 by 800" in words
    reason, words = screening.problem(False, (1200, 800), [4000.0, 6000.0, 7000.0])  # the median: 6000 ms
    assert reason == "round_trip" and "a round trip of 6000 ms; they need at most 5000 ms" in words
    assert screening.problem(False, (1200, 800), [1.0])[0] == "round_trip"  # fewer pings than asked: not measured


def test_the_evidence_of_attention_counted_by_hand_and_each_trial_rule_applied_to_it():
    page = [{"event": "blur", "t_server": 1000}, {"event": "focus", "t_server": 3000},  # 2 s out of focus
            {"event": "visibilitychange", "visible": False, "t_server": 5000},  # hidden 5-7 s, out of focus 6-9 s
            {"event": "blur", "t_server": 6000}, {"event": "visibilitychange", "visible": True, "t_server": 7000},
            {"event": "focus", "t_server": 9000}, {"event": "blur", "t_server": 11000}]  # still away at the end
    assert away_seconds(page, 0, 12000) == 2 + 4 + 1
    assert idle_seconds([1000, 2000, 9000], 0, 10000) == 7.0 and idle_seconds([], 0, 4000) == 4.0
    replay = SimpleNamespace(meta={"state_sent_ms": [0, 1000, 10000], "page_events": page[:2]},
                             key_events=[{"t_server": 1000}], belief_events=[{"t_server": 4000, "via": "probe"}])
    assert attention_figures(replay) == {"away_s": 2.0, "idle_s": 6.0}  # a statement or a probe's answer is a key
    study = parse_study(study_data(exclusions={"away_s": 5, "idle_s": 6, "round_trip_ms": 500}))

    def game(index: int, kind: str = "trial", ended: str = "complete", **figures) -> dict:
        return {"participant": "p", "game_id": index, "kind": kind, "trial_index": index, "condition_index": 0,
                "ended": ended, **{"away_s": None, "idle_s": None, "round_trip_ms": None, **figures}}

    games = [game(0, idle_s=7.0), game(1, idle_s=6.0, away_s=8.0), game(2, round_trip_ms=501.0),
             game(3, idle_s=60.0, kind="practice"), game(4, idle_s=60.0, ended="disconnected")]
    rows = exclusion_rows(study, games, [])
    assert [(r["game_id"], r["rule"], r["value"], r["threshold"]) for r in rows] == [
        (0, "idle", 7.0, 6.0), (1, "away", 8.0, 5.0), (2, "round_trip", 501.0, 500.0)]  # above it, not at it
    assert rows[0]["evidence"] == "7.00 s without a key (more than 6 s)"


# ---------------------------------------------------------------- a real server
def post(server, path: str, body: dict, token: str | None = None):
    """``(status, answer)`` of a POST to the study's API."""
    headers = {"Content-Type": "application/json", **({"Authorization": f"Bearer {token}"} if token else {})}
    request = urllib.request.Request(server.url + path, data=json.dumps(body).encode(), headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def summary(server) -> dict:
    request = urllib.request.Request(server.url + "/api/study/admin/summary", headers={"Authorization":
                                                                                      f"Bearer {TOKEN}"})
    with urllib.request.urlopen(request, timeout=60) as response:
        return json.loads(response.read())


GOOD = {"touch_only": False, "viewport": [1280, 800], "round_trips_ms": [2.0, 3.0, 2.5]}


def join(server, pid: str, screen: dict | None = GOOD):
    body = {"params": {"PROLIFIC_PID": pid}, **({"screen": screen} if screen is not None else {})}
    return post(server, "/api/study/join", body)


def play(server, who: dict, before=()) -> dict:
    """The participant's current game over the play socket: ``before`` sent after the welcome, then one key a step;
    returns the ``game_over``."""
    with connect(server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "study": {"participant": who["pid"], "session": who["session"]}}))
        seq = 0
        while True:
            msg = json.loads(ws.recv(timeout=60))
            if msg["type"] == "welcome":
                for message in before:
                    ws.send(json.dumps(message))
            elif msg["type"] == "state" and msg["step"] < msg["horizon"]:
                ws.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq, "t_client": time.time() * 1000}))
                seq += 1
            elif msg["type"] == "game_over":
                return msg
            elif msg["type"] in ("error", "full"):
                raise AssertionError(msg)


def advance(server, who: dict, view: dict, **body) -> tuple[int, dict]:
    return post(server, "/api/study/advance", {**who, "step": view["step"], **body})


@pytest.fixture(scope="module")
def screened_server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("screened")
    (tmp / "screened.toml").write_text(toml(study_data()))
    server = start_server(tmp, command=("study", "run", str(tmp / "screened.toml")),
                          env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    server.study_file = tmp / "screened.toml"
    yield server
    stop_server(server)


# ---------------------------------------------------------------- in chromium (before the study fills up)
def test_a_small_window_is_refused_in_words_with_the_return_code_in_chromium(screened_server, browser):
    context = browser.new_context(viewport={"width": 900, "height": 650})
    page = context.new_page()
    page.goto(f"{screened_server.url}/study?PROLIFIC_PID=chromium-small")
    expect(page.locator("#page-title")).to_have_text("This study cannot continue here")
    expect(page.locator("#page-text")).to_contain_text("at least 1000 by 700 pixels, and yours is 900 by 650")
    expect(page.locator("#code-label")).to_have_text("Your return code:")
    expect(page.locator("#completion-code")).to_have_text("SCR0")
    expect(page.locator("#redirect")).to_have_attribute("href", "https://example.org/done?cc=SCR0")
    expect(page.locator("#next")).to_be_hidden()
    context.close()
    assert summary(screened_server)["refused"].get("screening:viewport", 0) >= 1


def test_the_comprehension_check_shows_the_instructions_again_after_a_wrong_answer_in_chromium(screened_server,
                                                                                               browser):
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{screened_server.url}/study?PROLIFIC_PID=chromium-check")
    expect(page.locator("#page-title")).to_have_text("Consent")
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("How to play")
    expect(page.locator("#check-note")).to_be_hidden()
    page.locator(f"fieldset[data-id=your_disc] input[value='{WRONG}']").check()
    page.click("#next")
    expect(page.locator("#check-note")).to_have_text(
        "Not quite: please read the instructions again, then answer the question below once more.")
    expect(page.locator("#page-text")).to_contain_text("You are the yellow disc marked F.")
    expect(page.locator("#page-title")).to_have_text("How to play")
    expect(page.locator("fieldset[data-id=your_disc] .problem")).to_contain_text("1 try left")
    expect(page.locator(f"fieldset[data-id=your_disc] input[value='{WRONG}']")).not_to_be_checked()
    page.locator(f"fieldset[data-id=your_disc] input[value='{RIGHT}']").check()
    page.click("#next")
    expect(page.locator("#play")).to_be_visible()  # the first trial's page
    expect(page.locator("#check-note")).to_be_hidden()
    assert errors == []
    context.close()


def test_refusals_checks_and_exclusions_are_logged_exported_and_counted(screened_server, tmp_path):
    server = screened_server
    before = summary(server)
    # the screening: told why, given the return code, logged, and no place taken
    status, answer = join(server, "small-window", {**GOOD, "viewport": [800, 600]})
    assert status == 403 and answer["detail"]["return_code"] == "SCR0"
    assert answer["detail"]["redirect_url"] == "https://example.org/done?cc=SCR0"
    assert "at least 1000 by 700 pixels, and yours is 800 by 600" in answer["detail"]["message"]
    status, answer = join(server, "phone", {**GOOD, "touch_only": True})
    assert status == 403 and "needs a keyboard" in answer["detail"]["message"]
    status, answer = join(server, "no-screen", None)
    assert status == 403 and answer["detail"]["return_code"] == "SCR0"
    status, answer = join(server, "bad-screen", {**GOOD, "touch_only": "no"})
    assert status == 422  # strict: a string is no boolean
    # participant A answers the check wrong, is asked again, then right; away in trial 1, a slow connection in trial 2
    status, joined = join(server, "pa")
    assert status == 200
    a, view = {"pid": "pa", "session": joined["session"]}, joined["view"]
    status, view = advance(server, a, view, agree=True)
    assert view["kind"] == "instructions" and "answer" not in view["questions"][0]  # the answer stays on the server
    status, again = advance(server, a, view, answers={"your_disc": WRONG})
    assert status == 422 and again["detail"]["again"] is True
    assert "read the instructions again" in again["detail"]["problems"][0]["problem"]
    assert "1 try left" in again["detail"]["problems"][0]["problem"]
    status, view = advance(server, a, view, answers={"your_disc": RIGHT})
    assert status == 200 and view["kind"] == "trial"
    blur = [{"type": "page_event", "event": "blur", "visible": True, "t_client": 1.0},
            {"type": "page_event", "event": "focus", "visible": True, "t_client": 2.0}]
    first = play(server, a, blur)
    status, view = advance(server, a, view)
    second = play(server, a, [{"type": "ping"}, {"type": "ping", "round_trip_ms": 900.0},
                              {"type": "ping", "round_trip_ms": 700.0}])
    status, view = advance(server, a, view)
    assert view["kind"] == "debrief"
    # participant B fails the check on both tries, goes on, and plays both trials without breaking a rule
    status, joined = join(server, "pb")
    b, view = {"pid": "pb", "session": joined["session"]}, joined["view"]
    status, view = advance(server, b, view, agree=True)
    assert advance(server, b, view, answers={"your_disc": WRONG})[0] == 422
    status, view = advance(server, b, view, answers={"your_disc": WRONG})
    assert status == 200 and view["kind"] == "trial"  # the last try: the wrong answer is kept
    for _ in range(2):
        play(server, b)
        status, view = advance(server, b, view)
    # the study fills up: the next participant is refused, logged and counted
    for i in range(study_data()["max_participants"] - summary(server)["participants"]["total"]):
        assert join(server, f"filler-{i}")[0] == 200
    status, answer = join(server, "one-too-many")
    assert status == 403 and "the study is full" in answer["detail"]
    counts = summary(server)
    refused = {k: n - before["refused"].get(k, 0) for k, n in counts["refused"].items()}
    assert refused == {"screening:viewport": 1, "screening:touch_only": 1, "screening:not_screened": 1, "full": 1}
    assert counts["participants"]["total"] == study_data()["max_participants"]  # the refused took no place
    (arm,) = counts["arms"]
    assert arm["excluded"] == {"trials": 2, "participants": 1, "rules": {"away": 1, "round_trip": 1,
                                                                          "failed_checks": 1}}

    out = tmp_path / "export"
    study = load_study(server.study_file)
    write_tables(study, server.replays_dir / "study.sqlite", server.replays_dir, out)
    declared = export_schema(study)
    tables = {}
    for name in ("exclusions", "trials", "answers", "focus"):
        parquet, csv = pd.read_parquet(out / f"{name}.parquet"), read_csv(out, name)
        assert check_frame(parquet, declared[name]) == [] and check_frame(csv, declared[name]) == [], name
        assert check_arrow(pq.read_table(out / f"{name}.parquet").schema, declared[name]) == [], name
        pd.testing.assert_frame_equal(csv, parquet)
        tables[name] = parquet
    exclusions, trials = tables["exclusions"], tables["trials"].set_index("replay_id")
    first, second = (trials.loc[over["replay_id"], "game_id"] for over in (first, second))
    trials = trials.reset_index().set_index("game_id")
    rows = {(r.participant, r.rule): r for r in exclusions.itertuples()}
    assert set(rows) == {("pa", "away"), ("pa", "round_trip"), ("pb", "failed_checks")}
    away = rows[("pa", "away")]
    assert away.game_id == first and away.trial_index == 0 and away.condition == "C1"
    assert away.threshold == 0 and away.value == pytest.approx(trials.loc[first, "away_s"])
    focus = tables["focus"]
    clock = focus[focus.participant == "pa"].t_server_ms.tolist()  # the blur and the focus, by the server's clock
    assert away.value == pytest.approx((clock[1] - clock[0]) / 1000) and away.value > 0
    slow = rows[("pa", "round_trip")]
    assert slow.game_id == second and slow.value == 800.0 and slow.threshold == 500  # median of 900, 700
    assert trials.loc[second, "round_trip_ms"] == 800.0
    assert "800.0 ms during play (more than 500 ms)" in slow.evidence
    failed = rows[("pb", "failed_checks")]
    assert pd.isna(failed.game_id) and pd.isna(failed.trial_index) and failed.value == 1
    assert f"{WRONG!r} on the last of 2 tries (right: {RIGHT!r})" in failed.evidence
    assert str(exclusions.rule.dtype) == "category" and exclusions.value.dtype == "float64"
    answers = tables["answers"]
    checks = answers[answers.question == "your_disc"].set_index("participant")
    assert checks.loc["pa", "correct"] and not checks.loc["pb", "correct"]
    assert checks.loc["pb", "choice"] == WRONG and checks.question_kind.eq("check").all()
