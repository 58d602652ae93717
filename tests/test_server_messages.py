"""Every message the server sends is declared (``server.messages``): real games through a real server, every message
each page received validated against the declaration; the declaration refuses what it does not declare; and
docs/SERVER_PROTOCOL.md's table of the server's messages is the declaration's own text."""

import asyncio
import json
import re
import time

import pytest
from pydantic import ValidationError

from colorgrid.enums import Ending
from server.messages import (
    ENDING_WORDS,
    ROOM_CLOSED_WORDS,
    ROOM_ERROR_WORDS,
    SEAT_WORDS,
    SERVER_TYPES,
    messages_table,
    server_message,
)
from server.play.hub import GameHub
from server.protocol import RoomClosedReason, RoomErrorCode, RoomSeatStatus, SeatStatus
from server.settings import ServerSettings
from tests.conftest import ROOT, start_server, stop_server
from tests.helpers import Inbox
from tests.test_server import Client, wait_for_no_games

MOVES = ["ArrowUp", "ArrowLeft", "ArrowDown", "ArrowRight"]


class RecordingClient(Client):
    """A page's socket that keeps every message it received, those its test skipped too."""

    received: list[dict] = []  # shared by every client of a test: the messages of all its pages

    def recv(self, *types, timeout=20.0):
        end = time.monotonic() + timeout
        while True:
            msg = json.loads(self.ws.recv(timeout=max(0.01, end - time.monotonic())))
            self.received.append(msg)
            if not types or msg["type"] in types:
                return msg


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("messages"), "--followers", "bayes-people", "--followers", "copy",
                       "--leaders", "astar", "--max-sessions", "6", "--rejoin-grace-s", "600", "--tick-hz", "20",
                       "--new-games-per-minute", "300")
    yield srv
    stop_server(srv)


def play_out(client, first_state, moves=MOVES):
    """Press keys until the game is over (answering any probe); the ``game_over``."""
    state, t = first_state, 0
    while True:
        if state["step"] == state["horizon"]:  # the last state: the game is over, its connection closing
            return client.recv("game_over")
        if state.get("probe"):
            client.send({"type": "probe_answer", "probe": state["probe"]["id"], "color": 1, "confidence": 0.8})
        client.key(moves[t % len(moves)])
        t += 1
        state = client.recv("state", "game_over")
        if state["type"] == "game_over":
            return state


def test_every_message_sent_in_played_games_is_declared(server):
    RecordingClient.received = []
    # protocol errors and a ping
    probe = RecordingClient(server)
    probe.send("not json")
    assert probe.recv("error")["code"] == "bad_json"
    probe.send({"type": "no_such_type"})
    assert probe.recv("error")["code"] == "unknown_type"
    probe.send({"type": "ping"})
    assert probe.recv("pong")["t_server"] > 0
    probe.close()

    # a turn-based game to its end
    solo = RecordingClient(server)
    welcome, state = solo.new_game(mode="turn", horizon=4)
    assert play_out(solo, state)["reason"] == Ending.COMPLETE
    solo.close()

    # a real-time game: dropped, rejoined (within the grace: ten minutes here), taken over by another tab, then quit
    first = RecordingClient(server)
    welcome, _ = first.new_game(mode="realtime", horizon=400, follower="copy")
    first.recv("state")
    first.close()
    again = RecordingClient(server)
    again.send({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]})
    assert again.recv("welcome")["game_id"] == welcome["game_id"]
    again.recv("state")
    other = RecordingClient(server)
    other.send({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]})
    other.recv("welcome")
    assert again.recv("replaced")["game_id"] == welcome["game_id"]
    other.send({"type": "quit"})
    assert other.recv("game_over")["reason"] == Ending.QUIT
    for client in (again, other):
        client.close()

    # two people in a room: one leaves (a scripted leader plays on), the other plays to the end
    opener, guest = RecordingClient(server), RecordingClient(server)
    opener.send({"type": "create_room", "team": "2:1", "mode": "turn", "horizon": 6})
    code = opener.recv("room")["code"]
    guest.send({"type": "join_room", "code": code})
    guest.recv("room")
    for client in (opener, guest):
        client.send({"type": "ready"})
    states = [(client.recv("welcome"), client.recv("state"))[1] for client in (opener, guest)]
    for i, client in enumerate((opener, guest)):
        client.key(MOVES[i])
    for client in (opener, guest):
        assert client.recv("state")["step"] == 1
    guest.send({"type": "quit"})
    assert guest.recv("game_over")["reason"] == Ending.LEFT
    assert opener.recv("seats")["seats"][1]["status"] == "left"
    assert play_out(opener, states[0])["reason"] == Ending.COMPLETE
    for client in (opener, guest):
        client.close()

    # the follower seat beside an AI leader, with probes, and two AI followers in real time
    seat = RecordingClient(server)
    welcome, state = seat.new_game(seat="follower", leader="astar", mode="turn", horizon=5, probes="steps:1,3")
    assert welcome["seat"] == "follower"
    seat.send({"type": "belief", "color": 0, "t_client": 1.0})
    seat.send({"type": "belief", "color": 99, "t_client": 1.0})
    assert seat.recv("error")["code"] == "bad_belief"
    assert play_out(seat, state)["reason"] == Ending.COMPLETE
    seat.close()
    pair = RecordingClient(server)
    _, state = pair.new_game(team="1:2", mode="realtime", horizon=6, followers=["copy", "bayes-people"])
    assert pair.recv("game_over", timeout=30)["reason"] == Ending.COMPLETE
    pair.close()

    # a full server: as many games as it holds, and one more
    wait_for_no_games(server)
    players = [RecordingClient(server) for _ in range(7)]
    assert [p.new_game(mode="turn", horizon=5)[0]["type"] for p in players] == ["welcome"] * 6 + ["full"]
    for player in players[:6]:
        player.send({"type": "quit"})
        assert player.recv("game_over")["reason"] == Ending.QUIT
    for player in players:
        player.close()

    received = RecordingClient.received
    probes = [m for m in received if m["type"] == "state" and m.get("probe")]
    assert probes, "the follower seat's probes were asked"
    seen = {m["type"] for m in received}
    assert seen >= set(SERVER_TYPES) - {"room_closed"}, seen  # a room that expires: the test below
    problems = []
    for msg in received:
        try:
            server_message.validate_python(msg)
        except ValidationError as err:
            problems.append(f"{msg['type']}: {err}")
    assert not problems, "\n".join(problems[:5])


