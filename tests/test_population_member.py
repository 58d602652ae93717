"""A population leader's replay names the member that led: the policy says which member played each batch row, and a
play server's game records it under ``agents[name].member`` (through its inference process), for the member that
really moved."""

import json

import numpy as np
import pytest

from colorgrid.config import LEADER, EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies import make_policy
from colorgrid.replay import load, verify
from colorgrid.step_inputs import StepInputs
from tests.conftest import start_server, stop_server
from tests.test_server import Client

MEMBERS = {"straight": "astar", "slipping": "person:slip=1.0"}
"""A* walks a shortest path; the other replaces every move by a random one: their moves tell them apart."""


@pytest.fixture(scope="module")
def population(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("population") / "two.json"
    path.write_text(json.dumps({"training": {}, "held_out": MEMBERS}))
    return str(path)


def astar_moves(config: EnvConfig, seed: int, actions: list[list[int]]) -> list[int]:
    """What A* would have done at each step of a recorded game (the recorded moves are the ones made)."""
    env = BatchEnv(config, num_envs=1, seed=seed, autoreset=False)
    obs, _ = env.reset()
    astar = make_policy("astar", role="leader")
    astar.reset(config, 1, LEADER, seed=seed)
    last, out = StepInputs.begin(config, 1), []
    for joint in actions:
        out.append(int(astar.act(last.agent_input(obs, LEADER, env.penalty_coef, env.state.goal.copy())).actions[0]))
        obs, _, _, _, info = env.step(np.array([joint]))
        last.record(np.array([joint]), info)
    return out


def test_a_population_names_the_member_of_each_row_the_one_whose_moves_it_made(population):
    config = EnvConfig(horizon=12)
    env = BatchEnv(config, num_envs=8, seed=3, autoreset=False)
    obs, _ = env.reset()
    leader = make_policy(population, role="leader")
    leader.reset(config, 8, LEADER, seed=3)
    astar = make_policy("astar", role="leader")
    astar.reset(config, 8, LEADER, seed=3)
    last = StepInputs.begin(config, 8)
    same = np.ones(8, dtype=bool)
    for _ in range(config.horizon):
        inp = last.agent_input(obs, LEADER, env.penalty_coef, env.state.goal.copy())
        moves = leader.act(inp).actions
        same &= moves == astar.act(inp).actions
        joint = np.stack([moves, np.zeros(8, dtype=np.int64)], axis=1)  # the follower walks up
        obs, _, _, _, info = env.step(joint)
        last.record(joint, info)
    named = [leader.describe_row(row)["member"] for row in range(8)]
    assert set(named) == set(MEMBERS), named  # the seed draws both
    assert [name == "straight" for name in named] == same.tolist()
    assert leader.describe_row(0)["members"] == leader.describe()["members"]
    assert "member" not in astar.describe_row(0)  # a policy of one part names none


def test_a_play_servers_replay_names_the_member_that_led_each_game(population, tmp_path):
    server = start_server(tmp_path, "--leaders", population, "--max-sessions", "2")
    try:
        named = []
        for _ in range(6):
            client = Client(server)
            welcome, _ = client.new_game(seat="follower", mode="turn", horizon=8, leader=population)
            assert welcome["type"] == "welcome", welcome
            for _ in range(8):
                client.key("ArrowUp")
            over = client.recv("game_over")
            client.close()
            replay = load(server.replays_dir / f"{over['replay_id']}.replay.json")
            assert verify(replay).ok
            entry = replay.agents["leader"]
            assert entry["policy"] == "population" and set(entry["members"]) == set(MEMBERS)
            moved_as_astar = [a[0] for a in replay.actions] == astar_moves(replay.config, replay.seed, replay.actions)
            assert (entry["member"] == "straight") == moved_as_astar, (entry["member"], replay.actions)
            named.append(entry["member"])
        assert set(named) <= set(MEMBERS)
    finally:
        stop_server(server)
