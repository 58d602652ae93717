"""The play socket as the study page uses it, against a real study server, in chromium: one connection per game,
closed by the page and by the server when the game ends, and an idle limit for a socket without a game; keys that
number on across a reload (the export's ``(game_id, seq)`` names one key); real-time games through a network as
participants have it (``tests/delay_proxy.py``: 150 ms each way with jitter), where every key is logged once, nothing
is taken for a dropped connection, and the participant's own move is drawn at once (``web/predict.js``)."""

from __future__ import annotations

import json
import time

import pandas as pd
import pytest
from playwright.sync_api import expect
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from colorgrid.replay import load
from server.study.config import load_study
from server.study.export import write_tables
from tests import helpers
from tests.conftest import start_server, stop_server
from tests.delay_proxy import DelayProxy
from tests.helpers import WAIT_S
from tests.test_study import TOKEN, post

STUDY = """
id = "connections"
title = "Connections"
[defaults]
follower = "copy"
mode = "realtime"
horizon = 60
tick_hz = 5.0
[design]
assignment = "within"
order = "fixed"

[[pages]]
kind = "consent"
text = "Agree?"

[[pages]]
kind = "practice"
game = { follower = "copy", horizon = 30, mode = "realtime", tick_hz = 5.0 }

[[pages]]
kind = "trials"

[[pages]]
kind = "questionnaire"
id = "final"

[[pages.questions]]
id = "comments"
kind = "text"
prompt = "Anything else?"
required = false

[[pages]]
kind = "debrief"
text = "Thank you."
"""
IDLE_S = 2.0
"""The server's ``--connection-idle-s`` here: a socket without a game that says nothing this long is closed."""
# The games are real time, at 5 steps a second: the practice (6 s) holds the reload test's two keys, the trials (12 s)
# its six and a reload, with room for a loaded machine (a game waits while its page reloads).
ARROWS = {"ArrowUp": (-1, 0), "ArrowDown": (1, 0), "ArrowLeft": (0, -1), "ArrowRight": (0, 1)}


