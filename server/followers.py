"""Follower pools: one policy instance serves every live game of the same kind, in one batched call."""

from __future__ import annotations

import sys
import time

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies import IdleFollower, make_policy
from colorgrid.policies.base import AgentInput


class FollowerPool:
    """A follower policy with one row ("slot") per concurrent game of one config.

    ``act`` runs the policy for any subset of slots in one call. ``fallback`` is the
    documented move used when inference misses its deadline: a step to a free
    neighbouring cell that collects nothing (the ``idle`` follower).
    """

    def __init__(self, name: str, config: EnvConfig, capacity: int, seed: int = 0):
        self.name = name
        self.config = config
        self.policy = make_policy(name, role="follower")
        if "torch" in sys.modules:  # a trained follower: one inference thread, so that torch's worker
            import torch  # threads never spin against the event loop and the replay saver

            torch.set_num_threads(1)
        self.policy.reset(config, capacity, agent_index=1, seed=seed)
        self.idle = IdleFollower()
        self.idle.reset(config, capacity, agent_index=1, seed=seed + 1)
        self.capacity = capacity
        self.free = list(range(capacity - 1, -1, -1))
        self.busy = False  # an inference call is still running (it may outlive its deadline)
        self.last_release = time.monotonic()

    def warm_up(self) -> None:
        """One call on a fresh board in a free slot, and one env step (loading the compiled kernel), so that
        the first real step is as fast as the rest."""
        from colorgrid.env import BatchEnv

        env = BatchEnv(self.config, num_envs=1, seed=0)
        obs, _ = env.reset()
        A = self.config.num_agents
        slot = self.acquire()
        try:
            self.act([AgentInput(observation=obs["observation"].copy(), goal_info=obs["goal_info"][:, 1].copy(),
                                 episode_start=np.ones(1, dtype=bool), prev_reward=np.zeros(1, dtype=np.float32),
                                 prev_picked_color=np.full((1, A), -1), prev_actions=np.full((1, A), -1),
                                 true_goal=env.state.goal.copy())], [slot])
        finally:
            self.release(slot)
        env.step(np.zeros((1, A), dtype=np.int64))

    def acquire(self) -> int:
        if not self.free:
            raise RuntimeError(f"follower pool {self.name!r} is full")
        return self.free.pop()

    def release(self, slot: int) -> None:
        self.free.append(slot)
        self.last_release = time.monotonic()

    def idle_for(self) -> float:
        """Seconds since the pool last served a game; 0 while any game uses it."""
        return time.monotonic() - self.last_release if len(self.free) == self.capacity else 0.0

    def act(self, inputs: list[AgentInput], slots: list[int]) -> tuple[np.ndarray, np.ndarray | None]:
        """Actions ``[n]`` and beliefs ``[n, C]`` (or None) for the games in ``slots``."""
        batch = stack_inputs(inputs)
        self.busy = True
        try:
            out = self.policy.act(batch, rows=np.asarray(slots))
        finally:
            self.busy = False
        return out.actions, out.goal_probs

    def fallback(self, inputs: list[AgentInput], slots: list[int]) -> np.ndarray:
        return self.idle.act(stack_inputs(inputs), rows=np.asarray(slots)).actions


def stack_inputs(inputs: list[AgentInput]) -> AgentInput:
    """Concatenate batch-of-one (or larger) inputs along the batch axis."""
    first = inputs[0]
    return AgentInput(
        observation=np.concatenate([i.observation for i in inputs]),
        goal_info=np.concatenate([i.goal_info for i in inputs]),
        episode_start=np.concatenate([i.episode_start for i in inputs]),
        prev_reward=np.concatenate([i.prev_reward for i in inputs]),
        prev_picked_color=np.concatenate([i.prev_picked_color for i in inputs]),
        prev_actions=np.concatenate([i.prev_actions for i in inputs]),
        penalty_coef=first.penalty_coef,
        true_goal=np.concatenate([i.true_goal for i in inputs]),
    )
