"""The study layer: study files, assignment, the database, the study server and its export, for real."""

from __future__ import annotations

import copy
import json
import sqlite3
import subprocess
import sys
import time
import tomllib
import urllib.error
import urllib.request
from collections import Counter
from itertools import pairwise
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from websockets.sync.client import connect

from colorgrid.enums import Ending
from colorgrid.replay import load, verify
from server.study import service as service_module
from server.study.assign import williams
from server.study.config import StudyError, load_study, parse_study
from server.study.service import Finished, Refused, StudyService, study_hash
from server.study.store import StudyStore
from tests.conftest import ROOT, start_server, stop_server

EXAMPLE = ROOT / "studies" / "belief_display.toml"
TOKEN = "admin-token-for-tests"
FAST = """
[defaults]
mode = "turn"
horizon = 4

[[pages]]
kind = "practice"
game = { mode = "realtime", horizon = 4, tick_hz = 10.0, follower = "copy" }
"""


def example() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def fast_study(tmp: Path) -> Path:
    """The example study with short games (turn-based trials of 4 steps, a real-time practice of 4)."""
    data = example()
    data["defaults"] = {"mode": "turn", "horizon": 4}
    data["factors"]["follower"] = ["copy", "bayes"]
    for page in data["pages"]:
        if page["kind"] == "practice":
            page["game"] = {"mode": "realtime", "horizon": 4, "tick_hz": 10.0, "follower": "copy"}
    path = tmp / "study.toml"
    path.write_text(toml(data))
    return path


