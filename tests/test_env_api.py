"""Determinism, batch-equals-single, the PettingZoo views and rendering."""

import re
from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest
from pettingzoo.test import max_cycles_test, parallel_api_test, render_test

import colorgrid
from colorgrid import BatchEnv, EnvConfig, env, parallel_env, render_ansi, render_rgb
from colorgrid.render import PALETTE


def run_trajectory(seed, steps, num_envs=4, config=EnvConfig(), action_seed=0):
    environment = BatchEnv(config, num_envs=num_envs, seed=seed)
    obs, _ = environment.reset()
    actions = np.random.default_rng(action_seed).integers(0, config.num_actions, (steps, num_envs, 2))
    trace = [obs["observation"].copy()]
    rewards = []
    for a in actions:
        obs, r, _, _, info = environment.step(a)
        trace.append(obs["observation"].copy())
        rewards.append(np.concatenate([r.ravel(), info["goal_color"].astype(np.float32)]))
    return np.stack(trace), np.stack(rewards)


def test_same_seed_same_trajectory_for_1000_steps_and_different_seeds_differ():
    obs_a, rew_a = run_trajectory(seed=7, steps=1000)
    obs_b, rew_b = run_trajectory(seed=7, steps=1000)
    assert np.array_equal(obs_a, obs_b) and np.array_equal(rew_a, rew_b)
    obs_c, _ = run_trajectory(seed=8, steps=1000)
    assert not np.array_equal(obs_a[0], obs_c[0])
    assert (obs_a != obs_c).any(axis=(1, 2, 3, 4)).all()


@pytest.mark.parametrize("config", [EnvConfig(), EnvConfig(hemispheres=True, switch_prob=0.1, allow_stay=True)])
def test_env_i_of_a_batch_equals_a_single_env_seeded_with_seed_plus_i(config):
    seed, steps, batch = 100, 300, 64  # 300 steps crosses two autoresets
    actions = np.random.default_rng(1).integers(0, config.num_actions, (steps, batch, 2))
    batched = BatchEnv(config, num_envs=batch, seed=seed)
    obs, _ = batched.reset()
    batch_obs, batch_rew = [obs["observation"].copy()], []
    for a in actions:
        obs, r, *_ = batched.step(a)
        batch_obs.append(obs["observation"].copy())
        batch_rew.append(r.copy())
    batch_obs, batch_rew = np.stack(batch_obs), np.stack(batch_rew)
    for i in range(batch):
        single = BatchEnv(config, num_envs=1, seed=seed + i)
        obs, _ = single.reset()
        assert np.array_equal(obs["observation"][0], batch_obs[0, i])
        for t in range(steps):
            obs, r, *_ = single.step(actions[t, i:i + 1])
            assert np.array_equal(r[0], batch_rew[t, i]), (i, t)
            assert np.array_equal(obs["observation"][0], batch_obs[t + 1, i]), (i, t)


def test_reset_without_seed_draws_a_fresh_seed():
    environment = BatchEnv(EnvConfig(), num_envs=2)
    environment.reset()
    first = environment.state.seed.copy()
    environment.reset()
    assert (environment.state.seed != first).all()
    seeded = BatchEnv(EnvConfig(), num_envs=2, seed=5)
    seeded.reset()
    assert seeded.state.seed.tolist() == [5, 6]


def test_bad_seeds_are_rejected():
    environment = BatchEnv(EnvConfig(), num_envs=2)
    with pytest.raises(ValueError, match=r"seed must be an int or a sequence of 2 ints"):
        environment.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match=r"seeds must be integers in \[0, 2\*\*63 - 1\]"):
        environment.reset(seed=-1)


def test_pettingzoo_parallel_api():
    parallel_api_test(parallel_env(), num_cycles=300)
    parallel_api_test(parallel_env(hemispheres=True, allow_stay=True, asymmetric=False), num_cycles=200)


