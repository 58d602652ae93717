"""A study on two backends behind HAProxy, sharing the study's SQLite file: two participants in chromium complete
it through the proxy (one reloading mid-trial); a backend killed with SIGKILL in the middle of a game loses
nothing that was finished (its participant resumes on the other backend and plays the interrupted game again as
a new attempt) and is started again by the launcher; Ctrl+C stops every process."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import time

import pytest

from server.cluster.haproxy import BACKEND_HEADER, ROUTE_COOKIE
from tests.test_cluster import alive, children, receive, socket_to, start_cluster, stop_cluster
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


def play_keys(ws, keys: int) -> dict:
    """``keys`` moves of a turn-based game, each answered by its state; the last state."""
    for seq in range(keys):
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
        with pytest.raises(Exception):
            receive(ws, "state", timeout=5)  # the socket is gone with its process
        ws.close()

        # The page reconnects (socket.js: a second later): the proxy sends it to the other backend, which has
        # no such game; the page asks for its page again and is offered the game again.
        time.sleep(1)
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


def test_ctrl_c_stops_the_backends_their_workers_and_haproxy(study_cluster):
    launcher = study_cluster.process.pid
    started = children(launcher)
    everything = started + [p for child in started for p in children(child)]
    assert len(started) == 3  # two backends and haproxy
    assert stop_cluster(study_cluster) == 0
    deadline = time.monotonic() + 10
    while any(alive(p) for p in everything) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [p for p in everything if alive(p)]
    assert "stopping: the backends save their games" in study_cluster.log()
