"""The views' infos keep to Gymnasium's and PettingZoo's conventions over an episode's end: a single env's and
an agent's infos hold no ``_``-prefixed key (Gymnasium reserves them for a vector env's masks), and a vector
env's ``_`` keys are exactly its masks, so that ``gymnasium.make_vec`` batches the single view into a proper
``final_info``."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import colorgrid

HORIZON = 5
TOTALS = ("episode_block_reward", "episode_goal_pickups", "episode_wrong_pickups")


def reserved(keys) -> list[str]:
    return [k for k in keys if str(k).startswith("_")]


@pytest.mark.parametrize("make", [
    lambda: colorgrid.gym_env(seat="follower", partners="astar", horizon=HORIZON),
    lambda: colorgrid.gym_env(seat="leader", flatten=True, horizon=HORIZON),
    lambda: colorgrid.gym_env(seat="follower_1", num_leaders=2, num_followers=2, horizon=HORIZON),
    lambda: gymnasium.make(colorgrid.GYM_ID, seat="follower", partners="astar", horizon=HORIZON),
], ids=["follower", "leader-flat", "team-seat", "gymnasium.make"])
def test_a_seats_infos_hold_no_reserved_key_over_two_episode_ends(make):
    env = make()
    for seed in (3, None):
        _, info = env.reset(seed=seed)
        assert reserved(info) == [] and set(info) == {"seed", "goal_color"}
        for t in range(HORIZON):
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            assert reserved(info) == [], (t, info)
        assert truncated and not terminated
        assert set(TOTALS) <= set(info), "the step that ends the episode reports its totals"


@pytest.mark.parametrize("fields", [{}, {"flatten": True, "num_leaders": 2, "num_followers": 3}])
def test_every_agents_infos_hold_no_reserved_key_in_the_parallel_and_aec_views(fields):
    parallel = colorgrid.parallel_env(horizon=HORIZON, **fields)
    _, infos = parallel.reset(seed=1)
    steps = 0
    while parallel.agents:
        assert set(infos) == set(parallel.agents)
        assert all(reserved(info) == [] for info in infos.values()), infos
        *_, infos = parallel.step({a: parallel.action_space(a).sample() for a in parallel.agents})
        steps += 1
    assert steps == HORIZON and all(reserved(info) == [] for info in infos.values()), infos

    aec = colorgrid.env(horizon=HORIZON, **fields)
    aec.reset(seed=1)
    for agent in aec.agent_iter():
        *_, terminated, truncated, info = aec.last()
        assert reserved(info) == [], (agent, info)
        aec.step(None if terminated or truncated else aec.action_space(agent).sample())
    assert all(reserved(info) == [] for info in aec.infos.values())


def masks_are_proper(infos: dict, num_envs: int) -> None:
    """Every ``_k`` of a vector env's infos (nested too) is the bool mask ``[num_envs]`` of a key ``k`` beside it."""
    for key, value in infos.items():
        if key.startswith("_"):
            assert key[1:] in infos and not key[1:].startswith("_"), f"{key!r} masks nothing"
            assert value.dtype == np.bool_ and value.shape == (num_envs,), key
        elif isinstance(value, dict):
            masks_are_proper(value, num_envs)


@pytest.mark.parametrize("mode", [AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP])
def test_gymnasiums_sync_vectorisation_of_the_seat_ends_episodes_with_proper_infos(mode):
    n = 2
    envs = gymnasium.make_vec(colorgrid.GYM_ID, num_envs=n, vectorization_mode="sync",
                              vector_kwargs={"autoreset_mode": mode}, seat="follower", partners="astar",
                              horizon=HORIZON)
    _, infos = envs.reset(seed=7)
    masks_are_proper(infos, n)
    block_reward = np.zeros(n)
    for t in range(HORIZON):
        _, _, _, truncated, infos = envs.step(envs.action_space.sample())
        masks_are_proper(infos, n)
        assert "__final_info" not in infos
        if t < HORIZON - 1:
            assert not truncated.any() and "final_info" not in infos and not set(TOTALS) & set(infos)
            block_reward += infos["block_reward"]
    assert truncated.all()
    if mode == AutoresetMode.SAME_STEP:  # the ended episodes' last step infos, totals included, in final_info
        assert infos["_final_info"].all() and infos["_final_obs"].all()
        final = infos["final_info"]
        assert reserved(set(final) - {f"_{k}" for k in final}) == []
        block_reward += final["block_reward"]
        assert np.array_equal(final["episode_block_reward"], block_reward)
        for key in TOTALS:
            assert final[f"_{key}"].all(), key
        assert set(infos) == {"final_info", "_final_info", "final_obs", "_final_obs", "seed", "_seed",
                              "goal_color", "_goal_color"}, "and the next episodes' reset infos"
    else:  # the ended episodes' last step infos as they are; the reset comes with the next step
        assert "final_info" not in infos and "_final_info" not in infos
        block_reward += infos["block_reward"]
        assert np.array_equal(infos["episode_block_reward"], block_reward)
        assert all(infos[f"_{key}"].all() for key in TOTALS)


def test_the_seat_vector_envs_reserved_keys_are_its_masks():
    n = 3
    envs = gymnasium.make_vec(colorgrid.GYM_ID, num_envs=n, seat="leader", horizon=HORIZON)  # its own entry point
    assert isinstance(envs.unwrapped, colorgrid.SeatVectorEnv)
    envs.reset(seed=0)
    for _ in range(HORIZON):
        *_, infos = envs.step(envs.action_space.sample())
        masks_are_proper(infos, n)
    assert infos["_final_info"].all() and set(TOTALS) <= set(infos["final_info"])
