"""RLlib's multi-agent PPO trains the leader and the follower on ColorGrid's PettingZoo view (independent PPO).

``colorgrid.parallel_env()`` is a PettingZoo ``ParallelEnv``; RLlib wraps it as a ``MultiAgentEnv``
with its own ``ParallelPettingZooEnv``. Each agent's observation is a ``Dict`` (uint8 planes and the goal
one-hot), which RLlib's default networks do not take: the env-to-module pipeline needs RLlib's
``FlattenObservations(multi_agent=True)`` connector. Each agent gets its own module (policy id = agent
id), as in the paper's IPPO.

    pip install 'colorgrid[examples]'
    python examples/rllib_ippo.py --iterations 50

Prints each iteration's mean episode return per agent.
"""

from __future__ import annotations

import argparse

import colorgrid

ENV_NAME = "colorgrid_parallel"


def env_creator(env_config: dict):
    """RLlib's env maker: the PettingZoo view with ``env_config`` as EnvConfig fields, wrapped for RLlib."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    return ParallelPettingZooEnv(colorgrid.parallel_env(**env_config))


def flatten_observations(env, spaces, device):
    """The env-to-module connector: every agent's Dict observation flattened into one vector."""
    from ray.rllib.connectors.env_to_module import FlattenObservations

    return FlattenObservations(multi_agent=True)


def build(env_config: dict | None = None, batch: int = 2048, seed: int = 0):
    """A PPO ``Algorithm`` training one module per agent, on one local env runner (no extra processes)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.tune.registry import register_env

    register_env(ENV_NAME, env_creator)
    agents = colorgrid.parallel_env(**(env_config or {})).possible_agents
    config = (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_config or {})
        .env_runners(num_env_runners=0, env_to_module_connector=flatten_observations)
        .multi_agent(policies=set(agents), policy_mapping_fn=lambda agent_id, episode, **kwargs: agent_id)
        .training(train_batch_size_per_learner=batch, minibatch_size=min(256, batch), num_epochs=4, lr=3e-4)
        .debugging(seed=seed)
    )
    return config.build_algo()


def episode_returns(result: dict) -> dict[str, float]:
    """Each agent's mean episode return in an iteration's result (NaN before an episode has ended)."""
    per_agent = result.get("env_runners", {}).get("agent_episode_returns_mean", {})
    return {agent: float(value) for agent, value in per_agent.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=50)
    parser.add_argument("--batch", type=int, default=2048, help="env-steps per iteration (per agent)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import ray

    ray.init(include_dashboard=False, logging_level="WARNING")
    algo = build(batch=args.batch, seed=args.seed)
    try:
        for i in range(args.iterations):
            returns = episode_returns(algo.train())
            print(f"iteration {i + 1}: " + ", ".join(f"{a} {r:+.2f}" for a, r in sorted(returns.items())),
                  flush=True)
    finally:
        algo.stop()
        ray.shutdown()


if __name__ == "__main__":
    main()
