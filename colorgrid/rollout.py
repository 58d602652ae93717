"""Run batches of episodes with two policies and keep everything a report or replay needs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.env import BatchEnv
from colorgrid.policies.base import Policy
from colorgrid.step_inputs import StepInputs


@dataclass
class EpisodeBatch:
    """B complete episodes of T = horizon steps. Agents are ordered leader, follower."""

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
    goal_probs: list  # per agent: [T, B, C] float32 belief when acting, or None
    state_hashes: np.ndarray | None  # [T + 1, B] str: state before each step and after the last

    @property
    def num_episodes(self) -> int:
        return int(self.seeds.shape[0])


def run_episodes(config: EnvConfig, leader: Policy, follower: Policy, num_episodes: int, seed: int,
                 record_hashes: bool = False) -> EpisodeBatch:
    """Play ``num_episodes`` episodes at once (env ``i`` seeded ``seed + i``)."""
    B, A, T = num_episodes, config.num_agents, config.horizon
    env = BatchEnv(config, num_envs=B, seed=seed, autoreset=False)
    obs, _ = env.reset()
    seeds = env.state.seed.copy()
    policies = (leader, follower)
    for i, policy in enumerate(policies):
        policy.reset(config, B, i, seed=seed)
    actions = np.zeros((T, B, A), dtype=np.int64)
    goal = np.zeros((T, B), dtype=np.int64)
    block_reward = np.zeros((T, B, A), dtype=np.float32)
    team_reward = np.zeros((T, B), dtype=np.float32)
    picked = np.full((T, B, A), -1, dtype=np.int64)
    switched = np.zeros((T, B), dtype=bool)
    probs: list = [None, None]
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
