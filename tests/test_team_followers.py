"""Trained followers in teams: a network plays the team it was trained in, and a 1:2 game may give each of its
two AI followers its own kind (a real server on loopback)."""

from __future__ import annotations

import json

import pytest
from websockets.sync.client import connect

from tests.conftest import ROOT, start_server, stop_server
from tests.test_server import MOVES

TEAM_FOLLOWER = ROOT / "checkpoints" / "follower_2L1F.pt"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("teams"), "--followers", "copy", "--followers", "ippo",
                       "--followers", "ippo-2L1F", "--followers", "ippo-1L2F", "--followers", "bayes-people")
    yield srv
    stop_server(srv)


def test_each_team_offers_the_trained_followers_of_that_team(server):
    teams = {t["value"]: t["followers"] for t in server.get("/api/options")[0]["teams"]}
    assert "ippo" in teams["1:1"] and "ippo-2L1F" not in teams["1:1"]
    assert "ippo-2L1F" in teams["2:1"] and "ippo" not in teams["2:1"]
    assert "ippo" not in teams["1:2"] and {"copy", "bayes-people", "ippo-1L2F"} <= set(teams["1:2"])


def test_a_1_2_game_gives_each_ai_follower_its_own_kind_and_records_it(server):
    with connect(server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "team": "1:2", "mode": "turn", "horizon": 6,
                            "followers": ["ippo-1L2F", "bayes-people"]}))
        welcome = json.loads(ws.recv(timeout=60))
        assert welcome["type"] == "welcome", welcome
        assert welcome["followers"] == {"follower_0": "ippo-1L2F", "follower_1": "bayes-people"}
        assert welcome["follower"] == "ippo-1L2F + bayes-people"
        for seq in range(6):
            ws.send(json.dumps({"type": "key", "key": MOVES[seq % 4], "seq": seq, "t_client": 1.0}))
        while (msg := json.loads(ws.recv(timeout=60)))["type"] != "game_over":
            pass
    replay = json.loads((server.replays_dir / f"{msg['replay_id']}.replay.json").read_text())
    assert replay["agents"]["follower_0"]["policy"] == "ippo-1L2F"
    assert replay["agents"]["follower_1"]["policy"] == "bayes-people"


def test_a_2_1_room_plays_with_the_trained_2_1_follower(server):
    from tests.test_rooms import HORIZON, open_room, play_step

    first, second, welcomes, _ = open_room(server, follower="ippo-2L1F")
    assert all(w["follower"] == "ippo-2L1F" for w in welcomes)
    for step in range(HORIZON):
        play_step([first, second], step)
    over = first.recv("game_over")
    first.close(), second.close()
    replay = json.loads((server.replays_dir / f"{over['replay_id']}.replay.json").read_text())
    assert replay["agents"]["follower_0"]["policy"] == "ippo-2L1F"


@pytest.mark.parametrize("request_fields, message", [
    ({"team": "1:2", "follower": "ippo"}, "follower 'ippo' does not play in team 1:2"),
    ({"team": "1:1", "follower": "ippo-2L1F"}, "follower 'ippo-2L1F' does not play in team 1:1"),
    ({"team": "1:2", "followers": ["copy"]}, "team 1:2 has 2 AI follower(s); give one name each, got 1"),
    ({"team": "1:2", "follower": "copy", "followers": ["copy", "copy"]}, "give either follower"),
])
def test_a_follower_that_does_not_play_the_team_is_refused_in_one_line(server, request_fields, message):
    with connect(server.ws_url, open_timeout=20) as ws:
        ws.send(json.dumps({"type": "new_game", "mode": "turn", **request_fields}))
        reply = json.loads(ws.recv(timeout=30))
        assert reply["type"] == "error" and message in reply["message"], reply