def toml(data: dict) -> str:
    """Just enough TOML for study files (tables, arrays of tables, inline game tables)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise TypeError(v)

    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, (dict, list)) or
             (isinstance(v, list) and not (v and isinstance(v[0], dict)))]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += [f"[{k}]", *(f"{a} = {value(b)}" for a, b in v.items())]
    for page in data.get("pages", []):
        lines.append("[[pages]]")
        lines += [f"{a} = {value(b)}" for a, b in page.items() if not isinstance(b, list)]
        for name in ("questions", "after_each"):
            for q in page.get(name, []):
                lines.append(f"[[pages.{name}]]")
                lines += [f"{a} = {value(b)}" for a, b in q.items()]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- the study file
def test_the_example_study_loads_and_round_trips_through_the_test_writer():
    study = load_study(EXAMPLE)
    assert len(study.conditions) == 4 and study.design.assignment == "within"
    assert parse_study(tomllib.loads(toml(example()))) == study


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(id="has space"), "id='has space' is invalid: 1 to 64 letters"),
    (lambda d: d["pages"].pop(3), "exactly one page of kind 'trials' (got 0)"),
    (lambda d: d["pages"][0].update(kind="welcome"), "pages[0].kind='welcome' is invalid: one of ['consent'"),
    (lambda d: d["pages"][3]["after_each"][0].update(scale=1), "pages[3].after_each[0].scale=1 is invalid: a whole number in 2..11"),
    (lambda d: d["pages"][4]["questions"][0].update(options=["only"]), "pages[4].questions[0].options=('only',) is invalid: at least two"),
    (lambda d: d["pages"][4]["questions"][0].pop("prompt"), "pages[4].questions[0]: missing prompt"),
    (lambda d: d["factors"].update(speed=[1, 2]), "factors.speed is not a factor: choose from ['follower'"),
    (lambda d: d["factors"].update(horizon=[50, 5000]), "factors.horizon: level 5000 is invalid: a whole number in 1..1000"),
    (lambda d: d["design"].update(assignment="mixed"), "design.assignment='mixed' is invalid: 'within' or 'between'"),
    (lambda d: d["design"].update(quota=0), "design.quota=0 is invalid: a positive whole number"),
    (lambda d: d.update(redirect_url="prolific.com"), "redirect_url='prolific.com' is invalid: an http:// or https://"),
    (lambda d: d["pages"].append({"kind": "instructions", "text": "late"}), "at most one 'debrief' page, and it comes last"),
    (lambda d: d["pages"][0].update(text=""), "pages[0].text='' is invalid: the consent text"),
    (lambda d: d.update(colour="red"), "unknown field(s) ['colour']"),
])
def test_each_kind_of_mistake_in_a_study_file_gets_its_clear_message(change, message, tmp_path):
    data = copy.deepcopy(example())
    change(data)
    path = tmp_path / "study.toml"
    path.write_text(toml(data))
    with pytest.raises(StudyError) as err:
        load_study(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_the_cli_names_a_broken_study_file_in_one_line(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("id = 'x'\ntitle = [\n")
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "run", str(path)], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "not valid TOML" in result.stderr and str(path) in result.stderr


@pytest.mark.parametrize("change, blamed", [
    (lambda d: d["factors"].update(follower=["bayes-people", "bayes-peeple"]),
     "factors.follower: level 'bayes-peeple' is invalid: unknown policy 'bayes-peeple'; choose one of ["),
    (lambda d: d["pages"][2]["game"].update(follower="copyy"),
     "pages[2].game.follower='copyy' is invalid: unknown policy 'copyy'; choose one of ["),
])
def test_a_misspelled_follower_is_blamed_on_the_study_files_field_not_a_flag(change, blamed, tmp_path):
    data = copy.deepcopy(example())
    change(data)
    path = tmp_path / "study.toml"
    path.write_text(toml(data))
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "run", str(path), "--replays-dir",
                             str(tmp_path / "recordings")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert f"{path}: {blamed}" in result.stderr and "'bayes-people'" in result.stderr, result.stderr  # what is allowed
    assert "--follower" not in result.stderr


# ---------------------------------------------------------------- assignment
@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_williams_squares_balance_positions_and_neighbours(n):
    rows = williams(n)
    assert all(sorted(r) == list(range(n)) for r in rows)
    for position in range(n):
        assert Counter(r[position] for r in rows) == Counter({c: len(rows) // n for c in range(n)})
    neighbours = Counter(pair for r in rows for pair in pairwise(r))
    assert set(neighbours.values()) == {len(rows) // n}  # every ordered pair follows equally often
    assert len(neighbours) == n * (n - 1)


def test_assignment_is_balanced_over_many_participants_and_quotas_hold(study_database):
    data = example()
    data["max_participants"] = 1000
    data["design"]["quota"] = 60
    study = parse_study(data)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    for i in range(150):
        service.join({"PROLIFIC_PID": f"p{i}"}, None, "test")
    arms = Counter(r["arm"] for r in service.store.participants())
    assert sorted(arms) == [0, 1, 2, 3] and max(arms.values()) - min(arms.values()) <= 1, arms
    for i in range(150, 240):
        service.join({"PROLIFIC_PID": f"p{i}"}, None, "test")
    with pytest.raises(Refused, match="the study is full"):  # 4 arms x quota 60
        service.join({"PROLIFIC_PID": "one-too-many"}, None, "test")
    orders = {tuple(json.loads(r["conditions"])) for r in service.store.participants()}
    assert orders == {tuple(r) for r in williams(4)}


def test_a_participant_id_cannot_start_over_and_its_own_browser_resumes(study_database):
    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    first = service.join({"PROLIFIC_PID": "p1", "STUDY_ID": "s1"}, None, "browser A")
    assert service.join({"PROLIFIC_PID": "p1"}, first["session"], "browser A") == first
    with pytest.raises(Refused, match="already started this study in another browser"):
        service.join({"PROLIFIC_PID": "p1"}, None, "browser B")
    with pytest.raises(Refused, match="already started"):
        service.join({"PROLIFIC_PID": "p1"}, "a guess", "browser B")
    with pytest.raises(Refused, match="no participant id"):
        service.join({"other": "x"}, None, "browser C")
    resuming = parse_study({**example(), "returning": "resume"})
    again = StudyService(resuming, StudyStore(study_database, study.id, study_hash(resuming)))
    assert again.join({"PROLIFIC_PID": "p1"}, None, "browser B")["session"] == first["session"]


def test_a_join_sent_again_with_the_key_its_browser_proposed_resumes_instead_of_refusing(study_database):
    # The proxy (or the page) sends a join again when the process that stored it was killed before answering.
    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    proposed = "k" * 32
    first = service.join({"PROLIFIC_PID": "p1"}, proposed, "browser A")
    assert first == {"pid": "p1", "session": proposed}
    assert service.join({"PROLIFIC_PID": "p1"}, proposed, "browser A") == first
    with pytest.raises(Refused, match="already started"):
        service.join({"PROLIFIC_PID": "p1"}, "k" * 31, "browser B")
    assert service.join({"PROLIFIC_PID": "p2"}, "short", "browser C")["session"] != "short"  # not a key: one is made


def test_a_participant_who_finished_gets_their_completion_code_again_from_another_browser(study_database):
    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    first = service.join({"PROLIFIC_PID": "p1"}, None, "browser A")
    with service.store.transaction() as tx:
        assert tx.move_on("p1", 0, 11, True, time.time())  # the debrief: done
    with pytest.raises(Finished) as refused:
        service.join({"PROLIFIC_PID": "p1"}, None, "browser B")
    assert "already completed this study" in str(refused.value) and "CG7QX2" in str(refused.value)
    assert refused.value.completion_code == "CG7QX2"
    assert refused.value.redirect_url == "https://app.prolific.com/submissions/complete?cc=CG7QX2"
    assert service.join({"PROLIFIC_PID": "p1"}, first["session"], "browser A") == first  # their own browser resumes


def test_a_returning_participant_refused_stays_in_the_audit_log(study_database):
    # The refusal's event is written in the join's transaction: the refusal is raised once it is committed.
    from sqlalchemy import select

    from server.study.store import events

    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    service.join({"PROLIFIC_PID": "p1"}, None, "browser A")
    with pytest.raises(Refused, match="already started"):
        service.join({"PROLIFIC_PID": "p1"}, None, "browser B")
    with service.store.transaction() as tx:
        assert tx.move_on("p1", 0, 11, True, time.time())  # the debrief: done
    with pytest.raises(Finished):
        service.join({"PROLIFIC_PID": "p1"}, None, "browser C")
    with service.store.reading() as tx:
        logged = tx.conn.execute(select(events.c.kind, events.c.detail).where(events.c.pid == "p1")).all()
    refused = sorted(json.loads(detail)["reason"] for kind, detail in logged if kind == "refused")
    assert refused == ["already completed", "already started"], logged
    assert [kind for kind, _ in logged].count("joined") == 1


def test_the_summary_counts_games_by_ending_and_those_played_again(study_database):
    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    service.join({"PROLIFIC_PID": "p1"}, None, "browser A")
    with service.store.transaction() as tx:
        for attempt, ended in enumerate(("server_lost", "disconnected", "complete")):
            tx.add_game({"pid": "p1", "step": 3, "attempt": attempt, "kind": "trial", "trial_index": 0,
                         "condition": 0, "settings": "{}", "game_id": f"g{attempt}", "started": time.time()})
            tx.end_game("p1", 3, attempt, {"ended": ended, "finished": time.time(), "team_score": 2.0})
    summary = service.summary(0)
    assert summary["endings"] == {"counted": {"complete": 1}, "played_again": {"disconnected": 1, "server_lost": 1}}
    assert set(summary["ending_words"]) == {e.value for e in Ending}  # the admin page's words come from here
    assert summary["ending_words"]["server_lost"] == "lost with a process that stopped (server_lost)"
    assert summary["arms"][summary["recent"][0]["arm"]]["trials"]["games"] == 1  # the lost ones are not figures


@pytest.mark.parametrize("failures", [1, 2])
def test_a_failed_write_of_a_games_end_is_tried_once_more_and_never_leaves_the_game_running(failures, monkeypatch,
                                                                                             study_database):
    study = load_study(EXAMPLE)
    service = StudyService(study, StudyStore(study_database, study.id, study_hash(study)))
    service.join({"PROLIFIC_PID": "p1"}, None, "browser A")
    game = SimpleNamespace(game_id="g1", replay_id="r1", to_replay=lambda reason, described: None,
                           study={"participant": "p1", "step": 0, "attempt": 0, "kind": "trial", "trial_index": 0,
                                  "condition_index": 0, "condition": {}})
    service.game_started(game)
    left = [failures]

    def figures(replay):
        left[0] -= 1
        if left[0] >= 0:
            raise OSError("the database blinked")
        return {}

    monkeypatch.setattr(service_module, "game_figures", figures)
    monkeypatch.setattr(service_module, "END_RETRY_WAIT_S", 0)
    if failures == 1:
        service.game_over(game, "done", {"team": 3})
    else:
        with pytest.raises(OSError):
            service.game_over(game, "done", {"team": 3})
    last = service.store.last_game("p1", 0)
    assert "p1" not in service.live
    assert last["ended"] == ("done" if failures == 1 else None)
    assert service.interrupted("p1", last) == (failures == 2)  # not stored: the page offers to play it again


# ---------------------------------------------------------------- the study server
def post(server, path: str, body: dict, token: str | None = None):
    request = urllib.request.Request(server.url + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def get(server, path: str, token: str | None = None):
    headers = {"Authorization": f"Bearer {token}"} if token is not None else {}
    try:
        with urllib.request.urlopen(urllib.request.Request(server.url + path, headers=headers), timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as err:
        return err.code, err.read()


@pytest.fixture(scope="module")
def study_server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("study")
    server = start_server(tmp, "--rejoin-grace-s", "30", command=("study", "run", str(fast_study(tmp))),
                          env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    server.study_file = tmp / "study.toml"
    yield server
    stop_server(server)


def test_the_admin_pages_refuse_a_missing_or_wrong_token(study_server):
    for token in (None, "wrong", ""):
        status, body = get(study_server, "/api/study/admin/summary", token)
        assert status == 401 and b"token printed when the study started" in body
    status, body = get(study_server, "/api/study/admin/summary", TOKEN)
    assert status == 200 and json.loads(body)["study"] == "belief_display"


def test_free_play_and_replays_are_closed_while_a_study_runs(study_server):
    assert get(study_server, "/api/replays")[0] == 404
    with connect(study_server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "mode": "turn"}))
        reply = json.loads(ws.recv(timeout=20))
        assert reply["code"] == "rejected" and "games start from the study page" in reply["message"]


def test_a_game_the_study_refuses_gets_the_studys_reason(study_server):
    with connect(study_server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "study": {"participant": "nobody", "session": "none"}}))
        reply = json.loads(ws.recv(timeout=20))
        assert reply["type"] == "error" and reply["code"] == "rejected", reply
        assert "unknown participant or session" in reply["message"]


def play_turns(ws, study_ref: dict, keys: int = 4) -> dict:
    ws.send(json.dumps({"type": "new_game", "study": study_ref, "viewport": [1280, 800]}))
    welcome = json.loads(ws.recv(timeout=30))
    assert welcome["type"] == "welcome", welcome
    ws.send(json.dumps({"type": "page_event", "event": "blur", "visible": True, "t_client": 1.0}))
    for seq in range(keys):
        ws.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq, "t_client": 2.0 + seq}))
    while True:
        msg = json.loads(ws.recv(timeout=30))
        if msg["type"] == "game_over":
            return {"welcome": welcome, **msg}


def test_a_participant_goes_through_the_api_and_the_data_is_recorded(study_server):
    status, joined = post(study_server, "/api/study/join", {"params": {"PROLIFIC_PID": "api-1", "SESSION_ID": "s9"}})
    assert status == 200
    who = {"pid": "api-1", "session": joined["session"]}
    view = joined["view"]
    assert view["kind"] == "consent" and "<strong>I agree</strong>" in view["html"]
    status, body = post(study_server, "/api/study/advance", {**who, "step": 0})
    assert status == 409 and "agree to take part" in body["detail"]
    view = post(study_server, "/api/study/advance", {**who, "step": 0, "agree": True})[1]
    view = post(study_server, "/api/study/advance", {**who, "step": 1})[1]
    assert view["kind"] == "practice" and view["game"]["mode"] == "realtime"
    status, body = post(study_server, "/api/study/advance", {**who, "step": 2})
    assert status == 409 and "not over yet" in body["detail"]
    ref = {"participant": "api-1", "session": joined["session"]}
    with connect(study_server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        while json.loads(ws.recv(timeout=30))["type"] != "game_over":
            pass
    view = post(study_server, "/api/study/advance", {**who, "step": 2})[1]
    assert view["kind"] == "trial" and view["trial_index"] == 0
    with connect(study_server.ws_url, open_timeout=20) as ws:  # one game a socket: the server closed the last
        over = play_turns(ws, ref)
        assert over["welcome"]["mode"] == "turn" and over["reason"] == "complete"
    view = post(study_server, "/api/study/advance", {**who, "step": 3})[1]
    assert view["kind"] == "questions"
    status, body = post(study_server, "/api/study/advance", {**who, "step": 4, "answers": {"helpful": 9}})
    assert status == 422 and body["detail"]["problems"] == [  # every problem at once, in the question's words
        {"question": "helpful", "prompt": "How helpful was your AI partner in this game?",
         "problem": "Choose one of the points from 1 to 7."},
        {"question": "understood", "prompt": "How well did your AI partner understand the goal?",
         "problem": "Please answer this question."}]
    status, body = post(study_server, "/api/study/advance", {**who, "step": 4, "answers": {"helpful": 5}})
    assert status == 422 and [p["question"] for p in body["detail"]["problems"]] == ["understood"]
    status, body = post(study_server, "/api/study/advance", {**who, "step": 4, "answers": {"nope": 5}})
    assert status == 409 and "unknown question(s) ['nope']" in body["detail"]
    view = post(study_server, "/api/study/advance", {**who, "step": 4, "answers": {"helpful": 5, "understood": 6}})[1]
    assert view["kind"] == "trial" and view["trial_index"] == 1
    replay_path = next(study_server.replays_dir.glob(f"*{over['welcome']['game_id']}.replay.json"))
    replay = load(replay_path)
    assert verify(replay).ok
    meta = replay.meta
    assert meta["study"]["participant"] == "api-1" and meta["study"]["trial_index"] == 0
    assert meta["show_belief"] == meta["study"]["condition"]["show_belief"]
    assert meta["client"]["viewport"] == [1280, 800] and meta["page_events"][0]["event"] == "blur"


def complete_fast_study(browser, url: str, pid: str, reload_in_trial: int | None = None) -> None:
    """One participant through ``fast_study`` in chromium, from the link to the completion code; with
    ``reload_in_trial``, the page reloads in the middle of that trial's game (it resumes the same game)."""
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    page.goto(f"{url}/study?PROLIFIC_PID={pid}&STUDY_ID=st&SESSION_ID=se")
    expect(page.locator("#page-title")).to_have_text("Consent")
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("How to play")
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("Practice game")
    page.click("#play")
    expect(page.locator("#countdown")).to_have_text("3")  # real time: a visible 3-2-1 first
    expect(page.locator("#page-title")).to_have_text("Practice game")  # back when it ends
    expect(page.locator("#next")).to_be_visible()
    page.click("#next")
    for trial in range(4):
        expect(page.locator("#page-title")).to_have_text(f"Game {trial + 1} of 4")
        page.click("#play")
        expect(page.locator("#board")).to_be_visible()
        page.locator("#board").focus()
        for i in range(4):
            if trial == reload_in_trial and i == 2:
                page.reload()  # resumes the same game
                expect(page.locator("#board")).to_be_visible()
                expect(page.locator("#board")).to_have_attribute("data-step", "2")
                page.locator("#board").focus()
            expect(page.locator("#board")).to_have_attribute("data-step", str(i))
            page.keyboard.press("ArrowLeft" if i % 2 else "ArrowUp")
        expect(page.locator("#next")).to_be_visible()
        page.click("#next")
        page.locator("fieldset[data-id=helpful] input[value='6']").check()
        page.click("#next")
        expect(page.locator("fieldset[data-id=understood] .problem")).to_have_text("Please answer this question.")
        page.locator("fieldset[data-id=understood] input[value='5']").check()
        page.click("#next")
    expect(page.locator("#page-title")).to_have_text("A few last questions")
    page.locator("fieldset[data-id=belief_display] input[value='it helped']").check()
    page.click("#next")
    expect(page.locator("#completion-code")).to_have_text("CG7QX2")
    assert "cc=CG7QX2" in page.locator("#redirect").get_attribute("href")
    context.close()


