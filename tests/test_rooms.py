"""Teams on the play server: two people in a room with one AI follower (browser and WebSocket), a person who
leaves and the scripted leader that plays on in their seat, one person with two AI followers in real time,
and the errors of bad room codes and joins. What depends on time (the rejoin grace, a room's countdown) is tested
on the game hub with the time the test sets: the server's windows here are wider than any wait of a loaded machine."""

import asyncio
import re
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from playwright.sync_api import expect
from websockets.exceptions import ConnectionClosed

from colorgrid.replay import load, verify
from server.play.hub import GameHub, ServerFull
from server.protocol import ROOM_CODE_ALPHABET, ROOM_CODE_LENGTH, ROOM_COUNTDOWN_S, GameRequest
from server.settings import ServerSettings
from tests.conftest import start_server, stop_server
from tests.helpers import Inbox, until
from tests.test_server import Client

HORIZON = 12
MOVES = ["ArrowUp", "ArrowLeft", "ArrowDown", "ArrowRight"]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("rooms"), "--followers", "bayes-people", "--followers", "copy",
                       "--max-sessions", "6", "--rejoin-grace-s", "600", "--tick-hz", "20",
                       "--new-games-per-minute", "200")
    yield srv
    stop_server(srv)


def open_room(server, **fields):
    """Two people in one room, both ready: the clients, their welcomes and the room's code."""
    first, second = Client(server), Client(server)
    first.send({"type": "create_room", "team": "2:1", "mode": "turn", "horizon": HORIZON, **fields})
    room = first.recv("room", "error")
    assert room["type"] == "room", room
    code = room["code"]
    assert len(code) == ROOM_CODE_LENGTH and set(code) <= set(ROOM_CODE_ALPHABET) and room["link"] == f"/?room={code}"
    assert room["you"] == "leader_0" and [s["status"] for s in room["seats"]] == ["joined", "open"]
    second.send({"type": "join_room", "code": code.lower()})  # typed in lower case: still the code
    joined = second.recv("room")
    assert joined["you"] == "leader_1" and [s["status"] for s in joined["seats"]] == ["joined", "joined"]
    first.send({"type": "ready"})
    assert [s["status"] for s in second.recv("room")["seats"]] == ["ready", "joined"]
    second.send({"type": "ready"})
    welcomes = [c.recv("welcome") for c in (first, second)]
    for client in (first, second):
        assert client.recv("state")["step"] == 0
    return first, second, welcomes, code


def play_step(clients, step):
    """Every client presses a key; each sees the next state."""
    for i, client in enumerate(clients):
        client.key(MOVES[(step + i) % 4])
    for client in clients:
        assert client.recv("state")["step"] == step + 1


