"""TorchRL on ColorGrid's views, as docs/ECOSYSTEM.md shows them: its ``PettingZooWrapper`` on the PettingZoo view
(the Dict and the flat observation) and its ``GymWrapper`` on a seat, checked by TorchRL's own ``check_env_specs``
and rollouts with TorchRL's random policy; the documented forms of its multi-agent tutorial, with the default
groups (``RewardSum`` over every group's reward, a policy per group, TorchRL's ``Collector``) and with one group."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import GymWrapper, PettingZooWrapper
from torchrl.envs.utils import MarlGroupMapType, check_env_specs

import colorgrid
from tests.documented import documented_code

INFO_KEYS = {"block_reward", "team_reward", "goal_pickup", "wrong_pickup", "distance_shaping", "potential_shaping",
             "goal_color", "goal_switched", "seed"}
GROUPS = ("leader", "follower")
WRAPPER, DEFAULT_GROUPS, ONE_GROUP = documented_code("docs/ECOSYSTEM.md", "tests/test_torchrl.py")


def run_documented(code: str, seed: int) -> dict:
    """The namespace a documented block leaves, run as it stands with TorchRL's random numbers seeded."""
    namespace: dict = {}
    torch.manual_seed(seed)
    exec(compile(code, "docs/ECOSYSTEM.md", "exec"), namespace)
    return namespace


def returns_are_running_sums_within_episodes(data, key: tuple) -> None:
    """``data["next", *key, "episode_reward"]`` is the running sum of ``data["next", *key, "reward"]`` over each
    episode that starts within ``data`` (after a step that ends one), starting again at each."""
    reward, returns = data["next", *key, "reward"], data["next", *key, "episode_reward"]
    ends = data["next", "done"].reshape(-1).nonzero().flatten().tolist()
    assert ends, "an episode ended within the data"
    for start, end in zip([e + 1 for e in ends], ends[1:] + [len(reward) - 1]):
        assert torch.equal(returns[start:end + 1], reward[start:end + 1].cumsum(0)), (start, end)


def blocks_collected_and_rewards_checked(data) -> int:
    """Check a 1:1 rollout's rewards against colorgrid's infos; returns how many blocks the agents collected.

    Every agent's reward is the team's (shared mode), which is the sum of the agents' block rewards, each
    ``goal_pickup - wrong_pickup`` (goal_reward = wrong_penalty = penalty_coef = 1)."""
    info = {group: data["next", group, "info"][:, 0] for group in GROUPS}
    team = info["leader"]["team_reward"]
    assert torch.equal(team, info["follower"]["team_reward"])
    assert torch.allclose(info["leader"]["block_reward"] + info["follower"]["block_reward"], team)
    for group in GROUPS:
        assert torch.equal(info[group]["block_reward"], info[group]["goal_pickup"] - info[group]["wrong_pickup"])
        assert torch.equal(data["next", group, "reward"][:, 0, 0], team), group
    return int(sum(info[g]["goal_pickup"].sum() + info[g]["wrong_pickup"].sum() for g in GROUPS))


def test_the_documented_pettingzoo_wrapper_rolls_out_across_episodes_with_colorgrids_rewards_and_infos():
    """The documented block: two and a half 16-step episodes in one rollout, TorchRL resetting in between."""
    namespace = run_documented(WRAPPER, seed=0)
    env, data = namespace["env"], namespace["data"]
    assert env.group_map == {"leader": ["leader"], "follower": ["follower"]}
    assert data.batch_size == (40,)
    for group in GROUPS:
        assert set(data["next", group, "info"].keys()) == INFO_KEYS
        assert data["next", group, "observation", "observation"].shape == (40, 1, 5, 32, 32)
        assert data["next", group, "observation", "goal_info"].shape == (40, 1, 3)
        assert data["next", group, "reward"].shape == (40, 1, 1)
        truncated = data["next", group, "truncated"][:, 0, 0]
        assert truncated.nonzero().flatten().tolist() == [15, 31], "the env's horizon ends each episode"
        first = data[group, "info"][[0, 16, 32]]  # each episode's reset infos, before its first step
        for key in ("block_reward", "team_reward", "goal_pickup", "wrong_pickup", "goal_switched"):
            assert (first[key] == 0).all(), key
        assert ((first["goal_color"] >= 0) & (first["goal_color"] < 3)).all()
    blocks_collected_and_rewards_checked(data)

    torch.manual_seed(0)  # TorchRL's random actions; the seeded reset lays out the board
    seeded = env.rollout(16, auto_reset=False, tensordict=env.reset(seed=0))
    assert seeded.batch_size == (16,)
    assert blocks_collected_and_rewards_checked(seeded) > 0, "a block was collected: the checks bite"


