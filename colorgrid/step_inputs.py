"""What every agent may see of the previous step: the bookkeeping behind ``AgentInput``, in one place.

Rollouts, the trainer, the play server's games and its policy pools all keep the same
four things between steps (the reward each agent saw, the color each collected, everyone's
actions, which envs start an episode) and build each agent's ``AgentInput`` from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput


def reward_seen(config: EnvConfig, info: dict) -> np.ndarray:
    """``[B, A]`` float32: the unshaped reward each agent receives after a step: the team reward in
    ``shared`` mode, its own block reward otherwise (what ``AgentInput.prev_reward`` carries)."""
    if config.reward_mode == "shared":
        return np.repeat(info["team_reward"][:, None], config.num_agents, axis=1).astype(np.float32)
    return info["block_reward"].astype(np.float32)


@dataclass
class StepInputs:
    """The previous step of ``B`` envs, as every agent may see it."""

    config: EnvConfig
    reward: np.ndarray  # [B, A] float32: the unshaped reward each agent saw (``reward_seen``); 0 at a start
    picked_color: np.ndarray  # [B, A] int64: the color each agent collected, -1 if none or at a start
    actions: np.ndarray  # [B, A] int64: every agent's action, -1 at a start
    episode_start: np.ndarray  # [B] bool: the next step is an episode's first

    @classmethod
    def begin(cls, config: EnvConfig, num_envs: int) -> "StepInputs":
        """Every env at the start of an episode."""
        B, A = num_envs, config.num_agents
        return cls(config, np.zeros((B, A), dtype=np.float32), np.full((B, A), -1, dtype=np.int64),
                   np.full((B, A), -1, dtype=np.int64), np.ones(B, dtype=bool))

    def record(self, actions: np.ndarray, info: dict, done: np.ndarray | None = None) -> None:
        """After ``env.step(actions)``: remember what it showed. ``done [B]`` marks envs whose episode ended
        (with autoreset their next step starts a new one); None when no episode ended."""
        self.reward = reward_seen(self.config, info)
        self.picked_color = np.array(info["picked_color"], dtype=np.int64)
        self.actions = np.array(actions, dtype=np.int64)
        self.episode_start = np.zeros(len(self.actions), dtype=bool) if done is None else np.array(done, dtype=bool)

    def agent_input(self, obs: dict, agent: int, penalty_coef: float, true_goal: np.ndarray | None,
                    episode_start: np.ndarray | None = None) -> AgentInput:
        """Agent ``agent``'s input for the observations ``obs`` (``episode_start`` overrides the recorded one)."""
        return AgentInput(
            observation=obs["observation"], goal_info=obs["goal_info"][:, agent],
            episode_start=self.episode_start if episode_start is None else episode_start,
            prev_reward=self.reward[:, agent], prev_picked_color=self.picked_color, prev_actions=self.actions,
            penalty_coef=penalty_coef, true_goal=true_goal,
        )

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"reward": self.reward, "picked_color": self.picked_color, "actions": self.actions,
                "episode_start": self.episode_start}

    def load_state_dict(self, state: dict) -> None:
        for key, value in self.state_dict().items():
            setattr(self, key, np.asarray(state[key], dtype=value.dtype).copy())
