"""What a play-server process owns and what it shares: two apps in one process over one recordings folder
each run their own games, and each lists the games the other saved."""

import json

from fastapi.testclient import TestClient

from server.app import create_app
from server.settings import ServerSettings

BASE = "http://127.0.0.1"  # a host the server answers (TrustedHostMiddleware)


def play_to_the_end(client: TestClient, horizon: int = 3) -> dict:
    """A turn-based game of ``horizon`` steps on ``client``'s play socket; its ``game_over``."""
    with client.websocket_connect("ws://127.0.0.1/ws/play") as ws:
        ws.send_text(json.dumps({"type": "new_game", "mode": "turn", "horizon": horizon}))
        assert [json.loads(ws.receive_text())["type"] for _ in range(2)] == ["welcome", "state"]
        for seq in range(horizon):
            ws.send_text(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq, "t_client": 0}))
            assert json.loads(ws.receive_text())["type"] == "state"
        return json.loads(ws.receive_text())


def test_two_backends_own_their_games_and_share_the_recordings(tmp_path):
    settings = ServerSettings(replays_dir=tmp_path, follower="copy", followers=("copy", "idle"))
    first, second = create_app(settings), create_app(settings)
    assert first.state.backend.shared.recordings == second.state.backend.shared.recordings == tmp_path
    assert first.state.backend.hub is not second.state.backend.hub
    with TestClient(first, base_url=BASE) as one, TestClient(second, base_url=BASE) as other:
        over = play_to_the_end(one)
        assert over["reason"] == "complete" and over["replay_id"]
        assert one.get("/api/health").json()["games_saved"] == 1
        assert other.get("/api/health").json()["games_saved"] == 0  # the other process played nothing
        listed = other.get("/api/replays", params={"collection": "recorded"}).json()["items"]
        assert [item["id"] for item in listed] == [over["replay_id"]]
        assert other.get(f"/api/replays/{over['replay_id']}").status_code == 200
