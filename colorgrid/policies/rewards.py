"""What the reward of a step says about the goal: the reward each goal color predicts from the colors collected.

In ``shared`` mode every agent sees the team reward, the sum over every agent that collected a block in
the step (leaders and followers alike): under goal ``k`` each block of color ``k`` adds ``goal_reward``
and each other block ``-wrong_penalty * penalty_coef``. So the reward seen, beside the colors collected
(every pickup is visible on the board), tells exactly which goals are possible. In ``individual`` mode an
agent sees only its own block's reward.
"""

from __future__ import annotations

import numpy as np

from colorgrid.config import EnvConfig

REWARD_ATOL = 1e-4
"""Absolute tolerance when matching a predicted reward to the one seen (rewards arrive as float32)."""
REWARD_RTOL = 1e-5
"""Relative tolerance, for large rewards whose float32 rounding exceeds ``REWARD_ATOL``."""


def predicted_reward(picked: np.ndarray, config: EnvConfig, penalty_coef: float, agent_index: int) -> np.ndarray:
    """``[B, C]``: the unshaped reward agent ``agent_index`` would see under each goal color.

    picked: ``[B, A]`` colors collected last step (-1 none). Shared mode sums every agent's pickup;
    individual mode counts only the agent's own.
    """
    C = config.num_colors
    counted = picked if config.reward_mode == "shared" else picked[:, agent_index:agent_index + 1]
    goal = np.arange(C)[None, None, :]
    value = np.where(counted[:, :, None] == goal, config.goal_reward, -config.wrong_penalty * penalty_coef)
    return np.where(counted[:, :, None] >= 0, value, 0.0).sum(axis=1)  # [B, C]


def explains_reward(picked: np.ndarray, reward: np.ndarray, config: EnvConfig, penalty_coef: float,
                    agent_index: int) -> np.ndarray:
    """``[B, C]`` bool: which goal colors predict the reward seen (``reward [B]``) from the colors ``picked``."""
    predicted = predicted_reward(picked, config, penalty_coef, agent_index)
    return np.abs(predicted - reward[:, None]) < REWARD_ATOL + REWARD_RTOL * np.abs(reward[:, None])
