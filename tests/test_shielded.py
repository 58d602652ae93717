"""The shielded follower (``colorgrid/policies/shielded.py``): a trained network's moves, kept off the blocks a
Bayesian follower's belief doubts; and the one resolver of composite names (``inner_policies``) that what a
composite plays, reads and says of itself follows."""

from __future__ import annotations

import numpy as np
import pytest

from colorgrid.config import FOLLOWER, EnvConfig
from colorgrid.policies import inner_policies, make_policy, policy_card, policy_files, policy_teams
from colorgrid.policies.base import AgentInput
from colorgrid.replay import describe_agent
from colorgrid.rollout import run_episodes
from server.followers import is_scripted

CONFIG = EnvConfig()
SHIELD = "shielded:mover=ippo-people,reader=bayes-people,min_belief={}"


def boxed_board(batch: int) -> tuple[EnvConfig, AgentInput]:
    """The follower at (16, 16) of an otherwise empty board with a block of each color above, below and to the left
    and nothing to the right (actions: up, down, left, right); the first step of an episode, so a Bayesian reader's
    belief is uniform."""
    config = CONFIG
    obs = np.zeros((batch, config.num_colors + config.num_agents, config.height, config.width), dtype=np.uint8)
    obs[:, 0, 15, 16] = obs[:, 1, 17, 16] = obs[:, 2, 16, 15] = 1
    obs[:, config.num_colors + 0, 0, 0] = 1
    obs[:, config.num_colors + FOLLOWER, 16, 16] = 1
    inp = AgentInput(observation=obs, goal_info=np.zeros((batch, config.num_colors), dtype=np.float32),
                     episode_start=np.ones(batch, dtype=bool), prev_reward=np.zeros(batch, dtype=np.float32),
                     prev_picked_color=np.full((batch, config.num_agents), -1, dtype=np.int64),
                     prev_actions=np.full((batch, config.num_agents), -1, dtype=np.int64))
    return config, inp


def first_actions(min_belief: float, batch: int = 256) -> np.ndarray:
    config, inp = boxed_board(batch)
    policy = make_policy(SHIELD.format(min_belief), "follower")
    policy.reset(config, batch, FOLLOWER, seed=0)
    out = policy.act(inp)
    assert np.allclose(out.goal_probs, 1 / 3)  # the reader's belief at an episode's start, and the shield's
    return out.actions


def test_a_block_the_readers_belief_doubts_is_never_stepped_onto():
    """With a uniform belief (1/3 each) and min_belief 0.5 every block is doubted: of 256 sampled first moves none
    is onto a block, all go right. At 0.3 nothing is doubted and the network's own sampling goes onto blocks too."""
    assert set(first_actions(0.5).tolist()) == {3}
    assert set(first_actions(0.3).tolist()) - {3}


def test_boxed_in_by_doubted_blocks_it_still_moves():
    """Every move onto a doubted block: none is taken out (the follower must go somewhere)."""
    config, inp = boxed_board(64)
    inp.observation[:, 0, 16, 17] = 1
    policy = make_policy(SHIELD.format(0.5), "follower")
    policy.reset(config, 64, FOLLOWER, seed=0)
    assert len(set(policy.act(inp).actions.tolist()) & {0, 1, 2, 3}) > 1


def test_at_min_belief_zero_it_moves_as_its_mover_and_believes_as_its_reader():
    """Nothing is taken out at 0: the same episodes give the mover's own actions and the reader's own belief."""
    leader = lambda: make_policy("astar", "leader")  # noqa: E731
    shielded = run_episodes(CONFIG, leader(), make_policy(SHIELD.format(0), "follower"), 6, 11)
    mover = run_episodes(CONFIG, leader(), make_policy("ippo-people", "follower"), 6, 11)
    assert (shielded.actions == mover.actions).all()
    reader = make_policy("bayes-people", "follower")
    reader.reset(CONFIG, 6, FOLLOWER, seed=11)
    first = reader.act(run_inputs(CONFIG, 6, 11))
    assert np.allclose(shielded.goal_probs[FOLLOWER][0], first.goal_probs)


