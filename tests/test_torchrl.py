"""TorchRL on ColorGrid's views, as docs/ECOSYSTEM.md shows them: its ``PettingZooWrapper`` on the PettingZoo view
(the Dict and the flat observation) and its ``GymWrapper`` on a seat, checked by TorchRL's own ``check_env_specs``
and rollouts with TorchRL's random policy."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch", reason="the train extra (make test installs it)")
pytest.importorskip("torchrl", reason="the examples extra (make test installs it)")

from torchrl.envs import GymWrapper, PettingZooWrapper  # noqa: E402
from torchrl.envs.utils import MarlGroupMapType, check_env_specs  # noqa: E402

import colorgrid  # noqa: E402
from tests.documented import documented_code  # noqa: E402

INFO_KEYS = {"block_reward", "team_reward", "goal_pickup", "wrong_pickup", "distance_shaping", "potential_shaping",
             "goal_color", "goal_switched", "seed"}
GROUPS = ("leader", "follower")


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
    (code,) = documented_code("docs/ECOSYSTEM.md", "tests/test_torchrl.py")
    namespace: dict = {}
    torch.manual_seed(0)
    exec(compile(code, "docs/ECOSYSTEM.md", "exec"), namespace)
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
