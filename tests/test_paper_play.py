"""Checkpoints of the paper's own code, imported, play in the browser: the paper's follower beside a person (1:1),
and the paper's leader as the AI leader a person leads beside (2:1). A real server (uvicorn on loopback) and a real
chromium; each saved replay says which policy played each seat."""

import asyncio
import gzip
import io
import logging

import pytest
import torch
from playwright.sync_api import expect

from colorgrid.replay import load, verify
from colorgrid_apps.cli import main
from server.play.hub import GameHub
from server.protocol import Team
from server.settings import ServerSettings
from tests.conftest import ROOT, start_server, stop_server
from tests.test_rooms import run
from tests.test_server import Client

PAPER = ROOT / "tests" / "data" / "paper"
HORIZON = 6
MOVES = ["ArrowUp", "ArrowLeft", "ArrowDown", "ArrowRight"]


def import_paper_checkpoints(folder) -> dict:
    """The fixture's leader imported as a leader, and as an asymmetric follower with an LSTM (as the paper's
    followers are), through the command, into ``folder``: ``{"leader", "follower"}`` paths (also for
    ``bench/bench_paper_play.py``)."""
    state = torch.load(io.BytesIO(gzip.decompress((PAPER / "paper_leader.pth.gz").read_bytes())), map_location="cpu",
                       weights_only=True)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        lstm = {f"lstm.{k}": v for k, v in torch.nn.LSTM(192, 192).state_dict().items()}
    made = {}
    for role, weights, setting in (("leader", state, "--symmetric"), ("follower", {**state, **lstm}, "--asymmetric")):
        torch.save(weights, folder / f"{role}_iteration=3.pth")
        made[role] = folder / f"paper_{role}.pt"
        assert main(["checkpoint", "import-paper", str(folder / f"{role}_iteration=3.pth"), "--role", role, setting,
                     "--out", str(made[role])]) == 0
    return made


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory) -> dict:
    return import_paper_checkpoints(tmp_path_factory.mktemp("paper_play"))


@pytest.fixture(scope="module")
def server(tmp_path_factory, checkpoints):
    srv = start_server(tmp_path_factory.mktemp("paper_server"), "--follower", str(checkpoints["follower"]),
                       "--leaders", "astar", "--leaders", str(checkpoints["leader"]), "--max-sessions", "4",
                       "--new-games-per-minute", "200")
    yield srv
    stop_server(srv)


def play_page(server, browser) -> tuple:
    """The play page, and the list its script errors are gathered in."""
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url + "/")
    return page, errors


def start_turn_based(page) -> None:
    page.select_option("#mode", "turn")
    page.fill("#horizon", str(HORIZON))
    page.click("#start")
    expect(page.locator("#game")).to_be_visible()


def play_to_the_end(page) -> str:
    """Press a move at each step of a turn-based game of one person; the id of its saved replay."""
    board = page.locator("#board")
    for t in range(HORIZON):
        expect(board).to_have_attribute("data-step", str(t))
        page.keyboard.press(MOVES[t % 4])
    expect(page.locator("#over")).to_be_visible()
    expect(page.locator("#over-scores")).to_contain_text(f"after {HORIZON} steps")
    replay_id = page.locator("#replay-link").get_attribute("href").split("id=")[1]
    return replay_id


def saved(server, replay_id: str, steps: int = HORIZON):
    replay = load(server.replays_dir / f"{replay_id}.replay.json")
    assert verify(replay).ok and replay.num_steps == steps and replay.ended == "complete"
    return replay


def test_the_imported_paper_follower_plays_beside_a_person(server, browser, checkpoints):
    follower = str(checkpoints["follower"])
    page, errors = play_page(server, browser)
    expect(page.locator("#follower")).to_have_value(follower)  # the server's default follower
    expect(page.locator("#follower option:checked")).to_have_text("paper_follower.pt (imported from the paper's code)")
    expect(page.locator("#follower-description")).to_contain_text("paper_follower.md")  # its model card
    expect(page.locator("#leader-choice")).to_be_hidden()  # 1:1: you are the one leader
    start_turn_based(page)
    expect(page.locator("#follower-label")).to_contain_text("paper_follower.pt")
    replay = saved(server, play_to_the_end(page))
    assert replay.agents["leader"] == {"policy": "human"}
    played = replay.agents["follower"]
    assert played["checkpoint"] == follower and played["arch"] == "paper" and played["lstm"] is True
    assert len(replay.goal_probs["follower"]) == HORIZON  # its auxiliary head's belief, at every step
    assert set(replay.meta["deadline_misses"]) <= set(range(HORIZON))  # how often it keeps time: the bench
    speed = server.get("/api/health")[0]["policy_call_ms"][follower]  # timed at start-up, for max_sessions games
    assert speed["games"] == 4 and speed["one_game"] > 0 and speed["within_deadline"] in range(5)
    assert errors == []
    page.close()