def test_pettingzoo_render_modes_through_the_aec_conversion(capsys):
    render_test(env)
    assert "goal" in capsys.readouterr().out  # human mode prints the text view


def test_pettingzoos_max_cycles_test_ends_episodes_at_max_cycles():
    """PettingZoo's own test: ``env(max_cycles=4)`` and ``parallel_env(max_cycles=4)`` end their episodes there."""
    max_cycles_test(colorgrid)
    teams = {"num_leaders": 2, "num_followers": 3}
    max_cycles_test(SimpleNamespace(env=partial(env, **teams), parallel_env=partial(parallel_env, **teams)))


def test_max_cycles_is_the_horizon_and_a_horizon_that_disagrees_is_refused_in_one_line():
    for make in (parallel_env, env):
        assert make(max_cycles=7).unwrapped.config.horizon == 7
        assert make(max_cycles=7, horizon=7).unwrapped.config.horizon == 7
        assert make(EnvConfig(horizon=9), max_cycles=5).unwrapped.config.horizon == 5
        with pytest.raises(ValueError) as refused:
            make(max_cycles=7, horizon=8)
        assert str(refused.value) == ("max_cycles=7 and horizon=8 disagree: they are one setting (PettingZoo's name "
                                      "and ColorGrid's for the steps per episode); give one of them")
    e = parallel_env(max_cycles=3)
    e.reset(seed=0)
    for _ in range(3):
        *_, truncs, _ = e.step({a: 0 for a in e.agents})
    assert all(truncs.values()) and e.agents == []


def test_parallel_env_overrides_and_episode_end():
    e = parallel_env(horizon=3, reward_mode="individual")
    assert e.config.horizon == 3 and e.config.reward_mode == "individual"
    e.reset(seed=1)
    for _ in range(3):
        *_, truncs, infos = e.step({"leader": 0, "follower": 1})
    assert all(truncs.values()) and e.agents == []
    assert set(infos["follower"]) >= {"block_reward", "team_reward", "goal_pickup", "wrong_pickup", "goal_color"}
    with pytest.raises(RuntimeError, match="call reset"):
        e.step({"leader": 0, "follower": 0})
    with pytest.raises(ValueError, match="render_mode must be one of"):
        parallel_env(render_mode="window")


def test_rgb_frame_shows_blocks_agents_and_goal():
    e = BatchEnv(EnvConfig(), num_envs=1, seed=3)
    e.reset()
    frame = render_rgb(e.state, e.config, cell=16)
    assert frame.dtype == np.uint8 and frame.shape == (22 + 512 + 8, 512 + 8, 3)
    goal = int(e.state.goal[0])
    assert (frame[30, 1] == PALETTE[goal]).all(), "the border is the goal color"
    row, col = divmod(int(e.state.block_cell[0, 0]), 32)  # block 0 is red
    assert (frame[22 + 4 + row * 16 + 8, 4 + col * 16 + 8] == PALETTE[0]).all()
    for a, body in enumerate(([25, 25, 25], [255, 200, 0])):  # a dark leader, a yellow follower
        row, col = divmod(int(e.state.agent_cell[0, a]), 32)
        tile = frame[22 + 4 + row * 16: 22 + 4 + row * 16 + 16, 4 + col * 16: 4 + col * 16 + 16]
        assert (tile == body).all(axis=-1).sum() > 40, "agent body color fills its tile"


def test_ansi_view_marks_every_cell():
    e = BatchEnv(EnvConfig(), num_envs=1, seed=3)
    e.reset()
    text = render_ansi(e.state, e.config, color=False)
    lines = text.splitlines()
    assert lines[0].startswith("step 0/128  goal ")
    grid = "".join(lines[1:]).replace(" ", "")
    assert len(grid) == 1024 and grid.count("L") == 1 and grid.count("F") == 1
    assert grid.count("r") == grid.count("g") == grid.count("b") == 34
    colored = render_ansi(e.state, e.config, color=True)
    assert re.sub(r"\x1b\[[0-9;]*m", "", colored) == text
