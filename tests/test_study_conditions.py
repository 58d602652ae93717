"""A condition a game did not have is empty in the export, not a default: no AI follower (nor its belief shown) in the
follower seat, no AI leader, goal view or probes in a leader's seat, no clock turn-based. A study of both seats in
both modes, played through a real study server, exported by the command."""

import dataclasses
import json
import subprocess
import sys

import pandas as pd
from websockets.sync.client import connect

from server.study.config import GameSettings, load_study
from tests.conftest import start_server, stop_server
from tests.test_study import TOKEN, post

BOTH_SEATS = """
id = "both_seats"
title = "Both seats"
[factors]
seat = ["leader", "follower"]
mode = ["turn", "realtime"]
[defaults]
horizon = 3
tick_hz = 10.0
follower = "copy"
leader = "astar"
probes = "steps:1"
[design]
assignment = "within"
order = "fixed"

[[pages]]
kind = "consent"
text = "Agree?"

[[pages]]
kind = "practice"
game = { seat = "follower", goal = "shown", mode = "turn", horizon = 2 }

[[pages]]
kind = "trials"
"""


def play(ws, study_ref: dict) -> dict:
    """One study game: a move at each state, each probe answered first (a turn-based game waits for it)."""
    ws.send(json.dumps({"type": "new_game", "study": study_ref}))
    seq = 0
    while True:
        msg = json.loads(ws.recv(timeout=30))
        if msg["type"] == "state" and msg["step"] < msg["horizon"]:
            if msg.get("probe"):
                ws.send(json.dumps({"type": "probe_answer", "probe": msg["probe"]["id"], "color": 0,
                                    "confidence": 0.5}))
            ws.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq}))
            seq += 1
        elif msg["type"] in ("game_over", "error", "full"):
            return msg


def test_the_settings_a_game_did_not_have_are_none():
    follower_turn = GameSettings(seat="follower", mode="turn", probes="steps:2").played()
    assert follower_turn["follower"] is None and follower_turn["show_belief"] is None
    assert follower_turn["tick_hz"] is None and follower_turn["probes"] == "steps:2"
    leader_realtime = GameSettings(seat="leader", mode="realtime", tick_hz=8.0).played()
    assert leader_realtime["leader"] is None and leader_realtime["goal"] is None and leader_realtime["probes"] is None
    assert leader_realtime["tick_hz"] == 8.0 and leader_realtime["follower"] == "bayes-people"
    assert set(follower_turn) == {f.name for f in dataclasses.fields(GameSettings)}


def test_the_export_leaves_the_conditions_a_game_did_not_have_empty(tmp_path):
    path = tmp_path / "both_seats.toml"
    path.write_text(BOTH_SEATS)
    study = load_study(path)
    assert [(c.seat, c.mode) for c in study.conditions] == [("leader", "turn"), ("leader", "realtime"),
                                                            ("follower", "turn"), ("follower", "realtime")]
    server = start_server(tmp_path, command=("study", "run", str(path)), env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    try:
        joined = post(server, "/api/study/join", {"params": {"PROLIFIC_PID": "seats-1", "STUDY_ID": "s"}})[1]
        who = {"pid": "seats-1", "session": joined["session"]}
        ref = {"participant": "seats-1", "session": joined["session"]}
        view = post(server, "/api/study/advance", {**who, "step": 0, "agree": True})[1]
        while view.get("game") and not view.get("finished"):
            with connect(server.ws_url, open_timeout=20) as ws:  # one game a socket
                over = play(ws, ref)
                assert over.get("reason") == "complete", over
            status, view = post(server, "/api/study/advance", {**who, "step": view["step"]})
            assert status == 200, view
    finally:
        stop_server(server)
    out = tmp_path / "export"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "study", "export", str(path), "--replays-dir",
                           str(server.replays_dir), "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    for name in ("trials", "steps"):
        table = pd.read_parquet(out / f"{name}.parquet")
        games = table.drop_duplicates(["kind", "trial_index"]) if name == "steps" else table
        assert len(games) == 5, name
        for _, game in games.iterrows():
            follower_seat, turn = game.condition_seat == "follower", game.condition_mode == "turn"
            assert pd.isna(game.condition_follower) == follower_seat, (name, game.condition)
            assert pd.isna(game.condition_show_belief) == follower_seat, (name, game.condition)
            for field in ("condition_leader", "condition_goal", "condition_probes"):
                assert pd.isna(game[field]) != follower_seat, (name, field, game.condition)
            assert pd.isna(game.condition_tick_hz) == turn, (name, game.condition)
        realtime = games[games.condition_mode == "realtime"]
        assert (realtime.condition_tick_hz == 10.0).all() and (games[~games.condition_seat.eq(
            "follower")].condition_follower == "copy").all()
        practice = games[games.kind == "practice"]
        assert len(practice) == 1 and practice.condition_goal.tolist() == ["shown"]
        assert practice.condition_follower.isna().all() and practice.condition_tick_hz.isna().all()
