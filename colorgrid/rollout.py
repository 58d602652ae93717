"""Run batches of episodes with one policy per agent and keep everything a report or replay needs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies.base import Policy
from colorgrid.step_inputs import StepInputs


@dataclass
class EpisodeBatch:
    """B complete episodes of T = horizon steps. Agents are in index order (``config.agent_names``: the leaders,
    then the followers; 1:1: leader, follower)."""

    config: EnvConfig
    seeds: np.ndarray  # [B] uint64 episode seeds
    actions: np.ndarray  # [T, B, A] int64
    goal: np.ndarray  # [T, B] int64: goal when each action was chosen (before the step's switch)
    block_reward: np.ndarray  # [T, B, A] float32, unshaped
    team_reward: np.ndarray  # [T, B] float32
    picked_color: np.ndarray  # [T, B, A] int64, -1 if nothing collected
    goal_pickup: np.ndarray  # [T, B, A] bool
    wrong_pickup: np.ndarray  # [T, B, A] bool
    goal_switched: np.ndarray  # [T, B] bool: the goal switched at the end of the step
    goal_probs: list  # per agent (A entries): [T, B, C] float32 belief when acting, or None
    state_hashes: np.ndarray | None  # [T + 1, B] str: state before each step and after the last

    @property
    def num_episodes(self) -> int:
        return int(self.seeds.shape[0])


def run_episodes(config: EnvConfig, leader: Policy, follower: Policy, num_episodes: int, seed: int,
                 record_hashes: bool = False) -> EpisodeBatch:
    """A 1:1 team's ``run_team``: ``num_episodes`` episodes at once (env ``i`` seeded ``seed + i``)."""
    if not config.one_to_one:
        raise ValueError(f"run_episodes plays one leader and one follower; this config's team has "
                         f"{config.num_leaders} leader(s) and {config.num_followers} follower(s): use run_team")
    return run_team(config, [leader, follower], num_episodes, seed, record_hashes)


def run_team(config: EnvConfig, policies: Sequence[Policy], num_episodes: int, seed: int,
             record_hashes: bool = False) -> EpisodeBatch:
    """Play ``num_episodes`` episodes at once (env ``i`` seeded ``seed + i``), agent ``i`` acting by ``policies[i]``.

    ``policies`` holds one policy object per agent, in index order (the leaders, then the followers); each
    is reset with its agent index and ``seed``, so an object may not play two agents.
    """
    B, A, T = num_episodes, config.num_agents, config.horizon
    policies = list(policies)
    if len(policies) != A:
        raise ValueError(f"run_team needs one policy per agent {list(config.agent_names)}, got {len(policies)}")
    if len({id(p) for p in policies}) != A:
        raise ValueError("run_team needs a separate policy object for each agent (a policy keeps one agent's memory)")
    env = BatchEnv(config, num_envs=B, seed=seed, autoreset=False)
    obs, _ = env.reset()
    seeds = env.state.seed.copy()
    for i, policy in enumerate(policies):
        policy.reset(config, B, i, seed=seed)
    for policy in policies:
        policy.see_team(policies)
    actions = np.zeros((T, B, A), dtype=np.int64)
    goal = np.zeros((T, B), dtype=np.int64)
    block_reward = np.zeros((T, B, A), dtype=np.float32)
    team_reward = np.zeros((T, B), dtype=np.float32)
    picked = np.full((T, B, A), -1, dtype=np.int64)
    switched = np.zeros((T, B), dtype=bool)
    probs: list = [None] * A
    hashes = np.empty((T + 1, B), dtype=object) if record_hashes else None
    last = StepInputs.begin(config, B)
    for t in range(T):
        goal[t] = env.state.goal
        if record_hashes:
            hashes[t] = [env.state.state_hash(i) for i in range(B)]
        for i, policy in enumerate(policies):
            out = policy.act(last.agent_input(obs, i, env.penalty_coef, env.state.goal.copy()))
            actions[t, :, i] = out.actions
            if out.goal_probs is not None:
                if probs[i] is None:
                    probs[i] = np.zeros((T, B, config.num_colors), dtype=np.float32)
                probs[i][t] = out.goal_probs
        obs, rewards, _, _, info = env.step(actions[t])
        block_reward[t] = info["block_reward"]
        team_reward[t] = info["team_reward"]
        picked[t] = info["picked_color"]
        switched[t] = info["goal_switched"]
        last.record(actions[t], info)
    if record_hashes:
        hashes[T] = [env.state.state_hash(i) for i in range(B)]
    goal_hit = picked == goal[:, :, None]
    return EpisodeBatch(config, seeds, actions, goal, block_reward, team_reward, picked,
                        (picked >= 0) & goal_hit, (picked >= 0) & ~goal_hit, switched, probs, hashes)
