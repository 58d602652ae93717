"""A person in the follower seat, through a real server: the goal hidden, stated beliefs, probes, bad input."""

import subprocess
import sys

import pytest

from colorgrid.replay import load, verify
from server.stated import ProbePlan
from tests.conftest import start_server, stop_server
from tests.test_server import Client

LEADERS = ("astar", "person:slip=0.1,notice_delay=3", "population:people#held_out", "ippo-leader")


@pytest.fixture(scope="module")
def seat_server(tmp_path_factory):
    flags = [flag for kind in LEADERS for flag in ("--leaders", kind)]
    srv = start_server(tmp_path_factory.mktemp("seat"), "--max-sessions", "6", "--tick-hz", "10", *flags)
    yield srv
    stop_server(srv)


def follower_game(server, **fields) -> tuple[Client, dict, dict]:
    client = Client(server)
    welcome, state = client.new_game(seat="follower", **fields)
    assert welcome["type"] == "welcome", welcome
    return client, welcome, state


def test_options_offer_the_follower_seat_and_its_leaders_per_team(seat_server):
    options = seat_server.get("/api/options")[0]
    teams = {t["value"]: t for t in options["teams"]}
    assert teams["1:1"]["seats"] == ["leader", "follower"] and teams["2:1"]["seats"] == ["leader"]
    assert teams["1:1"]["follower_seat_leaders"] == list(LEADERS)
    assert "ippo-leader" not in teams["1:2"]["follower_seat_leaders"]  # trained beside one follower: 1:1 only
    assert [s["value"] for s in options["seats"]] == ["leader", "follower"]
    assert [g["value"] for g in options["goal_views"]] == ["hidden", "shown"]
    assert [k["value"] for k in options["probe_kinds"]] == ["none", "steps", "random"]
    labels = {info["value"]: info["label"] for info in options["leader_info"]}
    assert labels["person:slip=0.1,notice_delay=3"].startswith("Person-like scripted leader")
    assert labels["population:people#held_out"].startswith("A person-like leader from a population")


def test_turn_based_follower_seat_hides_the_goal_records_beliefs_and_waits_for_a_probe(seat_server):
    client, welcome, state = follower_game(seat_server, mode="turn", horizon=8, probes="steps:2,5",
                                           leader="person:slip=0.1,notice_delay=3")
    assert welcome["agent"] == "follower" and welcome["seat"] == "follower" and welcome["goal_view"] == "hidden"
    assert welcome["belief_keys"] == {"1": 0, "2": 1, "3": 2} and welcome["follower"] == "none"
    assert welcome["leaders"] == {"leader": "person:slip=0.1,notice_delay=3"}
    assert state["goal"] is None and state["stated"] is None and state["probe"] is None
    client.key("2")  # a belief, not a move: the world does not step
    client.send({"type": "belief", "color": 0, "t_client": 1.0})  # a click on red
    client.key("ArrowUp")
    assert client.recv("state")["step"] == 1
    client.key("ArrowUp")
    second = client.recv("state")
    assert second["step"] == 2 and second["stated"] == 0 and second["probe"] == {"id": 0, "step": 2}
    client.key("ArrowLeft")  # held: the game waits for the probe's answer
    client.send({"type": "ping"})  # answered after the key (one socket, in order): a step's state would come first
    before_pong = []
    while (msg := client.recv())["type"] != "pong":
        before_pong.append(msg["type"])
    assert "state" not in before_pong, before_pong
    client.send({"type": "probe_answer", "probe": 0, "color": 2, "confidence": 0.75, "t_client": 2.0})
    third = client.recv("state")  # the held move steps once the probe is answered
    assert third["step"] == 3 and third["stated"] == 2 and third["probe"] is None
    for _ in range(5):
        client.key("ArrowDown")
        state = client.recv("state")
        assert state["goal"] is None and not any("switch" in e for e in state["events"])
        if state["probe"]:
            client.send({"type": "probe_answer", "probe": state["probe"]["id"], "color": 1, "confidence": 1.0})
    over = client.recv("game_over")
    assert over["reason"] == "complete"
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok
    assert replay.agents["follower"] == {"policy": "human"} and replay.agents["leader"]["policy"] == "person"
    assert replay.stated_beliefs == {"follower": [0, 0, 2, 2, 2, 1, 1, 1]}
    assert [(e["color"], e["via"]) for e in replay.belief_events] == [(1, "key"), (0, "click"), (2, "probe"),
                                                                      (1, "probe")]
    assert [(p["step"], p["status"], p["color"], p["confidence"]) for p in replay.probes] == [
        (2, "answered", 2, 0.75), (5, "answered", 1, 1.0)]
    assert all(p["response_ms"] >= 0 and p["answered_step"] == p["step"] for p in replay.probes)
    statuses = [e["status"] for e in replay.key_events]
    assert statuses[0] == "stated" and replay.key_events[0]["color"] == 1 and statuses.count("applied") == 8
    assert replay.meta["seat"] == "follower" and replay.meta["probes"] == "steps:2,5"
    client.close()


