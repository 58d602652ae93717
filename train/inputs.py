"""From the common policy input (``AgentInput``, numpy) to a network's tensors, one step at a time."""

from __future__ import annotations

import numpy as np
import torch

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput


def one_hot(values: np.ndarray, n: int) -> np.ndarray:
    """One-hot of ``values [...]`` over ``n`` classes; values outside ``[0, n)`` (none) give all zeros."""
    out = np.zeros((*values.shape, n), dtype=np.float32)
    valid = (values >= 0) & (values < n)
    out[valid, values[valid]] = 1.0
    return out


def step_tensors(inp: AgentInput, env: EnvConfig, agent_index: int, device) -> dict[str, torch.Tensor]:
    """The tensors of one step for ``B`` envs, each with a leading time axis of 1."""
    obs = inp.observation
    B, _, H, W = obs.shape
    flat = obs[:, env.num_colors + agent_index].reshape(B, -1).argmax(axis=1)
    me = np.stack([flat // W, flat % W], axis=1)
    extras = np.concatenate([
        np.asarray(inp.prev_reward, dtype=np.float32).reshape(B, 1),
        one_hot(inp.prev_actions, env.num_actions).reshape(B, -1),
        one_hot(inp.prev_picked_color, env.num_colors).reshape(B, -1),
    ], axis=1)
    arrays = {"obs": obs, "me": me, "goal": inp.goal_info.astype(np.float32), "extras": extras,
              "starts": np.asarray(inp.episode_start, dtype=bool)}
    return {k: torch.as_tensor(np.array(v, copy=True))[None].to(device) for k, v in arrays.items()}


def rows_of_agents(steps: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Several agents' ``step_tensors`` as one batch, agent-major along the batch axis (``[1, k * B, ...]``):
    the rows of a network that those agents share. One agent's are returned as they are."""
    if len(steps) == 1:
        return steps[0]
    return {k: torch.cat([s[k] for s in steps], dim=1) for k in steps[0]}