def run_inputs(config: EnvConfig, batch: int, seed: int) -> AgentInput:
    """The follower's input at the first step of ``run_episodes``'s episodes with ``seed``."""
    from colorgrid.env import BatchEnv
    from colorgrid.step_inputs import StepInputs

    env = BatchEnv(config, num_envs=batch, seed=seed)
    obs, _ = env.reset()
    return StepInputs.begin(config, batch).agent_input(obs, FOLLOWER, env.penalty_coef, env.state.goal.copy())


def test_a_shield_takes_wrong_pickups_away_beside_astar():
    """Beside A* on the same episodes, a strict shield (0.9) makes fewer wrong pickups than its mover alone."""
    def wrong(follower: str) -> int:
        batch = run_episodes(CONFIG, make_policy("astar", "leader"), make_policy(follower, "follower"), 8, 3)
        return int(batch.wrong_pickup[:, :, FOLLOWER].sum())

    assert wrong(SHIELD.format(0.9)) < wrong("ippo-people")


def test_its_description_names_both_parts_and_replays_pin_the_movers_weights():
    described = describe_agent(make_policy(SHIELD.format(0.8), "follower").describe())
    assert described["policy"] == "shielded" and described["params"] == {"min_belief": 0.8}
    assert described["mover"]["policy"] == "ippo-people" and len(described["mover"]["checkpoint_sha256"]) == 64
    assert described["reader"]["policy"] == "bayes-people"


def test_what_a_composite_plays_reads_and_says_comes_from_its_parts(tmp_path):
    name = SHIELD.format(0.8)
    assert inner_policies(name) == {"mover": "ippo-people", "reader": "bayes-people"}
    assert inner_policies("person:base=ippo-leader,slip=0.1") == {"base": "ippo-leader"}
    assert inner_policies("person:slip=0.1") == inner_policies("bayes-people") == inner_policies("ippo") == {}
    assert policy_teams(name) == ("1:1",) and policy_teams("shielded:mover=ippo-1L2F,reader=bayes") == ("1:2",)
    assert not is_scripted(name) and is_scripted("person:slip=0.1")
    card = policy_card(name)
    assert card.belief and card.follow.label == "Shielded assistant" and card.lead is None
    assert "Trained assistant for people (IPPO)" in card.follow.description
    checkpoint = tmp_path / "x.pt"
    assert policy_files(f"shielded:mover={checkpoint},reader=bayes") == [str(checkpoint)]


@pytest.mark.parametrize("name, words", [
    ("shielded", "needs a mover and a reader"),
    ("shielded:mover=bayes", "mover 'bayes' cannot be kept off moves; a trained network can"),
    ("shielded:mover=ippo,reader=copy", "reader 'copy' forms no belief over the goal"),
    ("shielded:mover=ippo,min_belief=2", "min_belief=2 is invalid: a number in [0, 1]"),
    ("shielded:mover=nothing", "mover 'nothing': unknown policy 'nothing'"),
    ("shielded:mover=shielded", "a policy name other than a shielded follower"),
    ("shielded:mover=ippo,speed=3", "unknown parameter(s) ['speed']"),
    ("shielded:mover=ippo,reader=(bayes:rationality=3,lapse=0.05", "unbalanced brackets"),
    ("shielded:mover=ippo,reader=bayes:rationality=3,lapse=0.05", "unknown parameter(s) ['lapse']"),
])
def test_a_wrong_shield_is_refused_in_one_line(name, words):
    with pytest.raises(ValueError) as err:
        make_policy(name, "follower")
    assert words in str(err.value) and "\n" not in str(err.value)


def test_the_shipped_follower_replays_a_cell_of_its_declared_claims():
    """The kept episodes the claims were decided on are what the follower plays: beside one held-out leader, the
    whole cell (200 episodes from seed 10000, played at once as the measure played them), both followers."""
    import json
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "bench"))
    from beside_people import cell

    kept = json.loads((root / "docs" / "reproduction" / "shielded" / "measure.json").read_text())
    spec = "shielded:mover=ippo-people,reader=bayes-people,min_belief=0.8"
    for follower in ("bayes-people", spec):
        got = cell(kept["leaders"]["late_8"], follower, kept["episodes"], kept["seed"])
        assert got["net"] == kept["cells"]["late_8"][follower]["net"], follower
        assert got["wrong"] == kept["cells"]["late_8"][follower]["wrong"], follower