def test_two_participants_in_chromium_one_reloading_mid_trial(study_server, browser, tmp_path):
    complete_fast_study(browser, study_server.url, "browser-1")
    complete_fast_study(browser, study_server.url, "browser-2", reload_in_trial=1)
    summary = json.loads(get(study_server, "/api/study/admin/summary", TOKEN)[1])
    completed = {p["pid"] for p in summary["recent"] if p["status"] == "completed"}
    assert {"browser-1", "browser-2"} <= completed and summary["completion_minutes"]["median"] > 0

    out = tmp_path / "export"
    result = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "export", str(study_server.study_file),
                             "--replays-dir", str(study_server.replays_dir), "--out", str(out)],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    tables = {name: pd.read_parquet(out / f"{name}.parquet") for name in
              ("participants", "trials", "steps", "keys", "answers", "focus")}
    for name, frame in tables.items():
        assert len(pd.read_csv(out / f"{name}.csv")) == len(frame)
    ours = ["browser-1", "browser-2"]
    trials = tables["trials"][tables["trials"].participant.isin(ours)]
    assert len(trials[trials.kind == "trial"]) == 8 and len(trials[trials.kind == "practice"]) == 2
    assert {"condition_follower", "condition_show_belief", "follower_net_pickups", "follower_wrong_pickups",
            "belief_accuracy", "team_score"} <= set(trials.columns)
    steps = tables["steps"][tables["steps"].participant.isin(ours)]
    assert len(steps) == 10 * 4 and {"leader_row", "follower_col", "leader_action", "belief_0"} <= set(steps.columns)
    keys = tables["keys"][tables["keys"].participant.isin(ours)]
    assert (keys.status == "applied").sum() == 8 * 4 and keys.reaction_ms.notna().all()
    answers = tables["answers"][tables["answers"].participant.isin(ours)]
    assert len(answers) == 2 * (4 * 2 + 2)  # two after each trial, two at the end
    assert answers[answers.question == "comments"].text.isna().all()  # the optional one, skipped
    participants = tables["participants"].set_index("participant")
    assert participants.loc["browser-2", "url_STUDY_ID"] == "st" and participants.loc["browser-2", "status"] == "completed"
    assert (tables["focus"].participant == "api-1").any()
    status, archive = get(study_server, "/api/study/admin/export.zip", TOKEN)
    assert status == 200 and archive[:2] == b"PK"


