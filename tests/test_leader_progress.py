"""The belief core's leader-progress input: what it reads on hand-built boards, and the warm start that adds it."""

from __future__ import annotations

import numpy as np
import pytest

from colorgrid.config import EnvConfig
from colorgrid.env import ACTION_DELTAS
from colorgrid.policies import make_policy
from colorgrid.policies.base import AgentInput
from colorgrid.rollout import run_episodes
from train.config import NetConfig, TrainConfigError
from train.inputs import leader_progress, step_tensors
from train.nets import extra_size, with_leader_progress
from train.policy import NetPolicy

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3


def board(config: EnvConfig, blocks: dict, agents: list, prev_actions: list) -> AgentInput:
    """One env: ``blocks`` {(row, col): color}, ``agents`` their cells in index order, their last actions."""
    C, H, W = config.num_colors, config.height, config.width
    obs = np.zeros((1, C + config.num_agents, H, W), dtype=np.uint8)
    for (r, c), color in blocks.items():
        obs[0, color, r, c] = 1
    for i, (r, c) in enumerate(agents):
        obs[0, C + i, r, c] = 1
    A = config.num_agents
    return AgentInput(obs, np.zeros((1, C), np.float32), np.zeros(1, bool), np.zeros(1, np.float32),
                      np.full((1, A), -1), np.array([prev_actions]))


def test_a_leader_stepping_towards_a_color_reads_plus_one_for_it_and_minus_one_for_the_color_behind():
    assert tuple(ACTION_DELTAS[RIGHT]) == (0, 1) and tuple(ACTION_DELTAS[UP]) == (-1, 0)
    config = EnvConfig()
    # the leader moved right from (10, 10) to (10, 11): red (0) lies ahead, green (1) behind, and blue (2) above
    # it at (3, 10) and (3, 11), 7 steps away before and after
    inp = board(config, {(10, 20): 0, (10, 2): 1, (3, 10): 2, (3, 11): 2}, [(10, 11), (30, 30)], [RIGHT, LEFT])
    assert leader_progress(inp, config).tolist() == [[1.0, -1.0, 0.0]]


def test_no_move_no_evidence_and_a_missing_color_reads_zero():
    config = EnvConfig()
    blocks = {(10, 20): 0, (10, 2): 1}  # no blue block on the board
    assert leader_progress(board(config, blocks, [(10, 11), (30, 30)], [-1, -1]), config).tolist() == [[0, 0, 0]]
    # "up" on the bottom row would have come from outside the grid: another agent above blocked it
    assert leader_progress(board(config, blocks, [(31, 11), (30, 11)], [UP, LEFT]), config).tolist() == [[0, 0, 0]]
    moved = leader_progress(board(config, blocks, [(10, 11), (30, 30)], [RIGHT, LEFT]), config)
    assert moved.tolist() == [[1, -1, 0]]


def test_each_leader_of_a_team_has_its_own_values_and_followers_none():
    config = EnvConfig(num_leaders=2, num_followers=1)
    # leader 0 moved right (nearer red, farther from green and from blue); leader 1 moved down, onto blue's row
    inp = board(config, {(10, 20): 0, (10, 2): 1, (20, 5): 2}, [(10, 11), (19, 5), (30, 30)], [RIGHT, DOWN, UP])
    assert leader_progress(inp, config).tolist() == [[1, -1, -1, -1, -1, 1]]


def test_the_values_end_the_extras_only_when_asked():
    config = EnvConfig()
    inp = board(config, {(10, 20): 0}, [(10, 11), (30, 30)], [RIGHT, LEFT])
    plain = step_tensors(inp, config, 1, "cpu")["extras"]
    wide = step_tensors(inp, config, 1, "cpu", progress=True)["extras"]
    assert plain.shape[-1] == extra_size(config) and wide.shape[-1] == extra_size(config) + 3
    assert (wide[..., :extra_size(config)] == plain).all() and wide[0, 0, -3:].tolist() == [1, 0, 0]


def test_adding_the_input_to_a_trained_network_changes_nothing_until_it_learns():
    """``with_leader_progress`` (the trainer's warm start for ``net.leader_progress``) plays the same actions and
    beliefs as the network it widens, episode for episode."""
    trained = make_policy("ippo-people", "follower")
    wider = NetPolicy(with_leader_progress(trained.model), name="wider")
    assert wider.model.net.leader_progress and wider.model.lstm.input_size == trained.model.lstm.input_size + 3
    config = EnvConfig(horizon=40)
    a = run_episodes(config, make_policy("person:slip=0.2", "leader"), trained, 6, 0)
    b = run_episodes(config, make_policy("person:slip=0.2", "leader"), wider, 6, 0)
    assert (a.actions == b.actions).all() and np.array_equal(a.goal_probs[1], b.goal_probs[1])


def test_the_input_belongs_to_a_belief_core_and_not_to_a_cloned_leader():
    from colorgrid.configkit import ConfigError
    from train.bc import bc_config

    with pytest.raises(TrainConfigError, match="leader_progress"):
        NetConfig(leader_progress=True)
    NetConfig(goal_fusion="planes", lstm=True, extra_inputs=True, belief_input=True, leader_progress=True)
    core = ["net.belief_input=true", "net.lstm=true", "net.extra_inputs=true"]
    with pytest.raises(ConfigError, match="a follower's input"):
        bc_config({}, ["net.leader_progress=true", *core])