def test_a_realtime_probe_does_not_stop_the_clock(seat_server):
    client, welcome, _ = follower_game(seat_server, mode="realtime", horizon=600, probes="steps:3", goal="shown")
    assert welcome["goal_view"] == "shown"
    state = client.recv("state")
    assert state["goal"] is not None  # a control: the goal is shown
    while not state["probe"]:
        state = client.recv("state")
    asked = state["step"]
    state = client.recv("state")  # the clock goes on while the question is open
    assert state["step"] > asked and state["probe"] == {"id": 0, "step": 3}
    client.key("3")
    client.send({"type": "probe_answer", "probe": 0, "color": 1, "confidence": 0.5, "t_client": 3.0})
    while not (state["stated"] == 1 and state["probe"] is None):  # a step made since the answer
        state = client.recv("state")
    client.send({"type": "quit"})  # a minute long at 10 steps/s: answered long before its end
    over = client.recv("game_over")
    assert over["reason"] == "quit"
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok
    probe = replay.probes[0]
    assert probe["status"] == "answered" and probe["answered_step"] > probe["step"] == 3
    assert replay.stated_beliefs["follower"][-1] == 1 and replay.meta["goal_view"] == "shown"
    client.close()


def test_in_a_one_to_two_team_a_person_and_an_ai_follower_assist_an_ai_leader(seat_server):
    client, welcome, state = follower_game(seat_server, team="1:2", mode="turn", horizon=4, follower="bayes",
                                           leader="population:people#held_out")
    assert welcome["agent"] == "follower_0" and welcome["leaders"] == {"leader_0": "population:people#held_out"}
    assert set(state["beliefs"]) == {"follower_1"}
    client.key("1")
    for _ in range(4):
        client.key("ArrowUp")
    over = client.recv("game_over")
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok
    assert replay.agents["follower_0"] == {"policy": "human"} and replay.agents["follower_1"]["policy"] == "bayes"
    assert set(replay.goal_probs) == {"follower_1"} and replay.stated_beliefs == {"follower_0": [0, 0, 0, 0]}
    assert replay.belief_events[0]["agent"] == "follower_0"
    done = subprocess.run([sys.executable, "-m", "colorgrid_apps", "replay", "verify",
                           str(seat_server.replays_dir / f"{over['replay_id']}.replay.json")],
                          capture_output=True, text=True)
    assert done.returncode == 0 and ": ok" in done.stdout and "F1 follower_0 (follower, human)" in done.stdout
    client.close()


@pytest.mark.parametrize("fields, code, words", [
    ({"team": "2:1"}, "rejected", "team 2:1 has no follower seat for a person"),
    ({"team": "1:2", "leader": "ippo-leader"}, "rejected", "AI leader 'ippo-leader' cannot lead team 1:2"),
    ({"leader": "bayes"}, "rejected", "AI leader 'bayes' is not offered"),
    ({"probes": "steps:0"}, "rejected", "probes 'steps:0' is not a probe plan"),
    ({"seat": "leader", "probes": "steps:3"}, "rejected", "goal and probes are for the follower seat"),
    ({"seat": "judge"}, "invalid_message", "new_game: seat: Input should be 'leader' or 'follower'"),
])
def test_a_follower_seat_that_cannot_be_had_gets_one_clear_message(seat_server, fields, code, words):
    client = Client(seat_server)
    reply, _ = client.new_game(**{"seat": "follower", "mode": "turn", **fields})
    assert reply["type"] == "error" and reply["code"] == code and words in reply["message"], reply
    client.close()