def test_a_closed_room_is_declared_too(tmp_path):
    """The message the played games above do not reach: a room that expires (its wait over at the time the test
    gives the lobby)."""
    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", max_sessions=1, room_wait_s=0.1))
        waiting = Inbox()
        room = await hub.create_room("2:1", None, None, "turn", 5, True, waiting)
        await hub.lobby.expire(room.created + 0.05)
        open_then = len(hub.rooms)
        await hub.lobby.expire(room.created + 0.15)
        await hub.stop()
        return open_then, waiting.messages

    open_then, messages = asyncio.run(scenario())
    assert open_then == 1
    closed = [m for m in messages if m["type"] == "room_closed"]
    assert closed and closed[0]["reason"] == "expired"
    for msg in messages:
        server_message.validate_python(msg)


@pytest.mark.parametrize("message, words", [
    ({"type": "game_over", "reason": "complete", "replay_id": None, "steps": 3, "scores": {}, "extra": 1},
     "extra"),
    ({"type": "game_over", "reason": "finished", "replay_id": None, "steps": 3, "scores": {}}, "reason"),
    ({"type": "announcement", "message": "hello"}, "announcement"),
    ({"type": "seats", "seats": [{"agent": "leader_0", "symbol": "L1", "status": "asleep"}]}, "status"),
    ({"type": "state", "step": 0, "horizon": 4, "blocks": "", "goal": 1, "scores": {}, "events": [],
      "last_applied_seq": None, "leader": 3, "colour": 2}, "colour"),
])
def test_the_declaration_refuses_an_undeclared_type_field_or_value(message, words):
    with pytest.raises(ValidationError, match=words):
        server_message.validate_python(message)


def test_the_documented_table_of_the_servers_messages_is_the_declaration():
    text = (ROOT / "docs" / "SERVER_PROTOCOL.md").read_text()
    found = re.search(r"<!-- generated by server\.messages\.messages_table -->\n(.*?)<!-- end of generated -->",
                      text, re.DOTALL)
    assert found, "docs/SERVER_PROTOCOL.md must hold the generated table between its two marks"
    assert found.group(1) == messages_table(), "run: python -c 'from server.messages import messages_table; " \
                                               "print(messages_table())' and paste it between the marks"
    for kind in SERVER_TYPES:
        assert f"| `{kind}` |" in found.group(1)


def test_every_ending_has_words_and_the_options_send_them(server):
    assert set(ENDING_WORDS) == set(Ending) and all(ENDING_WORDS.values())
    options = server.get("/api/options")[0]
    assert options["endings"] == {ending.value: words for ending, words in ENDING_WORDS.items()}


def test_every_room_error_closing_and_seat_status_has_words_and_the_options_send_them(server):
    tables = {"errors": (ROOM_ERROR_WORDS, {*RoomErrorCode}), "closed": (ROOM_CLOSED_WORDS, {*RoomClosedReason}),
              "seats": (SEAT_WORDS, {*RoomSeatStatus, *SeatStatus})}
    for table, members in tables.values():
        assert set(table) == members and all(words.strip() for words in table.values())
    options = server.get("/api/options")[0]
    assert options["room_words"] == {name: {member.value: words for member, words in table.items()}
                                     for name, (table, _) in tables.items()}