def test_the_documented_default_groups_sum_each_groups_rewards_and_collect_with_a_policy_per_group():
    namespace = run_documented(DEFAULT_GROUPS, seed=0)
    base, env, actors, data = namespace["base"], namespace["env"], namespace["actors"], namespace["data"]
    assert env.group_map == {"leader": ["leader"], "follower": ["follower"]}
    with pytest.raises(KeyError, match="more than one key present"):
        base.reward_key  # the tutorial's one reward key: why the block takes reward_keys
    leader_weights, follower_weights = ({id(p) for p in actors[g].parameters()} for g in GROUPS)
    assert leader_weights and not leader_weights & follower_weights, "a network per group"

    assert data.batch_size == (40,)  # the collector's second batch: steps 40 to 79, episodes ending at 47 and 63
    assert data["next", "done"].reshape(-1).nonzero().flatten().tolist() == [7, 23, 39]
    for group in GROUPS:
        assert data["next", group, "episode_reward"].shape == (40, 1, 1)
        assert (data[group, "action_log_prob"] <= 0).all()  # the policy's own actions, with their log-probabilities
        returns_are_running_sums_within_episodes(data, (group,))
    assert torch.equal(data["next", "leader", "episode_reward"], data["next", "follower", "episode_reward"])

    collected = 0
    for seed in range(4):  # seeded episodes of the documented policy: blocks are collected in some
        torch.manual_seed(0)
        episode = namespace["env"].rollout(16, namespace["policy"], auto_reset=False,
                                           tensordict=namespace["env"].reset(seed=seed))
        for group in GROUPS:
            rewards = episode["next", group, "reward"][:, 0, 0]
            assert torch.equal(episode["next", group, "episode_reward"][:, 0, 0], rewards.cumsum(0)), (seed, group)
        collected += int(rewards.abs().sum())
    assert collected > 0, "a block was collected: the running sums are not all zeros"


def test_the_documented_one_group_runs_the_tutorials_reward_key():
    namespace = run_documented(ONE_GROUP, seed=0)
    base, data = namespace["base"], namespace["data"]
    assert base.group_map == {"agents": ["leader", "follower"]} and base.reward_key == ("agents", "reward")
    returns = data["next", "agents", "episode_reward"]
    assert data.batch_size == (40,) and returns.shape == (40, 2, 1)
    assert torch.equal(returns[:, 0], returns[:, 1]), "the team's return, for both agents (shared mode)"
    assert data["next", "done"].reshape(-1).nonzero().flatten().tolist() == [15, 31]
    returns_are_running_sums_within_episodes(data, ("agents",))


def test_pettingzoo_wrapper_on_the_flat_view_of_a_team_in_one_group():
    torch.manual_seed(1)
    env = PettingZooWrapper(env=colorgrid.parallel_env(flatten=True, num_leaders=2, num_followers=2),
                            group_map=MarlGroupMapType.ALL_IN_ONE_GROUP)
    check_env_specs(env)
    data = env.rollout(8)
    obs = data["next", "agents", "observation"]
    assert obs.dtype == torch.float32 and obs.shape == (8, 4, (3 + 4 + 1) * 32 * 32 + 3)
    goal_info = obs[..., -3:]
    assert goal_info[:, :2].sum(dim=-1).eq(1).all() and goal_info[:, 2:].eq(0).all(), "only leaders see the goal"
    own_cell = obs[..., -3 - 32 * 32:-3]  # the last plane marks the observer's own cell
    assert own_cell.sum(dim=-1).eq(1).all()
    assert data["next", "agents", "reward"].shape == (8, 4, 1)


def test_gym_wrapper_on_a_seat():
    torch.manual_seed(2)
    env = GymWrapper(colorgrid.gym_env(seat="follower", partners="astar", flatten=True, horizon=16))
    check_env_specs(env)
    data = env.rollout(20, break_when_any_done=False)
    assert data["next", "observation"].shape == (20, 5 * 32 * 32 + 3)
    assert data["next", "truncated"][:, 0].nonzero().flatten().tolist() == [15]