def test_bad_beliefs_keys_and_probe_answers_each_get_their_error_and_nothing_is_lost(seat_server):
    client, _, _ = follower_game(seat_server, mode="turn", horizon=4, probes="steps:1")
    client.key("7")  # not a move, not one of this game's colors
    error = client.recv("error")
    assert error["code"] == "bad_key" and "say which color you believe is the goal with 1/2/3" in error["message"]
    client.send({"type": "belief", "color": 3})
    error = client.recv("error")
    assert error["code"] == "bad_belief" and "color 3 is out of range: a color of this game is 0..2" in error["message"]
    client.key("ArrowUp")
    assert client.recv("state")["probe"] == {"id": 0, "step": 1}
    for answer, words in [({"probe": 0, "color": 5, "confidence": 0.9}, "color 5 is out of range"),
                          ({"probe": 0, "color": 1, "confidence": 1.5}, "confidence 1.5 is out of range"),
                          ({"probe": 0, "color": 1, "confidence": 0.2}, "from 0.33 (a guess among 3 colors) to 1"),
                          ({"probe": 4, "color": 1, "confidence": 0.9}, "probe 4 is not open (the open probe is 0)")]:
        client.send({"type": "probe_answer", **answer})
        error = client.recv("error")
        assert error["code"] == "bad_probe" and words in error["message"], error
    client.send({"type": "probe_answer", "probe": 0, "color": 1, "confidence": "sure"})
    assert client.recv("error")["code"] == "invalid_message"
    client.send({"type": "probe_answer", "probe": 0, "color": 1, "confidence": 0.9})  # still open: the answer counts
    client.send({"type": "probe_answer", "probe": 0, "color": 2, "confidence": 0.9})
    error = client.recv("error")
    assert error["code"] == "bad_probe" and "no probe is open" in error["message"]
    for _ in range(3):
        client.key("ArrowDown")
    over = client.recv("game_over")
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok and replay.num_steps == 4
    assert [e["status"] for e in replay.key_events] == ["ignored", "applied", "applied", "applied", "applied"]
    # three answers out of range refused (a wrong probe id is no answer to this probe); the fourth taken
    assert replay.probes[0]["status"] == "answered" and replay.probes[0]["refused"] == 3
    assert replay.stated_beliefs["follower"] == [None, 1, 1, 1] and len(replay.belief_events) == 1
    client.close()


def test_a_leader_never_states_a_belief(seat_server):
    client = Client(seat_server)
    client.new_game(mode="turn", horizon=3)
    client.send({"type": "belief", "color": 1})
    error = client.recv("error")
    assert error["code"] == "rejected" and "only a person in the follower seat states a belief" in error["message"]
    client.key("1")
    assert client.recv("error")["code"] == "bad_key"
    client.send({"type": "quit"})
    client.recv("game_over")
    client.close()


def test_probe_plans_read_back_and_random_steps_follow_from_the_seed():
    assert ProbePlan.parse("steps:40, 10,10").text == "steps:10,40"
    assert ProbePlan.parse(None) == ProbePlan.parse("none") == ProbePlan()
    plan = ProbePlan.parse("random:0.2")
    assert plan.schedule(50, seed=3) == plan.schedule(50, seed=3) != plan.schedule(50, seed=4)
    assert all(1 <= t < 50 for t in plan.schedule(50, seed=3))
    assert ProbePlan.parse("steps:5,60").schedule(50, seed=0) == (5,)
    for text in ("steps:", "random:0", "random:2", "every:3", "steps:a"):
        with pytest.raises(ValueError, match="is not a probe plan"):
            ProbePlan.parse(text)


def test_the_scripted_stand_in_of_the_docs_plays_the_follower_seat(seat_server):
    """``examples/scripted_assistant.py``, whose games docs/STUDIES.md measures (labelled: not people's)."""
    from tests.test_examples import example

    over = example("scripted_assistant").play(seat_server.ws_url, "astar", "steps:4", horizon=12)
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok and replay.num_steps == 12 and replay.probes[0]["status"] == "answered"
    assert replay.agents["follower"] == {"policy": "human"}  # a seat a page plays, as far as the server knows


def test_a_follower_seat_game_played_to_its_end_or_quit_is_no_longer_running(seat_server):
    """Neither a game that is over nor one quit waits on: rejoining either with its token is refused."""
    ended = []
    for reason in ("complete", "quit"):
        client, welcome, _ = follower_game(seat_server, mode="turn", horizon=3)
        if reason == "quit":
            client.send({"type": "quit"})
        else:
            for _ in range(3):
                client.key("ArrowUp")
        assert client.recv("game_over")["reason"] == reason
        client.close()
        ended.append(welcome)
    for welcome in ended:
        other = Client(seat_server)
        other.send({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]})
        assert "no game with that id and token is waiting" in other.recv("error")["message"]
        other.close()
