"""The one interface every agent implements, scripted or learned."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from colorgrid.config import EnvConfig


@dataclass
class AgentInput:
    """What an agent may legitimately observe at one step, for a batch of B envs.

    The previous-step fields describe what everyone sees on the board and in the
    reward signal: which block vanished under which agent, and the reward this
    agent received (the team reward in ``shared`` mode).
    """

    observation: np.ndarray  # [B, P, H, W] uint8 planes (colors, leader, follower)
    goal_info: np.ndarray  # [B, C] float32 one-hot goal, zeros if hidden from this agent
    episode_start: np.ndarray  # [B] bool: first step of an episode (reset internal state)
    prev_reward: np.ndarray  # [B] float32: this agent's unshaped block reward last step (0 at start)
    prev_picked_color: np.ndarray  # [B, A] int64: color collected by each agent last step, -1 if none
    prev_actions: np.ndarray  # [B, A] int64: both agents' last actions, -1 at start
    penalty_coef: float = 1.0  # the env's current penalty coefficient
    true_goal: np.ndarray | None = None  # [B] privileged ground truth; only the oracle reads it


@dataclass
class PolicyOutput:
    actions: np.ndarray  # [B] int64
    goal_probs: np.ndarray | None = None  # [B, C] float: the agent's belief over the goal, or None


class Policy:
    """Base class: ``reset`` once for a batch, then ``act`` every step.

    Subclasses keep any memory (beliefs, LSTM state) as batched arrays and clear
    the rows flagged by ``episode_start``. ``act(inp, rows)`` may be given inputs
    for a subset of the batch: ``rows`` are their indices (all rows when None).
    This lets one policy serve many independent games (the play server).
    """

    name = "policy"
    has_belief = False

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        self.config = config
        self.num_envs = num_envs
        self.agent_index = agent_index
        self.seed = seed

    def act(self, inp: AgentInput, rows: np.ndarray | None = None) -> PolicyOutput:
        raise NotImplementedError

    def _rows(self, rows: np.ndarray | None) -> np.ndarray:
        return np.arange(self.num_envs) if rows is None else np.asarray(rows)

    def describe(self) -> dict:
        """How replays and reports name this agent."""
        return {"policy": self.name}
