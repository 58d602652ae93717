"""The ecosystem's trainers on ColorGrid's views, as ``examples/`` runs them: Stable-Baselines3 PPO through the
Gymnasium view, RLlib's multi-agent PPO through the PettingZoo view."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from tests.conftest import ROOT


def example(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sb3_ppo_learns_a_follower_that_takes_fewer_wrong_blocks_than_a_random_one():
    """2,048 steps of SB3's PPO beside A* (two rollouts of 8 envs): on the same 8 evaluation episodes, fewer wrong
    pickups than moving at random (the first thing a follower learns: a wrong block costs the team)."""
    sb3 = example("sb3_follower")
    model = sb3.train(2048, seed=0)
    trained = sb3.evaluate(lambda obs: int(model.predict(obs, deterministic=True)[0]), episodes=8)
    random = sb3.evaluate(sb3.random_act(0), episodes=8)
    assert trained["wrong_pickups"] < random["wrong_pickups"], (trained, random)


@pytest.fixture
def ray_instance():
    import ray  # the examples extra (make test installs it)

    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    yield ray
    if started:
        ray.shutdown()


def test_rllib_multi_agent_ppo_trains_both_agents_for_two_iterations(ray_instance):
    rllib = example("rllib_ippo")
    algo = rllib.build({"horizon": 32}, batch=256, seed=0)
    try:
        weights = lambda agent: {k: np.array(v, copy=True) for k, v in algo.get_module(agent).get_state().items()}  # noqa: E731
        before = {a: weights(a) for a in ("leader", "follower")}
        for _ in range(2):
            result = algo.train()
        assert result["num_env_steps_sampled_lifetime"] == 512
        returns = rllib.episode_returns(result)
        assert set(returns) == {"leader", "follower"} and all(np.isfinite(list(returns.values())))
        for agent, old in before.items():
            new = weights(agent)
            assert old.keys() == new.keys() and any(not np.allclose(old[k], new[k]) for k in old), agent
    finally:
        algo.stop()