def saved(server, over):
    replay = load(server.replays_dir / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok, verify(replay)
    return replay


# ------------------------------------------------------------ (a) two people in one room, in chromium
def test_two_pages_play_one_room_to_the_end(server, browser):
    pages = [browser.new_context().new_page() for _ in range(2)]
    creator, guest = pages
    creator.goto(server.url + "/")
    creator.select_option("#team", "2:1")
    creator.select_option("#mode", "turn")
    creator.fill("#horizon", str(HORIZON))
    creator.click("#start")
    expect(creator.locator("#room")).to_be_visible()
    code = creator.locator("#room-code").text_content()
    assert re.fullmatch(f"[{ROOM_CODE_ALPHABET}]{{{ROOM_CODE_LENGTH}}}", code)
    link = creator.locator("#room-link").get_attribute("href")
    assert link.endswith(f"/?room={code}")
    guest.goto(link)  # the shared link joins
    expect(guest.locator("#room")).to_be_visible()
    expect(guest.locator("#room-code")).to_have_text(code)
    expect(creator.locator("#room-seats li")).to_have_count(2)
    expect(creator.locator("#room-seats li").nth(1)).to_contain_text("joined")
    for page in pages:
        page.click("#ready")
    for page, you in zip(pages, ("L1", "L2")):
        expect(page.locator("#game")).to_be_visible()
        expect(page.locator("#board")).to_have_attribute("data-step", "0")
        expect(page.locator("#you")).to_have_text(you)
        expect(page.locator("#agent-scores .agent")).to_have_count(3)  # L1, L2, F1
    for t in range(HORIZON):
        for i, page in enumerate(pages):
            page.locator("#board").focus()
            page.keyboard.press(MOVES[(t + i) % 4])
        if t < HORIZON - 1:
            for page in pages:
                expect(page.locator("#board")).to_have_attribute("data-step", str(t + 1))
    for page in pages:
        expect(page.locator("#over")).to_be_visible()
        expect(page.locator("#over-scores")).to_contain_text(f"after {HORIZON} steps")
    replay_id = creator.locator("#replay-link").get_attribute("href").split("id=")[1]
    replay = saved(server, {"replay_id": replay_id})
    assert replay.num_steps == HORIZON and replay.config.num_leaders == 2 and replay.config.num_followers == 1
    assert replay.agents["leader_0"] == replay.agents["leader_1"] == {"policy": "human"}
    applied = [e for e in replay.key_events if e["status"] == "applied"]
    for agent in ("leader_0", "leader_1"):  # each person's keys logged apart, one applied per step
        assert sorted(e["applied_step"] for e in applied if e["agent"] == agent) == list(range(HORIZON))
    assert replay.meta["team"] == "2:1" and replay.meta["room"] == code and replay.meta["seats_left"] == []
    for context in {p.context for p in pages}:
        context.close()


# ------------------------------------------------------------ (b) one person leaves, the scripted leader plays on
def test_a_person_away_and_back_keeps_the_seat_and_one_who_quits_is_replaced_by_the_scripted_leader(server):
    first, second, welcomes, code = open_room(server)
    assert [w["agent"] for w in welcomes] == ["leader_0", "leader_1"] and welcomes[0]["token"] != welcomes[1]["token"]
    assert welcomes[0]["room"] == code and welcomes[0]["team"] == "2:1"
    assert [a["symbol"] for a in welcomes[0]["look"]["agents"]] == ["L1", "L2", "F1"]
    for t in range(3):
        play_step([first, second], t)
    first.key("ArrowUp")  # away and back within the grace (this server's is ten minutes): the game waits for them
    second.close()
    assert first.recv("seats")["seats"][1]["status"] == "reconnecting"
    second = Client(server)
    second.send({"type": "rejoin", "game_id": welcomes[1]["game_id"], "token": welcomes[1]["token"]})
    again = second.recv("welcome")
    assert again["agent"] == "leader_1" and again["next_seq"] == 3 and second.recv("state")["step"] == 3
    assert first.recv("seats")["seats"][1]["status"] == "playing"
    second.seq = again["next_seq"]  # this person's keys number on
    second.key("ArrowDown")
    for client in (first, second):
        assert client.recv("state")["step"] == 4
    second.send({"type": "quit"})  # and now for good
    over = second.recv("game_over")
    assert over["reason"] == "left" and over["replay_id"] is None and over["steps"] == 4
    assert first.recv("seats")["seats"][1]["status"] == "left"
    for t in range(4, HORIZON):  # one person now: each key is a step
        first.key(MOVES[t % 4])
        assert first.recv("state")["step"] == t + 1
    over = first.recv("game_over")
    assert over["reason"] == "complete"
    replay = saved(server, over)
    assert replay.agents["leader_0"] == {"policy": "human"}
    assert replay.agents["leader_1"] == {"policy": "human", "replaced_by": "astar", "from_step": 4}
    assert replay.meta["seats_left"] == [{"agent": "leader_1", "reason": "quit", "from_step": 4,
                                          "replaced_by": "astar"}]
    by_agent = {a: [e for e in replay.key_events if e["agent"] == a and e["status"] == "applied"]
                for a in ("leader_0", "leader_1")}
    assert [e["applied_step"] for e in by_agent["leader_1"]] == [0, 1, 2, 3]
    assert [e["applied_step"] for e in by_agent["leader_0"]] == list(range(HORIZON))
    first.close()


def test_a_room_whose_people_all_leave_ends_and_is_saved(server):
    first, second, welcomes, _ = open_room(server)
    play_step([first, second], 0)
    second.send({"type": "quit"})
    assert second.recv("game_over")["reason"] == "left"
    first.send({"type": "quit"})
    over = first.recv("game_over")
    assert over["reason"] == "quit" and over["steps"] == 1
    replay = saved(server, over)
    assert replay.ended == "quit" and replay.agents["leader_1"]["replaced_by"] == "astar"
    for client in (first, second):
        client.close()


# ------------------------------------------------------------ (c) one person, two AI followers, real time
def test_one_person_with_two_followers_in_real_time(server):
    client = Client(server)
    welcome, state = client.new_game(team="1:2", mode="realtime", horizon=30, follower="bayes-people")
    assert welcome["team"] == "1:2" and welcome["agent"] == "leader_0" and welcome["room"] is None
    assert [a["name"] for a in welcome["look"]["agents"]] == ["leader_0", "follower_0", "follower_1"]
    assert {"leader_0", "follower_0", "follower_1"} <= set(state) and "belief" not in state
    assert set(state["beliefs"]) == {"follower_0", "follower_1"}
    end = time.monotonic() + 30
    while True:
        client.key(MOVES[client.seq % 4])
        msg = client.recv("state", "game_over")
        if msg["type"] == "game_over" or time.monotonic() > end:
            break
    assert msg["type"] == "game_over" and msg["reason"] == "complete", msg
    replay = saved(server, msg)
    assert replay.num_steps == 30 and replay.meta["tick_hz"] == 20 and replay.meta["team"] == "1:2"
    assert set(replay.goal_probs) == {"follower_0", "follower_1"}  # one belief list per follower
    assert all(len(p) == 30 for p in replay.goal_probs.values())
    assert replay.agents["follower_0"]["policy"] == replay.agents["follower_1"]["policy"] == "bayes-people"
    assert all(e["agent"] == "leader_0" for e in replay.key_events)
    client.close()


# ------------------------------------------------------------ (d) bad codes and joins
def test_bad_room_codes_and_joins_get_clear_errors(server):
    first, second, third = Client(server), Client(server), Client(server)

    def error(client, message):
        client.send(message)
        reply = client.recv("error", "room", "welcome")
        assert reply["type"] == "error", reply
        return reply

    assert error(first, {"type": "join_room", "code": "abc"})["code"] == "bad_room_code"
    assert error(first, {"type": "join_room", "code": "0OIL1234"})["code"] == "bad_room_code"  # letters never used
    assert error(first, {"type": "join_room", "code": "A" * ROOM_CODE_LENGTH})["code"] == "room_not_found"
    assert error(first, {"type": "ready"})["message"].startswith("no room on this connection")
    refused = error(first, {"type": "new_game", "team": "2:1"})
    assert refused["code"] == "rejected" and "create_room" in refused["message"]
    assert error(first, {"type": "create_room", "team": "1:2"})["code"] == "rejected"
    assert error(first, {"type": "create_room", "team": "3:1"})["code"] == "invalid_message"
    first.send({"type": "create_room", "team": "2:1", "horizon": 4})
    code = first.recv("room")["code"]
    assert "has not started" in error(first, {"type": "key", "key": "ArrowUp", "seq": 0})["message"]
    assert "waits in room" in error(first, {"type": "new_game"})["message"]
    second.send({"type": "join_room", "code": f"{code[:4]}-{code[4:]}"})  # as a page may show it
    assert second.recv("room")["you"] == "leader_1"
    full = error(third, {"type": "join_room", "code": code})
    assert full["code"] == "room_full" and "2 seats" in full["message"]
    for client in (first, second):
        client.send({"type": "ready"})
    for client in (first, second):
        client.recv("welcome")
    assert error(third, {"type": "join_room", "code": code})["code"] == "room_started"
    for client in (first, second):
        client.send({"type": "quit"})
        client.recv("game_over")
    for client in (first, second, third):
        client.close()


# ------------------------------------------------------------ rooms in the hub: expiry, sessions, time
def run(scenario):
    """``asyncio.run`` on a thread of its own (this module's chromium keeps an event loop on the main one)."""
    with ThreadPoolExecutor(1) as thread:
        return thread.submit(asyncio.run, scenario()).result()


async def room_game(hub, mode: str, horizon: int) -> tuple:
    """Two people (``Inbox``) in a 2:1 room, both ready: the room and its people."""
    first, second = Inbox(), Inbox()
    room = await hub.create_room("2:1", None, None, mode, horizon, True, first)
    await hub.join_room(room.code, second)
    for person in (first, second):
        await hub.set_ready(room, person)
    return room, first, second


def test_a_real_time_rooms_game_is_made_only_once_its_countdown_is_over(tmp_path):
    """The countdown held by the test: the room says how many seconds are left, and no game exists until the
    countdown is over; then it starts for both, on the server's clock."""
    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", tick_hz=20))
        asked, over = [], asyncio.Event()

        async def countdown(seconds):
            asked.append(seconds)
            await over.wait()

        hub.lobby.countdown = countdown
        room, first, second = await room_game(hub, "realtime", 20)
        await until(lambda: asked)
        during = (len(hub.games), len(hub.rooms), first.game, second.last("room")["starting_in_s"])
        over.set()
        await until(lambda: first.game is not None and second.game is not None)
        after = (len(hub.games), len(hub.rooms), first.game is second.game, first.last("welcome")["tick_hz"])
        await hub.stop()
        return asked, during, after

    asked, during, after = run(scenario)
    assert asked == [ROOM_COUNTDOWN_S]
    assert during == (0, 1, None, ROOM_COUNTDOWN_S)
    assert after == (1, 0, True, 20)


def test_a_seat_away_past_the_rejoin_grace_goes_to_the_scripted_leader(tmp_path):
    """The rejoin grace on the time the test gives the hub's sweep: a person whose socket closed keeps the seat (the
    game waits) until the grace is over, and after it the scripted leader plays on; the replay says so."""
    grace = 30.0

    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", rejoin_grace_s=grace))
        room, first, second = await room_game(hub, "turn", 4)
        await until(lambda: first.game is not None and second.game is not None)
        game = first.game
        for person, key in ((first, "ArrowUp"), (second, "ArrowDown")):
            await hub.key(game, key, 0, 0.0, game.seat_of(person))
        away = game.seat_of(second)
        hub.disconnect(game, second)
        gone_at = away.disconnected_at
        await hub.sessions.sweep(gone_at + grace - 0.01)
        within = (away.left, game.paused)
        await hub.sessions.sweep(gone_at + grace + 0.01)
        after = (away.left, game.paused, game.controlled())
        for seq in range(1, 4):  # the stand-in moves beside the one person left
            await hub.key(game, MOVES[seq], seq, 0.0, game.seat_of(first))
        steps = int(game.env.state.t[0])
        await hub.stop()
        return within, after, steps, first.last("game_over")

    within, after, steps, over = run(scenario)
    assert within == (None, True)
    assert after == ("disconnected", False, True)
    assert steps == 4 and over["reason"] == "complete"
    replay = load(tmp_path / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok
    assert replay.agents["leader_1"] == {"policy": "human", "replaced_by": "astar", "from_step": 1}
    assert replay.meta["seats_left"] == [{"agent": "leader_1", "reason": "disconnected", "from_step": 1,
                                          "replaced_by": "astar"}]


def test_waiting_rooms_count_as_sessions_and_expire(tmp_path):
    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", max_sessions=2, room_wait_s=0.2))
        waiting = [Inbox(), Inbox()]
        rooms = [await hub.create_room("2:1", None, None, "turn", 5, True, client) for client in waiting]
        with pytest.raises(ServerFull):
            await hub.create_room("2:1", None, None, "turn", 5, True, Inbox())
        with pytest.raises(ServerFull):
            await hub.new_game(GameRequest(mode="turn", horizon=5), Inbox())
        await hub.lobby.expire(min(room.created for room in rooms) + 0.1)  # the wait (0.2 s) is not over: they stay
        assert len(hub.rooms) == 2
        await hub.lobby.expire(max(room.created for room in rooms) + 0.3)
        assert not hub.rooms
        game = await hub.new_game(GameRequest(mode="turn", horizon=5, team="1:2"), Inbox())  # room for games again
        assert len(game.ai) == 2 and {p.pool.agent_index for p in game.ai.values()} == {1, 2}
        await hub.stop()
        return waiting

    for client in run(scenario):
        closed = client.last("room_closed")
        assert closed["reason"] == "expired" and "within 0.2 s" in closed["message"]


def test_followers_of_team_games_share_one_pool_per_agent_index(tmp_path):
    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy"))
        games = [await hub.new_game(GameRequest(follower="bayes", mode="turn", horizon=5, team="1:2"), Inbox()) for _ in range(3)]
        calls = []
        for pool in hub.pools.by_key.values():
            real = pool.act
            pool.act = lambda inputs, slots, real=real, pool=pool: calls.append((pool.agent_index, len(slots))) \
                or real(inputs, slots)
        for game in games:
            game.press("ArrowUp", 0, 0.0)
        await hub.step_games(games)
        keys = sorted((k[0], k[2]) for k in hub.pools.by_key)
        await hub.stop()
        return calls, keys, games

    calls, keys, games = run(scenario)
    assert keys == [("bayes", 1), ("bayes", 2)]
    assert sorted(calls) == [(1, 3), (2, 3)]  # one batched call per pool for the three games
    assert all(g.env.state.t[0] == 1 for g in games)


def test_a_real_time_room_counts_down_and_steps_with_each_persons_latest_key(server):
    first, second = Client(server), Client(server)
    first.send({"type": "create_room", "mode": "realtime", "horizon": 20})
    code = first.recv("room")["code"]
    second.send({"type": "join_room", "code": code})
    second.recv("room")
    for client in (first, second):
        client.send({"type": "ready"})
    starting = second.recv("room")
    while starting["starting_in_s"] is None:
        starting = second.recv("room")
    assert starting["starting_in_s"] == ROOM_COUNTDOWN_S  # every page counts down (the countdown: a test below)
    assert second.recv("welcome")["tick_hz"] == 20
    overs = {}
    while len(overs) < 2:
        for client in (first, second):
            if client in overs:
                continue
            try:
                client.key(MOVES[client.seq % 4])
            except ConnectionClosed:  # the game ended: the server sent game_over and closed this socket
                pass
            msg = client.recv("state", "game_over")
            if msg["type"] == "game_over":
                overs[client] = msg
    assert all(o["reason"] == "complete" and o["steps"] == 20 for o in overs.values())
    replay = saved(server, overs[first])
    assert replay.meta["tick_hz"] == 20 and {e["agent"] for e in replay.key_events} == {"leader_0", "leader_1"}
    for client in (first, second):
        client.close()


def test_a_person_whose_socket_closes_while_the_game_is_made_leaves_at_once(tmp_path):
    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", rejoin_grace_s=30))
        first, second = Inbox(), Inbox()
        room = await hub.create_room("2:1", "bayes", None, "turn", 5, True, first)
        await hub.join_room(room.code, second)
        await hub.set_ready(room, first)
        await hub.set_ready(room, second)
        await until(lambda: room.opening)  # the game is being made (its follower pool loads off the event loop)
        await hub.leave_room(room, second)  # the second page's socket closes now: it never gets its token
        await until(lambda: hub.games and not room.opening)
        game = next(iter(hub.games.values()))
        await until(game.controlled)  # the stand-in leader loads off the event loop, then takes the seat
        assert not game.paused, "the game must not wait the whole rejoin grace for a token nobody holds"
        await hub.key(game, "ArrowUp", 0, 0.0)  # the first person moves; the stand-in plays the other seat
        steps, seats = int(game.env.state.t[0]), [(s.name, s.left, s.left_at_step) for s in game.seats]
        await hub.stop()
        return steps, seats

    steps, seats = run(scenario)
    assert seats == [("leader_0", None, None), ("leader_1", "disconnected", 0)]
    assert steps == 1
