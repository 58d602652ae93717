"""RLlib's multi-agent PPO on the PettingZoo view's flat observations, with no connector added: the code
docs/ECOSYSTEM.md shows, run as it stands there."""

from __future__ import annotations

import numpy as np

from tests.documented import documented_code
from tests.test_examples import ray_instance  # noqa: F401  (the fixture: an in-process Ray of 2 CPUs)


def module_weights(algo, agent: str) -> dict:
    return {k: np.array(v, copy=True) for k, v in algo.get_module(agent).get_state().items()}


def test_rllib_ppo_trains_both_agents_on_the_flat_view_without_a_connector(ray_instance):  # noqa: F811
    (code,) = documented_code("docs/ECOSYSTEM.md", "tests/test_rllib_flat.py")
    assert "connector" not in code
    namespace: dict = {}
    exec(compile(code, "docs/ECOSYSTEM.md", "exec"), namespace)
    algo = namespace["algo"]
    try:
        for agent in ("leader", "follower"):
            space = algo.get_module(agent).observation_space
            assert space.shape == (5 * 32 * 32 + 3,) and space.dtype == np.float32, (agent, space)
        before = {a: module_weights(algo, a) for a in ("leader", "follower")}
        for _ in range(2):
            result = algo.train()
        assert result["num_env_steps_sampled_lifetime"] == 256
        assert set(result["env_runners"]["agent_episode_returns_mean"]) == {"leader", "follower"}
        for agent, old in before.items():
            new = module_weights(algo, agent)
            assert old.keys() == new.keys() and any(not np.allclose(old[k], new[k]) for k in old), agent
    finally:
        algo.stop()
