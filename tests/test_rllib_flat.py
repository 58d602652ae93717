"""RLlib's multi-agent PPO on the PettingZoo view's flat observations, with no connector added: the code
docs/ECOSYSTEM.md shows, run as it stands there."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import ROOT
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


def test_on_the_dict_view_rllib_stops_with_the_error_the_env_card_points_to_flatten_for(ray_instance):  # noqa: F811
    """The documented block with ``flatten=True`` left out: RLlib's default modules refuse the Dict, with the
    message docs/ENV_CARD.md quotes beside ``flatten=True`` for a reader who meets it."""
    (code,) = documented_code("docs/ECOSYSTEM.md", "tests/test_rllib_flat.py")
    message = "No default encoder config for obs space=Dict"
    assert message in (ROOT / "docs" / "ENV_CARD.md").read_text()
    dict_view = code.replace("colorgrid.parallel_env(flatten=True, **cfg)", "colorgrid.parallel_env(**cfg)")
    assert dict_view != code
    with pytest.raises(ValueError, match=message):
        exec(compile(dict_view.replace("colorgrid_flat", "colorgrid_dict"), "docs/ECOSYSTEM.md", "exec"), {})
