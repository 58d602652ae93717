"""From the common policy input (``AgentInput``, numpy) to a network's tensors, one step at a time."""

from __future__ import annotations

import functools

import numpy as np
import torch

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput


def one_hot(values: np.ndarray, n: int) -> np.ndarray:
    """One-hot of ``values [...]`` over ``n`` classes; values outside ``[0, n)`` (none) give all zeros."""
    values = np.asarray(values)
    rows = np.where((values >= 0) & (values < n), values, n)  # n: the all-zeros row
    return _identity_and_none(n)[rows]


@functools.cache
def _identity_and_none(n: int) -> np.ndarray:
    """``[n + 1, n]``: the one-hot rows of ``0 .. n-1``, then a row of zeros (read only)."""
    rows = np.eye(n + 1, n, dtype=np.float32)
    rows.flags.writeable = False
    return rows


def cells_of(obs: np.ndarray, plane: int) -> np.ndarray:
    """``[B, 2]``: the (row, col) of the one cell set in ``obs[:, plane]`` (an agent's plane)."""
    B, W = obs.shape[0], obs.shape[3]
    flat = obs[:, plane].reshape(B, -1).argmax(axis=1)
    cells = np.empty((B, 2), dtype=flat.dtype)
    np.divmod(flat, W, out=(cells[:, 0], cells[:, 1]))
    return cells


def leader_progress(inp: AgentInput, env: EnvConfig) -> np.ndarray:
    """``[B, L * C]`` float32: for each leader and color, +1 if the leader's last move brought it nearer to the
    nearest block of that color (Manhattan distance on the board now), -1 if farther; 0 if neither, at an
    episode's start, after a stay, or if no block of that color is on the board.

    The cell it moved from is its cell now minus its last action's step (the board does not show a move
    that a wall or another agent blocked: it reads as made, unless that cell is off the grid). This is the
    evidence the Bayesian follower's leader model weighs: a leader heads for the goal color's blocks.
    """
    from colorgrid.env import ACTION_DELTAS
    from colorgrid.policies.grid import decode, manhattan_to_nearest

    H, W = env.height, env.width
    block_color, agent_cell = decode(inp.observation, env)
    out = np.zeros((len(agent_cell), env.num_leaders, env.num_colors), dtype=np.float32)
    for j, leader in enumerate(env.leaders):
        action = np.asarray(inp.prev_actions)[:, leader]
        step = np.where((action >= 0)[:, None], ACTION_DELTAS[np.clip(action, 0, len(ACTION_DELTAS) - 1)], 0)
        row, col = np.divmod(agent_cell[:, leader], W)
        row0, col0 = row - step[:, 0], col - step[:, 1]
        moved = (step != 0).any(axis=1) & (row0 >= 0) & (row0 < H) & (col0 >= 0) & (col0 < W)
        cells = np.stack([np.where(moved, row0 * W + col0, agent_cell[:, leader]), agent_cell[:, leader]], axis=1)
        d = manhattan_to_nearest(env, block_color, cells)  # [B, 2, C]: from the cell before, and now
        out[:, j] = np.where(moved[:, None], np.sign(d[:, 0] - d[:, 1]), 0)
    return out.reshape(len(agent_cell), -1)


def step_tensors(inp: AgentInput, env: EnvConfig, agent_index: int, device,
                 progress: bool = False, copy_obs: bool = True) -> dict[str, torch.Tensor]:
    """The tensors of one step for ``B`` envs, each with a leading time axis of 1; with ``progress`` the extras
    end with ``leader_progress`` (a network with ``net.leader_progress``). ``copy_obs=False``: on the CPU the
    ``obs`` tensor shares the observation's memory (for a caller that reads it before the env steps again)."""
    obs = inp.observation
    B = obs.shape[0]
    me = cells_of(obs, env.num_colors + agent_index)
    parts = [np.asarray(inp.prev_reward, dtype=np.float32).reshape(B, 1),
             one_hot(inp.prev_actions, env.num_actions).reshape(B, -1),
             one_hot(inp.prev_picked_color, env.num_colors).reshape(B, -1)]
    if progress:
        parts.append(leader_progress(inp, env))
    extras = np.concatenate(parts, axis=1)
    arrays = {"obs": np.array(obs, copy=True) if copy_obs else np.ascontiguousarray(obs), "me": me,
              "goal": np.array(inp.goal_info, dtype=np.float32), "extras": extras,
              "starts": np.array(inp.episode_start, dtype=bool)}  # each its own memory (but obs, if asked)
    tensors = {k: torch.from_numpy(v[None]) for k, v in arrays.items()}  # (numpy's new axis costs less than torch's)
    return tensors if torch.device(device).type == "cpu" else {k: v.to(device) for k, v in tensors.items()}


def rows_of_agents(steps: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Several agents' ``step_tensors`` as one batch, agent-major along the batch axis (``[1, k * B, ...]``):
    the rows of a network that those agents share. One agent's are returned as they are."""
    if len(steps) == 1:
        return steps[0]
    return {k: torch.cat([s[k] for s in steps], dim=1) for k in steps[0]}
