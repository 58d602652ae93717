"""The Gymnasium views: Gymnasium's own checks, and the batched view equal to Gymnasium's vectorisation of the
single one."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import colorgrid
from colorgrid.gym_env import SeatEnv, SeatVectorEnv


@pytest.mark.parametrize("seat, partners, flatten", [
    ("follower", "astar", False),
    ("follower", "population:people#training", True),
    ("leader", None, False),
])
def test_the_seat_env_passes_gymnasiums_checker(seat, partners, flatten):
    env = gymnasium.make(colorgrid.GYM_ID, seat=seat, partners=partners, flatten=flatten, render_mode="rgb_array")
    check_env(env.unwrapped)
    obs, info = env.reset(seed=5)
    assert env.observation_space.contains(obs)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3


def test_a_larger_team_seat_sees_its_own_cell_as_the_last_plane():
    env = colorgrid.gym_env(seat="follower_1", num_leaders=1, num_followers=2)
    check_env(env)
    obs, _ = env.reset(seed=0)
    C = env.config.num_colors
    own = env.config.agent_names.index("follower_1")
    assert np.array_equal(obs["observation"][-1], obs["observation"][C + own])


def test_the_flat_observation_is_the_planes_then_the_goal():
    flat = colorgrid.gym_env(seat="leader", flatten=True)
    nested = colorgrid.gym_env(seat="leader")
    a, _ = flat.reset(seed=11)
    b, _ = nested.reset(seed=11)
    assert a.dtype == np.float32 and flat.observation_space.contains(a)
    assert np.array_equal(a, np.concatenate([b["observation"].reshape(-1), b["goal_info"]]).astype(np.float32))
    assert b["goal_info"].sum() == 1  # the leader knows the goal


def test_the_follower_does_not_see_the_goal_in_the_asymmetric_setting():
    env = colorgrid.gym_env(seat="follower")
    obs, info = env.reset(seed=2)
    assert obs["goal_info"].sum() == 0
    assert 0 <= info["goal_color"] < env.config.num_colors


@pytest.mark.parametrize("seat, partners", [("follower", "astar"), ("leader", "oracle")])  # partners that never wander at random
def test_the_vector_env_equals_gymnasiums_vectorisation_of_the_single_env(seat, partners):
    """Step for step, over a whole episode and the step that ends it: observations, rewards, ends, infos and
    the final observations of Gymnasium's SAME_STEP autoreset."""
    n, horizon = 3, 24
    ours = colorgrid.gym_vector_env(n, seat=seat, partners=partners, horizon=horizon)
    theirs = SyncVectorEnv([lambda: SeatEnv(seat, partners, horizon=horizon) for _ in range(n)],
                           autoreset_mode=AutoresetMode.SAME_STEP)
    assert ours.metadata["autoreset_mode"] == theirs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert ours.single_observation_space == theirs.single_observation_space
    a, _ = ours.reset(seed=100)
    b, _ = theirs.reset(seed=100)
    rng = np.random.default_rng(0)
    for t in range(horizon):
        actions = rng.integers(0, ours.single_action_space.n, n)
        for obs in (a, b):
            assert ours.observation_space.contains(obs)
        a_out, b_out = ours.step(actions), theirs.step(actions)
        for x, y in zip(a_out[:4], b_out[:4]):
            assert np.array_equal(x["observation"], y["observation"]) if isinstance(x, dict) else np.array_equal(x, y)
        a, b = a_out[0], b_out[0]
        a_info, b_info = a_out[4], b_out[4]
        last_step = b_info.get("final_info", b_info)  # Gymnasium keeps an ended episode's step infos there
        for key in ("block_reward", "goal_pickup", "wrong_pickup", "goal_color"):
            assert np.array_equal(a_info[key], last_step[key]), (t, key)
    assert a_out[3].all() and b_out[3].all()  # the horizon truncated every env
    assert a_info["_final_obs"].all() and b_info["_final_obs"].all()
    for x, y in zip(a_info["final_obs"], b_info["final_obs"]):
        assert np.array_equal(x["observation"], y["observation"]) and np.array_equal(x["goal_info"], y["goal_info"])
    for key in ("episode_block_reward", "episode_goal_pickups", "episode_wrong_pickups"):
        assert np.array_equal(a_info["final_info"][key], b_info["final_info"][key]), key
    # the next episodes too: an unseeded reset starts what autoreset starts
    for _ in range(3):
        actions = rng.integers(0, ours.single_action_space.n, n)
        assert np.array_equal(ours.step(actions)[0]["observation"], theirs.step(actions)[0]["observation"])


def test_the_vector_env_starts_new_episodes_in_the_step_that_ends_one():
    env = colorgrid.gym_vector_env(2, horizon=5)
    env.reset(seed=0)
    for _ in range(4):
        _, _, _, truncs, infos = env.step(np.zeros(2, dtype=np.int64))
        assert not truncs.any() and "final_obs" not in infos
    obs, _, _, truncs, infos = env.step(np.zeros(2, dtype=np.int64))
    assert truncs.all() and infos["_final_obs"].all()
    assert "episode_wrong_pickups" in infos["final_info"]
    _, _, _, truncs, _ = env.step(np.zeros(2, dtype=np.int64))  # the next episode goes on
    assert not truncs.any()


def test_seeded_resets_repeat_and_unseeded_ones_follow_the_seed():
    def episode_starts(env):
        first, _ = env.reset(seed=9)
        second, _ = env.reset()
        return first["observation"], second["observation"]

    a, b = episode_starts(colorgrid.gym_vector_env(2)), episode_starts(colorgrid.gym_vector_env(2))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], a[1])


@pytest.mark.parametrize("kwargs, message", [
    ({"seat": "assistant"}, "seat 'assistant' is not an agent of this team; choose one of"),
    ({"partners": {"follower": "astar"}}, r"partners: \['follower'\] are not other agents"),
    ({"partners": "no-such-policy"}, "unknown policy 'no-such-policy'"),
    ({"render_mode": "human"}, "render_mode must be one of"),
])
def test_bad_arguments_get_one_line_saying_what_is_allowed(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        colorgrid.gym_env(**kwargs)
    assert "\n" not in str(err.value)


def test_a_wrong_number_of_actions_is_refused():
    env = colorgrid.gym_vector_env(3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="expected 3 actions"):
        env.step(np.zeros(2, dtype=np.int64))
