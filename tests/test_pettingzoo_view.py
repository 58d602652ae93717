"""The PettingZoo view's flat observations (``flatten=True``) and its infos: the same keys at reset and every step."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from colorgrid import env, gym_env, parallel_env

STEP_INFO = {"block_reward": float, "team_reward": float, "goal_pickup": bool, "wrong_pickup": bool,
             "distance_shaping": float, "potential_shaping": float, "goal_color": int, "goal_switched": bool,
             "seed": int}


@pytest.mark.parametrize("teams", [{}, {"num_leaders": 2, "num_followers": 3}])
def test_the_flat_view_passes_the_api_test_and_holds_the_planes_then_the_goal(teams):
    flat, nested = parallel_env(flatten=True, **teams), parallel_env(**teams)
    parallel_api_test(flat, num_cycles=100)
    obs, _ = flat.reset(seed=4)
    expected, _ = nested.reset(seed=4)
    for agent in flat.possible_agents:
        space = flat.observation_space(agent)
        planes, goal = expected[agent]["observation"], expected[agent]["goal_info"]
        assert space.dtype == np.float32 and space.shape == (planes.size + goal.size,)
        assert obs[agent].dtype == np.float32 and space.contains(obs[agent])
        assert np.array_equal(obs[agent], np.concatenate([planes.reshape(-1), goal])), agent
        assert obs[agent].sum() == planes.sum() + goal.sum() > 0


def test_the_flat_view_is_the_gymnasium_seats_flat_layout():
    obs, _ = parallel_env(flatten=True, num_leaders=2, num_followers=2).reset(seed=9)
    for seat in ("leader_1", "follower_0"):
        seat_obs, _ = gym_env(seat=seat, flatten=True, num_leaders=2, num_followers=2).reset(seed=9)
        assert np.array_equal(obs[seat], seat_obs), seat


def test_reset_and_step_infos_have_the_same_keys_and_types_and_reset_ones_are_neutral():
    e = parallel_env(horizon=4)
    _, reset_infos = e.reset(seed=3)
    seed, goal = int(e.batch.state.seed[0]), int(e.batch.state.goal[0])
    for agent, info in reset_infos.items():
        assert {k: type(v) for k, v in info.items()} == STEP_INFO, agent
        assert info == {"block_reward": 0.0, "team_reward": 0.0, "goal_pickup": False, "wrong_pickup": False,
                        "distance_shaping": 0.0, "potential_shaping": 0.0, "goal_color": goal,
                        "goal_switched": False, "seed": seed}
    while e.agents:
        *_, infos = e.step({a: e.action_space(a).sample() for a in e.agents})
        for agent, info in infos.items():
            assert {k: type(v) for k, v in info.items()} == STEP_INFO, agent
            assert info["seed"] == seed and info["goal_color"] == int(e.batch.state.goal[0])


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_a_flatten_that_is_not_a_bool_is_refused_in_one_line(value):
    for make in (parallel_env, env):
        with pytest.raises(ValueError) as refused:
            make(flatten=value)
        assert str(refused.value) == f"flatten must be True (one float32 Box) or False (the Dict), got {value!r}"