@pytest.fixture(scope="module")
def study_server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("connections")
    (tmp / "study.toml").write_text(STUDY)
    server = start_server(tmp, "--connection-idle-s", str(IDLE_S), command=("study", "run", str(tmp / "study.toml")),
                          env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    server.study_file = tmp / "study.toml"
    yield server
    stop_server(server)


class PlaySockets:
    """A page's play sockets as chromium reports them: how many opened while another was still open, the keys each
    game was sent (by ``game_id``), the latest welcome and state, and the highest key the server has applied. A
    socket of a document the page navigated away from (a reload) is gone with it: chromium reports no close for it,
    so the server's count of sockets is checked too (``no_connections``)."""

    def __init__(self, page):
        self.sockets, self.overlapping, self.unloaded = [], 0, set()
        self.welcome = self.state = None
        self.games, self.welcomes = [], 0  # the game ids welcomed, in order; every welcome (rejoins too)
        self.sent_types: list[str] = []  # every message sent, by type
        self.keys: dict[str, list[int]] = {}
        self.applied, self.overs = -1, 0
        page.on("websocket", self._opened)
        page.on("framenavigated", lambda frame: frame.parent_frame is None and self.unloaded.update(self.sockets))

    def closed(self) -> list[bool]:
        return [w.is_closed() or w in self.unloaded for w in self.sockets]

    def _opened(self, ws):
        if ws.url.endswith("/ws/play"):
            self.overlapping += self.closed().count(False)
            self.sockets.append(ws)
            ws.on("framesent", self._sent)
            ws.on("framereceived", self._received)

    def _sent(self, payload):
        msg = json.loads(payload)
        self.sent_types.append(msg["type"])
        if msg["type"] == "key":
            self.keys.setdefault(self.welcome["game_id"], []).append(msg["seq"])

    def _received(self, payload):
        msg = json.loads(payload)
        if msg["type"] == "welcome":
            if msg["game_id"] not in self.games:
                self.games.append(msg["game_id"])
                self.applied = -1
            self.welcome, self.state, self.welcomes = msg, None, self.welcomes + 1
        elif msg["type"] == "state":
            self.state = msg
            if msg["last_applied_seq"] is not None:
                self.applied = max(self.applied, msg["last_applied_seq"])
        elif msg["type"] == "game_over":
            self.overs += 1

    @property
    def sent(self) -> list[int]:
        """The keys sent in the game of the latest welcome."""
        return self.keys.get(self.welcome["game_id"], [])

    def in_play(self) -> bool:
        return self.state is not None and self.state["step"] < self.state["horizon"]


def wait_until(page, condition, what: str, timeout_s: float = WAIT_S) -> None:
    """Ask ``condition()`` again until it holds, letting chromium's events in between (playwright delivers them
    while it waits on a reply of the browser's: one round trip each time)."""
    helpers.wait_until(lambda: page.context.cookies() is not None and condition(), what, timeout_s, every_s=0.025)


def free_move(welcome: dict, state: dict) -> tuple[str, int]:
    """A key that moves the participant's disc (on the board, in its columns, not onto the follower), towards the
    board's middle, and the cell it goes to; away from the follower where it can (it moves a cell a tick: the state
    seen here may be a tick old), so that the move is not blocked by the time it is drawn."""
    width, height = welcome["width"], welcome["height"]
    first, stop = welcome.get("prediction", {}).get("columns", (0, width))
    row, col = divmod(state["leader"], width)
    f_row, f_col = divmod(state["follower"], width)
    moves = []
    for key, (dr, dc) in ARROWS.items():
        r, c = row + dr, col + dc
        near = abs(r - f_row) + abs(c - f_col) < 3
        if 0 <= r < height and first <= c < stop and (r, c) != (f_row, f_col):
            moves.append((near, abs(r - height / 2) + abs(c - (first + stop) / 2), key, r * width + c))
    _, _, key, target = min(moves)
    return key, target


def press(page, sockets: PlaySockets) -> tuple[int, str | None]:
    """One free move, once the game is on: the cell it goes to and where the page drew the disc right after the
    press (before any state could answer through the delaying proxy). Returns once the server applied the key, or
    the game made its last step."""
    wait_until(page, sockets.in_play, "a state of the game in play")
    key, target = free_move(sockets.welcome, sockets.state)
    before = len(sockets.sent)
    page.keyboard.press(key)
    shown = page.locator("#board").get_attribute("data-you")
    wait_until(page, lambda: len(sockets.sent) > before, "the key to be sent")
    seq = sockets.sent[-1]
    wait_until(page, lambda: sockets.applied >= seq or not sockets.in_play(), f"key {seq} to be applied")
    return target, shown


def start_game(page, sockets: PlaySockets, games_before: int) -> None:
    """Press Play on a real-time game's page: its 3-2-1, "go", then the game's board."""
    page.click("#play")
    expect(page.locator("#countdown")).to_have_text("3")
    expect(page.locator("#countdown")).to_have_text("go")
    expect(page.locator("#board")).to_be_visible()
    wait_until(page, lambda: len(sockets.games) == games_before + 1 and sockets.state is not None,
               "the game's first state")


def finish_game(page, sockets: PlaySockets, overs: int) -> None:
    """The game runs to its end; the page shows its page again with Continue."""
    wait_until(page, lambda: sockets.overs >= overs, "game_over")
    expect(page.locator("#next")).to_be_visible()


def lost_connections(console: list[str]) -> list[str]:
    """What web/socket.js logged of connections it took for dropped."""
    return [line for line in console if "connection lost" in line]


def no_connections(server) -> None:
    """The server holds no play socket (it closes a game's once the game is over)."""
    helpers.wait_until(lambda: server.get("/api/health")[0]["connections"] == 0, "the server to close its play sockets")


def replays_of(server, pid: str) -> dict:
    """The participant's replays, by game id."""
    out = {}
    for path in server.replays_dir.glob("play-*.replay.json"):
        replay = load(path)
        if replay.meta.get("study", {}).get("participant") == pid:
            out[replay.meta["game_id"]] = replay
    return out


def open_study(browser, server_url: str, pid: str):
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    console, errors = [], []
    page.on("console", lambda message: console.append(message.text))
    page.on("pageerror", lambda err: errors.append(str(err)))
    sockets = PlaySockets(page)
    page.goto(f"{server_url}/study?PROLIFIC_PID={pid}")
    expect(page.locator("#page-title")).to_have_text("Consent")
    page.click("#next")
    return context, page, sockets, console, errors


# ---------------------------------------------------------------- one connection per game; keys across a reload
def test_one_connection_per_game_and_keys_number_on_across_a_reload(study_server, browser, tmp_path):
    context, page, sockets, console, errors = open_study(browser, study_server.url, "reload-1")
    start_game(page, sockets, 0)  # the practice
    for _ in range(2):
        press(page, sockets)
    practice = sockets.welcome["game_id"]
    finish_game(page, sockets, 1)
    wait_until(page, lambda: sockets.sockets[0].is_closed(), "the practice's socket to close")
    page.click("#next")

    start_game(page, sockets, 1)  # the trial: three keys, a reload in the middle of the game, three keys
    trial = sockets.welcome["game_id"]
    for _ in range(3):
        press(page, sockets)
    page.reload()
    wait_until(page, lambda: sockets.welcomes == 3 and sockets.state is not None, "the rejoined game's state")
    assert sockets.welcome["game_id"] == trial and sockets.welcome["next_seq"] == 3  # the server says where to go on
    expect(page.locator("#board")).to_be_visible()
    for _ in range(3):
        press(page, sockets)
    finish_game(page, sockets, 2)
    assert sockets.keys == {practice: [0, 1], trial: [0, 1, 2, 3, 4, 5]}
    # one socket per game (and one after the reload), never two at once, each closed once its game was over
    wait_until(page, lambda: all(sockets.closed()), "every socket to close")
    assert len(sockets.sockets) == 3 and sockets.overlapping == 0
    no_connections(study_server)
    assert lost_connections(console) == [] and errors == []
    context.close()

    out = tmp_path / "export"
    write_tables(load_study(study_server.study_file), study_server.replays_dir / "study.sqlite",
                 study_server.replays_dir, out)
    keys = pd.read_parquet(out / "keys.parquet")
    assert not keys.duplicated(["game_id", "seq"]).any()
    mine = keys[keys.participant == "reload-1"]
    assert mine[mine.game_id == trial].seq.tolist() == [0, 1, 2, 3, 4, 5]
    assert set(mine.status) <= {"applied", "unapplied"}
    assert json.loads((out / "schema.json").read_text())["tables"]["keys"]["unique"] == ["game_id", "seq"]


# ---------------------------------------------------------------- the server: one game a socket, an idle limit
def test_the_server_closes_a_finished_games_socket_and_an_idle_one_without_a_game(study_server):
    joined = post(study_server, "/api/study/join", {"params": {"PROLIFIC_PID": "sockets-1"}})[1]
    who, ref = {"pid": "sockets-1", "session": joined["session"]}, {"participant": "sockets-1",
                                                                     "session": joined["session"]}
    post(study_server, "/api/study/advance", {**who, "step": 0, "agree": True})
    with connect(study_server.ws_url, open_timeout=20) as ws:  # the practice, to its end
        ws.send(json.dumps({"type": "new_game", "study": ref}))
        while json.loads(ws.recv(timeout=30))["type"] != "game_over":
            pass
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
        assert (closed.value.rcvd.code, closed.value.rcvd.reason) == (1000, "game over")
    post(study_server, "/api/study/advance", {**who, "step": 1})

    old = connect(study_server.ws_url, open_timeout=20)
    try:
        replaced_then_idle(study_server, old, ref)
    finally:
        old.close()


def replaced_then_idle(study_server, old, ref) -> None:
    """A game on ``old``, rejoined on a new socket: ``old`` is closed for being idle without a game; the keys on the new
    one number on; its socket is closed once the game is over."""
    old.send(json.dumps({"type": "new_game", "study": ref}))
    welcome = recv(old, "welcome")
    assert welcome["next_seq"] == 0
    for seq in range(2):
        old.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": seq, "t_client": 1.0}))
    while recv(old, "state")["last_applied_seq"] != 1:
        pass
    with connect(study_server.ws_url, open_timeout=20) as new:
        new.send(json.dumps({"type": "rejoin", "game_id": welcome["game_id"], "token": welcome["token"]}))
        assert recv(new, "welcome")["next_seq"] == 2
        assert recv(old, "replaced")["game_id"] == welcome["game_id"]
        # the old socket has no game any more: closed once it has said nothing for IDLE_S
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                old.recv(timeout=15 * IDLE_S)
        assert (closed.value.rcvd.code, closed.value.rcvd.reason) == (1001, "idle: no game")
        new.send(json.dumps({"type": "key", "key": "ArrowUp", "seq": 1, "t_client": 2.0}))
        err = recv(new, "error")
        assert err["code"] == "bad_seq" and "from 2" in err["message"]
        new.send(json.dumps({"type": "key", "key": "ArrowDown", "seq": 2, "t_client": 3.0}))
        over = recv(new, "game_over", timeout=60)
        with pytest.raises(ConnectionClosed):
            new.recv(timeout=10)
    replay = load(study_server.replays_dir / f"{over['replay_id']}.replay.json")
    assert [e["seq"] for e in replay.key_events] == [0, 1, 2]


def recv(ws, kind: str, timeout: float = 20.0) -> dict:
    end = time.monotonic() + timeout
    while True:
        msg = json.loads(ws.recv(timeout=max(0.01, end - time.monotonic())))
        if msg["type"] == kind:
            return msg


# ---------------------------------------------------------------- the person's own move, predicted
def test_the_own_move_is_drawn_at_once_and_the_servers_state_corrects_it(study_server, browser):
    page = browser.new_page()
    page.goto(study_server.url + "/study?PROLIFIC_PID=predict-1")  # a page of the server, to import its modules
    shown = page.evaluate("""async () => {
        const { OwnMove } = await import("/static/predict.js");
        const moves = { ArrowUp: [-1, 0], ArrowDown: [1, 0], ArrowLeft: [0, -1], ArrowRight: [0, 1] };
        // a board of 3 rows and 4 columns (cell = row * 4 + col); the person's agent may stand on columns 0 and 1
        const welcome = { width: 4, height: 3, look: { agents: [{ name: "leader" }, { name: "follower" }] },
                          prediction: { moves, columns: [0, 2] } };
        const own = new OwnMove(welcome, "leader");
        const state = (leader, follower, applied, step = 1) =>
          ({ step, horizon: 10, leader, follower, last_applied_seq: applied });
        const out = [own.shown(state(5, 11, null)).leader];      // no key: where the server has it
        own.press("ArrowLeft", 0);
        out.push(own.shown(state(5, 11, null)).leader);         // at once: (1, 1) -> (1, 0)
        out.push(own.shown(state(5, 11, null, 2)).leader);      // a state before the key was applied: still ahead
        out.push(own.shown(state(4, 11, 0, 3)).leader);         // applied: the server's cell
        own.press("ArrowLeft", 1);
        out.push(own.shown(state(4, 11, 0)).leader);            // off the board: stays
        own.press("ArrowRight", 2);
        out.push(own.shown(state(5, 11, 1)).leader);            // out of its columns: stays
        own.press("ArrowDown", 3);
        out.push(own.shown(state(5, 9, 2)).leader);             // onto the follower: stays
        own.press("ArrowUp", 4);
        own.press("ArrowDown", 5);
        out.push(own.shown(state(5, 11, 3)).leader);            // the latest key only, as the server applies it
        out.push(own.shown(state(1, 11, 5)).leader);            // a later state: the server's cell, whatever was drawn
        own.press("ArrowUp", 6);
        out.push(own.shown(state(5, 11, 5, 10)).leader);        // the game's last step: nothing ahead
        const team = new OwnMove({ ...welcome, look: { agents: [{ name: "leader_0" }, { name: "leader_1" },
                                                               { name: "follower_0" }] } }, "leader_1");
        team.press("ArrowUp", 7);
        const teamState = (applied) => ({ step: 1, horizon: 10, leader_0: 1, leader_1: 5, follower_0: 11,
                                          last_applied_seq: { leader_0: 9, leader_1: applied } });
        out.push(team.shown(teamState(6)).leader_1);            // a team: its own key count (1 is leader_0's)
        out.push(team.shown(teamState(7)).leader_1);
        return out;
    }""")
    assert shown == [5, 4, 4, 4, 4, 5, 5, 9, 1, 5, 5, 5]
    page.close()


# ---------------------------------------------------------------- a network as participants have it
def test_real_time_games_through_a_slow_network_log_every_key_once_and_never_reconnect(study_server, browser):
    with DelayProxy(study_server.port, delay_s=0.15, jitter_s=0.03) as proxy:
        context, page, sockets, console, errors = open_study(browser, proxy.url, "network-1")
        games, drawn = [], []
        for n, label in enumerate(("practice", "trial")):
            start_game(page, sockets, n)
            games.append(sockets.welcome["game_id"])
            while sockets.in_play():
                target, shown = press(page, sockets)
                drawn.append((target, shown))
            finish_game(page, sockets, n + 1)
            expect(page.locator("#countdown")).to_be_hidden()
            page.click("#next")
        expect(page.locator("#page-title")).to_have_text("Questions")  # the last questionnaire (optional)
        page.click("#next")
        expect(page.locator("#page-title")).to_have_text("Thank you")  # the debrief
        wait_until(page, lambda: all(sockets.closed()), "every socket to close")
        context.close()
    # one socket per game, never two at once, never taken for a dropped connection
    assert len(sockets.sockets) == 2 and sockets.overlapping == 0
    assert lost_connections(console) == [] and errors == []
    # the participant's disc was drawn where each key took it at once, not a round trip later
    assert len(drawn) >= 4 and all(shown == str(target) for target, shown in drawn[:-1]), drawn
    # every key the page sent is in its game's log once, applied or (after the last step) unapplied
    replays = replays_of(study_server, "network-1")
    assert sorted(replays) == sorted(games)
    for game_id in games:
        log = replays[game_id].key_events
        assert [e["seq"] for e in log] == sockets.keys[game_id] == list(range(len(log)))
        assert {e["status"] for e in log} <= {"applied", "unapplied"} and log[0]["status"] == "applied"
        assert replays[game_id].ended == "complete"
    no_connections(study_server)
