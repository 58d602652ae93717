"""What a person states in the follower seat is taken as sent or refused: a string is not read as a number, nor
``true`` as a color (the protocol's strict fields), through a real server; each refusal is one error line."""

import pytest
from pydantic import ValidationError

from colorgrid.replay import load, verify
from server.protocol import client_message
from tests.conftest import start_server, stop_server
from tests.test_server import Client


@pytest.fixture(scope="module")
def seat_server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("strict"), "--max-sessions", "2", "--leaders", "astar")
    yield srv
    stop_server(srv)


def replies_until_pong(client: Client, message: dict) -> list[dict]:
    """Every message the server sends in answer to ``message``, up to the answer to a ping sent after it (one socket,
    in order: nothing it answers can come later)."""
    client.send(message)
    client.send({"type": "ping"})
    out = []
    while (msg := client.recv())["type"] != "pong":
        out.append(msg)
    return out


BAD_BELIEFS = [({"color": "1"}, "belief: color: Input should be a valid integer"),
               ({"color": True}, "belief: color: Input should be a valid integer"),
               ({"color": 1.0}, "belief: color: Input should be a valid integer"),
               ({"color": 1, "t_client": "12"}, "belief: t_client: Input should be a valid number")]
BAD_ANSWERS = [({"confidence": "0.8"}, "probe_answer: confidence: Input should be a valid number"),
               ({"confidence": True}, "probe_answer: confidence: Input should be a valid number"),
               ({"color": True}, "probe_answer: color: Input should be a valid integer"),
               ({"color": "2"}, "probe_answer: color: Input should be a valid integer"),
               ({"probe": "0"}, "probe_answer: probe: Input should be a valid integer"),
               ({"t_client": False}, "probe_answer: t_client: Input should be a valid number")]


@pytest.mark.parametrize("fields, words", BAD_BELIEFS + BAD_ANSWERS)
def test_the_declaration_refuses_strings_for_numbers_and_booleans_for_colors(fields, words):
    kind = words.split(":")[0]
    base = {"belief": {"color": 1}, "probe_answer": {"probe": 0, "color": 1, "confidence": 0.8}}[kind]
    with pytest.raises(ValidationError):
        client_message.validate_python({"type": kind, **base, **fields})
    sent = client_message.validate_python({"type": kind, **base, "t_client": 5})  # a whole number is a number
    assert sent.t_client == 5.0 and type(sent.color) is int


def test_a_real_server_refuses_each_lax_statement_in_one_line_and_records_none_of_them(seat_server):
    client = Client(seat_server)
    client.send({"type": "new_game", "seat": "follower", "mode": "turn", "horizon": 3, "probes": "steps:1"})
    assert client.recv("welcome", "error")["type"] == "welcome"
    client.recv("state")
    for fields, words in BAD_BELIEFS:
        replies = replies_until_pong(client, {"type": "belief", **fields})
        assert [(r["type"], r["code"]) for r in replies] == [("error", "invalid_message")], replies
        assert replies[0]["message"].startswith(words) and "\n" not in replies[0]["message"], replies
    client.key("ArrowUp")
    assert client.recv("state")["probe"] == {"id": 0, "step": 1}
    for fields, words in BAD_ANSWERS:
        answer = {"type": "probe_answer", "probe": 0, "color": 1, "confidence": 0.8, "t_client": 1.0, **fields}
        replies = replies_until_pong(client, answer)
        assert [(r["type"], r["code"]) for r in replies] == [("error", "invalid_message")], replies
        assert replies[0]["message"].startswith(words) and "\n" not in replies[0]["message"], replies
    # still open: the first answer of the right types counts, a confidence of 1 sent as a whole number included
    client.send({"type": "probe_answer", "probe": 0, "color": 2, "confidence": 1, "t_client": 2.0})
    client.key("ArrowUp")
    assert client.recv("state")["stated"] == 2
    client.key("ArrowUp")
    over = client.recv("game_over")
    replay = load(seat_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok
    assert [(e["color"], e["via"]) for e in replay.belief_events] == [(2, "probe")]  # none of the refused ones
    assert [(p["status"], p["color"], p["confidence"], p["refused"]) for p in replay.probes] == [
        ("answered", 2, 1.0, 0)]  # an invalid message never reaches the game: not a refused answer
    assert replay.stated_beliefs["follower"] == [None, 2, 2]
    client.close()