def test_a_person_leads_beside_the_imported_paper_leader(server, browser, checkpoints):
    leader = str(checkpoints["leader"])
    page, errors = play_page(server, browser)
    page.select_option("#team", "2:1")
    expect(page.locator("#leader-choice")).to_be_visible()
    assert page.locator("#leader option").all_text_contents() == [
        "another person (a room)", "Scripted leader (A*)", "paper_leader.pt (imported from the paper's code)"]
    expect(page.locator("#start")).to_have_text("Create a room")  # another person: as before
    page.select_option("#leader", leader)
    expect(page.locator("#start")).to_have_text("Start")
    expect(page.locator("#follower-description")).to_contain_text("it sees the game as 1:1")
    start_turn_based(page)
    expect(page.locator("#agent-scores .agent")).to_have_count(3)  # L1 (you), L2 (the AI leader), F1
    expect(page.locator("#you")).to_have_text("L1")
    expect(page.locator("#agent-scores [data-agent='leader_1'] .who")).to_have_text("the AI leader")
    expect(page.locator("#leader-note")).to_contain_text("paper_leader.pt (imported from the paper's code)")
    replay = saved(server, play_to_the_end(page))  # one key, one step: nobody else to wait for
    assert replay.config.num_leaders == 2 and replay.meta["team"] == "2:1" and replay.meta["room"] is None
    assert replay.agents["leader_0"] == {"policy": "human"}
    played = replay.agents["leader_1"]
    assert played["checkpoint"] == leader and played["arch"] == "paper" and played["checkpoint_sha256"]
    assert played["view"] == {"team": "1:1", "agents": ["leader_1", "follower_0"]}
    assert replay.agents["follower_0"]["policy"] == "bayes-people"  # the paper follower plays 1:1 only
    assert {e["agent"] for e in replay.key_events} == {"leader_0"} and replay.meta["seats_left"] == []
    assert errors == []
    page.close()


@pytest.mark.parametrize("request_fields, says", [
    ({"team": "2:1"}, "or one person plays beside an AI leader (leader: one of ['astar', "),
    ({"team": "2:1", "leader": "person"}, "AI leader 'person' is not offered; choose one of ['astar', "),
    ({"team": "1:1", "leader": "astar"}, "team 1:1 has one leader, you"),
])
def test_an_ai_leader_that_cannot_play_is_refused_in_one_line(server, request_fields, says):
    client = Client(server)
    welcome, _ = client.new_game(mode="turn", **request_fields)
    assert welcome["type"] == "error" and welcome["code"] == "rejected" and says in welcome["message"], welcome
    assert "\n" not in welcome["message"]
    client.close()


def test_settings_refuse_a_follower_or_an_unknown_name_as_a_leader_in_one_line():
    for bad in ("bayes", "astra"):
        with pytest.raises(ValueError) as refused:
            ServerSettings(leaders=("astar", bad))
        message = str(refused.value)
        assert message.startswith("leaders must be a scripted leader (astar, idle, person, random)")
        assert message.endswith(f"got {bad!r}") and "\n" not in message
    with pytest.raises(ValueError, match="leaders must be a tuple of leader names"):
        ServerSettings(leaders=("",))
    assert ServerSettings(leaders=("person:slip=0.1", "ippo-leader", "runs/x/leader.pt:temperature=0")).leaders


def test_the_paper_leader_plays_a_real_time_game_on_the_servers_clock(server, checkpoints):
    """The paper leader beside a person, on the server's clock: the game runs to its end and is saved; a step
    whose network missed its deadline is recorded as such (how often that happens on a machine is measured by
    ``bench/bench_paper_play.py``, not asserted here)."""
    client = Client(server)
    welcome, _ = client.new_game(mode="realtime", horizon=10, team="2:1", leader=str(checkpoints["leader"]))
    assert welcome["leaders"] == {"leader_1": str(checkpoints["leader"])} and welcome["tick_hz"] == 5
    assert [s["agent"] for s in welcome["seats"]] == ["leader_0"]  # the person's seat only
    over = client.recv("game_over", timeout=60)
    replay = saved(server, over["replay_id"], steps=10)
    assert set(replay.meta["deadline_misses"]) <= set(range(10))
    assert replay.agents["leader_1"]["checkpoint"] == str(checkpoints["leader"])
    client.close()


def test_a_checkpoint_that_holds_no_leader_is_not_offered_as_one(tmp_path, checkpoints, caplog):
    """The paper follower named as an AI leader: loading it at start-up says why in one line, and the team offers
    the others."""
    follower = str(checkpoints["follower"])

    async def scenario():
        hub = GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", followers=("copy",),
                                     leaders=("astar", follower)))
        hub.start()
        while not hub.ready:
            await asyncio.sleep(0.05)
        await hub.stop()
        return hub.team_leaders(Team.TWO_PEOPLE)

    with caplog.at_level(logging.ERROR, logger="colorgrid.server"):
        assert run(scenario) == {"astar": "direct"}
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    # an AI leader leads in 2:1 (people follow) and in 1:1 (a person in the follower seat): refused in both, once each
    assert sorted(said) == [f"AI leader {follower} is not offered in team {team}: {follower} holds no trained leader "
                            "(it has: ['follower'])" for team in ("1:1", "2:1")]