# ---------------------------------------------------------------- the export's declared schema
SEVERAL_CONDITIONS = """
id = "two_followers"
title = "Two followers"
[factors]
follower = ["copy", "bayes"]
show_belief = [true, false]
[defaults]
mode = "turn"
horizon = 3
[design]
assignment = "within"
order = "fixed"

[[pages]]
kind = "consent"
text = "Agree?"

[[pages]]
kind = "practice"
game = { follower = "copy", horizon = 2, mode = "turn" }

[[pages]]
kind = "trials"

[[pages.after_each]]
id = "helpful"
kind = "likert"
prompt = "How helpful was your AI partner?"
scale = 5
labels = ["not at all", "very"]

[[pages]]
kind = "questionnaire"
id = "final"

[[pages.questions]]
id = "which"
kind = "choice"
prompt = "Which partner did you prefer?"
options = ["the first", "the second"]

[[pages.questions]]
id = "comments"
kind = "text"
prompt = "Anything else?"
required = false

[[pages]]
kind = "debrief"
text = "Thank you."
"""


def test_every_exported_table_has_the_declared_columns_and_types_in_parquet_and_csv(tmp_path):
    import pyarrow.parquet as pq

    from server.study.export import tables as export_tables
    from server.study.export import write_tables
    from server.study.columns import SCHEMA_FILE, check_arrow, check_frame, read_csv, read_parquet
    from server.study.schema import export_schema

    path = tmp_path / "two.toml"
    path.write_text(SEVERAL_CONDITIONS)
    study = load_study(path)
    assert len(study.conditions) == 4
    server = start_server(tmp_path, command=("study", "run", str(path)), env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    try:
        for pid, finish in (("p-1", True), ("p-2", True), ("p-3", False)):
            joined = post(server, "/api/study/join", {"params": {"PROLIFIC_PID": pid, "STUDY_ID": "s"}})[1]
            who = {"pid": pid, "session": joined["session"]}
            view = post(server, "/api/study/advance", {**who, "step": 0, "agree": True})[1]
            if not finish:
                continue
            ref = {"participant": pid, "session": joined["session"]}
            while view["kind"] != "questionnaire":
                if view.get("game"):
                    with connect(server.ws_url, open_timeout=20) as ws:  # one game a socket
                        play_turns(ws, ref, keys=view["game"]["horizon"])
                    body = {}
                else:  # after a trial: the Likert question, an answer per trial
                    body = {"answers": {"helpful": view["trial_index"] + 1}}
                view = post(server, "/api/study/advance", {**who, "step": view["step"], **body})[1]
            view = post(server, "/api/study/advance", {**who, "step": view["step"],
                                                       "answers": {"which": "the second", "comments": None}})[1]
            assert view["kind"] == "debrief"
    finally:
        stop_server(server)

    out = tmp_path / "export"  # the command is run in the test above; here the function it calls
    database = server.replays_dir / "study.sqlite"
    counts = write_tables(study, database, server.replays_dir, out)
    assert counts["trials"] == 10 and counts["participants"] == 3
    # the figures the server stored at each game's end are those its replay file gives (games recorded before)
    stored = export_tables(study, database, server.replays_dir)["trials"]
    with sqlite3.connect(database) as db:
        db.execute("UPDATE games SET steps = NULL")
    pd.testing.assert_frame_equal(export_tables(study, database, server.replays_dir)["trials"], stored)
    assert stored.follower_net_pickups.notna().all() and stored.belief_accuracy.notna().any()
    declared = export_schema(study)
    assert json.loads((out / SCHEMA_FILE).read_text())["tables"]["answers"]["questions"]["after_trial"][0]["scale"] == 5
    tables = {}
    for name, table in declared.items():
        parquet = read_parquet(out, name)  # the follower seat's tables have no rows here: their categories kept
        csv = read_csv(out, name)
        arrow = pq.read_table(out / f"{name}.parquet").schema
        assert check_frame(parquet, table) == [] and check_frame(csv, table) == [] and check_arrow(arrow, table) == []
        # the follower seat's two tables, and exclusions (this study declares no rules)
        assert len(parquet) > 0 or name in ("probes", "statements", "exclusions"), name
        pd.testing.assert_frame_equal(csv, parquet)  # the same values and types from either file
        assert json.loads(arrow.metadata[b"colorgrid"])["columns"][0]["name"] == "participant"
        assert (parquet.arm_label.notna()).all(), name  # every row says whose arm it is
        tables[name] = parquet
    assert pd.api.types.is_integer_dtype(tables["trials"].trial_index)  # not float, empty for practice
    assert tables["trials"].trial_index.isna().sum() == 2 and (tables["trials"].kind == "practice").sum() == 2
    trials = tables["trials"][tables["trials"].kind == "trial"]
    assert set(trials.condition) == {"C1", "C2", "C3", "C4"}
    assert trials.groupby("condition_follower", observed=True).size().to_dict() == {"copy": 4, "bayes": 4}
    answers = tables["answers"]
    likert = answers[answers.question == "helpful"]
    assert likert.likert.dtype == "Int64" and (likert.scale == 5).all() and len(likert) == 8
    # each answer after a trial carries that trial's condition, as the trials table has it
    merged = likert.merge(trials, on=["participant", "trial_index"], suffixes=("", "_trial"))
    assert (merged.condition == merged.condition_trial).all() and len(merged) == 8
    assert answers.groupby("condition_show_belief", observed=True).likert.count().to_dict() == {True: 4, False: 4}
    final = answers[answers.page == "final"].set_index(["participant", "question"])
    assert final.loc[("p-1", "which"), "choice"] == "the second" and pd.isna(final.loc[("p-1", "comments"), "text"])
    people = tables["participants"].set_index("participant")
    assert people.loc["p-3", "status"] == "active" and pd.isna(people.loc["p-3", "completed"])
    assert str(people.started.dtype) == "datetime64[us, UTC]" and people.loc["p-1", "url_STUDY_ID"] == "s"
    steps = tables["steps"]
    assert steps.belief_0.notna().any() and steps[steps.condition_follower == "copy"].belief_0.isna().all()


def test_an_empty_table_has_the_declared_types_in_parquet_and_csv(tmp_path):
    # Parquet keeps a column's categories with its values: a table without rows holds none in its values.
    from server.study.export import write_tables
    from server.study.columns import check_frame, read_csv, read_parquet
    from server.study.schema import export_schema

    study = load_study(EXAMPLE)
    StudyStore(tmp_path / "study.sqlite", study.id, study_hash(study)).close()  # nobody has joined
    assert set(write_tables(study, tmp_path / "study.sqlite", tmp_path, tmp_path / "out").values()) == {0}
    for name, table in export_schema(study).items():
        parquet, csv = read_parquet(tmp_path / "out", name), read_csv(tmp_path / "out", name)
        assert len(parquet) == len(csv) == 0
        assert check_frame(parquet, table) == [] and check_frame(csv, table) == [], name
        pd.testing.assert_frame_equal(csv, parquet)
    assert list(read_parquet(tmp_path / "out", "focus").event.cat.categories) == ["blur", "focus", "visibilitychange"]


def test_a_study_without_questions_exports_its_empty_answers_table(tmp_path):
    """A study that asks nothing has no question ids: its answers' category columns have no categories, and the
    export still writes every table with the declared types in both formats."""
    from server.study.export import write_tables
    from server.study.columns import check_frame, read_csv, read_parquet
    from server.study.schema import export_schema

    data = tomllib.loads(EXAMPLE.read_text())
    data["pages"] = [{k: v for k, v in page.items() if k != "after_each"} for page in data["pages"]
                     if page.get("kind") != "questionnaire"]
    study = parse_study(data)
    answers = export_schema(study)["answers"]
    columns = {c.name: c for c in answers.columns}
    assert columns["question"].categories == () and columns["page"].categories == ()
    StudyStore(tmp_path / "study.sqlite", study.id, study_hash(study)).close()
    assert set(write_tables(study, tmp_path / "study.sqlite", tmp_path, tmp_path / "out").values()) == {0}
    parquet, csv = read_parquet(tmp_path / "out", "answers"), read_csv(tmp_path / "out", "answers")
    assert check_frame(parquet, answers) == [] and check_frame(csv, answers) == []
    assert list(parquet["question"].cat.categories) == [] and str(csv["question"].dtype) == "category"


def test_the_data_dictionary_in_the_docs_is_the_declared_schema():
    from server.study.schema import data_dictionary

    assert data_dictionary(load_study(EXAMPLE)) in (ROOT / "docs" / "STUDIES.md").read_text()


def test_a_value_outside_its_declared_type_stops_the_export_with_its_place():
    from server.study.columns import conform
    from server.study.schema import export_schema

    focus = export_schema(load_study(EXAMPLE))["focus"]
    with pytest.raises(ValueError, match=r"focus.event: \['scroll'\] not among its categories"):
        conform([{"participant": "p", "arm": 0, "kind": "trial", "attempt": 0, "event": "scroll"}], focus)
    with pytest.raises(ValueError, match=r"focus.arm: a missing value"):
        conform([{"participant": "p", "kind": "trial", "attempt": 0, "event": "blur"}], focus)
    with pytest.raises(ValueError, match=r"columns \['colour'\] are not declared"):
        conform([{"colour": 1}], focus)


def test_keys_recorded_before_are_numbered_on_and_a_repeated_key_stops_the_export():
    from server.study.export import numbered_on
    from server.study.columns import conform
    from server.study.schema import export_schema

    assert numbered_on([4, 5, 7]) == [4, 5, 7]  # as the server numbers them now (welcome.next_seq): unchanged
    assert numbered_on([0, 1, 2, 0, 1, 5, 3]) == [0, 1, 2, 3, 4, 8, 9]  # a page that started again at 0, twice
    keys = export_schema(load_study(EXAMPLE))["keys"]
    row = {"participant": "p", "arm": 0, "kind": "trial", "attempt": 0, "game_id": "g1", "seq": 3}
    with pytest.raises(ValueError, match=r"^keys: 2 rows share their \(game_id, seq\), which names one row; the "
                                         r"first: game_id=g1, seq=3$"):
        conform([row, dict(row)], keys)
    assert len(conform([row, dict(row, seq=4)], keys)) == 2