def test_ippo_shielded_is_the_shipped_shield_and_the_play_servers_default():
    from server.settings import ServerSettings

    policy = make_policy("ippo-shielded", "follower")
    assert policy.describe()["policy"] == "ippo-shielded" and policy.params.min_belief == 0.8
    assert policy.describe()["mover"]["policy"] == "ippo-people"
    assert ServerSettings().follower == "ippo-shielded" and policy_card("ippo-shielded").menu == 5


def test_where_stay_exists_a_boxed_in_shield_stays_rather_than_step_onto_a_doubted_block():
    """Real-time play gives the follower ``stay``, which its network never learned: boxed in by doubted blocks, it
    stays; and rows given as a subset (as the play server gives them) are kept off the same moves."""
    import dataclasses

    config, inp = boxed_board(64)
    inp.observation[:, 0, 16, 17] = 1
    staying = dataclasses.replace(config, allow_stay=True)
    policy = make_policy(SHIELD.format(0.5), "follower")
    policy.reset(staying, 64, FOLLOWER, seed=0)
    assert set(policy.act(inp).actions.tolist()) == {4}
    _, free_right = boxed_board(64)
    policy.reset(config, 64, FOLLOWER, seed=0)
    rows = np.arange(0, 64, 3)
    assert set(policy.act(free_right.select(rows), rows).actions.tolist()) == {3}


def test_two_masks_are_lifted_last_first():
    """The caller's mask (a shield's) outlasts the network's own: where both together leave no move, the second goes
    first; where the first alone leaves none, nothing is taken out."""
    from colorgrid.policies.grid import kept_off

    first = np.array([[1, 1, 0, 0], [1, 1, 1, 1], [1, 1, 0, 0]], dtype=bool)
    second = np.array([[0, 0, 1, 0], [0, 0, 0, 0], [0, 0, 1, 1]], dtype=bool)
    assert kept_off(first, second).astype(int).tolist() == [[1, 1, 1, 0], [0, 0, 0, 0], [1, 1, 0, 0]]
    assert kept_off(None, None) is None and (kept_off(None, second) == second).all()


def test_a_shield_around_a_yardstick_is_one_and_no_shield_holds_another():
    from server.settings import ServerSettings

    name = "shielded:mover=ippo-people,reader=bayes-limit"
    assert policy_card(name).yardstick == policy_card("bayes-limit").yardstick is not None
    with pytest.raises(ValueError, match="yardstick"):
        ServerSettings(follower=name)
    for inner in ("mover=ippo-people,reader=ippo-shielded", "mover=ippo-shielded"):
        with pytest.raises(ValueError, match="is a shielded follower itself"):
            make_policy(f"shielded:{inner}", "follower")


def test_a_part_with_parameters_of_its_own_is_given_whole_in_parentheses():
    """``reader=(bayes:rationality=3,lapse=0.05)``: the reader gets both of its parameters, the shield its own."""
    name = "shielded:mover=ippo-people,reader=(bayes:rationality=3,lapse=0.05),min_belief=0.7"
    assert inner_policies(name) == {"mover": "ippo-people", "reader": "bayes:rationality=3,lapse=0.05"}
    policy = make_policy(name, "follower")
    assert policy.params.min_belief == 0.7
    described = describe_agent(policy.describe())
    assert described["reader"]["params"]["rationality"] == 3 and described["reader"]["params"]["lapse"] == 0.05
    assert policy_teams(name) == ("1:1",) and policy_files(name) == policy_files("ippo-people")


def test_a_person_whose_base_is_a_population_part_is_a_person():
    from colorgrid.policies.names import PolicyKind, is_population, read_name

    name = "person:base=(populations/people.json#training),slip=0.1"
    assert not is_population(name) and read_name(name).kind is PolicyKind.SCRIPTED
    assert is_population("populations/people.json#training") and is_population("population:people#held_out")
