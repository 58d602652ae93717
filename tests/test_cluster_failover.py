"""A study on two backends behind HAProxy, sharing the study's SQLite file: two participants in chromium complete
it through the proxy (one reloading mid-trial); a backend killed with SIGKILL in the middle of a game loses
nothing that was finished (its participant resumes on the other backend and plays the interrupted game again as
a new attempt) and is started again by the launcher; the study page in chromium goes on after a backend is killed
while its game is being made and another in the middle of its game (one connection at a time, waits that grow);
Ctrl+C stops every process."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import time

import pytest
from playwright.sync_api import expect
from websockets.exceptions import ConnectionClosed

from server.cluster.haproxy import BACKEND_COOKIE, BACKEND_HEADER, ROUTE_COOKIE
from tests.helpers import wait_until as wait_for
from tests.test_cluster import alive, children, receive, socket_to, start_cluster, stop_cluster
from tests.test_page_connections import PlaySockets, wait_until
from tests.test_study import TOKEN, complete_fast_study, fast_study


@pytest.fixture(scope="module")
def study_cluster(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("study-cluster")
    cluster = start_cluster(tmp, "--rejoin-grace-s", "30", command=("study", "run", str(fast_study(tmp))),
                            processes=2, env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    yield cluster
    stop_cluster(cluster)


def games_of(cluster, pid: str) -> list[dict]:
    with sqlite3.connect(cluster.folder / "study.sqlite") as db:
        db.row_factory = sqlite3.Row
        return [dict(r) for r in db.execute("SELECT * FROM games WHERE pid = ? ORDER BY step, attempt", (pid,))]


def test_two_participants_in_chromium_complete_the_study_through_the_proxy(study_cluster, browser):
    complete_fast_study(browser, study_cluster.url, "proxied-1")
    complete_fast_study(browser, study_cluster.url, "proxied-2", reload_in_trial=1)
    assert study_cluster.request("/api/study/admin/summary").status_code == 401
    summary = study_cluster.request("/api/study/admin/summary", token=TOKEN).json()  # any backend takes the token
    completed = {p["pid"] for p in summary["recent"] if p["status"] == "completed"}
    assert completed == {"proxied-1", "proxied-2"}
    assert [b["name"] for b in summary["backends"]] == ["b1", "b2"] and all(b["up"] for b in summary["backends"])
    for pid in ("proxied-1", "proxied-2"):
        games = games_of(study_cluster, pid)
        assert len(games) == 5 and {g["ended"] for g in games} == {"complete"}, games  # practice and 4 trials
        for game in games:
            assert (study_cluster.folder / f"{game['replay_id']}.replay.json").is_file()


def play_keys(ws, keys: int, first: int = 0) -> dict:
    """``keys`` moves of a turn-based game from step ``first`` (the welcome's ``next_seq``), each answered by its
    state; the last state."""
    for seq in range(first, first + keys):
        ws.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq, "t_client": 1.0 + seq}))
        state = receive(ws, "state")
        while state["step"] == seq:  # the state before this key (the game's first, sent with its welcome)
            state = receive(ws, "state")
        assert state["step"] == seq + 1
    return state


def test_a_backend_killed_mid_game_loses_nothing_finished_and_is_started_again(study_cluster):
    pid, cookies = "killed-1", {ROUTE_COOKIE: "killed-1"}
    page = study_cluster.request(f"/study?PROLIFIC_PID={pid}")
    assert page.cookies[ROUTE_COOKIE] == pid
    home = page.headers[BACKEND_HEADER]
    joined = study_cluster.request("/api/study/join", {"params": {"PROLIFIC_PID": pid}}, cookies).json()
    who = {"pid": pid, "session": joined["session"]}
    ref = {"participant": pid, "session": joined["session"]}
    for step in range(2):  # consent, instructions
        study_cluster.request("/api/study/advance", {**who, "step": step, "agree": True}, cookies).raise_for_status()
    with socket_to(study_cluster, cookies) as ws:  # the practice game (real time, 4 steps), finished
        assert ws.response.headers[BACKEND_HEADER] == home
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        assert receive(ws, "game_over")["reason"] == "complete"
    trial = study_cluster.request("/api/study/advance", {**who, "step": 2}, cookies).json()
    assert trial["kind"] == "trial" and trial["game"]["mode"] == "turn"

    before = {b["name"]: b for b in study_cluster.health()["backends"]}
    ws = socket_to(study_cluster, cookies)
    ws.send(json.dumps({"type": "new_game", "study": ref}))
    welcome = receive(ws, "welcome")
    play_keys(ws, 2)
    # The launcher is held (SIGSTOP) until the page has reconnected: started again within its 1 s wait, the
    # killed backend could take the reconnect itself, and this test is about the other backend taking it.
    os.kill(study_cluster.process.pid, signal.SIGSTOP)
    try:
        os.kill(before[home]["pid"], signal.SIGKILL)  # mid-game: two of its four steps played
        with pytest.raises(ConnectionClosed):
            receive(ws, "state", timeout=60)  # the socket is gone with its process
        ws.close()

        # The page reconnects once the process is gone: the proxy sends it to the other backend (a refused
        # connection is tried on another), which has no such game; the page asks for its page again and is offered
        # the game again.
        wait_for(lambda: not alive(before[home]["pid"]), "the killed backend's process to be gone")
        again = socket_to(study_cluster, cookies)
    finally:
        os.kill(study_cluster.process.pid, signal.SIGCONT)
    with again:
        away = again.response.headers[BACKEND_HEADER]
        assert away != home
        again.send(json.dumps({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]}))
        assert receive(again, "error")["code"] == "rejected"
        view = study_cluster.request("/api/study/view", who, cookies).json()
        assert view["kind"] == "trial" and view.get("interrupted") and "live" not in view and "done" not in view
        again.send(json.dumps({"type": "new_game", "study": ref}))
        assert receive(again, "welcome")["game_id"] != welcome["game_id"]
        play_keys(again, 4)
        assert receive(again, "game_over")["reason"] == "complete"
    after = study_cluster.request("/api/study/advance", {**who, "step": 3}, cookies).json()
    assert after["kind"] == "questions"

    games = games_of(study_cluster, pid)
    practice, lost, replayed = games
    assert practice["kind"] == "practice" and practice["ended"] == "complete"  # finished before: intact
    assert (study_cluster.folder / f"{practice['replay_id']}.replay.json").is_file()
    assert (lost["step"], lost["attempt"], lost["ended"], lost["replay_id"]) == (3, 0, "server_lost", None)
    assert (replayed["step"], replayed["attempt"], replayed["ended"]) == (3, 1, "complete")
    assert (study_cluster.folder / f"{replayed['replay_id']}.replay.json").is_file()

    # The launcher started the killed backend again; the proxy sends its participants back to it.
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        now = {b["name"]: b for b in study_cluster.health()["backends"]}
        if now[home]["up"] and now[home].get("ready") and now[home]["pid"] != before[home]["pid"]:
            break
        time.sleep(0.5)
    else:
        raise AssertionError(f"{home} was not started again: {study_cluster.log()}")
    assert f"{home} stopped (killed by signal 9)" in study_cluster.log()
    deadline = time.monotonic() + 30
    while study_cluster.request(f"/study?PROLIFIC_PID={pid}").headers[BACKEND_HEADER] != home:
        assert time.monotonic() < deadline, "the proxy did not send the participant back"
        time.sleep(0.5)
    assert study_cluster.request("/api/study/view", who, cookies).json()["kind"] == "questions"


def backends_up(cluster, timeout_s: float = 120) -> dict:
    """Every backend up and ready behind the proxy (the launcher starts a killed one again): name -> its health.
    Ready by its own health is not yet up for HAProxy, which wants two good checks a second apart: a backend
    counts once a request carrying its cookie reaches it."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            now = {b["name"]: b for b in cluster.health()["backends"]}
            if all(b["up"] and b.get("ready") for b in now.values()) and all(
                    cluster.request("/api/health", cookies={BACKEND_COOKIE: name}).headers[BACKEND_HEADER] == name
                    for name in now):
                return now
        except (ValueError, KeyError):  # the proxy's answer while no backend is up
            pass
        assert time.monotonic() < deadline, f"the backends are not all up: {cluster.log()}"
        time.sleep(0.5)


def page_backend(page) -> str:
    """The backend the page's own requests reach now (its cookies), as the proxy names it."""
    return page.evaluate(f"async () => (await fetch('/api/health')).headers.get('{BACKEND_HEADER}')")


def reconnect_waits(console: list[str]) -> list[int]:
    """What web/socket.js logged of each wait before it connected again (ms), in order."""
    return [int(ms) for line in console for ms in re.findall(r"connecting again in (\d+) ms", line)]


def test_the_study_page_goes_on_after_backends_are_killed_mid_join_and_mid_game(study_cluster, browser):
    pid = "page-killed-1"
    before = backends_up(study_cluster)
    home = study_cluster.request(f"/study?PROLIFIC_PID={pid}").headers[BACKEND_HEADER]
    other = next(name for name in before if name != home)
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    # The page is held to its backend by the cookie the backends set for a game elsewhere (HAProxy's persistence):
    # the consistent-hash ring alone would move it if the proxy's health checks blinked under load.
    context.add_cookies([{"name": BACKEND_COOKIE, "value": home, "url": study_cluster.url}])
    page = context.new_page()
    console = []
    page.on("console", lambda message: console.append(message.text))
    sockets = PlaySockets(page)
    page.goto(f"{study_cluster.url}/study?PROLIFIC_PID={pid}")
    for title in ("Consent", "How to play"):
        expect(page.locator("#page-title")).to_have_text(title)
        page.click("#next")
    page.click("#play")  # the practice (real time, 4 steps), on the participant's own backend
    expect(page.locator("#next")).to_be_visible()
    page.click("#next")
    expect(page.locator("#page-title")).to_have_text("Game 1 of 4")

    # Mid-join: the study's database is held (another writer has it), so the backend cannot record the new game and
    # answer; it is killed once the page has sent its new_game. The launcher is held (SIGSTOP), so the other backend
    # takes the participant.
    database = sqlite3.connect(study_cluster.folder / "study.sqlite", isolation_level=None, timeout=30)
    database.execute("BEGIN IMMEDIATE")
    os.kill(study_cluster.process.pid, signal.SIGSTOP)
    try:
        assert page_backend(page) == home, study_cluster.log()
        asked = sockets.sent_types.count("new_game")  # (the practice's: waiting for any would not wait for this one)
        page.click("#play")
        wait_until(page, lambda: sockets.sent_types.count("new_game") > asked, "the page's new_game for game 1")
        os.kill(before[home]["pid"], signal.SIGKILL)
        database.execute("ROLLBACK")
        database.close()
        # Not asked again (the game may have been made): the page asks for its page, which offers the game again.
        try:
            expect(page.locator("#status")).to_contain_text("lost while your game was starting")
        except AssertionError as error:
            raise AssertionError(f"{error}\nsent: {sockets.sent_types}\n{study_cluster.log()}") from None
        expect(page.locator("#play")).to_be_visible()
        assert sockets.sent_types.count("new_game") == 2 and len(sockets.sockets) == 2  # the practice's, this one

        # Mid-game: the game is on the other backend, two steps in; it is killed too. With both down the page tries
        # one connection at a time, each after a longer wait.
        page.click("#play")
        wait_until(page, lambda: len(sockets.games) == 2 and sockets.state is not None, "the game on the other backend")
        page.locator("#board").focus()
        for step in range(2):
            page.keyboard.press("ArrowUp" if step else "ArrowLeft")
            expect(page.locator("#board")).to_have_attribute("data-step", str(step + 1))
        os.kill(before[other]["pid"], signal.SIGKILL)
        expect(page.locator("#status")).to_contain_text("connection lost: reconnecting")
        wait_until(page, lambda: len(reconnect_waits(console)) >= 3, "three tries to connect again", timeout_s=60)
        first, second, third = reconnect_waits(console)[:3]
        assert first < second < third, reconnect_waits(console)  # about 1 s, 2 s, 4 s
    finally:
        os.kill(study_cluster.process.pid, signal.SIGCONT)

    # The launcher starts both again; the page's next try rejoins, the game is gone with its process: the page offers
    # it again (interrupted), and it is played to its end.
    expect(page.locator("#status")).to_contain_text("interrupted", timeout=120_000)
    page.click("#play")
    wait_until(page, lambda: len(sockets.games) == 3 and sockets.state is not None, "the game played again")
    page.locator("#board").focus()
    for step in range(4):
        expect(page.locator("#board")).to_have_attribute("data-step", str(step))
        page.keyboard.press("ArrowLeft" if step % 2 else "ArrowUp")
    expect(page.locator("#next")).to_be_visible()
    assert sockets.overlapping == 0, "never two connections at once"
    context.close()
    trial = [g for g in games_of(study_cluster, pid) if g["kind"] == "trial"]
    assert [(g["attempt"], g["ended"]) for g in trial] == [(0, "server_lost"), (1, "complete")]
    backends_up(study_cluster)  # as the next test expects them


def test_a_page_that_reaches_another_backend_than_its_game_rejoins_the_game_there(study_cluster):
    # As when a backend started again takes its participants back while one of them still plays on the other: the
    # game runs on one backend (sent there by the backend cookie here, by the proxy while the other was down), the
    # reloaded page's requests reach the other, the key's own. That one asks its sibling before calling the game lost.
    backends_up(study_cluster)
    pid, route = "elsewhere-1", {ROUTE_COOKIE: "elsewhere-1"}
    home = study_cluster.request(f"/study?PROLIFIC_PID={pid}").headers[BACKEND_HEADER]
    away = "b1" if home == "b2" else "b2"
    joined = study_cluster.request("/api/study/join", {"params": {"PROLIFIC_PID": pid}}, route).json()
    who = {"pid": pid, "session": joined["session"]}
    ref = {"participant": pid, "session": joined["session"]}
    for step in range(2):  # consent, instructions
        study_cluster.request("/api/study/advance", {**who, "step": step, "agree": True}, route).raise_for_status()
    with socket_to(study_cluster, route) as ws:  # the practice game
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        assert receive(ws, "game_over")["reason"] == "complete"
    study_cluster.request("/api/study/advance", {**who, "step": 2}, route).raise_for_status()

    with socket_to(study_cluster, {**route, BACKEND_COOKIE: away}) as ws:  # the trial, on the other backend
        assert ws.response.headers[BACKEND_HEADER] == away
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        welcome = receive(ws, "welcome")
        play_keys(ws, 2)
    # The page reloads (its socket is gone; the game waits for it to rejoin) and its requests reach the key's backend.
    view = study_cluster.request("/api/study/view", who, route)
    assert view.headers[BACKEND_HEADER] == home
    assert view.json().get("live") == {"game_id": welcome["game_id"], "token": welcome["token"]}, view.json()
    assert view.cookies[BACKEND_COOKIE] == away  # the page's socket goes where the game runs
    with socket_to(study_cluster, route) as ws:  # a new attempt, asked of the key's backend, is refused
        assert ws.response.headers[BACKEND_HEADER] == home
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        assert "still running" in receive(ws, "error")["message"]
    with socket_to(study_cluster, {**route, BACKEND_COOKIE: view.cookies[BACKEND_COOKIE]}) as ws:
        assert ws.response.headers[BACKEND_HEADER] == away
        ws.send(json.dumps({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]}))
        play_keys(ws, 2, first=receive(ws, "welcome")["next_seq"])
        assert receive(ws, "game_over")["reason"] == "complete"
    trial = [(g["attempt"], g["ended"]) for g in games_of(study_cluster, pid) if g["kind"] == "trial"]
    assert trial == [(0, "complete")]  # played once, never called lost


def test_ctrl_c_stops_the_backends_their_workers_and_haproxy(study_cluster):
    backends_up(study_cluster)  # the launcher has started again whatever a test before killed
    launcher = study_cluster.process.pid
    started = children(launcher)
    everything = started + [p for child in started for p in children(child)]
    assert len(started) == 3  # two backends and haproxy
    assert stop_cluster(study_cluster) == 0
    wait_for(lambda: not any(alive(p) for p in everything), "every process the launcher started to end")
    assert "stopping: the backends save their games" in study_cluster.log()
